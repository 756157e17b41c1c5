"""A frame's depth image moved to its colour image's capture time.

A Kinect-class sensor takes its colour and depth images apart: in the TUM and Bonn recordings
the depth image's timestamp is up to half a frame (-8 to +16 ms) from its colour image's. The
estimator back-projects each pixel with its depth and reads its luminance, as if both were taken
together; a hand-held camera turning at 10-20 deg/s moves the depth image by one or two pixels
against the colour in that time, and the offset differs from frame to frame.

When a frame becomes the odometry's reference (``TrackConfig.retime_depth``), the frames around
it are posed: :func:`depth_motion` interpolates the camera at the depth's time along the twist
between two of them, and :func:`retimed_depth` moves the depth image by the motion from there to
the colour's time: every pixel back-projected (camera frame at the depth's time), transformed,
projected into the camera at the colour's time and kept at the nearest pixel, the nearest surface
winning (a z-buffer, ``scatter-min``). A pixel that no point lands on but had a depth keeps its
own (the splat's cracks, where the surface is stretched by a fraction of a pixel); one that had
none stays invalid (docs/decisions/depth-time.md).
"""
from __future__ import annotations

import operator
from typing import Optional

import jax.numpy as jnp
import numpy as np

from jaxvo import geometry
from jaxvo.camera import Camera, backproject_planes
from jaxvo.runtime import aot

__all__ = ["depth_motion", "retimed_depth"]


def depth_motion(T_world_a: np.ndarray, T_world_b: np.ndarray, t_a: float, t_b: float,
                 T_world_cam: np.ndarray, depth_time: float) -> Optional[np.ndarray]:
    """T_colour_depth (4, 4) float64: the camera at its depth image's time ``depth_time`` seen from
    the camera ``T_world_cam`` at its colour image's time (points in the first to points in the
    second). The camera at ``depth_time`` is interpolated (or extrapolated) along the twist from
    its pose ``T_world_a`` at time ``t_a`` to ``T_world_b`` at ``t_b`` (seconds; ``T_world_cam``
    (4, 4)): ``T_a exp(s log(T_a^-1 T_b))``, s = (depth_time - t_a) / (t_b - t_a). None where
    t_b <= t_a."""
    if not t_b > t_a:
        return None
    s = (float(depth_time) - float(t_a)) / (float(t_b) - float(t_a))
    T_world_depth = geometry.interpolate(np.asarray(T_world_a, np.float64), np.asarray(T_world_b, np.float64), s)
    return geometry.inverse(np.asarray(T_world_cam, np.float64)) @ T_world_depth


def _retimed(depth, T_colour_depth, camera: Camera):
    """(H, W) float32 depth (metres, 0 = invalid) seen from the camera moved by T_colour_depth."""
    h, w = depth.shape
    v, u = jnp.meshgrid(jnp.arange(h, dtype=jnp.float32), jnp.arange(w, dtype=jnp.float32), indexing="ij")
    ok = depth > 0
    # separate planes, element-wise (docs/decisions/cpu-kernels.md)
    P = backproject_planes(camera, u, v, depth)
    T = T_colour_depth.astype(jnp.float32)
    x, y, z = (T[i, 0] * P[0] + T[i, 1] * P[1] + T[i, 2] * P[2] + T[i, 3] for i in range(3))
    front = z > 0
    zs = jnp.where(front, z, 1.0)
    u2 = jnp.round(camera.fx * x / zs + camera.cx)
    v2 = jnp.round(camera.fy * y / zs + camera.cy)
    lands = ok & front & (u2 >= 0) & (u2 <= w - 1) & (v2 >= 0) & (v2 <= h - 1)
    # points that land nowhere go to one slot past the image, dropped below
    slot = jnp.where(lands, v2 * w + u2, h * w).astype(jnp.int32)
    nearest = jnp.full(h * w + 1, jnp.inf, jnp.float32).at[slot.reshape(-1)].min(jnp.where(lands, z, jnp.inf).reshape(-1))
    moved = nearest[:h * w].reshape(h, w)
    hole = ~jnp.isfinite(moved)
    return jnp.where(hole, jnp.where(ok, depth, 0.0), moved)


_RETIMED = aot.Program("retimed_depth", _retimed, result=operator.itemgetter(0))


def retimed_depth(depth: np.ndarray, T_colour_depth: np.ndarray, camera: Camera) -> np.ndarray:
    """``depth`` ((H, W) float32 metres, 0 = invalid, taken by ``camera`` at its depth time) as
    the camera sees it at its colour image's time, ``T_colour_depth`` apart (:func:`depth_motion`):
    (H, W) float32 on the host. One compiled program per image size."""
    return np.asarray(_RETIMED(np.asarray(depth, np.float32), np.asarray(T_colour_depth, np.float32), camera))
