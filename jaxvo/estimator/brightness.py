"""Exposure changes between frames: a luminance offset ``I_cur ~ I_ref + offset``.

Kinect-class cameras set their exposure automatically. When a person in a light
pullover fills half of the picture the exposure changes, and the static wall behind
comes out 30-40 grey levels brighter or darker a few frames later (Bonn crowd, frames
109 -> 120: over the pixels whose depth agrees at the true pose, the median luminance
residual is +36; ``python -m experiments.diagnostics.exposure``). Most pixels then fail the paper's
|luminance residual| < 30 test at the true pose.

Depth does not depend on exposure, so the pixels whose depth agrees at the pose the
level starts from pick out surfaces both frames see; the median of their luminance
residuals is the offset (robust to the half of them that belong to something else).
Offsets under a third of ``thresh_lum`` are left alone: the inlier test and the Huber
weights absorb them, and fitting them only adds noise. The reference's intensities are
shifted; the current image, whose gradients the Jacobian uses, is left as it is.
Only an offset is fitted, no gain (DSO's affine model): a gain fitted over the same pixels
is noisier than the offset it adds to (docs/decisions/brightness.md).
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxvo.camera import Camera
from jaxvo.estimator.pyramid import Level
from jaxvo.estimator.residuals import RefPoints, residuals

__all__ = ["fit_offset", "apply", "masked_median"]

# fewer agreeing pixels than this and the fit is not trusted
_MIN_PIXELS = 64
# bisection steps of masked_median: enough to close any float32 interval of the luminance range
_STEPS = 40


def fit_offset(T_cur_ref, ref: RefPoints, cur: Level, camera: Camera, thresh_lum, thresh_depth):
    """Scalar luminance offset (0-255 units) of the current level against the reference points
    ``ref`` at the pose T_cur_ref: the median luminance residual over the points trusted as static
    (weight >= 0.5) whose |depth residual| < thresh_depth. 0 when fewer than 64 points agree or
    |offset| <= thresh_lum / 3."""
    res = residuals(T_cur_ref, ref, cur, camera)
    ok = res.valid_depth & (jnp.abs(res.r_depth) < thresh_depth) & (ref.weight >= 0.5)
    offset = masked_median(res.r_int, ok)
    use = (jnp.sum(ok) >= _MIN_PIXELS) & (jnp.abs(offset) > thresh_lum / 3)
    return jnp.where(use, offset, 0.0).astype(jnp.float32)


def masked_median(x, mask):
    """The median of the finite values ``x[mask]`` (x: (N,) float32, mask: (N,) bool): the mean of
    the two middle values for an even count, as ``jnp.nanmedian``; NaN for an empty mask.

    Each middle value is found by bisection on the value (count the values at or below the
    midpoint, keep the half that holds it), then snapped to the largest value at or below the
    upper end: O(N) per step and no sort, where XLA's CPU sort makes ``jnp.nanmedian`` of a
    level's points several times slower (docs/decisions/cpu-kernels.md).
    (:func:`jaxvo.estimator.solvers.robust_scale` reads the Huber scale's median of |r| off a histogram
    instead, to a bin's width; the offset is compared with thresh_lum / 3 and shifts every
    reference pixel, and this one reproduces ``jnp.nanmedian``'s value exactly;
    docs/decisions/brightness.md.)"""
    n = jnp.sum(mask)
    k = jnp.stack([(n - 1) // 2, n // 2])          # ranks (from 0) of the two middle values
    lo = jnp.min(jnp.where(mask, x, jnp.inf)) - 1.0
    hi = jnp.max(jnp.where(mask, x, -jnp.inf))
    bounds = (jnp.stack([lo, lo]), jnp.stack([hi, hi]))   # count(<= lo) <= k < count(<= hi)

    def step(_, b):
        lo, hi = b
        mid = 0.5 * (lo + hi)
        above = jnp.sum(mask & (x <= mid[:, None]), axis=1) > k
        return jnp.where(above, lo, mid), jnp.where(above, mid, hi)

    _, hi = jax.lax.fori_loop(0, _STEPS, step, bounds)
    middle = jnp.max(jnp.where(mask & (x <= hi[:, None]), x, -jnp.inf), axis=1)
    return jnp.where(n > 0, 0.5 * (middle[0] + middle[1]), jnp.nan)


def apply(level: Level, offset) -> Level:
    """The reference level with ``offset`` added to its luminance (gradients unchanged)."""
    shift = jnp.stack([offset, jnp.zeros_like(offset), jnp.zeros_like(offset)])
    return level._replace(intensity=level.intensity + offset, igrad=level.igrad + shift)
