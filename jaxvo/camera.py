"""Pinhole camera intrinsics as a JAX pytree, presets, pyramid scaling, projection.

Pixel convention (OpenCV): ``u`` is the column, ``v`` the row, and pixel
centres sit at integer coordinates. A 3-D point ``(X, Y, Z)`` in the camera
frame (x right, y down, z forward, metres) projects to
``u = fx * X / Z + cx``, ``v = fy * Y / Z + cy``.

Lens distortion (:class:`Lens`, OpenCV's radial-tangential model) is not part of the
camera the estimator sees: a distorted recording is undistorted to the pinhole ``Camera``
with the same intrinsics when its frames are read (:func:`jaxvo.frame.undistort`).

Pyramid level ``l`` halves the image ``l`` times by averaging 2x2 blocks, so a
pixel centre ``c`` at level 0 lands at ``(c + 0.5) / 2 - 0.5`` at level 1:
``f_l = f / 2^l`` and ``c_l = (c + 0.5) / 2^l - 0.5``.
"""
from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple, Tuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxvo.validation import check_fields, integer, real

__all__ = [
    "Camera", "TUM_FR1", "TUM_FR2", "TUM_FR3", "BONN", "DEFAULT", "PRESETS",
    "Lens", "NO_LENS", "LENSES", "DEPTH_CORRECTIONS", "camera_for_sequence", "lens_for_sequence",
    "depth_correction_for_sequence", "preset_for_sequence", "undistortion_map", "camera_for_size",
    "backproject", "backproject_planes", "project",
]


