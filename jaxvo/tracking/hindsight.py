"""Moving-pixel masks of a recorded sequence, decided in hindsight from its trajectory.

Online (:mod:`jaxvo.tracking.segmentation`) a frame can only be compared with frames before it,
and between frames a fraction of a second apart a person who walks slowly, or moves
with the camera, stays on most of the pixels it covered: the evidence that it moves
grows only as it leaves them (``python -m experiments.diagnostics.mask_limits``). Once a whole sequence has
been tracked every pose is known, so each frame can be compared with frames *before and
after* it, up to ~1.6 s away, where the person has long moved on.

Each frame (the reference) is warped into the views ``offsets`` frames away at the
trajectory's relative pose, at full resolution. In a view, a reference pixel is

* *seen* when its warped point lands in the view with depth there and is not hidden
  behind something nearer (depth residual above minus the depth tolerance below): an
  occluder says nothing about the pixel;
* *changed* when, seen, its depth disagrees by ``thresh_depth`` (plus ``depth_slope * z^2``,
  the sensor's noise and the poses' error growing with depth) or more, or its luminance,
  less the pair's exposure offset (the median luminance residual of the pixels whose depth
  agrees, :func:`jaxvo.estimator.brightness.masked_median`), differs by more than ``thresh_lum`` plus
  the view's gradient magnitude there (what a one-pixel misalignment at an edge explains,
  which would otherwise flag the static scene's edges; docs/decisions/hindsight-masks.md).

A pixel is moving when it changed in at least ``ratio`` of the views that saw it. The
reference's 3-D points are then grouped (:func:`jaxvo.tracking.segmentation.coherent_regions`,
k-means), and a group at least ``region_ratio`` of whose pixels are moving is flagged
whole, so that a body seen by no view (hidden in all of them) joins its moving part.

The masks are as good as the poses: a view at a wrong pose sees the static scene change.
This runs after tracking and does not feed back into it (the odometry's own segmentation
is causal). Every function is pure JAX with static shapes but the host-side loop
:func:`sequence_masks`, which holds the frames of a sliding window.
"""
from __future__ import annotations

from typing import Callable, Iterator, NamedTuple, Optional, Sequence, Tuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxvo import geometry
from jaxvo.estimator.brightness import masked_median
from jaxvo.camera import Camera
from jaxvo.config import Config
from jaxvo.estimator.pyramid import Level, build_pyramid
from jaxvo.estimator.residuals import reference_points, residuals, sample_bilinear
from jaxvo.tracking.segmentation import SegmentParams, coherent_regions

__all__ = ["HindsightParams", "OFFSETS", "frame_level", "view_votes", "decide", "sequence_masks"]

# frames before (negative) and after each frame it is compared with: 0.13-1.6 s at 30 Hz
OFFSETS: Tuple[int, ...] = (-48, -32, -24, -16, -8, -4, 4, 8, 16, 24, 32, 48)


class HindsightParams(NamedTuple):
    """Numeric parameters of the hindsight masks (pytree leaves).

    ratio: a pixel is moving when it changed in at least this share of the views that saw it.
    region_ratio: a 3-D region (k-means group of the frame's points) with at least this share of
      its valid pixels moving is flagged whole.
    depth_slope: the depth tolerance grows as ``thresh_depth + depth_slope * z^2`` (m, z in m):
      Kinect-class depth is quantised in disparity, so its steps grow with z^2, and a pose
      a few tenths of a degree off over a second moves a wall 3 m away by centimetres.

    ratio and region_ratio balance the masks' precision and recall; depth_slope keeps a wall
    3 m away, whose depth residuals over a second grow to centimetres, from being flagged
    (docs/decisions/hindsight-masks.md).
    """
    ratio: float = 0.25
    region_ratio: float = 0.5
    depth_slope: float = 0.005


@jax.jit
def frame_level(intensity, depth, max_depth=4.0) -> Level:
    """(H, W) luminance 0-255 and depth (m) -> the full-resolution pyramid level (with gradients)."""
    return build_pyramid(intensity, depth, 1, max_depth)[0]


@jax.jit
def view_votes(ref: Level, view: Level, T_view_ref, camera: Camera, thresh_lum, thresh_depth, depth_slope=0.0):
    """One view's evidence on each reference pixel: (seen, changed), (H, W) bool each.

    ref, view: full-resolution levels (:func:`frame_level`). T_view_ref: (4, 4) maps reference-camera
    points into the view's camera. The depth tolerance at a point z metres from the view is
    ``tol = thresh_depth + depth_slope * z^2`` (m). seen: the warped point lands in the view, with
    depth there, not hidden behind a surface nearer by more than tol. changed: seen, and
    |depth residual| >= tol or |luminance residual - the pair's exposure offset| > thresh_lum +
    |grad I_view| (0-255 units).
    """
    res = residuals(T_view_ref, reference_points(ref, camera), view, camera)
    tol = thresh_depth + depth_slope * res.z * res.z
    seen = res.valid_depth & (res.r_depth > -tol)
    agree = seen & (jnp.abs(res.r_depth) < tol)
    offset = masked_median(res.r_int, agree)
    offset = jnp.where(jnp.isfinite(offset), offset, 0.0)
    g = sample_bilinear(view.igrad[..., 1:], res.u, res.v)
    edge = jnp.sqrt(g[:, 0] ** 2 + g[:, 1] ** 2)
    changed = seen & (~agree | (jnp.abs(res.r_int - offset) > thresh_lum + edge))
    shape = ref.depth.shape
    return seen.reshape(shape), changed.reshape(shape)


