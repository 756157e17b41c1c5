"""The coarse-to-fine program: one pair of frames' pyramids, level by level from the coarsest,
each level starting at the pose of the one before, to a :class:`MotionEstimate`.

:func:`estimate_arrays` (arguments: :class:`jaxvo.estimator.inputs.EstimateArgs`) is the whole
estimate as one traced function, compiled once per (image shape, static config); numeric config
fields are traced. Per level: the brightness offset (``Config.brightness``), then the method's
solve (``Config.method``: plain least squares, Huber IRLS, or RANSAC then least squares on its
consensus); at the end the dense pass at the finest level that gives the masks, the information
matrix and the failure flag (:mod:`jaxvo.estimator.trust`).
"""
from __future__ import annotations

import functools
from typing import Tuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxvo import geometry
from jaxvo.camera import Camera
from jaxvo.config import Config
from jaxvo.estimator import brightness
from jaxvo.estimator.inputs import num_levels
from jaxvo.estimator.pyramid import build_pyramid, level_slice, stack_padded, weight_pyramid
from jaxvo.estimator.ransac import inliers, ransac_level, sampling_table
from jaxvo.estimator.residuals import RefPoints, reference_points, residuals, select_points
from jaxvo.estimator.result import MotionEstimate
from jaxvo.estimator.solvers import irls, jit, solve_pose, solve_pose_small
from jaxvo.estimator.trust import final_counts, final_residuals, trust_stats, trusted

__all__ = ["depth_gradient_levels", "estimate_arrays", "estimate_arrays_jit", "level_block", "ransac_options",
           "reads_depth_gradients",
           "trace_count"]


_TRACES = {"count": 0}


def trace_count() -> int:
    """How many times the estimator has been traced (compiled) in this process; for tests and benchmarks."""
    return _TRACES["count"]


def level_block(config: Config, level: int) -> int:
    """Side of the square blocks a level's refinement points are chosen in (one point per block):
    ``Config.blocks[level]``, 1 past its end."""
    blocks = config.blocks
    return int(blocks[level]) if level < len(blocks) else 1


def ransac_options(config: Config) -> dict:
    """The keyword arguments of :func:`jaxvo.estimator.ransac.ransac_level` that ``config`` sets
    (the hypothesis count, thresholds, batches, the hypotheses' residual and their scoring): the
    estimator's, and those of a caller that runs one level's RANSAC alone (experiments' stage
    timings)."""
    return dict(p=config.p, w=config.w, thresh_lum=config.thresh_lum, thresh_depth=config.thresh_depth,
                early_exit_ratio=config.early_exit_ratio, n=config.n_points, radius=config.patch_radius,
                max_hypotheses=config.max_hypotheses, batch_size=config.batch_size,
                hypothesis_iterations=config.hypothesis_iterations,
                depth_weight=config.depth_weight if config.hypothesis_terms == "rgbd" else None,
                scoring=config.scoring, depth_power=config.score_depth_power, adaptive=config.adaptive_hypotheses,
                batches_per_trip=config.batches_per_trip)


def _score_stride(level, config: Config) -> int:
    """Stride of the regular subgrid of at most about ``max_score_pixels`` pixels of a level."""
    hh, ww = level.depth.shape
    return max(1, int(np.ceil(np.sqrt(hh * ww / config.max_score_pixels))))


# the padding (invalid points) a scanned group may add, as a share of all levels' refinement points
_PAD_BUDGET = 0.1


