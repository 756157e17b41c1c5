"""Weighted Gauss-Newton pose refinement and robust weight functions.

This is the one module that touches jaxopt. The pose is refined by
``jaxopt.LevenbergMarquardt`` (Gauss-Newton with adaptive damping, which keeps
the tiny 54-residual RANSAC problems well posed) on the photometric residual,
with per-residual weights passed as arrays so that shapes stay static: a
weight of 0 removes a pixel without changing any shape. The Jacobian is
materialised analytically (:func:`jaxvo.residuals.photometric_terms`), not by
autodiff through the image sampler.

The parameters jaxopt sees are a left increment ``delta`` (twist (w, v)) of
the pose being refined: ``T_cur_ref = exp(hat(delta)) @ T0``, starting at
``delta = 0``, so the Jacobian at each iterate is the standard one.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import jaxopt

from jaxvo import geometry
from jaxvo.camera import Camera
from jaxvo.pyramid import Level
from jaxvo.residuals import RefPoints, photometric_terms, residuals, rgbd_terms

__all__ = ["Solution", "solve_pose", "robust_scale", "huber_weights", "irls"]

# Consistency constant of the MAD for a Gaussian: sigma = 1.4826 * median(|r|).
MAD_TO_SIGMA = 1.4826


class Solution(NamedTuple):
    """Result of a weighted refinement.

    T: (4, 4) refined T_cur_ref. iterations: LM iterations run (int32).
    hessian: (6, 6) J^T W J at the last accepted iterate (w.r.t. a left
    perturbation of T). cost: 0.5 * sum(w * r^2) there.
    """
    T: jnp.ndarray
    iterations: jnp.ndarray
    hessian: jnp.ndarray
    cost: jnp.ndarray


def _terms(delta, T0, ref, cur, camera, depth_weight):
    """Residuals (M,) and Jacobian (M, 6) at exp(delta) @ T0; M = N (photometric) or 2N (RGB-D)."""
    T = geometry.exp(delta) @ T0
    if depth_weight is None:
        r, J, _ = photometric_terms(T, ref, cur, camera)
        return r, J
    r, J, _ = rgbd_terms(T, ref, cur, camera, depth_weight)
    return r.reshape(-1), J.reshape(-1, 6)


def _weighted_residual_fun(T0, ref, cur, camera, sqrt_w, depth_weight):
    """The weighted residual ``delta -> sqrt_w * r(exp(delta) @ T0)`` as a function of the twist alone,
    whose derivative is the analytic Jacobian (a ``jax.custom_jvp``).

    jaxopt's LevenbergMarquardt with ``materialize_jac=True`` forms the Jacobian by ``jax.jacfwd``
    of the residual function (jaxopt 0.8.x ignores ``jac_fun`` on that path), which here yields
    the custom JVP applied to the six basis twists: the analytic Jacobian, not autodiff through
    the image sampler. The rule computes residual and Jacobian together, so each LM step warps
    and gathers once.
    """
    @jax.custom_jvp
    def fun(delta):
        return sqrt_w * _terms(delta, T0, ref, cur, camera, depth_weight)[0]

    @fun.defjvp
    def fun_jvp(primals, tangents):
        (delta,), (t,) = primals, tangents
        r, J = _terms(delta, T0, ref, cur, camera, depth_weight)
        return sqrt_w * r, (sqrt_w[:, None] * J) @ t

    return fun


def _run_lm(solver, params, maxiter: int, xtol: float):
    """Drive ``solver`` (a jaxopt.LevenbergMarquardt) through its public ``init_state`` / ``update``
    until an LM step is shorter than ``xtol`` (absolute twist norm), two steps in a row were
    rejected, or ``maxiter`` updates ran (the first one always runs).

    jaxopt's own criteria (gradient norm, step relative to ||params||) do not suit a left
    increment that starts at 0. Rejections matter because the Jacobian uses smoothed image
    gradients, not the exact derivative of the bilinear interpolant: at the noise floor the
    proposed step stays finite but no longer lowers the cost, and further iterations are
    wasted. A rejected step leaves the parameters unchanged.
    Returns (params, state).
    """
    def step(carry):
        params, state, rejected = carry
        new, state = solver.update(params, state)
        same = jnp.all(new == params)
        return new, state, jnp.where(same, rejected + 1, 0)

    def cond(carry):
        _, state, rejected = carry
        return (state.iter_num < maxiter) & (jnp.linalg.norm(state.delta) > xtol) & (rejected < 2)

    carry = step((params, solver.init_state(params), jnp.int32(0)))
    params, state, _ = jax.lax.while_loop(cond, step, carry)
    return params, state


def solve_pose(T0, ref: RefPoints, cur: Level, camera: Camera, weights, maxiter: int,
               xtol: float = 1e-4, depth_weight=None) -> Solution:
    """Minimise 0.5 * sum_i w_i r_i(T)^2 over T_cur_ref, starting at T0.

    With ``depth_weight=None`` the residuals are photometric only (the paper's
    cost); with a number they are the joint photometric + depth residuals of
    :func:`jaxvo.residuals.rgbd_terms`, the depth term scaled by ``depth_weight``
    (luminance units per metre).

    Args:
      T0: (4, 4) initial T_cur_ref. ref: (N,) reference points. cur: current level.
      weights: (N,) non-negative weights per point (0 = ignore), or (N, 2) per
        term for the RGB-D residual; invalid residuals are 0 anyway.
      maxiter: static iteration cap.
      xtol: stop once an LM step is shorter than this (twist norm: radians and metres mixed;
        1e-5 is 0.01 mm / 0.0006 deg).
    """
    weights = jnp.maximum(weights, 0.0).astype(jnp.float32)
    if depth_weight is not None:
        weights = jnp.broadcast_to(weights.reshape(weights.shape[0], -1), (weights.shape[0], 2)).reshape(-1)
    # Normalise the cost by the total weight: the optimum is unchanged, and the
    # Hessian then has a size-independent scale, so that LM's damping (capped at
    # 2^32 by jaxopt) can still shrink a rejected step until the step test stops it.
    total = jnp.maximum(jnp.sum(weights), 1.0)
    sqrt_w = jnp.sqrt(weights / total)
    solver = jaxopt.LevenbergMarquardt(
        residual_fun=_weighted_residual_fun(T0, ref, cur, camera, sqrt_w, depth_weight), materialize_jac=True,
        solver="cholesky", maxiter=maxiter, damping_parameter=1e-6, implicit_diff=False, jit=True)
    params, state = _run_lm(solver, jnp.zeros(6, jnp.float32), maxiter, xtol)
    # guard: a degenerate system (e.g. no valid pixel) must not poison the pose
    ok = jnp.all(jnp.isfinite(params))
    delta = jnp.where(ok, params, 0.0)
    return Solution(geometry.exp(delta) @ T0, state.iter_num.astype(jnp.int32), state.jtj * total,
                    state.value * total)


def robust_scale(r, valid, max_abs: float = 256.0, bins: int = 1024):
    """MAD scale estimate sigma = 1.4826 * median(|r|) over valid residuals.

    The median is read off a fixed-size histogram of |r| on [0, max_abs) with
    linear interpolation inside the bin: O(N), static shapes, no sort.
    Residuals are assumed centred on zero (true at the optimum of the
    photometric cost), so the MAD about zero is used.
    """
    a = jnp.abs(r)
    width = max_abs / bins
    idx = jnp.clip((a / width).astype(jnp.int32), 0, bins - 1)
    hist = jnp.zeros(bins, jnp.float32).at[idx].add(valid.astype(jnp.float32))
    cdf = jnp.cumsum(hist)
    half = 0.5 * cdf[-1]
    k = jnp.clip(jnp.searchsorted(cdf, half), 0, bins - 1)
    below = jnp.where(k > 0, cdf[jnp.maximum(k - 1, 0)], 0.0)
    frac = (half - below) / jnp.maximum(hist[k], 1.0)
    median = (k + jnp.clip(frac, 0.0, 1.0)) * width
    return jnp.maximum(MAD_TO_SIGMA * median, 1e-3)


def huber_weights(r, valid, k, sigma):
    """Huber IRLS weights: 1 for |r| <= k*sigma, k*sigma/|r| beyond; 0 for invalid residuals."""
    a = jnp.abs(r)
    c = k * sigma
    return jnp.where(valid, jnp.where(a <= c, 1.0, c / jnp.maximum(a, 1e-12)), 0.0)


def irls(T0, ref: RefPoints, cur: Level, camera: Camera, base_weights, huber_k, outer: int,
         inner: int, depth_weight=None) -> Solution:
    """Huber M-estimation by iteratively re-weighted least squares.

    Each of ``outer`` rounds recomputes the residuals at the current pose,
    re-estimates the scale with :func:`robust_scale` (MAD, separately for the
    photometric and, with ``depth_weight``, the depth term) and the Huber
    weights, then runs ``inner`` LM iterations with those weights fixed.
    ``base_weights`` (N,) multiply the Huber weights (e.g. a consensus mask).
    """
    def round_(carry, _):
        T, iters = carry
        r, valid = _residual_columns(T, ref, cur, camera, depth_weight)
        valid = valid & (base_weights[:, None] > 0)
        sigma = jax.vmap(robust_scale, in_axes=(1, 1))(r, valid)
        w = base_weights[:, None] * huber_weights(r, valid, huber_k, sigma[None, :])
        if depth_weight is None:
            w = w[:, 0]
        sol = solve_pose(T, ref, cur, camera, w, inner, depth_weight=depth_weight)
        return (sol.T, iters + sol.iterations), sol

    (T, iters), sols = jax.lax.scan(round_, (T0, jnp.int32(0)), None, length=outer)
    last = jax.tree_util.tree_map(lambda x: x[-1], sols)
    return Solution(T, iters, last.hessian, last.cost)


def _residual_columns(T, ref, cur, camera, depth_weight):
    """Residuals (N, K) and validity (N, K) of the cost :func:`solve_pose` minimises (K = 1 or 2)."""
    if depth_weight is None:
        res = residuals(T, ref, cur, camera)
        return res.r_int[:, None], res.valid_int[:, None]
    r, _, valid = rgbd_terms(T, ref, cur, camera, depth_weight)
    return r, valid
