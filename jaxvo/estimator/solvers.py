"""Weighted Gauss-Newton pose refinement and robust weight functions.

This is the one module that touches jaxopt. The pose is refined by
``jaxopt.LevenbergMarquardt`` (Gauss-Newton with adaptive damping) on the photometric residual
(:func:`solve_pose`: the levels' solves and the consensus refinement); the tiny 54-residual
RANSAC hypotheses, solved by the hundred under ``vmap``, use the same LM written out on the
closed-form 6x6 normal equations (:func:`solve_pose_small`), a fraction of jaxopt's program,
with per-residual weights passed as arrays so that shapes stay static: a
weight of 0 removes a pixel without changing any shape. The Jacobian is
materialised analytically (:func:`jaxvo.estimator.residuals.photometric_terms`), not by
autodiff through the image sampler.

Both solvers form the normal equations in one pass over the pixels (:func:`_system`: warp,
sample, accumulate [J r]^T W [J r]); jaxopt is handed the problem in its equivalent 7-residual
square-root form (:func:`_square_root_form`), so its iterates are those of the N-residual
problem while its own work is on 7 x 6 arrays. Programs that run the solvers are compiled with
:data:`COMPILER_OPTIONS` (:func:`jit`).

The parameters jaxopt sees are a left increment ``delta`` (twist (w, v)) of
the pose being refined: ``T_cur_ref = exp(hat(delta)) @ T0``, starting at
``delta = 0``, so the Jacobian at each iterate is the standard one.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxvo import geometry
from jaxvo.camera import Camera
from jaxvo.estimator.pyramid import Level
from jaxvo.estimator.residuals import RefPoints, photometric_terms, residuals, rgbd_terms

__all__ = ["Solution", "solve_pose", "solve_pose_small", "robust_scale", "huber_weights", "irls", "COMPILER_OPTIONS",
           "jit"]

# Consistency constant of the MAD for a Gaussian: sigma = 1.4826 * median(|r|).
MAD_TO_SIGMA = 1.4826


# XLA options for every program that runs these solvers (``jit`` below). Loop-invariant code
# motion is off: it hoists the invariant parts of each of the evaluations that jaxopt's update makes
# at one point (residual, auxiliary output, Jacobian) into separate loop-carried values, after which
# XLA can no longer merge the evaluations into one pass over the pixels, which makes the
# consensus refinement several times slower for the same results (docs/decisions/cpu-kernels.md).
COMPILER_OPTIONS = {"xla_disable_hlo_passes": "while-loop-invariant-code-motion"}


def jit(fun, **kwargs):
    """``jax.jit(fun, **kwargs)`` compiled with :data:`COMPILER_OPTIONS`."""
    return jax.jit(fun, compiler_options=COMPILER_OPTIONS, **kwargs)


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


# jitted: jaxopt's solver and the LM loops evaluate the system at 18 places of the default
# estimator, with 3 distinct shapes; a nested jit traces it once per shape, so the lowered
# program is smaller and traced sooner (docs/decisions/cpu-kernels.md). XLA inlines the call:
# the same compiled program, the same poses.
@jax.jit
def _system(delta, T0, ref, cur, camera, w, depth_weight):
    """The weighted normal equations at exp(delta) @ T0 in one pass over the pixels: the (7, 7)
    matrix M = [J r]^T diag(w) [J r], i.e. M[:6, :6] = J^T W J, M[:6, 6] = J^T W r and
    M[6, 6] = r^T W r, with w (M,) per residual (M = N or 2N, see :func:`_terms`)."""
    r, J = _terms(delta, T0, ref, cur, camera, depth_weight)
    A = jnp.concatenate([J, r[:, None]], 1)
    return (A * w[:, None]).T @ A


# Relative diagonal loading of J^T W J before its Cholesky factor is taken (1e-6 of the largest
# diagonal entry, the size of LM's initial damping): keeps the factor finite in float32 when the
# pose is poorly constrained (or no pixel is valid), and changes a step by about that fraction.
_JITTER = 1e-6


def _loaded(H):
    """J^T W J (6, 6) with the diagonal loading that both Levenberg-Marquardt solvers factor."""
    return H + (_JITTER * jnp.max(jnp.diag(H)) + 1e-30) * jnp.eye(6, dtype=H.dtype)


def _square_root_form(M):
    """A 7-residual least-squares problem equivalent to the normal equations M (see :func:`_system`)
    at one linearisation point: returns (rho (7,), R (7, 6)) with R^T R = J^T W J (loaded, see
    :data:`_JITTER`), R^T rho = J^T W r and |rho|^2 = r^T W r, where R is the upper Cholesky factor
    over a row of zeros and rho = (R^-T J^T W r, sqrt(r^T W r - |R^-T J^T W r|^2)).

    Cost, gradient and Gauss-Newton matrix are those of the N-residual problem, so
    Levenberg-Marquardt on (rho, R) takes exactly the steps it takes on (sqrt(w) r, sqrt(w) J).
    """
    H, g, c = M[:6, :6], M[:6, 6], M[6, 6]
    L = jnp.linalg.cholesky(_loaded(0.5 * (H + H.T)))
    y = jax.scipy.linalg.solve_triangular(L, g, lower=True)
    rho = jnp.concatenate([y, jnp.sqrt(jnp.maximum(c - y @ y, 0.0))[None]])
    return rho, jnp.concatenate([L.T, jnp.zeros((1, 6), L.dtype)])


def _square_root_fun(T0, ref, cur, camera, w, depth_weight):
    """The residual function jaxopt minimises: ``delta -> (rho(delta), M(delta))`` (the 7-residual
    square-root form of :func:`_square_root_form` and, as jaxopt's auxiliary output, the normal
    equations M of :func:`_system`), for the left increment ``delta`` of ``T0``.

    Its derivative is a ``jax.custom_jvp``: the Cholesky factor R (analytic, from the analytic
    Jacobian of :mod:`jaxvo.estimator.residuals`, never autodiff through the image sampler). jaxopt's
    LevenbergMarquardt with ``materialize_jac=True`` forms the Jacobian by ``jax.jacfwd``
    (jaxopt 0.8.x ignores ``jac_fun`` on that path), which yields R. Handing jaxopt the
    problem in this form instead of the N (weighted) residuals and their N x 6 Jacobian gives the
    same iterates, while every evaluation is one fused pass over the pixels (warp, sample,
    accumulate M) and jaxopt's own work is on 7 x 6 arrays; jaxopt evaluates the residual
    function and its Jacobian at the same point within an update, and XLA computes that pass
    once for both.
    """
    @jax.custom_jvp
    def fun(delta):
        M = _system(delta, T0, ref, cur, camera, w, depth_weight)
        return _square_root_form(M)[0], M

    @fun.defjvp
    def fun_jvp(primals, tangents):
        (delta,), (t,) = primals, tangents
        M = _system(delta, T0, ref, cur, camera, w, depth_weight)
        rho, R = _square_root_form(M)
        return (rho, M), (R @ t, jnp.zeros_like(M))

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
        # the first update inside the loop too: one copy of jaxopt's update in the program, not two
        first = state.iter_num == 0
        return first | ((state.iter_num < maxiter) & (jnp.linalg.norm(state.delta) > xtol) & (rejected < 2))

    params, state, _ = jax.lax.while_loop(cond, step, (params, solver.init_state(params), jnp.int32(0)))
    return params, state


def solve_pose(T0, ref: RefPoints, cur: Level, camera: Camera, weights, maxiter: int,
               xtol: float = 1e-4, depth_weight=None) -> Solution:
    """Minimise 0.5 * sum_i w_i r_i(T)^2 over T_cur_ref, starting at T0.

    With ``depth_weight=None`` the residuals are photometric only (the paper's
    cost); with a number they are the joint photometric + depth residuals of
    :func:`jaxvo.estimator.residuals.rgbd_terms`, the depth term scaled by ``depth_weight``
    (luminance units per metre).

    Args:
      T0: (4, 4) initial T_cur_ref. ref: (N,) reference points. cur: current level.
      weights: (N,) non-negative weights per point (0 = ignore), or (N, 2) per
        term for the RGB-D residual; invalid residuals are 0 anyway.
      maxiter: static iteration cap.
      xtol: stop once an LM step is shorter than this (twist norm: radians and metres mixed;
        1e-5 is 0.01 mm / 0.0006 deg).
    """
    import jaxopt   # at trace time only: a program loaded from the cache needs neither jaxopt nor scipy

    w, total = _normalised_weights(weights, depth_weight)
    solver = jaxopt.LevenbergMarquardt(
        residual_fun=_square_root_fun(T0, ref, cur, camera, w, depth_weight), materialize_jac=True,
        has_aux=True, solver="cholesky", maxiter=maxiter, damping_parameter=1e-6, implicit_diff=False, jit=True)
    params, state = _run_lm(solver, jnp.zeros(6, jnp.float32), maxiter, xtol)
    # guard: a degenerate system (e.g. no valid pixel) must not poison the pose
    ok = jnp.all(jnp.isfinite(params))
    delta = jnp.where(ok, params, 0.0)
    M = state.aux  # the normal equations at the last accepted iterate
    return Solution(geometry.exp(delta) @ T0, state.iter_num.astype(jnp.int32), M[:6, :6] * total,
                    0.5 * M[6, 6] * total)


def least_squares(residual_fun, params, maxiter: int, xtol: float = 1e-6, damping: float = 1e-6):
    """Minimise 0.5 * ||residual_fun(params)||^2 over a flat parameter vector with the same jaxopt
    Levenberg-Marquardt (Cholesky normal equations, autodiff Jacobian) and stopping rule as
    :func:`solve_pose` (:func:`_run_lm`). For small problems on the host's side of tracking, e.g.
    the keyframe window's pose graph (:mod:`jaxvo.tracking.window`). Traceable (call it inside
    ``jax.jit``). Returns (params, iterations)."""
    import jaxopt

    solver = jaxopt.LevenbergMarquardt(residual_fun=residual_fun, materialize_jac=True, solver="cholesky",
                                       maxiter=maxiter, damping_parameter=damping, implicit_diff=False,
                                       jit=True)
    params, state = _run_lm(solver, params, maxiter, xtol)
    return params, state.iter_num.astype(jnp.int32)


def _normalised_weights(weights, depth_weight):
    """(w (M,), total): per-residual weights from per-point ``weights`` ((N,) or (N, 2)), negative
    ones 0, divided by their sum ``total`` (at least 1).

    The normalisation leaves the optimum unchanged and gives the Hessian a size-independent
    scale, so that LM's damping (capped at 2^32 by jaxopt) can still shrink a rejected step
    until the step test stops it.
    """
    weights = jnp.maximum(weights, 0.0).astype(jnp.float32)
    if depth_weight is not None:
        weights = jnp.broadcast_to(weights.reshape(weights.shape[0], -1), (weights.shape[0], 2)).reshape(-1)
    total = jnp.maximum(jnp.sum(weights), 1.0)
    return weights / total, total


def _cholesky_solve6(A, b):
    """x with A x = b for a symmetric positive definite (6, 6) A, Cholesky written out.

    For tiny systems solved by the thousand under ``vmap`` this is plain element-wise
    arithmetic, cheaper to compile and to run than a batched LAPACK call.
    """
    n = A.shape[0]
    Lm = [[None] * n for _ in range(n)]
    for i in range(n):
        for j in range(i + 1):
            acc = A[i, j] - sum((Lm[i][k] * Lm[j][k] for k in range(j)), jnp.zeros((), A.dtype))
            if i == j:
                Lm[i][i] = jnp.sqrt(jnp.maximum(acc, 1e-30))
            else:
                Lm[i][j] = acc / Lm[j][j]
    y = []
    for i in range(n):
        y.append((b[i] - sum((Lm[i][k] * y[k] for k in range(i)), jnp.zeros((), b.dtype))) / Lm[i][i])
    x = [None] * n
    for i in reversed(range(n)):
        x[i] = (y[i] - sum((Lm[k][i] * x[k] for k in range(i + 1, n)), jnp.zeros((), b.dtype))) / Lm[i][i]
    return jnp.stack(x)


def solve_pose_small(T0, ref: RefPoints, cur: Level, camera: Camera, weights, maxiter: int,
                     xtol: float = 1e-4, depth_weight=None) -> Solution:
    """:func:`solve_pose` written out for small problems (the RANSAC hypotheses' 54 pixels).

    The same Levenberg-Marquardt (Madsen & Nielsen's damping update, as jaxopt's, on the left
    increment ``delta`` of ``T0``, the same stopping rules: step shorter than ``xtol``, two
    rejections in a row, or ``maxiter`` iterations) on the closed-form 6x6 normal equations,
    with one residual + Jacobian evaluation per iteration. It compiles to a fraction of
    jaxopt's program and is cheap under ``jax.vmap``; same arguments and result as
    :func:`solve_pose`.
    """
    w, total = _normalised_weights(weights, depth_weight)

    def system(delta):
        return _system(delta, T0, ref, cur, camera, w, depth_weight)

    def normal(M):  # the loaded Gauss-Newton matrix, gradient and cost that jaxopt sees
        return _loaded(0.5 * (M[:6, :6] + M[:6, :6].T)), M[:6, 6], 0.5 * M[6, 6]

    def cond(state):
        it, _, _, _, inc, step_norm = state
        return (it < maxiter) & (step_norm > xtol) & (inc < 8)

    def body(state):
        # the first trip (it = -1) only evaluates the system at delta = 0 and sets the initial
        # damping: one evaluation of the system in the program (compile time), not two
        it, delta, M, mu, inc, _ = state
        first = it < 0
        H, g, loss = normal(M)
        step = jnp.where(first, 0.0, -_cholesky_solve6(H + mu * jnp.eye(6, dtype=H.dtype), g))
        M2 = system(delta + step)
        gain = (loss - 0.5 * M2[6, 6]) / (0.5 * step @ (mu * step - g))
        ok = first | (gain > 0)
        big = jnp.float32(2.0 ** 32)
        delta = jnp.where(ok, delta + step, delta)
        M = jnp.where(ok, M2, M)
        mu_first = 1e-6 * jnp.max(jnp.diag(normal(M2)[0]))
        mu = jnp.where(first, mu_first,
                       jnp.where(ok, mu * jnp.maximum(1 / 3, 1 - (2 * gain - 1) ** 3), jnp.minimum(mu * inc, big)))
        inc = jnp.where(first | ok, 2.0, jnp.minimum(2 * inc, big))
        return it + 1, delta, M, mu, inc, jnp.where(first, jnp.inf, jnp.linalg.norm(step))

    z = jnp.zeros((), jnp.float32)
    state = (jnp.int32(-1), jnp.zeros(6, jnp.float32), jnp.zeros((7, 7), jnp.float32), z, jnp.float32(2.0),
             jnp.float32(jnp.inf))
    it, delta, M, _, _, _ = jax.lax.while_loop(cond, body, state)
    ok = jnp.all(jnp.isfinite(delta))
    delta = jnp.where(ok, delta, 0.0)
    return Solution(geometry.exp(delta) @ T0, it, M[:6, :6] * total, 0.5 * M[6, 6] * total)


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
    # one query: the count of bins whose cdf is < half, without the binary search's loop
    k = jnp.clip(jnp.searchsorted(cdf, half, method="compare_all"), 0, bins - 1)
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
