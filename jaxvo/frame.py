"""RGB-D frames: the Frame pytree and host-side input validation.

A :class:`Frame` holds

* ``intensity``: (H, W) float32 luminance on the 0-255 scale (the RANSAC
  luminance threshold is in these units);
* ``depth``: (H, W) float32 metres along the optical axis, 0 = invalid.

:func:`make_frame` builds one from what readers produce (uint8 colour or grey,
uint16 depth in sensor units, or float metres) and checks it, raising a
``ValueError`` that names the problem (and the source, when given) instead of
letting a bad array reach jit-compiled code. Two things it cannot guess are explicit:
the colour order (``color_order="bgr"`` or :meth:`Frame.from_cv2` for ``cv2.imread``
images) and the depth scale of integer depth (``depth_scale``; without it integer depth is
an error naming the scale that fits, :func:`suggest_depth_scale`, shared with the
sequence readers' check of a recording's first frame).
"""
from __future__ import annotations

from typing import NamedTuple, Optional

import numpy as np

from jaxvo.validation import check_values, choice, number

__all__ = ["Frame", "make_frame", "undistort", "undistort_images", "luminance", "validate_pair", "validate_frame", "check_frame",
           "has_depth",
           "suggest_depth_scale",
           "DEPTH_UNIT_LIMIT", "PLAUSIBLE_DEPTH", "COMMON_DEPTH_SCALES", "COLOR_ORDERS"]


#: metres: no RGB-D sensor reads farther, so depth beyond it everywhere is in another unit
#: (millimetres, sensor units) and is refused rather than estimated on as "too far"
DEPTH_UNIT_LIMIT = 100.0
#: where a median valid depth (metres) is taken as plausible for an RGB-D camera
PLAUSIBLE_DEPTH = (0.2, 10.0)
#: depth scales of common sensors and formats (sensor value / scale = metres): millimetres
#: (Kinect v2, RealSense, Redwood), TUM / Bonn / ETH3D PNGs, 0.1 mm, 0.25 mm, centimetres, metres
COMMON_DEPTH_SCALES = (1000.0, 5000.0, 10000.0, 4000.0, 100.0, 1.0)
#: channel orders of colour images: "rgb" (imageio, PIL, matplotlib), "bgr" (OpenCV's cv2.imread)
COLOR_ORDERS = ("rgb", "bgr")
_ORDER_RULE = {"color_order": choice(*COLOR_ORDERS)}
_SCALE_RULE = {"depth_scale": number(0, lo_open=True, none_means="float depth in metres")}


def suggest_depth_scale(raw_median: float, exclude: Optional[float] = None) -> float:
    """The depth scale (sensor value / scale = metres) to suggest for depth whose median valid raw
    value is ``raw_median``: of :data:`COMMON_DEPTH_SCALES` (but ``exclude``, the scale that
    failed) the one that puts the median inside :data:`PLAUSIBLE_DEPTH`, nearest 2 m (a typical
    indoor median); if none does, the scale that puts it at 2 m."""
    lo, hi = PLAUSIBLE_DEPTH
    fits = [c for c in COMMON_DEPTH_SCALES if c != exclude and lo <= raw_median / c <= hi]
    return min(fits, key=lambda c: abs(np.log(raw_median / c / 2.0))) if fits else raw_median / 2.0


class Frame(NamedTuple):
    """One RGB-D frame: intensity (H, W) float32 on 0-255, depth (H, W) float32 metres (0 = invalid).

    mask: optional (H, W) bool, True where the pixel may be used (as OpenCV's
    ``OdometryFrame`` mask, e.g. False on a detector's people); None = every pixel.
    It applies where the frame is the reference of an estimate.

    time, depth_time: optional capture times (seconds, one clock) of the colour image and of the
    depth image, which a Kinect-class sensor takes apart (up to half a frame); the sequence
    readers set both from the recording's timestamps. The odometry can move the depth to the
    colour image's time (``TrackConfig.retime_depth``); None (or equal times): taken together.
    """
    intensity: np.ndarray
    depth: np.ndarray
    mask: Optional[np.ndarray] = None
    time: Optional[float] = None
    depth_time: Optional[float] = None

    @property
    def shape(self):
        return tuple(self.intensity.shape)

    @classmethod
    def from_cv2(cls, image, depth, depth_scale: Optional[float] = None, **kwargs) -> "Frame":
        """:func:`make_frame` of a colour image in OpenCV's BGR order (``cv2.imread``,
        ``cv2.VideoCapture``): ``Frame.from_cv2(cv2.imread(c), cv2.imread(d, cv2.IMREAD_UNCHANGED), 5000)``.
        ``kwargs``: ``source``, ``mask``."""
        return make_frame(image, depth, depth_scale, color_order="bgr", **kwargs)


