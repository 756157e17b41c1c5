"""What the estimator returns: :class:`MotionEstimate`, the motion between two frames."""
from __future__ import annotations

from typing import NamedTuple, Optional

import jax.numpy as jnp

__all__ = ["MotionEstimate"]


class MotionEstimate(NamedTuple):
    """Result of :func:`jaxvo.estimator.motion.estimate_motion`.

    T_cur_ref: (4, 4) float32, maps reference-camera points into the current camera.
    xi: (6,) twist (w, v) with T_cur_ref = exp(hat(xi)).
    inlier_mask: (h, w) bool at the finest level processed: pixels whose
      luminance and depth residuals are both under the thresholds at the final pose
      (False where undefined: invalid depth, warped outside the image).
    valid_mask: (h, w) bool, pixels where both residuals are defined.
    inlier_ratio: inliers / reference pixels with valid depth at that level.
    hypotheses: (L,) int32 RANSAC hypotheses evaluated per level (index 0 = finest; 0 if not run).
    iterations: (L,) int32 LM iterations per level.
    valid: bool, a trustworthy estimate: finite, a well-conditioned information matrix,
      inlier ratio >= min_inlier_ratio, enough depth and photometric agreement, and enough
      pixels with depth to judge it (see :class:`TrustStats`, :func:`explain_validity`).
    information: (6, 6) J^T W J / sigma^2 at the finest level (inverse covariance of a
      left perturbation of T_cur_ref, twist order (w, v)).
    residual_rms: weighted RMS photometric residual at the finest level (0-255 units).
    occluded_mask: (h, w) bool at the finest level processed: valid pixels whose current
      depth is more than thresh_depth in front of the warped reference point: something
      came between, so the reference pixel is hidden, not moving (see
      :func:`jaxvo.pipelines.mapping.moving_mask`). None where an estimate was made without it.
    brightness: float32 scalar, the luminance offset of the exposure change fitted at the
      finest level, I_cur ~ I_ref + brightness (0-255 units; see :mod:`jaxvo.estimator.brightness`;
      0 with ``Config.brightness = "none"``). None where an estimate was made without it.
    """
    T_cur_ref: jnp.ndarray
    xi: jnp.ndarray
    inlier_mask: jnp.ndarray
    valid_mask: jnp.ndarray
    inlier_ratio: jnp.ndarray
    hypotheses: jnp.ndarray
    iterations: jnp.ndarray
    valid: jnp.ndarray
    information: jnp.ndarray
    residual_rms: jnp.ndarray
    occluded_mask: Optional[jnp.ndarray] = None
    brightness: Optional[jnp.ndarray] = None
