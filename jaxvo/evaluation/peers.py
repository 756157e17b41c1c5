"""Peer RGB-D odometries run on exactly the inputs jaxvo uses.

Each peer takes two :class:`~jaxvo.frame.Frame` objects (``ref`` first /
earlier, ``cur`` second / later) and a :class:`~jaxvo.camera.Camera`, applies
the same depth cut-off (``max_depth``, metres; depth above it becomes invalid,
0) and returns a :class:`PeerResult` whose ``T_cur_ref`` follows jaxvo's
convention: a (4, 4) float64 rigid transform that maps 3-D points in the
reference camera's frame into the current camera's frame (x right, y down,
z forward). Ground truth for a pair of TUM poses ``T_world_cam`` is
``inv(T_world_cur) @ T_world_ref``.

Peers:

* :class:`OpenCVOdometry` -- ``cv2.Odometry`` of OpenCV 5 (``kind`` "rgb":
  photometric, "depth": ICP, "rgbd": both). Always available with the
  OpenCV jaxvo depends on (:func:`opencv_available` says whether the installed
  build has it).
* :class:`Open3DOdometry` -- ``open3d.pipelines.odometry.compute_rgbd_odometry``
  with the colour term (Steinbruecker et al.) or the hybrid term (Park et al.).
  Optional: ``pip install jaxvo[peers]``; :func:`open3d_available` says
  whether it imports. This module never imports open3d at import time.

Conversions from a Frame (checked against the installed builds):

* OpenCV wants an 8-bit grey image (``CV_8UC1``; BGR is converted with the
  same BT.601 weights jaxvo uses, so we round/clip our luminance to uint8) and
  ``CV_32FC1`` depth. Its OpenCV 5.0 frame preparation silently divides depth
  by 5000 when the image's maximum exceeds 10 ("probably raw TUM units"), so a
  metric depth map with a far wall at 10.5 m would be shrunk 5000x. With the
  4 m cut-off applied first this never triggers; when ``max_depth`` > 10 the
  wrapper hands OpenCV depth x 5000 instead, which that rescale maps back to
  metres exactly (up to float32 rounding). The returned ``Rt`` satisfies
  ``Rt * p_src = p_dst`` with src = ref, dst = cur, i.e. it already is
  ``T_cur_ref`` (verified on TUM fr2/desk pairs against ground truth).
* Open3D gets float32 intensity on 0-1 (our luminance / 255, so no second grey
  conversion) and float32 depth in metres; its result maps source (ref) points
  into the target (cur) frame, i.e. ``T_cur_ref`` as well.

``seconds`` is the wall time of the whole call: input conversion, the peer's
frame preparation (pyramids, gradients, normals) and the solve, for both
frames of the pair -- the same work jaxvo's per-pair estimate does. Objects
that do not depend on the frames (settings, the odometry object, intrinsics,
options, Jacobian term) are built once in the constructor.
"""
from __future__ import annotations

import functools
import importlib
import time
from typing import NamedTuple, Optional, Sequence

import numpy as np

from jaxvo.camera import Camera

__all__ = [
    "PeerResult", "OpenCVOdometry", "Open3DOdometry", "opencv_available", "open3d_available",
    "PEER_NAMES", "available_peers", "make_peer", "cut_depth",
]


class PeerResult(NamedTuple):
    """Result of one peer on one frame pair.

    T_cur_ref: (4, 4) float64, maps points in the reference camera frame into the current one
      (identity when ``success`` is False).
    success: the peer's own success flag.
    seconds: wall time of the call (conversion + preparation + solve).
    """
    T_cur_ref: np.ndarray
    success: bool
    seconds: float


# --------------------------------------------------------------------------- availability

def opencv_available() -> bool:
    """True when the installed OpenCV has the OpenCV 5 ``cv2.Odometry`` RGB-D API."""
    try:
        import cv2
    except Exception:  # pragma: no cover - cv2 is a hard dependency
        return False
    return all(hasattr(cv2, n) for n in ("Odometry", "OdometryFrame", "OdometrySettings",
                                         "OdometryType_RGB", "OdometryType_DEPTH",
                                         "OdometryType_RGB_DEPTH"))