def luminance(image: np.ndarray, order: str = "rgb") -> np.ndarray:
    """(H, W, 3) colour (or (H, W) grey) -> (H, W) float32 luminance, ITU-R BT.601 weights.

    ``order`` is the channel order of ``image``: "rgb", or "bgr" for what
    ``cv2.imread`` returns. uint16 colour is rescaled to 0-255.
    """
    check_values({"color_order": order}, _ORDER_RULE, "luminance")
    img = np.asarray(image)
    scale = 255.0 / 65535.0 if img.dtype == np.uint16 else 1.0
    img = img.astype(np.float32) * np.float32(scale)
    if img.ndim == 2:
        return img
    if img.ndim == 3 and img.shape[2] in (3, 4):
        c = img[..., :3]
        if order == "bgr":
            c = c[..., ::-1]
        return (0.299 * c[..., 0] + 0.587 * c[..., 1] + 0.114 * c[..., 2]).astype(np.float32)
    raise ValueError(f"colour image must be (H, W) or (H, W, 3), got shape {img.shape}")


def make_frame(image, depth, depth_scale: Optional[float] = None, *, color_order: str = "rgb",
               source: str = "", mask=None) -> Frame:
    """Build and validate a Frame.

    Args:
      image: (H, W, 3) colour or (H, W) grey; uint8 (0-255), uint16, or float already on 0-255.
      depth: (H, W) depth. Integer depth (sensor units, e.g. uint16 PNGs) needs ``depth_scale``:
        value / depth_scale = metres (5000 for TUM, Bonn and ETH3D PNGs, 1000 for millimetres);
        without it the ValueError names the scale that fits. Float depth is metres, or is
        divided by ``depth_scale`` when one is given. NaN, inf and negative values become 0
        (invalid). Depth without any valid pixel (a covered sensor, or a scene inside its minimum
        range) makes a frame too, one without depth (:func:`has_depth` False): the odometry holds
        its pose, and :func:`jaxvo.estimate_motion` refuses it.
      color_order: "rgb" (default), or "bgr" for OpenCV images (``cv2.imread``); the same as
        :meth:`Frame.from_cv2`. Grey images ignore it.
      source: a name (e.g. the file) to put in error messages.
      mask: optional (H, W) usable-pixel mask (nonzero = usable), see :class:`Frame`.

    Raises:
      ValueError: wrong shapes or dtypes, mismatched sizes, an unknown color_order, integer
        depth without depth_scale, depth whose range says the scale is wrong (e.g. millimetres
        passed as metres), or a float image on [0, 1] (not 0-255).
    """
    where = f"{source}: " if source else ""
    check_values({"color_order": color_order}, _ORDER_RULE, f"{where}make_frame")
    check_values({"depth_scale": depth_scale}, _SCALE_RULE, f"{where}make_frame")
    img = np.asarray(image)
    d = np.asarray(depth)
    if img.dtype == object or d.dtype == object:
        raise ValueError(f"{where}image and depth must be numeric arrays")
    if not (np.issubdtype(img.dtype, np.number) and np.issubdtype(d.dtype, np.number)):
        raise ValueError(f"{where}image and depth must be numeric arrays, got {img.dtype} and {d.dtype}")
    if d.ndim != 2:
        raise ValueError(f"{where}depth must be a 2-D (H, W) array, got shape {d.shape}")
    if img.ndim not in (2, 3):
        raise ValueError(f"{where}image must be (H, W) or (H, W, 3), got shape {img.shape}")
    if img.shape[:2] != d.shape:
        raise ValueError(f"{where}image size {img.shape[1]}x{img.shape[0]} does not match "
                         f"depth size {d.shape[1]}x{d.shape[0]}")
    inten = luminance(img, color_order)
    z = d.astype(np.float32)
    if depth_scale is not None:
        z = z / np.float32(depth_scale)
    z = np.where(np.isfinite(z) & (z > 0), z, 0.0).astype(np.float32)
    valid = z > 0
    # without a valid pixel there is no median to check the scale by: the frame has no depth
    med = float(np.median(z[valid])) if valid.any() else 0.0
    if valid.any() and depth_scale is None and np.issubdtype(d.dtype, np.integer):
        s = suggest_depth_scale(med)
        raise ValueError(f"{where}depth is {d.dtype} (sensor units) and no depth_scale was given: pass "
                         f"depth_scale={s:g} (value / {s:g} = metres: median {med / s:.2f} m); 5000 for TUM, "
                         f"Bonn and ETH3D PNGs, 1000 for millimetres")
    if med > DEPTH_UNIT_LIMIT:
        raw = med * (1.0 if depth_scale is None else float(depth_scale))
        s = suggest_depth_scale(raw, exclude=depth_scale)
        raise ValueError(f"{where}depth looks like it has the wrong scale: median {med:.1f} m "
                         f"(expected metres; pass depth_scale={s:g}, which gives {raw / s:.2f} m)")
    if not np.isfinite(inten).all():
        raise ValueError(f"{where}intensity contains NaN or inf")
    if np.issubdtype(img.dtype, np.floating) and 0.0 < float(inten.max()) <= 1.0:
        # the residual thresholds (Config.thresh_lum, 30) are grey levels of 0-255: a [0, 1] image
        # would make every pixel an inlier
        raise ValueError(f"{where}image is floating point with values in [0, 1]; jaxvo reads colour on 0-255 "
                         f"(uint8, uint16, or float already on 0-255): pass image * 255")
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != d.shape:
            raise ValueError(f"{where}mask size {mask.shape[1] if mask.ndim > 1 else mask.shape} does not match "
                             f"the image size {d.shape[1]}x{d.shape[0]}")
        mask = mask != 0
    return Frame(np.ascontiguousarray(inten, dtype=np.float32), np.ascontiguousarray(z), mask)


