"""The estimator: its result and the coarse-to-fine ``estimate_motion`` of one pair of frames.

``estimate_motion(ref, cur, camera, config, key)`` returns ``T_cur_ref``: the
4x4 rigid transform that maps a 3-D point in the *reference* camera's
coordinates (the earlier frame) into the *current* camera's coordinates
(``P_cur = T_cur_ref @ P_ref``, the paper's ``P' = T P``). ``track`` chains
these into camera-to-world poses ``T_world_cam`` with
``T_world_cur = T_world_ref @ inv(T_cur_ref)``, on the host in float64.

Methods (``Config.method``):

* ``"classic"``: plain least squares on the photometric residual (the paper's baseline);
* ``"huber"``: IRLS with Huber weights (k = 1.345 sigma, sigma by MAD each round);
* ``"ransac"``: the paper's RANSAC per pyramid level, then least squares on the consensus set.

The estimate is two jit-compiled programs per (image shape, static config): each frame's
pyramid (:func:`prepare_frame`, kept by a caller whose frames take part in several estimates)
and the coarse-to-fine estimate from the two pyramids. Numeric config fields are traced, so
``jax.vmap`` over a field of ``Config`` is a hyperparameter sweep compiled once (inside a
caller's ``vmap`` or ``jit`` the estimate is one program, pyramids included).
"""
from __future__ import annotations

from typing import Dict, NamedTuple, Optional, Tuple, Union

import jax
import numpy as np

from jaxvo.camera import Camera
from jaxvo.config import Config
from jaxvo.estimator.inputs import as_float32, checked_config, estimate_args, num_levels
from jaxvo.estimator.levels import (_estimate, _estimate_call, _estimate_pyramids, _frame_pyramid, depth_gradient_levels,
                                    jit_with_fallback)
from jaxvo.estimator.pyramid import Level
from jaxvo.estimator.result import MotionEstimate
from jaxvo.estimator.solvers import COMPILER_OPTIONS
from jaxvo.frame import Frame, validate_frame
from jaxvo.runtime import aot

__all__ = ["MotionEstimate", "PreparedFrame", "estimate_motion", "prepare_frame"]


class PreparedFrame(NamedTuple):
    """A frame made ready for estimates (:func:`prepare_frame`): its pyramid is built once, and
    every estimate it takes part in, as reference or as current frame, reads it.

    frame: the :class:`Frame`. levels: its pyramid (:class:`jaxvo.estimator.pyramid.Level` per
    level, index 0 = full resolution, float32 device arrays; ``weight`` None: the weights are an
    estimate's own; ``dgrad`` None on the levels where an estimate with the config it was prepared
    for never reads depth gradients, :func:`jaxvo.estimator.levels.depth_gradient_levels`).
    max_depth: metres, the ``Config.max_depth`` it was built with.
    """
    frame: Frame
    levels: Tuple[Level, ...]
    max_depth: float


_estimate_pyramids_call = jit_with_fallback(_estimate_pyramids)
# per (level count, levels with depth gradients): the frame pyramid's program (run through its
# kept program, as the estimator)
_PYRAMIDS: Dict[Tuple[int, Tuple[int, ...]], aot.Program] = {}


def _pyramid_program(n: int, dgrad_levels: Tuple[int, ...]) -> aot.Program:
    """The program that builds a frame's ``n``-level pyramid with depth gradients on ``dgrad_levels``
    (:func:`_frame_pyramid`), kept with the estimator's (:mod:`jaxvo.runtime.aot`), so that a
    later process neither traces nor lowers it."""
    if (n, dgrad_levels) not in _PYRAMIDS:
        def frame_pyramid(intensity, depth, max_depth):
            return _frame_pyramid(intensity, depth, n, max_depth, dgrad_levels)

        def levels(leaves) -> Tuple[Level, ...]:
            # the pyramid from its leaves: three arrays per level, four with depth gradients
            out, i = [], 0
            for level in range(n):
                k = 4 if level in dgrad_levels else 3
                out.append(Level(*leaves[i:i + k], *([None] * (4 - k)), weight=None))
                i += k
            return tuple(out)
        name = f"frame_pyramid_{n}_d{''.join(map(str, dgrad_levels))}"
        _PYRAMIDS.setdefault((n, dgrad_levels), aot.Program(name, frame_pyramid, levels))
    return _PYRAMIDS[(n, dgrad_levels)]


def _pyramid(intensity, depth, config: Config) -> Tuple[Level, ...]:
    """The pyramid of checked float32 (H, W) images for ``config`` (:func:`_frame_pyramid`): with
    the depth gradients the estimates with ``config`` read (:func:`depth_gradient_levels`)."""
    h, w = intensity.shape
    n = num_levels(config, w, h)
    return _pyramid_program(n, depth_gradient_levels(config, n))(intensity, depth, np.float32(config.max_depth))


