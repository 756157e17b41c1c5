"""Whether an estimate can be trusted: the statistics of the final dense pass
(:class:`TrustStats`), the failure flag's rule on them, and :func:`explain_validity`."""
from __future__ import annotations

from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from jaxvo.camera import Camera
from jaxvo.config import Config
from jaxvo.estimator import brightness
from jaxvo.estimator.inputs import as_float32, checked_config, num_levels
from jaxvo.estimator.pyramid import build_pyramid
from jaxvo.estimator.ransac import inliers
from jaxvo.estimator.residuals import reference_points, residuals
from jaxvo.estimator.result import MotionEstimate
from jaxvo.frame import Frame, validate_pair

__all__ = ["TrustStats", "conditioning", "explain_validity", "final_counts", "final_residuals", "pixel_counts",
           "position_sd", "trust_stats", "trusted", "MIN_CONDITIONING", "MIN_VALID_PIXELS"]

#: Smallest ratio of the information matrix's extreme eigenvalues (:func:`conditioning`) that an
#: estimate is trusted at: below it some direction of the twist is not determined by the pixels.
MIN_CONDITIONING = 1e-9

#: Fewest reference pixels with valid depth, at the finest level processed, that an estimate
#: is trusted on. The other statistics are fractions of pixels, and they judge a pose to within
#: about a pixel: on images smaller than about 64x48 a pixel spans degrees, so a pose a few
#: degrees and centimetres off agrees with the data as well as the right one. Every level of
#: a 640x480 or 320x240 recording down to 80x60 holds several thousand.
MIN_VALID_PIXELS = 2000


def final_residuals(ref_l, cur_l, cam, T, config):
    """Every reference pixel of a level, its residuals at the final pose, the inlier mask and the
    pixels the residual scale is taken over (those the final solve trusted: inliers for ransac)."""
    dense = reference_points(ref_l, cam, 1)
    res = residuals(T, dense, cur_l, cam)
    inl = inliers(res, config.thresh_lum, config.thresh_depth)
    return dense, res, inl, (inl if config.method == "ransac" else res.valid_int)


class TrustStats(NamedTuple):
    """What :attr:`MotionEstimate.valid` is decided on (scalars, at the finest level processed).

    finite: T_cur_ref and the information matrix are finite.
    conditioning: smallest / largest eigenvalue of the information matrix.
    inlier_ratio: inliers / reference pixels with valid depth (as in MotionEstimate).
    overlap: reference pixels with valid depth that land inside the current image on valid
      depth, as a fraction of the reference pixels with valid depth.
    depth_agreement: overlapping pixels whose depth residual is under thresh_depth, as a
      fraction of the overlapping pixels (the geometry agrees; people moving lower it).
    textured: fraction of the valid-depth reference pixels that are textured (intensity
      gradient above thresh_lum / 6 per pixel).
    photometric_agreement: of the textured pixels whose depth agrees, the fraction whose
      luminance residual is under thresh_lum too. Where the geometry agrees the scene is
      the same surface, and at the right pose its texture lands on the same texture;
      smooth areas agree with any pose, so only textured pixels count (0 without any).
    valid_pixels: reference pixels with valid depth (int32), the number the fractions are
      taken over; fewer than :data:`MIN_VALID_PIXELS` (images under about 64x48) is too few
      to tell a pose from one a pixel off.
    """
    finite: jnp.ndarray
    conditioning: jnp.ndarray
    inlier_ratio: jnp.ndarray
    overlap: jnp.ndarray
    depth_agreement: jnp.ndarray
    textured: jnp.ndarray
    photometric_agreement: jnp.ndarray
    valid_pixels: jnp.ndarray


class _Counts(NamedTuple):
    """Pixel counts (int32 scalars) of the final dense pass, see :func:`final_counts`."""
    valid: jnp.ndarray           # reference pixels with valid depth
    inliers: jnp.ndarray         # inlier pixels
    weighted: jnp.ndarray        # pixels the residual scale is taken over
    valid_inliers: jnp.ndarray
    overlap: jnp.ndarray
    depth_ok: jnp.ndarray
    textured: jnp.ndarray
    textured_depth_ok: jnp.ndarray
    textured_agree: jnp.ndarray


def final_counts(ref_l, res, inl, dense, wts, config) -> _Counts:
    """The final pass's pixel counts (what :class:`TrustStats` and the inlier ratio divide), in one
    reduction (:func:`pixel_counts`). ``wts``: (N,) bool, the pixels the residual scale is taken over.

    The statistics count every reference pixel with valid depth, trusted as static or not:
    counting only the pixels the segmentation trusts would let a wrong segmentation also hide
    a wrong estimate (docs/decisions/failure-flag.md)."""
    ref_valid = dense.valid
    g = jnp.sqrt(ref_l.igrad[..., 1] ** 2 + ref_l.igrad[..., 2] ** 2).reshape(-1)
    textured = ref_valid & (g > config.thresh_lum / 6)
    overlap = res.valid_depth & ref_valid
    depth_ok = overlap & (jnp.abs(res.r_depth) < config.thresh_depth)
    photo_ok = jnp.abs(res.r_int) < config.thresh_lum
    return _Counts(*pixel_counts(ref_valid, inl, wts, inl & ref_valid, overlap, depth_ok, textured,
                                  textured & depth_ok, textured & depth_ok & photo_ok))