def _level_groups(config: Config, L: int, width: int, height: int):
    """The levels processed (coarse to fine) in groups: each level its own group, unless
    ``Config.scan_levels``. Then consecutive RANSAC levels (levels >= ransac_finest) share a
    group, which runs as one ``lax.scan`` (one compiled level body, no cond on the level inside
    it) with its point lists padded to the longest, as long as the padding of all groups stays
    within ``_PAD_BUDGET`` of the refinement points of all levels: a level padded to a finer
    one's points works through all of them. Default tiles: levels 3-1 (4800 points each, no
    padding). The paper's every pixel: levels 3-2 (4800 and 19200 points, 3.5 % padding): more
    padding would cost more time per pair than the shorter compilation saves. Each level
    without RANSAC is a group of its own: those compile in about a second each, and scanning
    them costs time per pair for little less compilation (docs/decisions/scan-levels.md)."""
    levels = range(L - 1, config.finest_level - 1, -1)
    if not config.scan_levels:
        return [[level] for level in levels]

    def points(level):
        b = level_block(config, level)
        return ((height >> level) // b) * ((width >> level) // b)

    def padding(group):
        return len(group) * max(map(points, group)) - sum(map(points, group))

    budget = _PAD_BUDGET * sum(map(points, levels))
    groups, padded = [], 0
    for level in levels:
        scanned = config.method == "ransac" and level >= config.ransac_finest
        last = groups[-1] if groups else []
        if scanned and last and last[-1] >= config.ransac_finest:
            extra = padding(last + [level]) - padding(last)
            if padded + extra <= budget:
                last.append(level)
                padded += extra
                continue
        groups.append([level])
    return groups


def _pad_points(pts: RefPoints, n: int) -> RefPoints:
    """``pts`` extended to n points with invalid ones (valid False, weight 0, at pixel (0, 0))."""
    return RefPoints(*(jnp.pad(x, [(0, n - x.shape[0])] + [(0, 0)] * (x.ndim - 1)) for x in pts))


def _stack_points(point_lists):
    """Per-level RefPoints padded to a common length and stacked with a leading level axis."""
    n = max(p.valid.shape[0] for p in point_lists)
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *[_pad_points(p, n) for p in point_lists])


def _level_inputs(ref_pyr, cur_pyr, camera: Camera, config: Config, levels):
    """What the level body of :func:`_estimate` reads, for ``levels`` (coarse to fine): (xs,
    stacks). xs, stacked along a leading axis for ``lax.scan``: the level index, the sizes of
    its reference and current level in the stacks, its camera, and its refinement, scoring and
    brightness points (padded with invalid points; none of them depends on the pose, and the
    brightness offset is added to their intensities in the body). stacks: the reference and
    current levels padded to the largest and stacked (:func:`jaxvo.estimator.pyramid.stack_padded`),
    without their sizes: the body reads them whole (slicing an entry out of them per level
    would copy it)."""
    cams, pts, score, grid = [], [], [], []
    for level in levels:
        cams.append(camera.at_level(level))
        for lst, p in zip((pts, score, grid), _level_points(ref_pyr[level], cams[-1], config, level)):
            lst.append(p)
    # one camera pytree: width/height are static metadata, the padded arrays' size
    w, h = cams[-1].width, cams[-1].height
    cam = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *[c.with_size(w, h) for c in cams])
    # only what the body reads: the reference's pixels for RANSAC's samples, the current
    # level's images for the warped points (select_points above read the rest)
    ransac = config.method == "ransac" and levels[0] >= config.ransac_finest
    rgbd = reads_depth_gradients(config, levels[0])
    ref = stack_padded([ref_pyr[l] for l in levels], ("intensity", "depth", "weight") if ransac else ())
    cur = stack_padded([cur_pyr[l] for l in levels], ("intensity", "depth", "igrad") + (("dgrad",) if rgbd else ()))
    xs = (jnp.asarray(levels, jnp.int32), ref.size, cur.size, cam, _stack_points(pts), _stack_points(score),
          _stack_points(grid))
    return xs, (ref._replace(size=None), cur._replace(size=None))


def reads_depth_gradients(config: Config, level: int) -> bool:
    """Whether the estimate with ``config`` reads the current frame's depth gradients
    (``Level.dgrad``) at pyramid ``level``: where a refinement minimises the joint RGB-D cost
    (``Config.terms``), or RANSAC fits its hypotheses on it (``Config.hypothesis_terms``), on a
    level it processes. Elsewhere the depth is sampled at the nearest pixel (the residuals, the
    masks and statistics) and its gradients are never read."""
    if level < config.finest_level:
        return False
    ransac = config.method == "ransac" and level >= config.ransac_finest
    return config.terms == "rgbd" or (ransac and config.hypothesis_terms == "rgbd")