@functools.lru_cache(maxsize=None)
def _open3d_import():
    """Import open3d once; returns (module or None, error message or None)."""
    try:
        return importlib.import_module("open3d"), None
    except Exception as e:  # ImportError, or OSError for a missing system library (libusb)
        return None, f"{type(e).__name__}: {e}"


def open3d_available() -> bool:
    """True when ``import open3d`` works (the optional ``peers`` extra is installed)."""
    return _open3d_import()[0] is not None


def _require_open3d():
    o3d, err = _open3d_import()
    if o3d is None:
        raise ImportError("Open3D odometry needs the optional dependency open3d, which could not be "
                          f"imported ({err}). Install it with `pip install jaxvo[peers]` "
                          "(on Linux it also needs the system library libusb-1.0, e.g. "
                          "`apt-get install libusb-1.0-0`).")
    return o3d


# --------------------------------------------------------------------------- shared input handling

def cut_depth(depth, max_depth: Optional[float]) -> np.ndarray:
    """Float32 metres with the cut-off applied: non-finite, <= 0 and > ``max_depth`` become 0."""
    d = np.asarray(depth, dtype=np.float32)
    ok = np.isfinite(d) & (d > 0)
    if max_depth is not None:
        ok &= d <= np.float32(max_depth)
    return np.where(ok, d, np.float32(0.0)).astype(np.float32, copy=False)


def _grey_u8(intensity) -> np.ndarray:
    return np.clip(np.rint(np.asarray(intensity, dtype=np.float32)), 0, 255).astype(np.uint8)


def _check(ref, cur, camera: Camera) -> None:
    for name, f in (("reference", ref), ("current", cur)):
        if not hasattr(f, "intensity") or not hasattr(f, "depth"):
            raise ValueError(f"{name} frame must be a jaxvo.Frame (intensity, depth), got {type(f).__name__}")
        shp = tuple(np.shape(f.intensity))
        if shp != tuple(np.shape(f.depth)) or len(shp) != 2:
            raise ValueError(f"{name} frame: intensity {shp} and depth {tuple(np.shape(f.depth))} "
                             "must be the same 2-D (H, W) size")
        if shp != (camera.height, camera.width):
            raise ValueError(f"camera intrinsics are for {camera.width}x{camera.height} but the "
                             f"{name} frame is {shp[1]}x{shp[0]}")


# --------------------------------------------------------------------------- OpenCV

_OPENCV_KINDS = {"rgb": "OdometryType_RGB", "depth": "OdometryType_DEPTH", "rgbd": "OdometryType_RGB_DEPTH"}
_OPENCV_ALGOS = {"common": "OdometryAlgoType_COMMON", "fast": "OdometryAlgoType_FAST"}


@functools.lru_cache(maxsize=None)
def _opencv_rescales_depth() -> bool:
    """Whether this OpenCV build divides float depth whose max exceeds 10 by 5000 (5.0 does)."""
    import cv2
    d = np.full((16, 16), 20.0, np.float32)
    f = cv2.OdometryFrame(d, np.zeros((16, 16), np.uint8))
    cv2.Odometry(cv2.OdometryType_RGB).prepareFrame(f)
    return bool(abs(float(f.getProcessedDepth().max()) - 20.0 / 5000.0) < 1e-6)


