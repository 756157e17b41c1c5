"""Two frames in, one MotionEstimate out: pyramid, residuals, brightness, solvers, RANSAC, the coarse-to-fine estimate.

Modules, in data-flow order: :mod:`~jaxvo.estimator.pyramid` (image pyramids),
:mod:`~jaxvo.estimator.residuals` (warped points and their photometric and depth residuals),
:mod:`~jaxvo.estimator.brightness` (the exposure offset), :mod:`~jaxvo.estimator.solvers`
(least squares and IRLS on the pose), :mod:`~jaxvo.estimator.ransac` (hypotheses and consensus
per level), :mod:`~jaxvo.estimator.trust` (the final pass's statistics and the failure flag),
:mod:`~jaxvo.estimator.levels` (the coarse-to-fine program), :mod:`~jaxvo.estimator.inputs` (its
checked arguments) and :mod:`~jaxvo.estimator.motion` (:func:`estimate_motion`, the entry point).
"""
from jaxvo.estimator.inputs import EstimateArgs, as_float32, checked_config, checked_key, estimate_args, num_levels
from jaxvo.estimator.levels import estimate_arrays, estimate_arrays_jit, trace_count
from jaxvo.estimator.motion import PreparedFrame, estimate_motion, prepare_frame
from jaxvo.estimator.result import MotionEstimate
from jaxvo.estimator.solvers import least_squares
from jaxvo.estimator.trust import MIN_CONDITIONING, TrustStats, conditioning, explain_validity, pixel_counts, \
    position_sd

__all__ = ["EstimateArgs", "MIN_CONDITIONING", "MotionEstimate", "PreparedFrame", "TrustStats", "as_float32",
           "checked_config", "checked_key", "conditioning", "estimate_args", "estimate_arrays", "estimate_arrays_jit",
           "estimate_motion", "explain_validity", "least_squares", "num_levels", "pixel_counts", "position_sd",
           "prepare_frame", "trace_count"]