def depth_gradient_levels(config: Config, num_levels: int) -> Tuple[int, ...]:
    """The levels of a ``num_levels`` pyramid whose depth gradients an estimate with ``config`` reads
    (:func:`reads_depth_gradients`), finest first: with the defaults the RANSAC levels, 1 and up."""
    return tuple(level for level in range(num_levels) if reads_depth_gradients(config, level))


def _level_points(ref_l, cam, config: Config, level: int):
    """(refinement, scoring, brightness) points of a reference level: one per block of
    :func:`level_block` (the strongest gradient), the scoring grid or its strongest-gradient pixels, and
    the grid the brightness offset is fitted on."""
    stride = _score_stride(ref_l, config)
    grid = reference_points(ref_l, cam, stride)
    score = select_points(ref_l, cam, stride) if config.score_selection == "gradient" else grid
    return select_points(ref_l, cam, level_block(config, level)), score, grid


def _shifted(pts: RefPoints, offset) -> RefPoints:
    return pts._replace(intensity=pts.intensity + offset)


def _level_step(config: Config, key, dw, ransac: bool, stacks, carry, xs):
    """One pyramid level: carry (T, brightness offset) in, the level's pose and offset out, with
    (hypotheses, iterations, information J^T W J) of the level. The body of the scan over levels
    (``stacks``, ``xs``: see :func:`_level_inputs`; the level images are the whole stacks, read
    at the level's entry, never copied out), or called once per level with its own plain
    (reference, current) levels as ``stacks``, sizes None and unpadded points."""
    T, offset = carry
    level, ref_size, cur_size, cam, pts, score_pts, grid_pts = xs
    ref_l, cur_l = stacks[0]._replace(size=ref_size), stacks[1]._replace(size=cur_size)
    if config.brightness == "offset":   # exposure changes: fitted at the level's starting pose
        with jax.named_scope("brightness"):
            offset = brightness.fit_offset(T, grid_pts, cur_l, cam, config.thresh_lum, config.thresh_depth)
            # added to the reference points' luminance (brightness.apply on the level, point by point)
            pts, score_pts = _shifted(pts, offset), _shifted(score_pts, offset)
    ones = pts.weight
    hyps = jnp.int32(0)
    if config.method == "classic":
        with jax.named_scope("refinement"):
            sol = solve_pose(T, pts, cur_l, cam, ones, config.max_iterations, depth_weight=dw)
        iters = sol.iterations
    elif config.method == "huber":
        inner = config.irls_iterations
        with jax.named_scope("refinement"):
            sol = irls(T, pts, cur_l, cam, ones, config.huber_k, config.irls_rounds, inner, depth_weight=dw)
        iters = sol.iterations
    else:
        if ransac:  # finer levels: refine the carried-up consensus only
            T_carried = T if config.prior_candidate == "both" else None
            if config.prior_candidate != "raw":  # a plain fit: the written-out LM (jaxopt's iterates)
                with jax.named_scope("prior_fit"):
                    T = solve_pose_small(T, pts, cur_l, cam, ones, config.max_iterations, depth_weight=dw).T
            with jax.named_scope("ransac_sampling"):
                table = sampling_table(_gated(level_slice(ref_l), cur_l, cam, T, config.sample_gate),
                                       config.patch_radius)
            rs = ransac_level(T, ref_l, cur_l, cam, score_pts, jax.random.fold_in(key, level), offset=offset,
                              table=table, T_other=T_carried, **ransac_options(config))
            hyps = rs.hypotheses
            T = rs.T
        iters = jnp.int32(0)
        for _ in range(config.refine_rounds):
            with jax.named_scope("refinement"):
                mask = inliers(residuals(T, pts, cur_l, cam), config.thresh_lum, config.thresh_depth)
                consensus = jnp.where(mask, pts.weight, 0.0)
                if config.consensus_weights == "huber":
                    inner = config.irls_iterations
                    sol = irls(T, pts, cur_l, cam, consensus, config.huber_k, config.irls_rounds,
                               inner, depth_weight=dw)
                else:
                    sol = solve_pose(T, pts, cur_l, cam, consensus, config.max_iterations, depth_weight=dw)
            T = sol.T
            iters = iters + sol.iterations
    return (sol.T, offset), (hyps, iters, sol.hessian)


