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

import functools
from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from jaxvo import geometry
from jaxvo.estimator import brightness
from jaxvo.runtime import aot
from jaxvo.camera import Camera
from jaxvo.config import METHODS, Config
from jaxvo.frame import Frame, validate_pair
from jaxvo.estimator.pyramid import build_pyramid, level_slice, num_levels_for, stack_padded
from jaxvo.estimator.ransac import inliers, ransac_level, sampling_table
from jaxvo.estimator.residuals import RefPoints, reference_points, residuals, select_points
from jaxvo.estimator.solvers import COMPILER_OPTIONS, irls, jit, solve_pose, solve_pose_small

__all__ = ["MotionEstimate", "TrustStats", "estimate_motion", "explain_validity", "trace_count"]

class MotionEstimate(NamedTuple):
    """Result of :func:`estimate_motion`.

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
      inlier ratio >= min_inlier_ratio, and enough depth and photometric agreement
      (see :class:`TrustStats`, :func:`explain_validity`).
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


_TRACES = {"count": 0}


def trace_count() -> int:
    """How many times the estimator has been traced (compiled) in this process; for tests and benchmarks."""
    return _TRACES["count"]


def _levels(config: Config, width: int, height: int) -> int:
    return config.num_levels if config.num_levels is not None else num_levels_for(width, height)


def _block(config: Config, level: int) -> int:
    blocks = config.blocks
    return int(blocks[level]) if level < len(blocks) else 1


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
    padding). The paper's every pixel: levels 3-2 (4800 and 19200 points, 3.5 % padding; XLA
    compiled its estimator in 7.0 instead of 9.4 s, at 1.04x / 1.03x the time per static / Bonn
    pair: experiments/results/scan_levels_paper.md; levels 3-1 as one group took 1.5x the time
    per pair in a scratch run). Each level without RANSAC is a group of its own: those compile in about a
    second each (classic with its four levels as one group took up to 1.37x the time per pair,
    for 1 s less compilation: see ``Config.scan_levels``)."""
    levels = range(L - 1, config.finest_level - 1, -1)
    if not config.scan_levels:
        return [[level] for level in levels]

    def points(level):
        b = _block(config, level)
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
    rgbd = config.terms == "rgbd" or (ransac and config.hypothesis_terms == "rgbd")
    ref = stack_padded([ref_pyr[l] for l in levels], ("intensity", "depth", "weight") if ransac else ())
    cur = stack_padded([cur_pyr[l] for l in levels], ("intensity", "depth", "igrad") + (("dgrad",) if rgbd else ()))
    xs = (jnp.asarray(levels, jnp.int32), ref.size, cur.size, cam, _stack_points(pts), _stack_points(score),
          _stack_points(grid))
    return xs, (ref._replace(size=None), cur._replace(size=None))


