"""RGB-D frames: the Frame pytree and host-side input validation.

A :class:`Frame` holds

* ``intensity``: (H, W) float32 luminance on the 0-255 scale (the RANSAC
  luminance threshold is in these units);
* ``depth``: (H, W) float32 metres along the optical axis, 0 = invalid.

:func:`make_frame` builds one from what readers produce (uint8 colour or grey,
uint16 depth in sensor units, or float metres) and checks it, raising a
``ValueError`` that names the problem (and the source, when given) instead of
letting a bad array reach jit-compiled code.
"""
from __future__ import annotations

from typing import NamedTuple, Optional

import numpy as np

__all__ = ["Frame", "make_frame", "luminance", "validate_pair"]


class Frame(NamedTuple):
    """One RGB-D frame: intensity (H, W) float32 on 0-255, depth (H, W) float32 metres (0 = invalid).

    mask: optional (H, W) bool, True where the pixel may be used (as OpenCV's
    ``OdometryFrame`` mask, e.g. False on a detector's people); None = every pixel.
    It applies where the frame is the reference of an estimate.
    """
    intensity: np.ndarray
    depth: np.ndarray
    mask: Optional[np.ndarray] = None

    @property
    def shape(self):
        return tuple(self.intensity.shape)


def luminance(image: np.ndarray, order: str = "rgb") -> np.ndarray:
    """(H, W, 3) colour (or (H, W) grey) -> (H, W) float32 luminance, ITU-R BT.601 weights.

    ``order`` is the channel order of ``image``: "rgb", or "bgr" for what
    ``cv2.imread`` returns. uint16 colour is rescaled to 0-255.
    """
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
      depth: (H, W) depth. Integer depth is divided by ``depth_scale`` (default 5000, the TUM
        factor: value / 5000 = metres); float depth is taken as metres unless ``depth_scale``
        is given. NaN, inf and negative values become 0 (invalid).
      source: a name (e.g. the file) to put in error messages.
      mask: optional (H, W) usable-pixel mask (nonzero = usable), see :class:`Frame`.

    Raises:
      ValueError: wrong shapes or dtypes, mismatched sizes, no valid depth at all, or depth
        whose range says the scale is wrong (e.g. millimetres passed as metres).
    """
    where = f"{source}: " if source else ""
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
    if np.issubdtype(d.dtype, np.integer):
        z = d.astype(np.float32) / np.float32(5000.0 if depth_scale is None else depth_scale)
    else:
        z = d.astype(np.float32)
        if depth_scale is not None:
            z = z / np.float32(depth_scale)
    z = np.where(np.isfinite(z) & (z > 0), z, 0.0).astype(np.float32)
    valid = z > 0
    if not valid.any():
        raise ValueError(f"{where}depth has no valid pixel (all zero, negative or NaN)")
    med = float(np.median(z[valid]))
    if med > 100.0:
        raise ValueError(f"{where}depth looks like it has the wrong scale: median {med:.1f} m "
                         f"(expected metres; pass depth_scale, e.g. 1000 for millimetres)")
    if not np.isfinite(inten).all():
        raise ValueError(f"{where}intensity contains NaN or inf")
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != d.shape:
            raise ValueError(f"{where}mask size {mask.shape[1] if mask.ndim > 1 else mask.shape} does not match "
                             f"the image size {d.shape[1]}x{d.shape[0]}")
        mask = mask != 0
    return Frame(np.ascontiguousarray(inten, dtype=np.float32), np.ascontiguousarray(z), mask)


def validate_pair(ref: Frame, cur: Frame, camera) -> None:
    """Check two frames and a camera agree; raise ValueError naming the problem.

    Only concrete (NumPy or committed JAX) arrays can be checked; traced
    arrays inside a user's jit skip the value checks.
    """
    for name, f in (("reference", ref), ("current", cur)):
        if not hasattr(f, "intensity") or not hasattr(f, "depth"):
            raise ValueError(f"{name} frame must be a jaxvo.Frame (intensity, depth), got {type(f).__name__}")
        i, d = f.intensity, f.depth
        if getattr(i, "ndim", None) != 2 or getattr(d, "ndim", None) != 2:
            raise ValueError(f"{name} frame: intensity and depth must be 2-D (H, W), got shapes "
                             f"{getattr(i, 'shape', None)} and {getattr(d, 'shape', None)}")
        if tuple(i.shape) != tuple(d.shape):
            raise ValueError(f"{name} frame: intensity {tuple(i.shape)} and depth {tuple(d.shape)} differ in size")
        for arr, what in ((i, "intensity"), (d, "depth")):
            if not np.issubdtype(np.dtype(arr.dtype), np.floating):
                raise ValueError(f"{name} frame: {what} must be floating point (got {arr.dtype}); "
                                 f"build frames with jaxvo.make_frame")
    if tuple(ref.intensity.shape) != tuple(cur.intensity.shape):
        raise ValueError(f"frames differ in size: reference {tuple(ref.intensity.shape)}, "
                         f"current {tuple(cur.intensity.shape)}")
    h, w = ref.intensity.shape
    if (camera.width, camera.height) != (w, h):
        raise ValueError(f"camera intrinsics are for {camera.width}x{camera.height} but the images are {w}x{h}")
    for name, f in (("reference", ref), ("current", cur)):
        try:
            d = np.asarray(f.depth)
        except Exception:  # a tracer: cannot check values
            continue
        if not _has_valid_depth(d):
            raise ValueError(f"{name} frame: depth has no valid pixel (all zero, negative or NaN)")


def _has_valid_depth(d: np.ndarray) -> bool:
    """Whether (H, W) depth ``d`` has a finite positive pixel. Every 8th row first: a frame with
    depth nearly always has one there, and the whole test costs 0.4 ms at 640x480, a per-pair
    cost of every estimate."""
    def valid(x):
        return bool(np.any((x > 0) & (x < np.inf)))   # NaN fails both comparisons
    return valid(d[::8]) or valid(d)