@jax.jit
def decide(n_seen, n_changed, depth, camera: Camera, params: HindsightParams):
    """(H, W) bool moving mask of a frame from its views' counts ((H, W) int each) and its depth
    ((H, W) m, 0 = invalid): changed in at least ``ratio`` of the views that saw it, or in a
    3-D region at least ``region_ratio`` of whose valid pixels are."""
    moving = (n_seen > 0) & (n_changed >= params.ratio * n_seen) & (depth > 0)
    # log-odds as the online map holds them: > 0 moving, < 0 seen and kept, 0 never seen
    L = jnp.where(moving, 1.0, jnp.where(n_seen > 0, -1.0, 0.0))
    region = coherent_regions(L, depth, camera, SegmentParams(region_ratio=params.region_ratio)) >= 2.0
    return moving | (region & (depth > 0))


def sequence_masks(frame_at: Callable[[int], object], poses, camera: Camera, config: Optional[Config] = None,
                   params: HindsightParams = HindsightParams(), offsets: Sequence[int] = OFFSETS,
                   frames: Optional[Sequence[int]] = None) -> Iterator[Tuple[int, np.ndarray]]:
    """Yield ``(i, mask)`` for each frame i in ``frames`` (default: every frame with a pose), in order.

    frame_at(i): the i-th :class:`~jaxvo.frame.Frame` (e.g. ``TumSequence.frame``); it is called once
      per frame while that frame is inside the window of ``offsets`` around the frame decided.
    poses: (N, 4, 4) T_world_cam (e.g. :attr:`jaxvo.tracking.odometry.Track.poses`); a frame whose pose is
      not finite (NaN) takes part neither as reference nor as view. Give NaN for the frames whose
      pose is a guess (``Track.valid`` False: the estimate failed and the previous pose was kept;
      ``# held`` lines of a trajectory file, :func:`jaxvo.data.trajectory.read_held`): a view at a
      guessed pose sees the static scene change (docs/decisions/hindsight-masks.md).
    config: its ``thresh_lum``, ``thresh_depth`` and ``max_depth`` (default ``Config()``).
    mask: (H, W) bool, True on the frame's moving pixels (see the module docstring).
    A list of frames may stand for ``frame_at`` (its items are read by index). The arguments are
    checked when this is called (ValueError naming the problem), not at the first mask.
    """
    if not callable(frame_at):
        if not hasattr(frame_at, "__getitem__"):
            raise ValueError(f"frame_at must be a function i -> Frame (e.g. TumSequence.frame) or a list of "
                             f"frames, got {type(frame_at).__name__}")
        frame_at = frame_at.__getitem__
    config = Config() if config is None else config
    poses = np.asarray(poses, np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise ValueError(f"poses must be (N, 4, 4) T_world_cam matrices, got shape {poses.shape}")
    offsets = sorted({int(o) for o in offsets if int(o) != 0})
    if not offsets:
        raise ValueError("offsets must hold at least one nonzero frame offset")
    n = poses.shape[0]
    frames = range(n) if frames is None else list(frames)
    if any(not 0 <= i < n for i in frames):
        raise ValueError(f"frames must be indices of the {n} poses, got {[i for i in frames if not 0 <= i < n][:5]}")
    return _sequence_masks(frame_at, poses, camera, config, params, offsets, frames)


def _sequence_masks(frame_at, poses, camera: Camera, config: Config, params: HindsightParams, offsets, frames):
    """:func:`sequence_masks`' generator, on its checked arguments."""
    n = poses.shape[0]
    has_pose = np.isfinite(poses).all(axis=(1, 2))
    todo = [i for i in frames if has_pose[i]]
    reach = max(abs(o) for o in offsets)
    window = {}   # frame index -> (Level, depth); the frames within ``reach`` of the one decided
    for i in todo:
        for j in [j for j in window if abs(j - i) > reach]:
            del window[j]
        needed = [i] + [i + o for o in offsets if 0 <= i + o < n and has_pose[i + o]]
        for j in needed:
            if j not in window:
                f = frame_at(j)
                window[j] = frame_level(f.intensity, f.depth, config.max_depth)
        ref = window[i]
        n_seen = jnp.zeros(ref.depth.shape, jnp.int32)
        n_changed = jnp.zeros(ref.depth.shape, jnp.int32)
        for j in needed[1:]:
            T = (geometry.inverse(poses[j]) @ poses[i]).astype(np.float32)
            seen, changed = view_votes(ref, window[j], T, camera, config.thresh_lum, config.thresh_depth,
                                       params.depth_slope)
            n_seen, n_changed = n_seen + seen, n_changed + changed
        yield i, np.asarray(decide(n_seen, n_changed, ref.depth, camera, params))
