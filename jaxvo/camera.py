"""Pinhole camera intrinsics as a JAX pytree, presets, pyramid scaling, projection.

Pixel convention (OpenCV): ``u`` is the column, ``v`` the row, and pixel
centres sit at integer coordinates. A 3-D point ``(X, Y, Z)`` in the camera
frame (x right, y down, z forward, metres) projects to
``u = fx * X / Z + cx``, ``v = fy * Y / Z + cy``.

Pyramid level ``l`` halves the image ``l`` times by averaging 2x2 blocks, so a
pixel centre ``c`` at level 0 lands at ``(c + 0.5) / 2 - 0.5`` at level 1:
``f_l = f / 2^l`` and ``c_l = (c + 0.5) / 2^l - 0.5``.
"""
from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxvo.validation import check_fields, integer, real

__all__ = [
    "Camera", "TUM_FR1", "TUM_FR2", "TUM_FR3", "BONN", "DEFAULT", "PRESETS",
    "camera_for_sequence", "camera_for_size", "backproject", "backproject_planes", "project",
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


def camera_for_sequence(name: str) -> Camera:
    """Pick the preset from a sequence folder name (``freiburg1/2/3``, ``rgbd_bonn_*``), else DEFAULT."""
    n = str(name).lower()
    if "bonn" in n:
        return BONN
    for i, cam in ((1, TUM_FR1), (2, TUM_FR2), (3, TUM_FR3)):
        if f"freiburg{i}" in n or f"fr{i}" in n:
            return cam
    return DEFAULT


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