_MAPS: dict = {}   # (intrinsics, size, lens) -> undistortion_map


def _undistortion_maps(camera, lens):
    """The cached :func:`jaxvo.camera.undistortion_map` of ``camera`` and ``lens``."""
    from jaxvo.camera import undistortion_map

    key = (float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy), camera.width, camera.height,
           tuple(float(c) for c in lens))
    if key not in _MAPS:
        if len(_MAPS) > 8:
            _MAPS.clear()
        # float maps: OpenCV's fixed-point maps (convertMaps) would floor, not round, the nearest
        # pixel, shifting depth by half a pixel against the intensity
        _MAPS[key] = undistortion_map(camera, lens)
    return _MAPS[key]


def _remap(image, maps, linear: bool):
    import cv2
    if linear:
        return cv2.remap(image, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return cv2.remap(image, maps[0], maps[1], cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def undistort(frame: Frame, camera, lens) -> Frame:
    """``frame`` as the pinhole ``camera`` would image it, for a recording made through ``lens``
    (:class:`jaxvo.camera.Lens`; the images are (camera.height, camera.width)): each pixel reads the
    distorted images where :func:`jaxvo.camera.undistortion_map` puts it. Intensity bilinear
    (edge pixels repeated beyond the border), depth and mask nearest (a depth is never blended
    across an edge; beyond the border: depth 0, i.e. invalid, mask False). A pinhole lens
    returns ``frame`` itself."""
    if lens.is_pinhole:
        return frame
    maps = _undistortion_maps(camera, lens)
    intensity = _remap(np.asarray(frame.intensity, np.float32), maps, True)
    depth = _remap(np.asarray(frame.depth, np.float32), maps, False)
    mask = None if frame.mask is None else _remap(np.asarray(frame.mask).astype(np.uint8), maps, False) != 0
    return frame._replace(intensity=intensity, depth=depth, mask=mask)


def undistort_images(color, depth, camera, lens):
    """(color, depth) images (any dtypes; (H, W, C) and (H, W)) as the pinhole ``camera`` would
    image them through ``lens``, resampled as :func:`undistort` does (colour bilinear, depth
    nearest, 0 beyond the border); a pinhole lens returns them as they are."""
    if lens.is_pinhole:
        return color, depth
    maps = _undistortion_maps(camera, lens)
    return _remap(np.asarray(color), maps, True), _remap(np.asarray(depth), maps, False)


def check_frame(frame, what: str = "frame") -> None:
    """Raise ValueError unless ``frame`` is a Frame (anything with ``intensity`` and ``depth``),
    naming ``what`` and, for a ``(timestamp, Frame)`` pair (what iterating a sequence yields),
    how to pass the frames."""
    if hasattr(frame, "intensity") and hasattr(frame, "depth"):
        return
    hint = ""
    if isinstance(frame, tuple) and len(frame) == 2 and hasattr(frame[1], "intensity"):
        hint = ("; iterating a sequence yields (timestamp, Frame) pairs: pass the frames, "
                "e.g. (f for _, f in seq)")
    raise ValueError(f"{what} must be a jaxvo.Frame (intensity, depth; see jaxvo.make_frame), "
                     f"got {type(frame).__name__}{hint}")


def validate_pair(ref: Frame, cur: Frame, camera) -> None:
    """Check two frames and a camera agree; raise ValueError naming the problem.

    Only concrete (NumPy or committed JAX) arrays can be checked; traced
    arrays inside a user's jit skip the value checks.
    """
    for name, f in (("reference", ref), ("current", cur)):
        _check_images(f, f"{name} frame")
    if tuple(ref.intensity.shape) != tuple(cur.intensity.shape):
        raise ValueError(f"frames differ in size: reference {tuple(ref.intensity.shape)}, "
                         f"current {tuple(cur.intensity.shape)}")
    _check_camera(ref, camera)
    for name, f in (("reference", ref), ("current", cur)):
        _check_depth(f, f"{name} frame")


def validate_frame(frame: Frame, camera, what: str = "frame") -> None:
    """:func:`validate_pair`'s checks of one frame against a camera; ValueError naming ``what``."""
    _check_images(frame, what)
    _check_camera(frame, camera)
    _check_depth(frame, what)


def _check_images(f, what: str) -> None:
    check_frame(f, what)
    i, d = f.intensity, f.depth
    if not (hasattr(i, "ndim") and hasattr(d, "ndim")):
        raise ValueError(f"{what}: intensity and depth must be arrays (NumPy or JAX; see jaxvo.make_frame), got "
                         f"{type(i).__name__} and {type(d).__name__}")
    if i.ndim != 2 or d.ndim != 2:
        raise ValueError(f"{what}: intensity and depth must be 2-D (H, W), got shapes "
                         f"{getattr(i, 'shape', None)} and {getattr(d, 'shape', None)}")
    if tuple(i.shape) != tuple(d.shape):
        raise ValueError(f"{what}: intensity {tuple(i.shape)} and depth {tuple(d.shape)} differ in size")
    for arr, field in ((i, "intensity"), (d, "depth")):
        if not np.issubdtype(np.dtype(arr.dtype), np.floating):
            raise ValueError(f"{what}: {field} must be floating point (got {arr.dtype}); "
                             f"build frames with jaxvo.make_frame")


def _check_camera(f, camera) -> None:
    h, w = f.intensity.shape
    if (camera.width, camera.height) != (w, h):
        raise ValueError(f"camera intrinsics are for {camera.width}x{camera.height} but the images are {w}x{h}")


def has_depth(frame, what: str = "frame") -> bool:
    """Whether ``frame`` has a valid depth pixel (in (0, :data:`DEPTH_UNIT_LIMIT`] m); True for a
    frame whose depth is traced (inside a user's jit: its values cannot be read). A frame without
    one (a covered sensor, a scene inside its minimum range) cannot take part in an estimate.

    Raises ValueError naming ``what`` where the depth has no valid pixel because it is in another
    unit (finite values, all beyond the limit: millimetres?), not because the sensor saw nothing."""
    try:
        d = np.asarray(frame.depth)
    except Exception:  # a tracer: cannot check values
        return True
    if _has_valid_depth(d):
        return True
    beyond = d[(d > DEPTH_UNIT_LIMIT) & (d < np.inf)]
    if beyond.size:
        raise ValueError(f"{what}: depth has no pixel within 0-{DEPTH_UNIT_LIMIT:g} m (median "
                         f"{float(np.median(beyond)):.4g}): a Frame's depth is metres; millimetres? "
                         f"jaxvo.make_frame(image, depth, depth_scale=1000) converts")
    return False


def _check_depth(f, what: str) -> None:
    if not has_depth(f, what):
        raise ValueError(f"{what}: depth has no valid pixel (all zero, negative or NaN)")


def _has_valid_depth(d: np.ndarray) -> bool:
    """Whether (H, W) depth ``d`` has a pixel in (0, :data:`DEPTH_UNIT_LIMIT`] metres. Every 8th
    row first: a frame with depth nearly always has one there, and the whole test costs 0.4 ms
    at 640x480, a per-pair cost of every estimate."""
    def valid(x):
        return bool(np.any((x > 0) & (x <= DEPTH_UNIT_LIMIT)))   # NaN fails both comparisons
    return valid(d[::8]) or valid(d)