@dataclasses.dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics (pixels) and image size.

    ``fx, fy, cx, cy`` are pytree leaves (floats or scalar arrays, so they can
    be traced or vmapped); ``width, height`` (pixels) are static metadata
    because they fix array shapes.
    """
    fx: Any
    fy: Any
    cx: Any
    cy: Any
    width: int = 640
    height: int = 480

    def at_level(self, level: int) -> "Camera":
        """Intrinsics of pyramid level ``level`` (0 = full resolution)."""
        s = 2 ** level
        return Camera(self.fx / s, self.fy / s, (self.cx + 0.5) / s - 0.5, (self.cy + 0.5) / s - 0.5,
                      self.width // s, self.height // s)

    @property
    def K(self):
        """3x3 intrinsic matrix (NumPy float64 for host use)."""
        return np.array([[float(self.fx), 0.0, float(self.cx)],
                         [0.0, float(self.fy), float(self.cy)],
                         [0.0, 0.0, 1.0]])

    def with_size(self, width: int, height: int) -> "Camera":
        return dataclasses.replace(self, width=int(width), height=int(height))

    def validate(self) -> None:
        """Raise ValueError naming the first bad field: fx, fy finite and > 0, cx in [0, width],
        cy in [0, height] (the principal point lies inside the image), width, height integers >= 1."""
        check_fields(self, _RULES, "Camera")

    def __repr__(self) -> str:  # short and readable even with array leaves
        def f(x):
            try:
                return f"{float(x):g}"
            except Exception:  # traced
                return "traced"
        return (f"Camera(fx={f(self.fx)}, fy={f(self.fy)}, cx={f(self.cx)}, cy={f(self.cy)}, "
                f"width={self.width}, height={self.height})")


_RULES = {"fx": real(0, lo_open=True), "fy": real(0, lo_open=True), "cx": real(0, "width"),
          "cy": real(0, "height"), "width": integer(1), "height": integer(1)}

jax.tree_util.register_dataclass(Camera, data_fields=["fx", "fy", "cx", "cy"], meta_fields=["width", "height"])

# Published intrinsics of the TUM RGB-D benchmark (images not undistorted) and
# the Bonn RGB-D Dynamic dataset (ASUS Xtion Pro Live).
TUM_FR1 = Camera(517.3, 516.5, 318.6, 255.3)
TUM_FR2 = Camera(520.9, 521.0, 325.1, 249.7)
TUM_FR3 = Camera(535.4, 539.2, 320.1, 247.6)
BONN = Camera(542.822841, 542.576870, 315.593520, 237.756098)
DEFAULT = Camera(525.0, 525.0, 319.5, 239.5)

PRESETS = {"fr1": TUM_FR1, "fr2": TUM_FR2, "fr3": TUM_FR3, "bonn": BONN, "default": DEFAULT}


class Lens(NamedTuple):
    """Lens distortion, OpenCV's radial-tangential (Brown-Conrady) model and coefficient order.

    A point at normalised pinhole coordinates ``(x, y) = (X / Z, Y / Z)`` is imaged at
    ``x_d = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2)``,
    ``y_d = y (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 y^2) + 2 p2 x y`` (``r^2 = x^2 + y^2``),
    i.e. at pixel ``(fx x_d + cx, fy y_d + cy)``. All zeros (:data:`NO_LENS`): a pinhole camera.
    Dimensionless, so the same for any image size of the same camera.
    """
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0

    @property
    def is_pinhole(self) -> bool:
        return all(float(c) == 0.0 for c in self)

    def distort(self, x, y) -> Tuple[np.ndarray, np.ndarray]:
        """Normalised pinhole coordinates (x, y) (NumPy, any shape) -> where the lens images them."""
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        return (x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
                y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y)

    def to_list(self) -> list:
        return [float(c) for c in self]

    @classmethod
    def parse(cls, value) -> "Lens":
        """A Lens from 5 numbers (k1, k2, p1, p2, k3; a list, or a string "k1,k2,p1,p2,k3"), a preset
        name of :data:`LENSES`, or "none"; ValueError naming what is wrong otherwise."""
        if isinstance(value, Lens):
            return value
        given = value
        if isinstance(value, str):
            if value.strip().lower() in ("none", "pinhole"):
                return NO_LENS
            if value.strip() in LENSES:
                return LENSES[value.strip()]
            value = value.split(",")
        try:
            coeffs = [float(v) for v in value]
        except (TypeError, ValueError):
            coeffs = None
        if coeffs is None or len(coeffs) != 5 or not all(np.isfinite(coeffs)):
            raise ValueError(f"lens must be 5 finite numbers k1,k2,p1,p2,k3 (OpenCV's order), 'none' or one of "
                             f"{', '.join(sorted(LENSES))}, got {given!r}")
        return cls(*coeffs)


NO_LENS = Lens()
#: Published distortion of the colour cameras: TUM fr1 and fr2 (the images are not undistorted),
#: fr3 (already undistorted), Bonn (ASUS Xtion Pro Live, the dataset's calibration).
LENSES = {"fr1": Lens(0.262383, -0.953104, -0.005358, 0.002628, 1.163314),
          "fr2": Lens(0.231222, -0.784899, -0.003257, -0.000105, 0.917205),
          "fr3": NO_LENS, "bonn": Lens(0.039903, -0.099343, -0.000730, -0.000144, 0.0), "default": NO_LENS}

#: Published depth correction ``ds`` of each sensor: PNG value / (layout scale x ``ds``) is metres
#: (the readers' ``depth_scale="fr2"``). TUM fr1 and fr2: ``ds`` from the same calibration as the
#: lenses (their depth reads ``ds`` times too far at 1/5000 m). Bonn: the published marker-to-camera
#: calibration ``T_m`` (:data:`jaxvo.data.groundtruth.T_M_BONN`) has a 3x3 block of 1.0593 x a
#: rotation, so a camera point times 1.0593 is the motion capture's metres: the depth reads 1.0593
#: times too near, ``ds`` = 1 / 1.0593. fr3 and any other sensor: 1, none published.
DEPTH_CORRECTIONS = {"fr1": 1.035, "fr2": 1.031, "fr3": 1.0, "bonn": 1 / 1.0593, "default": 1.0}


def preset_for_sequence(name: str) -> str:
    """The key of :data:`PRESETS` / :data:`LENSES` / :data:`DEPTH_CORRECTIONS` for a sequence folder
    name (``freiburg1/2/3``, ``rgbd_bonn_*``), else "default"."""
    n = str(name).lower()
    if "bonn" in n:
        return "bonn"
    for i in (1, 2, 3):
        if f"freiburg{i}" in n or f"fr{i}" in n:
            return f"fr{i}"
    return "default"


def camera_for_sequence(name: str) -> Camera:
    """Pick the preset from a sequence folder name (``freiburg1/2/3``, ``rgbd_bonn_*``), else DEFAULT."""
    return PRESETS[preset_for_sequence(name)]


def lens_for_sequence(name: str) -> Lens:
    """The lens of the preset :func:`camera_for_sequence` picks (:data:`LENSES`)."""
    return LENSES[preset_for_sequence(name)]


def depth_correction_for_sequence(name: str) -> float:
    """The depth correction of the preset :func:`camera_for_sequence` picks (:data:`DEPTH_CORRECTIONS`)."""
    return DEPTH_CORRECTIONS[preset_for_sequence(name)]


def undistortion_map(camera: Camera, lens: Lens) -> Tuple[np.ndarray, np.ndarray]:
    """(map_u, map_v): (height, width) float32 each, where pixel (u, v) of the undistorted
    (pinhole) image lies in the distorted one: ``lens.distort`` of its normalised coordinates,
    through the same intrinsics (OpenCV's ``initUndistortRectifyMap`` with ``newCameraMatrix = K``)."""
    fx, fy, cx, cy = (float(c) for c in (camera.fx, camera.fy, camera.cx, camera.cy))
    v, u = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
    xd, yd = lens.distort((u - cx) / fx, (v - cy) / fy)
    return (fx * xd + cx).astype(np.float32), (fy * yd + cy).astype(np.float32)


def camera_for_size(base: Camera, width: int, height: int) -> Camera:
    """``base`` scaled to a ``width`` x ``height`` image: the focal lengths times
    min(width / base.width, height / base.height) (the field of view is at least base's in
    both directions), the principal point at the image centre. Exact pyramid sizes of a
    centred camera give the same intrinsics as :meth:`Camera.at_level` (DEFAULT at 320x240
    is DEFAULT.at_level(1))."""
    s = min(width / base.width, height / base.height)
    return Camera(float(base.fx) * s, float(base.fy) * s, (width - 1) / 2.0, (height - 1) / 2.0, int(width), int(height))


def backproject_planes(camera: Camera, u, v, z):
    """Pixels (u, v) with depth z (metres, along the optical axis) -> camera-frame (x, y, z), each
    of the broadcast shape of u, v and z: separate arrays, for code that stays element-wise
    (XLA on CPU is several times slower on interleaved (..., 3) points there)."""
    return (u - camera.cx) / camera.fx * z, (v - camera.cy) / camera.fy * z, z


def backproject(camera: Camera, u, v, z):
    """Pixels (u, v) with depth z (metres, along the optical axis) -> (..., 3) points in the camera frame."""
    return jnp.stack(backproject_planes(camera, u, v, z), -1)


def project(camera: Camera, P, min_depth: float = 1e-6):
    """(..., 3) camera-frame points -> (u, v, z, in_front); points with z <= min_depth get u = v = -1e6."""
    z = P[..., 2]
    in_front = z > min_depth
    zs = jnp.where(in_front, z, 1.0)
    u = jnp.where(in_front, camera.fx * P[..., 0] / zs + camera.cx, -1e6)
    v = jnp.where(in_front, camera.fy * P[..., 1] / zs + camera.cy, -1e6)
    return u, v, z, in_front