def _estimate(ref_int, ref_depth, cur_int, cur_depth, camera: Camera, config: Config, key, T_init, ref_weight):
    """The whole estimate of one pair -> :class:`MotionEstimate`; the arguments are the fields of
    :class:`jaxvo.estimator.inputs.EstimateArgs`, in its order. Traced once per image shape and
    static config (:func:`trace_count`)."""
    _TRACES["count"] += 1
    h, w = ref_int.shape
    L = num_levels(config, w, h)
    # the named scopes mark the stages in the compiled program's metadata (op_name), where a
    # profile of it finds them (experiments/kernel_profile.py); they change nothing else
    with jax.named_scope("pyramid"):
        ref_pyr = build_pyramid(ref_int, ref_depth, L, config.max_depth, ref_weight)
        cur_pyr = build_pyramid(cur_int, cur_depth, L, config.max_depth)
    return _coarse_to_fine(ref_pyr, cur_pyr, camera, config, key, T_init)


def _frame_pyramid(intensity, depth, num_levels: int, max_depth, dgrad_levels: Tuple[int, ...]):
    """A frame's pyramid without weights (``Level.weight`` None) and with depth gradients
    (``Level.dgrad``) only on ``dgrad_levels`` (None elsewhere, :func:`depth_gradient_levels`):
    what every estimate it takes part in reads of it, as :func:`_estimate` builds it. (Inside
    :func:`_estimate` XLA drops what the estimate does not read; a pyramid returned by a program of
    its own holds what it returns: at 640x480 the full-resolution depth gradients are a 4.9 MB
    array and a third of the time of the program.)"""
    return tuple(level._replace(weight=None, dgrad=level.dgrad if i in dgrad_levels else None)
                 for i, level in enumerate(build_pyramid(intensity, depth, num_levels, max_depth)))


def _estimate_pyramids(ref_pyr, cur_pyr, camera: Camera, config: Config, key, T_init, ref_weight):
    """:func:`_estimate` from the frames' pyramids (:func:`_frame_pyramid`), the reference's
    weights ``ref_weight`` (H, W) added to its levels as :func:`build_pyramid` adds them. Traced once
    per image shape and static config (:func:`trace_count`)."""
    _TRACES["count"] += 1
    with jax.named_scope("pyramid"):
        weights = weight_pyramid(ref_weight, len(ref_pyr))
        ref_pyr = tuple(level._replace(weight=wt) for level, wt in zip(ref_pyr, weights))
    return _coarse_to_fine(ref_pyr, cur_pyr, camera, config, key, T_init)