def pixel_counts(*masks):
    """The True pixels of each of ``masks`` (bool arrays of one shape), int32 scalars, in one
    reduction over the pixels: XLA reduces each ``jnp.sum`` in a pass of its own over them
    (docs/decisions/cpu-kernels.md), and integer sums are exact in any
    order, so the counts are those of ``jnp.sum``."""
    ops = tuple(m.astype(jnp.int32) for m in masks)
    dims = tuple(range(ops[0].ndim))
    return jax.lax.reduce(ops, (jnp.int32(0),) * len(ops), lambda a, b: tuple(x + y for x, y in zip(a, b)), dims)


def conditioning(info, xp=jnp):
    """Smallest over largest eigenvalue of the (6, 6) information matrix ``info`` (symmetrised),
    with the array module ``xp``: jax.numpy inside the estimator, numpy on the host."""
    eig = xp.linalg.eigvalsh(0.5 * (info + info.T))
    return eig[0] / xp.maximum(eig[-1], 1e-30)


def position_sd(info) -> float:
    """The largest standard deviation (metres) of an estimate's translation that its (6, 6)
    information matrix ``info`` (twist order w, v) leaves, on the host: the square root of the
    largest diagonal entry of the translation block of its (pseudo-)inverse; inf or NaN where
    ``info`` is not finite. Large where the pixels that constrain the pose lie in a small part of
    the image."""
    info = np.asarray(info, np.float64)
    if not np.all(np.isfinite(info)):
        return float("nan")
    C = np.linalg.pinv(0.5 * (info + info.T))
    return float(np.sqrt(np.max(np.abs(np.diag(C)[3:]))))


def trust_stats(c: _Counts, info, T) -> TrustStats:
    """The :class:`TrustStats` of the final pass's counts, information matrix and pose."""
    def frac(a, b):
        return a / jnp.maximum(b, 1)
    finite = jnp.all(jnp.isfinite(T)) & jnp.all(jnp.isfinite(info))
    return TrustStats(finite, conditioning(info), frac(c.valid_inliers, c.valid),
                      frac(c.overlap, c.valid), frac(c.depth_ok, c.overlap), frac(c.textured, c.valid),
                      frac(c.textured_agree, c.textured_depth_ok), c.valid)


def trusted(s: TrustStats, config: Config):
    """The failure flag's rule (measured as a classifier by experiments/failure_flag.py)."""
    return (s.finite & (s.conditioning > MIN_CONDITIONING) & (s.inlier_ratio >= config.min_inlier_ratio)
            & (s.depth_agreement >= config.min_depth_agreement)
            & (s.photometric_agreement >= config.min_photometric_agreement)
            & (s.valid_pixels >= MIN_VALID_PIXELS))


@jax.jit
def _explain(ref_int, ref_depth, cur_int, cur_depth, camera, config, T, info, offset):
    level = config.finest_level
    L = num_levels(config, ref_int.shape[1], ref_int.shape[0])
    ref_l = build_pyramid(ref_int, ref_depth, L, config.max_depth)[level]
    ref_l = brightness.apply(ref_l, offset)
    cur_l = build_pyramid(cur_int, cur_depth, L, config.max_depth)[level]
    dense, res, inl, wts = final_residuals(ref_l, cur_l, camera.at_level(level), T, config)
    s = trust_stats(final_counts(ref_l, res, inl, dense, wts, config), info, T)
    return s, trusted(s, config)


def explain_validity(ref: Frame, cur: Frame, camera: Camera, estimate: "MotionEstimate",
                     config: Optional[Config] = None):
    """Why ``estimate`` (of ``estimate_motion(ref, cur, camera, config)``) is or is not ``valid``:
    returns ``(TrustStats, valid)``, recomputed exactly as the estimator does at the end. The rule
    (:func:`trusted`): finite, conditioning > :data:`MIN_CONDITIONING`, ``inlier_ratio``, ``depth_agreement`` and
    ``photometric_agreement`` at least the config's ``min_*`` values, and ``valid_pixels`` at
    least :data:`MIN_VALID_PIXELS`."""
    config = checked_config(config, camera)
    validate_pair(ref, cur, camera)
    offset = 0.0 if estimate.brightness is None else estimate.brightness
    return _explain(as_float32(ref.intensity), as_float32(ref.depth), as_float32(cur.intensity),
                    as_float32(cur.depth), camera, config, estimate.T_cur_ref, estimate.information,
                    jnp.float32(offset))
