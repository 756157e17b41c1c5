"""Exposure changes between frames: a luminance offset ``I_cur ~ I_ref + offset``.

Kinect-class cameras set their exposure automatically. When a person in a light
pullover fills half of the picture the exposure changes, and the static wall behind
comes out 30-40 grey levels brighter or darker a few frames later (Bonn crowd, frames
109 -> 120: over the pixels whose depth agrees at the true pose, the median luminance
residual is +36; ``python experiments/exposure.py``). Most pixels then fail the paper's
|luminance residual| < 30 test at the true pose.

Depth does not depend on exposure, so the pixels whose depth agrees at the pose the
level starts from pick out surfaces both frames see; the median of their luminance
residuals is the offset (robust to the half of them that belong to something else).
Offsets under a third of ``thresh_lum`` are left alone: the inlier test and the Huber
weights absorb them, and fitting them only adds noise. The reference's intensities are
shifted; the current image, whose gradients the Jacobian uses, is left as it is.
A gain (DSO's affine model) was tried too: matching the quartiles of the two sides'
luminance over the same pixels was noisier (Bonn crowd, seeds 0-2, RPE 1 s 0.084 against
0.070 m/s without any compensation).
"""
from __future__ import annotations

import jax.numpy as jnp

from jaxvo.camera import Camera
from jaxvo.pyramid import Level
from jaxvo.residuals import RefPoints, residuals

__all__ = ["fit_offset", "apply"]

# fewer agreeing pixels than this and the fit is not trusted
_MIN_PIXELS = 64


def fit_offset(T_cur_ref, ref: RefPoints, cur: Level, camera: Camera, thresh_lum, thresh_depth):
    """Scalar luminance offset (0-255 units) of the current level against the reference points
    ``ref`` at the pose T_cur_ref: the median luminance residual over the points trusted as static
    (weight >= 0.5) whose |depth residual| < thresh_depth. 0 when fewer than 64 points agree or
    |offset| <= thresh_lum / 3."""
    res = residuals(T_cur_ref, ref, cur, camera)
    ok = res.valid_depth & (jnp.abs(res.r_depth) < thresh_depth) & (ref.weight >= 0.5)
    offset = jnp.nanmedian(jnp.where(ok, res.r_int, jnp.nan))
    use = (jnp.sum(ok) >= _MIN_PIXELS) & (jnp.abs(offset) > thresh_lum / 3)
    return jnp.where(use, offset, 0.0).astype(jnp.float32)


def apply(level: Level, offset) -> Level:
    """The reference level with ``offset`` added to its luminance (gradients unchanged)."""
    shift = jnp.stack([offset, jnp.zeros_like(offset), jnp.zeros_like(offset)])
    return level._replace(intensity=level.intensity + offset, igrad=level.igrad + shift)