def _coarse_to_fine(ref_pyr, cur_pyr, camera: Camera, config: Config, key, T_init):
    """The estimate from the two frames' pyramids (the reference's with its weights), level by
    level from the coarsest, to the :class:`MotionEstimate`."""
    h, w = ref_pyr[0].depth.shape
    L = len(ref_pyr)
    dw = config.depth_weight if config.terms == "rgbd" else None
    hyps = jnp.zeros(L, jnp.int32)
    iters = jnp.zeros(L, jnp.int32)
    carry = (T_init, jnp.float32(0.0))
    for levels in _level_groups(config, L, w, h):
        ransac = levels[0] >= config.ransac_finest
        if config.scan_levels and len(levels) > 1:
            # the group's levels run as one scan, compiled once (not once per level); the level
            # images padded to the group's largest, the point lists to its longest (invalid points)
            with jax.named_scope("points"):
                xs, stacks = _level_inputs(ref_pyr, cur_pyr, camera, config, levels)
            step = functools.partial(_level_step, config, key, dw, ransac, stacks)
            carry, (hy, it, hess) = jax.lax.scan(step, carry, xs)
            hessian = hess[-1]
        else:  # each level its own code, at its own size
            hy, it = [], []
            for level in levels:
                cam = camera.at_level(level)
                with jax.named_scope("points"):
                    xs = (level, None, None, cam) + _level_points(ref_pyr[level], cam, config, level)
                step = functools.partial(_level_step, config, key, dw, ransac, (ref_pyr[level], cur_pyr[level]))
                carry, (h1, i1, hessian) = step(carry, xs)
                hy.append(h1)
                it.append(i1)
        hyps = hyps.at[jnp.asarray(levels)].set(jnp.asarray(hy))
        iters = iters.at[jnp.asarray(levels)].set(jnp.asarray(it))
    T, offset = carry
    level = config.finest_level
    cam, ref_l, cur_l = camera.at_level(level), ref_pyr[level], cur_pyr[level]
    if config.brightness == "offset":
        with jax.named_scope("brightness"):
            ref_l = brightness.apply(ref_l, offset)

    # per-pixel masks and statistics at the finest level processed, all pixels
    # ref_l, cur_l: the finest level processed, ref_l with the brightness fitted there
    with jax.named_scope("final"):
        dense, res, inl, wts = final_residuals(ref_l, cur_l, cam, T, config)
        hl, wl = ref_l.depth.shape
        counts = final_counts(ref_l, res, inl, dense, wts, config)
        ratio = counts.inliers / jnp.maximum(counts.valid, 1)
        nw = jnp.maximum(counts.weighted, 1)
        var = jnp.sum(jnp.where(wts, res.r_int ** 2, 0.0)) / nw
        info = hessian / jnp.maximum(var, 1e-6)
        valid = trusted(trust_stats(counts, info, T), config)
    return MotionEstimate(T, geometry.log(T), inl.reshape(hl, wl), res.valid_depth.reshape(hl, wl), ratio,
                          hyps, iters, valid, info, jnp.sqrt(var),
                          (res.valid_depth & (res.r_depth < -config.thresh_depth)).reshape(hl, wl),
                          offset)


_estimate_jit = jit(_estimate)

# the estimator's internal API for batched and profiled estimates (jaxvo.tracking.batch, experiments):
# the traced function (its compiled programs are named after ``_estimate``) and its jit with the
# estimator's compiler options
estimate_arrays = _estimate
estimate_arrays_jit = _estimate_jit


def jit_with_fallback(fn, with_options=None):
    """``fn`` jitted with the estimator's compiler options (``with_options``, default
    :func:`jaxvo.estimator.solvers.jit` of it); inside a caller's ``jax.jit`` (where JAX refuses a
    nested jit with compiler options) the plain jit, which then runs with the caller's options."""
    with_options, plain = (jit(fn) if with_options is None else with_options), jax.jit(fn)

    def call(*args):
        try:
            return with_options(*args)
        except ValueError as e:
            if "compiler_options" not in str(e):
                raise
            return plain(*args)
    return call


_estimate_call = jit_with_fallback(_estimate, _estimate_jit)


def _gated(ref_l, cur_l, cam, T, gate):
    """``ref_l`` with the weight of pixels whose depth residual at T exceeds ``gate`` set to 0
    (RANSAC draws its samples among weight >= 0.5); unchanged if gate <= 0 or if fewer than
    10 % of the trusted pixels would remain. ``ref_l``: 2-D arrays (a stacked level's entry,
    jaxvo.estimator.pyramid.level_slice, or a plain level); ``cur_l`` may be stacked."""
    def gate_weights(weight):
        res = residuals(T, reference_points(ref_l, cam, 1), cur_l, cam)
        far = (res.valid_depth & (jnp.abs(res.r_depth) > gate)).reshape(ref_l.depth.shape)
        trusted = (ref_l.depth > 0) & (weight >= 0.5)
        apply = jnp.sum(trusted & ~far) >= 0.1 * jnp.sum(trusted)
        return jnp.where(apply & far, 0.0, weight)

    # off by default: no dense residual pass per level then (a cond, as gate may be traced)
    return ref_l._replace(weight=jax.lax.cond(gate > 0, gate_weights, lambda w: w, ref_l.weight))