def _read_by(levels: Tuple[Level, ...], config: Config, name: str) -> Tuple[Level, ...]:
    """A frame's ``levels`` as the estimate with ``config`` reads them as its ``name`` frame
    ("reference" or "current"): depth gradients kept only where it reads them (the current
    frame's, :func:`depth_gradient_levels`; never the reference's), so that there is one compiled
    estimate per config whatever config a frame was prepared with; ValueError naming the frame
    where a level read has none."""
    needed = depth_gradient_levels(config, len(levels)) if name == "current" else ()
    if any(levels[i].dgrad is None for i in needed):
        raise ValueError(f"{name} frame was prepared for another config (no depth gradients on pyramid levels "
                         f"{[i for i in needed if levels[i].dgrad is None]}, which this config reads); prepare it "
                         "with this one (jaxvo.estimator.prepare_frame)")
    return tuple(level if i in needed else level._replace(dgrad=None) for i, level in enumerate(levels))


def prepare_frame(frame: Frame, camera: Camera, config: Optional[Config] = None, what: str = "frame") -> PreparedFrame:
    """``frame`` made ready for :func:`estimate_motion` with ``camera`` and ``config`` (default
    ``Config()``): its pyramid built once (one compiled program, dispatched without waiting).

    A frame that takes part in several estimates (the odometry's current frame becomes the next
    reference; retries and keyframe windows estimate it again) then skips rebuilding its pyramid
    in each: ``estimate_motion(prepare_frame(a, ...), prepare_frame(b, ...), ...)`` gives bitwise the
    estimate of ``estimate_motion(a, b, ...)``, which prepares both frames itself. ValueError as :func:`estimate_motion` for a bad frame,
    naming it ``what``.
    """
    config = checked_config(config, camera)
    validate_frame(frame, camera, what)
    return PreparedFrame(frame, _pyramid(as_float32(frame.intensity), as_float32(frame.depth), config),
                         float(config.max_depth))


def estimate_motion(ref: Union[Frame, PreparedFrame], cur: Union[Frame, PreparedFrame], camera: Camera, config: Optional[Config] = None, key=None,
                    init=None, weights=None) -> MotionEstimate:
    """Estimate the rigid motion between two RGB-D frames.

    Args:
      ref: reference (earlier) Frame: intensity (H, W) float32 0-255, depth (H, W) float32 metres, 0 = invalid.
      cur: current (later) Frame, same size. Either may be a :class:`PreparedFrame`
        (:func:`prepare_frame`): its pyramid is then not built again.
      camera: intrinsics for (H, W) images.
      config: :class:`Config` (default: RANSAC with jaxvo's defaults; ``Config.paper()`` is the
        published algorithm).
      key: ``jax.random`` key (used by "ransac"); default ``jax.random.key(0)``. The
        same key gives a bitwise identical result.
      init: optional (4, 4) rigid initial guess of T_cur_ref (default identity).
      weights: optional (H, W) trust in each *reference* pixel as static scene, in [0, 1]
        (e.g. a static-probability prior; 0 = ignore). It multiplies ``ref.mask`` (a
        user mask: True = the pixel may be used, as OpenCV's ``OdometryFrame`` mask).
        RANSAC samples only pixels of weight >= 0.5, scoring and refinement weigh by it.
        NumPy weights are checked; a JAX array is taken as it is (reading it back would wait for it).

    Returns:
      :class:`MotionEstimate` whose ``T_cur_ref`` maps reference-camera points into the current camera.

    Raises:
      ValueError: mismatched sizes, wrong dtypes or shapes, intrinsics that do not match the
        images, no valid depth, an invalid config, an ``init`` that is not a finite rigid
        transform, or weights outside [0, 1] (NaN included).
    """
    frames = [x.frame if isinstance(x, PreparedFrame) else x for x in (ref, cur)]
    args = estimate_args(frames[0], frames[1], camera, config, key, init, weights)   # every check
    if any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(args)):
        # inside a caller's jax.vmap / jax.jit (e.g. a sweep over a Config field): one program
        # with both pyramids, as the caller traces it anyway
        return MotionEstimate(*aot.call("estimate", _estimate, _estimate_call, tuple(args), COMPILER_OPTIONS))
    config = args.config
    h, w = frames[0].intensity.shape
    for name, p in (("reference", ref), ("current", cur)):
        if isinstance(p, PreparedFrame) and (len(p.levels) != num_levels(config, w, h)
                                             or p.max_depth != float(config.max_depth)):
            raise ValueError(f"{name} frame was prepared for another config ({len(p.levels)} levels, max_depth "
                             f"{p.max_depth}); prepare it with this one (jaxvo.estimator.prepare_frame)")
    # the frames' pyramids, then the estimate from them: the program an odometry's prepared frames
    # run too (one compilation serves both)
    ref_levels = _read_by(ref.levels if isinstance(ref, PreparedFrame)
                          else _pyramid(args.ref_intensity, args.ref_depth, config), config, "reference")
    cur_levels = _read_by(cur.levels if isinstance(cur, PreparedFrame)
                          else _pyramid(args.cur_intensity, args.cur_depth, config), config, "current")
    leaves = (ref_levels, cur_levels, camera, config, args.key, args.T_init, args.ref_weight)
    # through the program exported into the cache folder when the cache is on (jaxvo.runtime.cache,
    # by default): a second process then skips tracing; else plain jit (the arguments as a
    # plain tuple: the pytree, and so the exported program's name, as the estimate's signature)
    return MotionEstimate(*aot.call("estimate", _estimate_pyramids, _estimate_pyramids_call, leaves, COMPILER_OPTIONS))