class OpenCVOdometry:
    """OpenCV 5 ``cv2.Odometry`` on jaxvo frames.

    Args:
      camera: intrinsics and image size (frames must match it).
      kind: "rgb" (photometric, Steinbruecker et al.), "depth" (point-to-plane ICP) or
        "rgbd" (both terms).
      max_depth: depth cut-off in metres, applied to the input (pixels farther are invalid)
        and passed to OpenCV's ``setMaxDepth``; None keeps every depth.
      algo: "common" (OpenCV's default, accurate) or "fast" (ICP variant; only for kinds
        "depth" and "rgbd" -- OpenCV 5.0 raises inside compute for "rgb" with "fast").
      min_depth, max_translation, max_rotation: optional overrides of the OpenCV settings
        (defaults 0 m, 0.15 m, 15 deg; a result beyond the last two makes OpenCV report
        failure). The pyramid keeps OpenCV's default iteration counts [7, 7, 7, 10] (4
        levels): the 5.0 Python binding of ``setIterCounts`` keeps only the first element of
        a column vector and crashes on a row vector, so it is not exposed.

    Calling the object on ``(ref, cur)`` returns a :class:`PeerResult` with
    ``T_cur_ref``; on failure ``T_cur_ref`` is the identity and ``success`` False.
    """

    def __init__(self, camera: Camera, kind: str = "rgbd", max_depth: Optional[float] = 4.0, *,
                 algo: str = "common", min_depth: Optional[float] = None,
                 max_translation: Optional[float] = None, max_rotation: Optional[float] = None):
        if not opencv_available():
            import cv2
            raise RuntimeError(f"the installed OpenCV {cv2.__version__} has no cv2.Odometry RGB-D API "
                               "(it needs OpenCV 5)")
        import cv2
        if kind not in _OPENCV_KINDS:
            raise ValueError(f"kind must be one of {sorted(_OPENCV_KINDS)}, got {kind!r}")
        if algo not in _OPENCV_ALGOS:
            raise ValueError(f"algo must be one of {sorted(_OPENCV_ALGOS)}, got {algo!r}")
        if algo == "fast" and kind == "rgb":
            raise ValueError('algo="fast" is an ICP variant: use it with kind "depth" or "rgbd"')
        self.camera, self.kind, self.algo = camera, kind, algo
        self.max_depth = None if max_depth is None else float(max_depth)
        s = cv2.OdometrySettings()
        s.setCameraMatrix(np.asarray(camera.K, dtype=np.float32))  # the binding asserts CV_32F
        s.setMaxDepth(float(self.max_depth) if self.max_depth is not None else float(np.finfo(np.float32).max))
        if min_depth is not None:
            s.setMinDepth(float(min_depth))
        if max_translation is not None:
            s.setMaxTranslation(float(max_translation))
        if max_rotation is not None:
            s.setMaxRotation(float(max_rotation))
        self.settings = s
        self._odometry = cv2.Odometry(getattr(cv2, _OPENCV_KINDS[kind]), s, getattr(cv2, _OPENCV_ALGOS[algo]))
        self._uses_image = kind != "depth"
        self._rescales = _opencv_rescales_depth()

    @property
    def name(self) -> str:
        return f"opencv-{self.kind}" + ("" if self.algo == "common" else f"-{self.algo}")

    def _depth(self, frame) -> np.ndarray:
        d = cut_depth(frame.depth, self.max_depth)
        if self._rescales and float(d.max(initial=0.0)) > 10.0:
            d = d * np.float32(5000.0)  # undone by OpenCV's own "max > 10 -> / 5000" rescale
        return d

    def odometry_frame(self, frame):
        """The unprepared ``cv2.OdometryFrame`` this wrapper builds from a jaxvo Frame."""
        import cv2
        if self._uses_image:
            return cv2.OdometryFrame(self._depth(frame), _grey_u8(frame.intensity))
        return cv2.OdometryFrame(self._depth(frame))

    def __call__(self, ref, cur) -> PeerResult:
        _check(ref, cur, self.camera)
        t0 = time.perf_counter()
        src, dst = self.odometry_frame(ref), self.odometry_frame(cur)
        self._odometry.prepareFrames(src, dst)
        ok, Rt = self._odometry.compute(src, dst)
        seconds = time.perf_counter() - t0
        T = np.asarray(Rt, dtype=np.float64).reshape(4, 4) if Rt is not None else np.eye(4)
        ok = bool(ok) and bool(np.isfinite(T).all())
        return PeerResult(T if ok else np.eye(4), ok, seconds)

    def __repr__(self) -> str:
        return f"OpenCVOdometry(kind={self.kind!r}, algo={self.algo!r}, max_depth={self.max_depth}, camera={self.camera})"


# --------------------------------------------------------------------------- Open3D