def _level_points(ref_l, cam, config: Config, level: int):
    """(refinement, scoring, brightness) points of a reference level: one per block of
    ``_block`` (the strongest gradient), the scoring grid or its strongest-gradient pixels, and
    the grid the brightness offset is fitted on."""
    stride = _score_stride(ref_l, config)
    grid = reference_points(ref_l, cam, stride)
    score = select_points(ref_l, cam, stride) if config.score_selection == "gradient" else grid
    return select_points(ref_l, cam, _block(config, level)), score, grid


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
            rs = ransac_level(T, ref_l, cur_l, cam, score_pts,
                              jax.random.fold_in(key, level),
                              p=config.p, w=config.w, thresh_lum=config.thresh_lum,
                              thresh_depth=config.thresh_depth, early_exit_ratio=config.early_exit_ratio,
                              n=config.n_points, radius=config.patch_radius,
                              max_hypotheses=config.max_hypotheses, batch_size=config.batch_size,
                              hypothesis_iterations=config.hypothesis_iterations,
                              depth_weight=config.depth_weight if config.hypothesis_terms == "rgbd" else None,
                              scoring=config.scoring, depth_power=config.score_depth_power, offset=offset,
                              table=table, T_other=T_carried)
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
    _TRACES["count"] += 1
    h, w = ref_int.shape
    L = _levels(config, w, h)
    # the named scopes mark the stages in the compiled program's metadata (op_name), where a
    # profile of it finds them (experiments/kernel_profile.py); they change nothing else
    with jax.named_scope("pyramid"):
        ref_pyr = build_pyramid(ref_int, ref_depth, L, config.max_depth, ref_weight)
        cur_pyr = build_pyramid(cur_int, cur_depth, L, config.max_depth)
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
        dense, res, inl, wts = _final_residuals(ref_l, cur_l, cam, T, config)
        hl, wl = ref_l.depth.shape
        counts = _final_counts(ref_l, res, inl, dense, wts, config)
        ratio = counts.inliers / jnp.maximum(counts.valid, 1)
        nw = jnp.maximum(counts.weighted, 1)
        var = jnp.sum(jnp.where(wts, res.r_int ** 2, 0.0)) / nw
        info = hessian / jnp.maximum(var, 1e-6)
        valid = _trusted(_trust_stats(counts, info, T), config)
    return MotionEstimate(T, geometry.log(T), inl.reshape(hl, wl), res.valid_depth.reshape(hl, wl), ratio,
                          hyps, iters, valid, info, jnp.sqrt(var),
                          (res.valid_depth & (res.r_depth < -config.thresh_depth)).reshape(hl, wl),
                          offset)


_estimate_jit = jit(_estimate)
_estimate_nested = jax.jit(_estimate)


def _estimate_call(*args):
    """``_estimate_jit(*args)``; inside a caller's ``jax.jit`` (where JAX refuses a nested jit with
    compiler options) the plain jit, which then runs with the caller's program's options."""
    try:
        return _estimate_jit(*args)
    except ValueError as e:
        if "compiler_options" not in str(e):
            raise
        return _estimate_nested(*args)


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


def _final_residuals(ref_l, cur_l, cam, T, config):
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
    """
    finite: jnp.ndarray
    conditioning: jnp.ndarray
    inlier_ratio: jnp.ndarray
    overlap: jnp.ndarray
    depth_agreement: jnp.ndarray
    textured: jnp.ndarray
    photometric_agreement: jnp.ndarray


class _Counts(NamedTuple):
    """Pixel counts (int32 scalars) of the final dense pass, see :func:`_final_counts`."""
    valid: jnp.ndarray           # reference pixels with valid depth
    inliers: jnp.ndarray         # inlier pixels
    weighted: jnp.ndarray        # pixels the residual scale is taken over
    valid_inliers: jnp.ndarray
    overlap: jnp.ndarray
    depth_ok: jnp.ndarray
    textured: jnp.ndarray
    textured_depth_ok: jnp.ndarray
    textured_agree: jnp.ndarray


def _final_counts(ref_l, res, inl, dense, wts, config) -> _Counts:
    """The final pass's pixel counts (what :class:`TrustStats` and the inlier ratio divide), in one
    reduction (:func:`_pixel_counts`). ``wts``: (N,) bool, the pixels the residual scale is taken over.

    The statistics count every reference pixel with valid depth, trusted as static or not:
    counting only the pixels the segmentation trusts was measured worse on Bonn crowd
    (experiments/keyframes.py defaults, seeds 0-2: RPE 1 s 0.099 vs 0.080 m/s, ATE 0.064 vs
    0.056 m), since a wrong segmentation then also hides a wrong estimate."""
    ref_valid = dense.valid
    g = jnp.sqrt(ref_l.igrad[..., 1] ** 2 + ref_l.igrad[..., 2] ** 2).reshape(-1)
    textured = ref_valid & (g > config.thresh_lum / 6)
    overlap = res.valid_depth & ref_valid
    depth_ok = overlap & (jnp.abs(res.r_depth) < config.thresh_depth)
    photo_ok = jnp.abs(res.r_int) < config.thresh_lum
    return _Counts(*_pixel_counts(ref_valid, inl, wts, inl & ref_valid, overlap, depth_ok, textured,
                                  textured & depth_ok, textured & depth_ok & photo_ok))


def _pixel_counts(*masks):
    """The True pixels of each of ``masks`` (bool arrays of one shape), int32 scalars, in one
    reduction over the pixels: XLA reduces each ``jnp.sum`` in a pass of its own over them (1.0
    against 0.25 ms for 7 counts at 640x480 on a 2-core Xeon), and integer sums are exact in any
    order, so the counts are those of ``jnp.sum``."""
    ops = tuple(m.astype(jnp.int32) for m in masks)
    dims = tuple(range(ops[0].ndim))
    return jax.lax.reduce(ops, (jnp.int32(0),) * len(ops), lambda a, b: tuple(x + y for x, y in zip(a, b)), dims)


def _trust_stats(c: _Counts, info, T) -> TrustStats:
    """The :class:`TrustStats` of the final pass's counts, information matrix and pose."""
    def frac(a, b):
        return a / jnp.maximum(b, 1)
    eig = jnp.linalg.eigvalsh(0.5 * (info + info.T))
    finite = jnp.all(jnp.isfinite(T)) & jnp.all(jnp.isfinite(info))
    return TrustStats(finite, eig[0] / jnp.maximum(eig[-1], 1e-30), frac(c.valid_inliers, c.valid),
                      frac(c.overlap, c.valid), frac(c.depth_ok, c.overlap), frac(c.textured, c.valid),
                      frac(c.textured_agree, c.textured_depth_ok))


