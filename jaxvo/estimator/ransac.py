"""RANSAC over pose hypotheses from random pixel patches (the paper's Algorithm 1, per level).

One call of :func:`ransac_level` runs, for one pyramid level:

1. k = ceil(log(1 - p) / log(1 - (1 - w)^n)) hypotheses (37 for p = 0.99,
   w = 0.3, n = 6), computed in batches of ``batch_size`` inside a
   ``lax.while_loop`` so that the loop can stop early; ``batches_per_trip`` batches are
   fitted in one vmapped call per trip (fewer, larger kernels), the stop still tested after
   each batch in turn;
2. each hypothesis: n random reference pixels with valid depth, each with its
   (2r+1)^2 neighbourhood (54 pixels for n = 6, r = 1), and the weighted
   Gauss-Newton/LM solve of the photometric least squares on those pixels
   only, starting from the level's initial pose; a batch is solved with
   ``jax.vmap``;
3. each hypothesis is scored by its inliers on the level's scoring pixels:
   |luminance residual| < ``thresh_lum`` and |depth residual| < ``thresh_depth``,
   each weighted by z^depth_power (jaxvo's default 2: the scene surface it images;
   0: the paper's count);
4. the best hypothesis so far is kept; the loop stops when a hypothesis's
   inlier ratio (or its share of the weighted total) exceeds ``early_exit_ratio``
   or after k hypotheses; with ``adaptive`` also once the batches drawn reach p for
   w = 1 - the best inlier ratio so far (adaptive RANSAC, Hartley & Zisserman Alg. 4.5).

The initial pose itself (the previous level's result) is scored first as
hypothesis zero: on a static scene it usually passes the early exit at once,
and it is never worse to keep the best of it and the sampled ones.
All shapes are static: k may be a traced value (so p and w can be swept with
``jax.vmap``); only ``max_hypotheses``, ``batch_size`` and ``batches_per_trip`` fix array sizes.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxvo.camera import Camera
from jaxvo.estimator.pyramid import Level, level_size, level_slice
from jaxvo.estimator.residuals import RefPoints, Residuals, gather_points, residuals
from jaxvo.estimator.solvers import solve_pose_small

__all__ = ["num_hypotheses", "inliers", "SamplingTable", "sampling_table", "sample_patches", "score_pose",
           "score_weights", "fit_hypothesis", "RansacResult", "ransac_level"]


def num_hypotheses(p, w, n):
    """k = ceil(log(1 - p) / log(1 - (1 - w)^n)): draws needed to see one all-inlier sample with probability p.

    p: success probability, w: outlier fraction, n: points per sample. Works on
    Python floats and on traced JAX values.
    """
    # at least one draw (w = 0 would give log(1-p) / -inf = 0)
    return jnp.maximum(jnp.ceil(_draws(p, (1.0 - w) ** n)), 1).astype(jnp.int32)


def _draws(p, good):
    """log(1 - p) / log(1 - good), in floats: the draws after which a sample that is all inliers
    (each with probability ``good``) has come with probability p (inf for good = 0)."""
    return jnp.log(1.0 - p) / jnp.log1p(-good)


def inliers(res: Residuals, thresh_lum, thresh_depth):
    """(N,) bool: |r_int| < thresh_lum (0-255 units) and |r_depth| < thresh_depth (metres), both defined."""
    return res.valid_depth & (jnp.abs(res.r_int) < thresh_lum) & (jnp.abs(res.r_depth) < thresh_depth)


# pixels per chunk of a row in the sampling table: the draws look up 16-wide chunks, not rows
_CHUNK = 16


class SamplingTable(NamedTuple):
    """Where :func:`sample_patches` may put patch centres on one level, counted so that the j-th
    such pixel (row-major) is found in three small look-ups (row, 16-pixel chunk, pixel): the
    pixel a search in the prefix sum over every pixel finds, without that prefix sum (its scan
    compiled into ~25 XLA kernels per call site, about 0.4 s of the default estimator's
    compilation, and ran in O(h w) per level).

    ok: (h, wc * 16) bool, the drawable pixels (the level's arrays, right-padded to whole chunks);
    chunks: (h, wc) int32 drawable pixels per chunk; rows: (h,) int32 inclusive running count over
    rows (rows[-1]: the total)."""
    ok: jnp.ndarray
    chunks: jnp.ndarray
    rows: jnp.ndarray


def sampling_table(level: Level, radius: int) -> SamplingTable:
    """The :class:`SamplingTable` of ``level`` (plain, or stacked: its own entry, whose arrays may be
    padded beyond its image): drawable pixels have valid depth, ``level.weight`` >= 0.5 (trusted
    as static) and their (2r+1)^2 neighbourhood inside the image."""
    h, w = level_size(level)
    one = level_slice(level)
    vv, uu = jnp.meshgrid(jnp.arange(one.depth.shape[0]), jnp.arange(one.depth.shape[1]), indexing="ij")
    ok = (one.depth > 0) & (one.weight >= 0.5) & (uu >= radius) & (uu < w - radius) & (vv >= radius) & (vv < h - radius)
    ok = jnp.pad(ok, [(0, 0), (0, -ok.shape[1] % _CHUNK)])
    chunks = ok.reshape(ok.shape[0], -1, _CHUNK).sum(-1, dtype=jnp.int32)
    return SamplingTable(ok, chunks, jnp.cumsum(chunks.sum(-1)))


def _nth_true(table: SamplingTable, j):
    """Row-major flat index (in the table's padded width) of the (j+1)-th drawable pixel, for int32 j
    (any shape) in [0, total); the flat size of the table where there is none."""
    cw = table.ok.shape[1]
    # "compare_all": the count of rows <= j, the same index as the default binary search over a
    # sorted array, without its loop (fewer kernels to compile; the queries are a few hundred)
    r = jnp.searchsorted(table.rows, j, side="right", method="compare_all")
    rc = jnp.minimum(r, table.rows.shape[0] - 1)
    j = j - (table.rows[rc] - table.chunks[rc].sum(-1))   # rank within the row
    run = jnp.cumsum(table.chunks[rc], axis=-1)            # (..., wc): 16-pixel chunks of the row
    c = jnp.sum(run <= j[..., None], axis=-1)
    cc = jnp.minimum(c, run.shape[-1] - 1)
    j = j - (jnp.take_along_axis(run, cc[..., None], -1)[..., 0] - table.chunks[rc, cc])  # rank within the chunk
    px = table.ok[rc[..., None], cc[..., None] * _CHUNK + jnp.arange(_CHUNK)]
    k = jnp.sum(jnp.cumsum(px, axis=-1, dtype=jnp.int32) <= j[..., None], axis=-1)
    return jnp.where(r < table.rows.shape[0], r * cw + cc * _CHUNK + k, table.ok.size)


def sample_patches(key, level: Level, n: int, batch: int, radius: int, table=None):
    """Draw ``batch`` samples of ``n`` patch centres uniformly among reference pixels with valid depth,
    trusted as static (``level.weight`` >= 0.5), whose (2r+1)^2 neighbourhood lies inside the image.

    Returns integer (u, v) coordinates of the patch pixels, each (batch, n * (2r+1)^2).
    Each centre is the j-th drawable pixel for a uniform j, found through the level's
    :class:`SamplingTable` (O(h w) once, then O(log h + w / 16 + 16) per draw), so it costs
    about the same at every level. ``table``: the level's :func:`sampling_table`, when the caller
    draws several batches from the same level.
    """
    table = sampling_table(level, radius) if table is None else table
    # drawn flat, then shaped: the same numbers (JAX's counter-based generator numbers the draws
    # in row-major order), but XLA compiles the (batch, n) counter hash ~0.1 s slower per copy
    draws = jax.random.randint(key, (batch * n,), 0, jnp.maximum(table.rows[-1], 1)).reshape(batch, n)
    flat = _nth_true(table, draws)
    w = table.ok.shape[1]
    cu, cv = flat % w, flat // w
    d = jnp.arange(-radius, radius + 1)
    du, dv = jnp.meshgrid(d, d, indexing="xy")
    pu = (cu[..., None] + du.reshape(-1)).reshape(batch, -1)
    pv = (cv[..., None] + dv.reshape(-1)).reshape(batch, -1)
    return pu, pv


def score_pose(T, score_ref: RefPoints, cur_level: Level, camera: Camera, thresh_lum, thresh_depth,
               scoring: str = "count", surface_weights=None):
    """(quality, count, surface) of the pose T_cur_ref on the scoring points; see :func:`ransac_level`.

    count: its inliers weighted by their static-trust weight; quality and surface weigh them by
    ``surface_weights`` ((N,), :func:`score_weights`; default the static-trust weights, i.e.
    depth_power 0); surface: their plain sum. The caller computes the weights once per level."""
    res = residuals(T, score_ref, cur_level, camera)
    inl = inliers(res, thresh_lum, thresh_depth)
    count = jnp.sum(jnp.where(inl, score_ref.weight, 0.0))
    w = score_ref.weight if surface_weights is None else surface_weights
    surface = jnp.sum(jnp.where(inl, w, 0.0))
    if scoring == "count":
        return surface, count, surface
    e2 = 0.5 * ((res.r_int / thresh_lum) ** 2 + (res.r_depth / thresh_depth) ** 2)
    return jnp.sum(jnp.where(inl, w * (1.0 - e2), 0.0)), count, surface


def score_weights(score_ref: RefPoints, depth_power=0.0):
    """(N,) what each scoring point counts for: its static-trust weight times z^depth_power (z: its
    reference depth, metres; 0 where it has none). 0: the weights themselves (the paper's count)."""
    return score_ref.weight * score_ref.points[:, 2] ** depth_power


def fit_hypothesis(T_init, ref_level: Level, cur_level: Level, camera: Camera, pu, pv, iterations: int,
                   depth_weight=None, offset=0.0):
    """(4, 4) T_cur_ref fitted, from ``T_init``, to the reference pixels (pu, pv) (integer, (M,)) only;
    ``offset`` is added to their luminance (an exposure change, :mod:`jaxvo.estimator.brightness`)."""
    pts = gather_points(ref_level, camera, pu, pv)
    pts = pts._replace(intensity=pts.intensity + offset)
    # the written-out 6x6 LM: jaxopt's iterates, a much smaller program under vmap
    return solve_pose_small(T_init, pts, cur_level, camera, pts.valid.astype(jnp.float32),
                            iterations, depth_weight=depth_weight).T


class RansacResult(NamedTuple):
    """T: (4, 4) best T_cur_ref; inlier_ratio: its ratio on the scoring pixels;
    hypotheses: sampled hypotheses evaluated (int32, the scored initial pose not counted)."""
    T: jnp.ndarray
    inlier_ratio: jnp.ndarray
    hypotheses: jnp.ndarray


def ransac_level(T_init, ref_level: Level, cur_level: Level, camera: Camera, score_ref: RefPoints, key, *,
                 p, w, thresh_lum, thresh_depth, early_exit_ratio, n: int, radius: int,
                 max_hypotheses: int, batch_size: int, hypothesis_iterations: int,
                 depth_weight=None, scoring: str = "count", depth_power=0.0, table=None, offset=0.0,
                 T_other=None, adaptive: bool = False, batches_per_trip: int = 1) -> RansacResult:
    """Best pose hypothesis for one level; see the module docstring.

    T_init: (4, 4) T_cur_ref to start every hypothesis from. score_ref: the
    reference points the hypotheses are scored on. depth_weight: None fits each
    hypothesis on the photometric residual only (the paper); a number adds the
    depth residual of the same pixels (see :func:`jaxvo.estimator.solvers.solve_pose_small`).
    scoring: "count" ranks hypotheses by their inlier count (the paper);
    "msac" by the truncated-quadratic (MSAC, Torr & Zisserman 2000) score
    sum over inliers of 1 - ((r_I/t_I)^2 + (r_Z/t_Z)^2) / 2, which prefers the
    hypothesis that aligns its inliers more tightly. depth_power: each scoring pixel counts in
    the quality with weight z^depth_power (2: the surface it images, see
    ``Config.score_depth_power``; 0: the paper's pixel count). The inlier ratio's
    denominator is the number of scoring points with valid reference depth; the loop stops
    early once the best hypothesis's inlier ratio, or its share of the z^depth_power-weighted
    total, exceeds early_exit_ratio (far pixels fail the fixed depth threshold more often, so
    either share alone draws more hypotheses than needed; docs/decisions/depth-weighting.md). table: the
    :func:`sampling_table` to draw sample centres from (default the level's). offset: added to
    the luminance of the sampled reference pixels (see :func:`fit_hypothesis`). T_other: an
    optional further (4, 4) candidate, scored beside T_init before any hypothesis (the pose a
    plain fit started from, which a moving object may have dragged T_init away from).
    adaptive: also stop once the batches drawn reach p for w = 1 - the best inlier ratio so far
    (``Config.adaptive_hypotheses``). batches_per_trip: batches fitted in one vmapped call per
    trip of the loop (``Config.batches_per_trip``); the stopping test still runs after each batch,
    in order, and a batch after the stop does not count, so the result is that of one batch per trip
    (the same draws: batch b's samples come from ``fold_in(key, b)`` either way).
    """
    k = jnp.minimum(num_hypotheses(p, w, n), max_hypotheses)
    # no trip needs more batches than the cap holds (k <= max_hypotheses): the slots past it never count
    batches_per_trip = max(1, min(batches_per_trip, -(-max_hypotheses // batch_size)))
    # scoring pixels count by their static-trust weight (1 everywhere without a prior)
    n_ref = jnp.maximum(jnp.sum(score_ref.weight), 1.0)
    # the same times z^depth_power: the share of the scene surface the ranking measures
    # (once per level: XLA's loop-invariant code motion is off for these programs, jaxvo.estimator.solvers)
    surface_w = score_weights(score_ref, depth_power)
    s_ref = jnp.maximum(jnp.sum(surface_w), 1e-6)

    def score(T):
        return score_pose(T, score_ref, cur_level, camera, thresh_lum, thresh_depth, scoring, surface_w)

    def hypothesis(pu, pv):
        return fit_hypothesis(T_init, ref_level, cur_level, camera, pu, pv, hypothesis_iterations, depth_weight,
                              offset)

    def cond(state):
        b, _, _, best_count, best_surface, _ = state
        # done once the best hypothesis explains the share of the pixels or of their surface
        # (with depth_power 0 the two are the same)
        done = jnp.maximum(best_count / n_ref, best_surface / s_ref) > early_exit_ratio
        if not adaptive:
            return (b * batch_size < k) & ~done
        # adaptive RANSAC: the best inlier ratio so far bounds the outlier fraction, so fewer
        # draws reach the same success probability p (at least one batch: the prior is no draw;
        # in floats, as a ratio near 0 gives inf draws, which no int32 holds)
        k_seen = jnp.maximum(_draws(p, jnp.clip(best_count / n_ref, 0.0, 1.0) ** n), 1.0)
        return (b * batch_size < jnp.minimum(k, k_seen)) & ~done

    def take(state, Ts, quality, counts, surfaces):
        """The state after batch b = state[0], whose poses and scores are given."""
        b, T_best, best, best_count, best_surface, evaluated = state
        idx = b * batch_size + jnp.arange(batch_size)
        quality = jnp.where(idx < k, quality, -jnp.inf)
        j = jnp.argmax(quality)
        better = quality[j] > best
        T_best = jnp.where(better, Ts[j], T_best)
        best = jnp.where(better, quality[j], best)
        best_count = jnp.where(better, counts[j], best_count)
        best_surface = jnp.where(better, surfaces[j], best_surface)
        evaluated = evaluated + jnp.sum(idx < k)
        return b + 1, T_best, best, best_count, best_surface, evaluated

    def body(state):
        # named scopes: the stages in the compiled program's metadata (experiments/kernel_profile.py)
        b = state[0]
        with jax.named_scope("ransac_sampling"):
            # the trip's batches drawn under one vmap over their keys: the numbers of one draw per
            # key (a counter-based generator), in one copy of the sampling code instead of one per batch
            keys = jax.vmap(lambda i: jax.random.fold_in(key, b + i))(jnp.arange(batches_per_trip))
            pu, pv = jax.vmap(lambda k_: sample_patches(k_, ref_level, n, batch_size, radius, table))(keys)
            pu, pv = pu.reshape(-1, pu.shape[-1]), pv.reshape(-1, pv.shape[-1])
        with jax.named_scope("ransac_hypotheses"):
            Ts = jax.vmap(hypothesis)(pu, pv)
        with jax.named_scope("ransac_scoring"):
            quality, counts, surfaces = jax.vmap(score)(Ts)
        # the batches in order, each only while the loop's test would still have let it run: the
        # stop after any one of them is the stop of one batch per trip (a loop over the trip's
        # batches, one copy of its code; the first always runs, as the while loop's test let it)
        def one(i, state):
            part = [jax.lax.dynamic_slice_in_dim(x, i * batch_size, batch_size) for x in (Ts, quality, counts, surfaces)]
            go = (i == 0) | cond(state)
            return jax.tree_util.tree_map(lambda new, old: jnp.where(go, new, old), take(state, *part), state)
        return jax.lax.fori_loop(0, batches_per_trip, one, state)

    with jax.named_scope("ransac_sampling"):
        table = sampling_table(ref_level, radius) if table is None else table  # once per level, not per batch
    with jax.named_scope("ransac_scoring"):
        q0, c0, s0 = score(T_init)
    T0 = T_init
    if T_other is not None:
        with jax.named_scope("ransac_scoring"):
            q1, c1, s1 = score(T_other)
        better = q1 > q0
        T0, q0, c0, s0 = (jnp.where(better, a, b) for a, b in ((T_other, T0), (q1, q0), (c1, c0), (s1, s0)))
    state = (jnp.int32(0), T0, q0, c0, s0, jnp.int32(0))
    _, T_best, _, best_count, _, evaluated = jax.lax.while_loop(cond, body, state)
    return RansacResult(T_best, best_count / n_ref, evaluated)