class Open3DOdometry:
    """Open3D ``compute_rgbd_odometry`` on jaxvo frames (optional dependency ``open3d``).

    Args:
      camera: intrinsics and image size (frames must match it).
      term: "color" (``RGBDOdometryJacobianFromColorTerm``) or "hybrid"
        (``RGBDOdometryJacobianFromHybridTerm``).
      max_depth: depth cut-off in metres, applied to the input and as ``OdometryOption.depth_max``.
      depth_diff_max, iterations: ``OdometryOption`` settings (Open3D defaults 0.03 m, [20, 10, 5]).

    Raises:
      ImportError: open3d is not installed (``pip install jaxvo[peers]``).
    """

    def __init__(self, camera: Camera, term: str = "hybrid", max_depth: Optional[float] = 4.0, *,
                 depth_diff_max: float = 0.03, iterations: Sequence[int] = (20, 10, 5)):
        o3d = _require_open3d()
        odo = o3d.pipelines.odometry
        terms = {"color": odo.RGBDOdometryJacobianFromColorTerm, "hybrid": odo.RGBDOdometryJacobianFromHybridTerm}
        if term not in terms:
            raise ValueError(f"term must be one of {sorted(terms)}, got {term!r}")
        self.camera, self.term = camera, term
        self.max_depth = None if max_depth is None else float(max_depth)
        self._o3d = o3d
        self._jacobian = terms[term]()
        self._intrinsic = o3d.camera.PinholeCameraIntrinsic(int(camera.width), int(camera.height),
                                                            float(camera.fx), float(camera.fy),
                                                            float(camera.cx), float(camera.cy))
        self._trunc = self.max_depth if self.max_depth is not None else float(np.finfo(np.float32).max)
        self.option = odo.OdometryOption(iteration_number_per_pyramid_level=o3d.utility.IntVector(list(iterations)),
                                         depth_diff_max=float(depth_diff_max), depth_min=0.0,
                                         depth_max=float(self._trunc))
        self._init = np.eye(4)

    @property
    def name(self) -> str:
        return f"open3d-{self.term}"

    def rgbd_image(self, frame):
        """The ``open3d.geometry.RGBDImage`` (float intensity 0-1, depth metres) built from a Frame."""
        o3d = self._o3d
        col = o3d.geometry.Image(np.ascontiguousarray(np.asarray(frame.intensity, np.float32) / np.float32(255.0)))
        dep = o3d.geometry.Image(np.ascontiguousarray(cut_depth(frame.depth, self.max_depth)))
        return o3d.geometry.RGBDImage.create_from_color_and_depth(
            col, dep, depth_scale=1.0, depth_trunc=self._trunc, convert_rgb_to_intensity=True)

    def __call__(self, ref, cur) -> PeerResult:
        _check(ref, cur, self.camera)
        t0 = time.perf_counter()
        src, dst = self.rgbd_image(ref), self.rgbd_image(cur)
        ok, T, _info = self._o3d.pipelines.odometry.compute_rgbd_odometry(
            src, dst, self._intrinsic, self._init, self._jacobian, self.option)
        seconds = time.perf_counter() - t0
        T = np.asarray(T, dtype=np.float64).reshape(4, 4)
        ok = bool(ok) and bool(np.isfinite(T).all())
        return PeerResult(T if ok else np.eye(4), ok, seconds)

    def __repr__(self) -> str:
        return f"Open3DOdometry(term={self.term!r}, max_depth={self.max_depth}, camera={self.camera})"


# --------------------------------------------------------------------------- registry

PEER_NAMES = ("opencv-rgb", "opencv-depth", "opencv-rgbd", "open3d-color", "open3d-hybrid")


def available_peers() -> list:
    """Names from :data:`PEER_NAMES` that can run here."""
    out = [n for n in PEER_NAMES if n.startswith("opencv-")] if opencv_available() else []
    if open3d_available():
        out += [n for n in PEER_NAMES if n.startswith("open3d-")]
    return out


def make_peer(name: str, camera: Camera, max_depth: Optional[float] = 4.0, **kwargs):
    """Build a peer by name ("opencv-rgb", "opencv-depth", "opencv-rgbd", "open3d-color", "open3d-hybrid")."""
    if name.startswith("opencv-"):
        return OpenCVOdometry(camera, name[len("opencv-"):], max_depth, **kwargs)
    if name.startswith("open3d-"):
        return Open3DOdometry(camera, name[len("open3d-"):], max_depth, **kwargs)
    raise ValueError(f"unknown peer {name!r}; choose from {PEER_NAMES}")