def _trusted(s: TrustStats, config: Config):
    """The failure flag's rule (measured as a classifier by experiments/failure_flag.py)."""
    return (s.finite & (s.conditioning > 1e-9) & (s.inlier_ratio >= config.min_inlier_ratio)
            & (s.depth_agreement >= config.min_depth_agreement)
            & (s.photometric_agreement >= config.min_photometric_agreement))


@jax.jit
def _explain(ref_int, ref_depth, cur_int, cur_depth, camera, config, T, info, offset):
    level = config.finest_level
    L = _levels(config, ref_int.shape[1], ref_int.shape[0])
    ref_l = build_pyramid(ref_int, ref_depth, L, config.max_depth)[level]
    ref_l = brightness.apply(ref_l, offset)
    cur_l = build_pyramid(cur_int, cur_depth, L, config.max_depth)[level]
    dense, res, inl, wts = _final_residuals(ref_l, cur_l, camera.at_level(level), T, config)
    s = _trust_stats(_final_counts(ref_l, res, inl, dense, wts, config), info, T)
    return s, _trusted(s, config)


def explain_validity(ref: Frame, cur: Frame, camera: Camera, estimate: "MotionEstimate",
                     config: Optional[Config] = None):
    """Why ``estimate`` (of ``estimate_motion(ref, cur, camera, config)``) is or is not ``valid``:
    returns ``(TrustStats, valid)``, recomputed exactly as the estimator does at the end."""
    config = _checked_settings(config, camera)
    validate_pair(ref, cur, camera)
    offset = 0.0 if estimate.brightness is None else estimate.brightness
    return _explain(_float32(ref.intensity), _float32(ref.depth), _float32(cur.intensity), _float32(cur.depth),
                    camera, config, estimate.T_cur_ref, estimate.information, jnp.float32(offset))


def _is_concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def _checked_settings(config: Optional[Config], camera: Camera) -> Config:
    """The config (default ``Config()``) after checking it and the camera (ValueError naming the field)."""
    config = Config() if config is None else config
    if not isinstance(config, Config):
        raise ValueError(f"config must be a jaxvo.Config, got {type(config).__name__}")
    if not isinstance(camera, Camera):
        raise ValueError(f"camera must be a jaxvo.Camera, got {type(camera).__name__} "
                         f"(e.g. jaxvo.camera.PRESETS['fr2'])")
    # the checks cost ~0.2 ms (scratch timing), every estimate: a (config, camera) pair that passed once is not
    # checked again (equal values pass equally; configs holding arrays are not hashable: checked)
    try:
        known = (config, camera) in _CHECKED
    except TypeError:
        known = None
    if not known:
        config.validate()
        camera.validate()
        if known is not None:
            if len(_CHECKED) > 256:
                _CHECKED.clear()
            _CHECKED.add((config, camera))
    return config


