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

The whole estimate is one jit-compiled function per (image shape, static
config); numeric config fields are traced, so ``jax.vmap`` over a field of
``Config`` is a hyperparameter sweep compiled once.
"""
from __future__ import annotations

from typing import Optional

from jaxvo.camera import Camera
from jaxvo.config import Config
from jaxvo.estimator.inputs import estimate_args
from jaxvo.estimator.levels import _estimate, _estimate_call
from jaxvo.estimator.result import MotionEstimate
from jaxvo.estimator.solvers import COMPILER_OPTIONS
from jaxvo.frame import Frame
from jaxvo.runtime import aot

__all__ = ["MotionEstimate", "estimate_motion"]


def estimate_motion(ref: Frame, cur: Frame, camera: Camera, config: Optional[Config] = None, key=None,
                    init=None, weights=None) -> MotionEstimate:
    """Estimate the rigid motion between two RGB-D frames.

    Args:
      ref: reference (earlier) Frame: intensity (H, W) float32 0-255, depth (H, W) float32 metres, 0 = invalid.
      cur: current (later) Frame, same size.
      camera: intrinsics for (H, W) images.
      config: :class:`Config` (default: RANSAC with jaxvo's defaults; ``Config.paper()`` is the
        published algorithm).
      key: ``jax.random`` key (used by "ransac"); default ``jax.random.key(0)``. The
        same key gives a bitwise identical result.
      init: optional (4, 4) initial guess of T_cur_ref (default identity).
      weights: optional (H, W) trust in each *reference* pixel as static scene, in [0, 1]
        (e.g. a static-probability prior; 0 = ignore). It multiplies ``ref.mask`` (a
        user mask: True = the pixel may be used, as OpenCV's ``OdometryFrame`` mask).
        RANSAC samples only pixels of weight >= 0.5, scoring and refinement weigh by it.

    Returns:
      :class:`MotionEstimate` whose ``T_cur_ref`` maps reference-camera points into the current camera.

    Raises:
      ValueError: mismatched sizes, wrong dtypes or shapes, intrinsics that do not match the
        images, no valid depth, or an invalid config.
    """
    args = estimate_args(ref, cur, camera, config, key, init, weights)
    # through the program exported into the cache folder when the cache is on (jaxvo.runtime.cache,
    # by default): a second process then skips tracing; else plain jit (the arguments as a
    # plain tuple: the pytree, and so the exported program's name, as the estimate's signature)
    return MotionEstimate(*aot.call("estimate", _estimate, _estimate_call, tuple(args), COMPILER_OPTIONS))