_CHECKED: set = set()


def _checked_key(key):
    """``key`` (default ``jax.random.key(0)``) if it is a jax.random key, else ValueError with a hint."""
    if key is None:
        return jax.random.key(0)
    dtype = getattr(key, "dtype", None)
    if dtype is not None and (jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key)
                              or (dtype == jnp.uint32 and tuple(key.shape) == (2,))):
        return key
    shown = repr(key) if isinstance(key, (int, float, str)) else type(key).__name__
    raise ValueError(f"key must be a jax.random key, got {shown}; pass jax.random.key(seed), "
                     f"e.g. jax.random.key({key if isinstance(key, int) else 0})")


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
    args = _estimate_args(ref, cur, camera, config, key, init, weights)
    # through the program exported into the cache folder when the CLI (jaxvo.runtime.cache.enable)
    # switched that on: a second process then skips tracing; else plain jit
    return MotionEstimate(*aot.call("estimate", _estimate, _estimate_call, args, COMPILER_OPTIONS))


def _estimate_args(ref: Frame, cur: Frame, camera: Camera, config: Optional[Config], key, init, weights):
    """The checked arguments of the compiled estimate for :func:`estimate_motion`'s inputs."""
    config = _checked_settings(config, camera)
    validate_pair(ref, cur, camera)
    h, w = ref.intensity.shape
    L = _levels(config, w, h)
    if config.finest_level >= L:
        raise ValueError(f"config.finest_level={config.finest_level} but the pyramid has only {L} levels")
    if (w >> (L - 1)) < 8 or (h >> (L - 1)) < 8:
        raise ValueError(f"{L} pyramid levels are too many for {w}x{h} images")
    key = _checked_key(key)
    T0 = _IDENTITY if init is None else _float32(init)
    if T0.shape != (4, 4):
        raise ValueError(f"init must be a 4x4 transform, got shape {T0.shape}")
    return (_float32(ref.intensity), _float32(ref.depth), _float32(cur.intensity), _float32(cur.depth),
            camera, config, key, T0, _reference_weights(ref, weights))


_IDENTITY = np.eye(4, dtype=np.float32)
_IDENTITY.flags.writeable = False
_ONES: dict = {}   # (h, w) -> read-only float32 ones: the weights when none are given


def _float32(x):
    """``x`` as float32 without a dispatch per array: NumPy (and lists) stay on the host, as NumPy,
    and travel with the compiled call (one transfer, not one ``jnp.asarray`` each: ~0.1 ms per
    array per estimate); JAX arrays (and tracers) stay where they are."""
    if isinstance(x, jax.Array):
        return x if x.dtype == jnp.float32 else x.astype(jnp.float32)
    return np.asarray(x, np.float32)


def _reference_weights(ref: Frame, weights=None):
    """(H, W) float32 trust of the reference pixels: ``weights`` (default 1) times ``ref.mask``."""
    h, w = ref.intensity.shape
    if weights is None:
        if (h, w) not in _ONES:
            _ONES[(h, w)] = np.ones((h, w), np.float32)
            _ONES[(h, w)].flags.writeable = False
        wt = _ONES[(h, w)]
    else:
        wt = _float32(weights)
    if wt.shape != (h, w):
        raise ValueError(f"weights must have the images' shape {(h, w)}, got {wt.shape}")
    if getattr(ref, "mask", None) is not None:
        m = ref.mask if isinstance(ref.mask, jax.Array) else np.asarray(ref.mask)
        if m.shape != (h, w):
            raise ValueError(f"reference frame: mask must have the images' shape {(h, w)}, got {m.shape}")
        wt = wt * (m != 0)
    return wt
