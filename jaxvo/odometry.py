"""The estimator: configuration, result, coarse-to-fine ``estimate_motion`` and ``track``.

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

import dataclasses
from typing import Any, Iterable, NamedTuple, Optional, Tuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxvo import geometry
from jaxvo.camera import Camera
from jaxvo.frame import Frame, validate_pair
from jaxvo.pyramid import build_pyramid, num_levels_for
from jaxvo.ransac import inliers, ransac_level
from jaxvo.residuals import reference_points, residuals, select_points
from jaxvo.solvers import irls, solve_pose

__all__ = ["Config", "MotionEstimate", "estimate_motion", "track", "Track", "TrackConfig", "METHODS", "trace_count"]

METHODS = ("classic", "huber", "ransac")


@dataclasses.dataclass(frozen=True)
class Config:
    """Estimator settings. Numeric fields are pytree leaves (traceable, vmappable);
    fields marked *static* fix shapes or control flow and trigger a recompile when changed.

    method: *static*, "classic" | "huber" | "ransac".
    p, w: RANSAC success probability and assumed outlier fraction (k from p, w, n).
    thresh_lum: inlier threshold on |luminance residual|, 0-255 units.
    thresh_depth: inlier threshold on |depth residual|, metres.
    early_exit_ratio: RANSAC stops once a hypothesis's inlier ratio exceeds it.
    huber_k: Huber threshold in units of the MAD scale estimate.
    max_depth: depth beyond this (metres) is ignored.
    min_inlier_ratio: below this final inlier ratio the estimate is flagged invalid.
    n_points: *static*, pixels per RANSAC sample (the paper's n = 6).
    patch_radius: *static*, neighbourhood radius around each sampled pixel (1 -> 3x3).
    max_hypotheses: *static*, hard cap on k per level.
    batch_size: *static*, hypotheses solved together (vmapped) between early-exit checks.
    num_levels: *static*, pyramid levels; None = halve down to 80x60 (4 for 640x480).
    finest_level: *static*, stop after this level (0 = full resolution).
    max_iterations: *static*, LM iterations per level (classic, RANSAC refinement).
    hypothesis_iterations: *static*, LM iterations per RANSAC hypothesis.
    irls_rounds: *static*, Huber re-weighting rounds per level (huber, and the RANSAC
      consensus refinement with consensus_weights="huber").
    irls_iterations: *static*, LM iterations per re-weighting round.
    refine_rounds: *static*, RANSAC consensus -> refine rounds per level.
    blocks: *static*, per level (index 0 = finest): the refinement uses one reference
      pixel per b x b tile, the one with the strongest intensity gradient (b = 1: every
      pixel). The current image is always sampled at that level's full resolution.
      Missing entries mean 1.
    max_score_pixels: *static*, RANSAC scores hypotheses on at most about this many
      reference pixels per level (a regular subgrid); the paper scores all pixels.
    depth_weight: luminance units per metre of depth residual where a joint RGB-D
      cost is used (600 = 30 / 0.05: the two inlier thresholds weigh the same).
    terms: *static*, "photometric" (the paper) or "rgbd" (photometric + depth residual,
      the depth term scaled by depth_weight): the cost every refinement minimises.
    hypothesis_terms: *static*, "photometric" (the paper) or "rgbd": the residuals each
      RANSAC hypothesis is fitted on.
    scoring: *static*, "count" (the paper: most inliers) or "msac" (truncated quadratic).
    prior_candidate: *static*, the pose RANSAC scores first and starts every hypothesis
      from: "raw" (the previous level's result as it is) or "refined" (that pose after a
      plain least-squares fit of this level): where the scene is mostly static the
      refined pose is the best candidate, and sampled patches rarely beat it.
    consensus_weights: *static*, the RANSAC refinement on the consensus set: "binary"
      (least squares on the inliers, the paper) or "huber" (Huber IRLS on the inliers,
      which also discounts the moving pixels that happen to pass the thresholds).
    score_selection: *static*, which pixels score a hypothesis when there are more than
      max_score_pixels: "grid" (a regular subgrid) or "gradient" (the strongest-gradient
      pixel of each tile, so textureless areas that agree with any pose do not dilute it).
    """
    method: str = "ransac"
    p: Any = 0.99
    w: Any = 0.3
    thresh_lum: Any = 30.0
    thresh_depth: Any = 0.05
    early_exit_ratio: Any = 0.9
    huber_k: Any = 1.345
    max_depth: Any = 4.0
    min_inlier_ratio: Any = 0.2
    n_points: int = 6
    patch_radius: int = 1
    max_hypotheses: int = 64
    batch_size: int = 8
    num_levels: Optional[int] = None
    finest_level: int = 0
    max_iterations: int = 6
    hypothesis_iterations: int = 6
    irls_rounds: int = 2
    irls_iterations: int = 2
    refine_rounds: int = 1
    blocks: Tuple[int, ...] = (4, 2, 1, 1)
    max_score_pixels: int = 10000
    depth_weight: Any = 600.0
    terms: str = "photometric"
    hypothesis_terms: str = "rgbd"
    scoring: str = "msac"
    score_selection: str = "grid"
    consensus_weights: str = "huber"
    prior_candidate: str = "refined"

    @classmethod
    def paper(cls, method: str = "ransac", **changes) -> "Config":
        """The seed paper's algorithm as published: hypotheses fitted on the photometric
        residual only, ranked by inlier count, scored on every pixel of every level, and
        every pixel used in the refinement, plain least squares on the consensus set.
        The defaults differ from it in these six places (measured to be more accurate or faster; see the README)."""
        return cls(method=method, hypothesis_terms="photometric", scoring="count", consensus_weights="binary",
                   prior_candidate="raw",
                   max_score_pixels=1 << 30, blocks=(1, 1, 1, 1)).replace(**changes)

    def replace(self, **changes) -> "Config":
        return dataclasses.replace(self, **changes)

    def validate(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"unknown method {self.method!r}; choose one of {', '.join(METHODS)}")
        for name, allowed in _CHOICES.items():
            if getattr(self, name) not in allowed:
                raise ValueError(f"config.{name} must be one of {', '.join(map(repr, allowed))}, "
                                 f"got {getattr(self, name)!r}")
        for name in ("n_points", "max_hypotheses", "batch_size", "max_iterations", "hypothesis_iterations",
                     "irls_rounds", "irls_iterations", "refine_rounds", "max_score_pixels"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"config.{name} must be >= 1, got {getattr(self, name)}")
        if self.finest_level < 0 or (self.num_levels is not None and self.finest_level >= self.num_levels):
            raise ValueError(f"config.finest_level={self.finest_level} must lie in [0, num_levels)")
        if any(int(b) < 1 for b in self.blocks):
            raise ValueError(f"config.blocks must be >= 1, got {self.blocks}")


# the string-valued static fields and their allowed values
_CHOICES = {"terms": ("photometric", "rgbd"), "hypothesis_terms": ("photometric", "rgbd"),
            "prior_candidate": ("raw", "refined"), "consensus_weights": ("binary", "huber"),
            "score_selection": ("grid", "gradient"), "scoring": ("count", "msac")}

_STATIC = ["method", "n_points", "patch_radius", "max_hypotheses", "batch_size", "num_levels", "finest_level",
           "max_iterations", "hypothesis_iterations", "irls_rounds", "irls_iterations", "refine_rounds", "blocks",
           "max_score_pixels", "terms", "hypothesis_terms", "scoring", "score_selection", "consensus_weights",
           "prior_candidate"]
jax.tree_util.register_dataclass(
    Config, data_fields=[f.name for f in dataclasses.fields(Config) if f.name not in _STATIC], meta_fields=_STATIC)


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
    valid: bool, a trustworthy estimate: finite, inlier ratio >= min_inlier_ratio and
      a well-conditioned information matrix.
    information: (6, 6) J^T W J / sigma^2 at the finest level (inverse covariance of a
      left perturbation of T_cur_ref, twist order (w, v)).
    residual_rms: weighted RMS photometric residual at the finest level (0-255 units).
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


_TRACES = {"count": 0}


def trace_count() -> int:
    """How many times the estimator has been traced (compiled) in this process; for tests and benchmarks."""
    return _TRACES["count"]


def _levels(config: Config, width: int, height: int) -> int:
    return config.num_levels if config.num_levels is not None else num_levels_for(width, height)


def _block(config: Config, level: int) -> int:
    return int(config.blocks[level]) if level < len(config.blocks) else 1


def _estimate(ref_int, ref_depth, cur_int, cur_depth, camera: Camera, config: Config, key, T_init):
    _TRACES["count"] += 1
    h, w = ref_int.shape
    L = _levels(config, w, h)
    ref_pyr = build_pyramid(ref_int, ref_depth, L, config.max_depth)
    cur_pyr = build_pyramid(cur_int, cur_depth, L, config.max_depth)
    T = T_init
    dw = config.depth_weight if config.terms == "rgbd" else None
    hyps = [jnp.int32(0)] * L
    iters = [jnp.int32(0)] * L
    sol = None
    for level in range(L - 1, config.finest_level - 1, -1):
        cam = camera.at_level(level)
        ref_l, cur_l = ref_pyr[level], cur_pyr[level]
        pts = select_points(ref_l, cam, _block(config, level))
        ones = pts.valid.astype(jnp.float32)
        if config.method == "classic":
            sol = solve_pose(T, pts, cur_l, cam, ones, config.max_iterations, depth_weight=dw)
            iters[level] = sol.iterations
        elif config.method == "huber":
            inner = config.irls_iterations
            sol = irls(T, pts, cur_l, cam, ones, config.huber_k, config.irls_rounds, inner, depth_weight=dw)
            iters[level] = sol.iterations
        else:
            hh, ww = ref_l.depth.shape
            score_stride = max(1, int(np.ceil(np.sqrt(hh * ww / config.max_score_pixels))))
            if config.score_selection == "gradient":
                score_pts = select_points(ref_l, cam, score_stride)
            else:
                score_pts = reference_points(ref_l, cam, score_stride)
            if config.prior_candidate == "refined":
                T = solve_pose(T, pts, cur_l, cam, ones, config.max_iterations, depth_weight=dw).T
            rs = ransac_level(T, ref_l, cur_l, cam, score_pts, jax.random.fold_in(key, level),
                              p=config.p, w=config.w, thresh_lum=config.thresh_lum,
                              thresh_depth=config.thresh_depth, early_exit_ratio=config.early_exit_ratio,
                              n=config.n_points, radius=config.patch_radius,
                              max_hypotheses=config.max_hypotheses, batch_size=config.batch_size,
                              hypothesis_iterations=config.hypothesis_iterations,
                              depth_weight=config.depth_weight if config.hypothesis_terms == "rgbd" else None,
                              scoring=config.scoring)
            hyps[level] = rs.hypotheses
            T = rs.T
            it = jnp.int32(0)
            for _ in range(config.refine_rounds):
                mask = inliers(residuals(T, pts, cur_l, cam), config.thresh_lum, config.thresh_depth)
                if config.consensus_weights == "huber":
                    inner = config.irls_iterations
                    sol = irls(T, pts, cur_l, cam, mask.astype(jnp.float32), config.huber_k, config.irls_rounds,
                               inner, depth_weight=dw)
                else:
                    sol = solve_pose(T, pts, cur_l, cam, mask.astype(jnp.float32), config.max_iterations,
                                     depth_weight=dw)
                T = sol.T
                it = it + sol.iterations
            iters[level] = it
        T = sol.T

    # per-pixel masks and statistics at the finest level processed, all pixels
    level = config.finest_level
    cam = camera.at_level(level)
    ref_l, cur_l = ref_pyr[level], cur_pyr[level]
    dense = reference_points(ref_l, cam, 1)
    res = residuals(T, dense, cur_l, cam)
    inl = inliers(res, config.thresh_lum, config.thresh_depth)
    hl, wl = ref_l.depth.shape
    n_valid = jnp.maximum(jnp.sum(dense.valid), 1)
    ratio = jnp.sum(inl) / n_valid
    # residual scale on the pixels the final solve trusted (inliers for ransac)
    wts = inl if config.method == "ransac" else res.valid_int
    nw = jnp.maximum(jnp.sum(wts), 1)
    var = jnp.sum(jnp.where(wts, res.r_int ** 2, 0.0)) / nw
    info = sol.hessian / jnp.maximum(var, 1e-6)
    eig = jnp.linalg.eigvalsh(0.5 * (info + info.T))
    finite = jnp.all(jnp.isfinite(T)) & jnp.all(jnp.isfinite(info))
    conditioned = eig[0] > 1e-9 * jnp.maximum(eig[-1], 1e-30)
    valid = finite & conditioned & (ratio >= config.min_inlier_ratio)
    return MotionEstimate(T, geometry.log(T), inl.reshape(hl, wl), res.valid_depth.reshape(hl, wl), ratio,
                          jnp.stack(hyps), jnp.stack(iters), valid, info, jnp.sqrt(var))


_estimate_jit = jax.jit(_estimate)


def _is_concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def estimate_motion(ref: Frame, cur: Frame, camera: Camera, config: Optional[Config] = None, key=None,
                    init=None) -> MotionEstimate:
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

    Returns:
      :class:`MotionEstimate` whose ``T_cur_ref`` maps reference-camera points into the current camera.

    Raises:
      ValueError: mismatched sizes, wrong dtypes or shapes, intrinsics that do not match the
        images, no valid depth, or an invalid config.
    """
    config = Config() if config is None else config
    if not isinstance(config, Config):
        raise ValueError(f"config must be a jaxvo.Config, got {type(config).__name__}")
    config.validate()
    if not isinstance(camera, Camera):
        raise ValueError(f"camera must be a jaxvo.Camera, got {type(camera).__name__}")
    validate_pair(ref, cur, camera)
    h, w = ref.intensity.shape
    L = _levels(config, w, h)
    if config.finest_level >= L:
        raise ValueError(f"config.finest_level={config.finest_level} but the pyramid has only {L} levels")
    if (w >> (L - 1)) < 8 or (h >> (L - 1)) < 8:
        raise ValueError(f"{L} pyramid levels are too many for {w}x{h} images")
    if key is None:
        key = jax.random.key(0)
    T0 = jnp.eye(4, dtype=jnp.float32) if init is None else jnp.asarray(init, jnp.float32)
    if T0.shape != (4, 4):
        raise ValueError(f"init must be a 4x4 transform, got shape {T0.shape}")
    return _estimate_jit(jnp.asarray(ref.intensity, jnp.float32), jnp.asarray(ref.depth, jnp.float32),
                         jnp.asarray(cur.intensity, jnp.float32), jnp.asarray(cur.depth, jnp.float32),
                         camera, config, key, T0)


class TrackConfig(NamedTuple):
    """How :func:`track` chooses each frame's reference and treats failed estimates (host-side policy).

    Frame j is estimated against a reference frame k < j (a keyframe), starting from
    frame j-1's pose relative to k. After frame j, once ``j - k >= max_gap`` the
    reference moves to frame ``max(j - lag, k + 1)``, whose pose is already known.
    ``max_gap=1, lag=0`` (the default) is the paper's frame-to-frame chaining;
    :meth:`keyframes` (``max_gap=6, lag=3``) is what jaxvo recommends where people or
    objects move through the picture (measured with ``experiments/keyframes.py``: on Bonn
    crowd ransac scores alike with gaps 6 and 8, and the shorter gap keeps more frames
    tracked by the weaker methods).

    Why keyframes: between consecutive frames (33 ms) people who walk at ~1 m/s move
    ~3 cm, under the 5 cm depth threshold, so no inlier test can tell them from the
    static scene and every estimator partly follows them. Against a reference a few
    frames back they have moved far more than the camera, fail the thresholds, and
    RANSAC's consensus is the static background. ``lag`` keeps the reference at least
    ``lag`` frames back after a switch, and because the reference's pose came from an
    estimate over a long baseline, errors of the short-baseline estimates do not
    accumulate.

    max_gap: frames between the reference and the current frame before the reference
      moves (>= 1).
    lag: after a move the reference is this many frames behind the current frame
      (0 <= lag < max_gap; 0 = the current frame becomes the reference). Frames whose
      estimate failed are skipped: the reference moves to the latest successful frame at
      least ``lag`` back, or stays where it is.
    hold_invalid: an estimate that is not ``valid`` or implies an implausible step from the
      previous frame (beyond ``max_step`` metres or ``max_step_deg`` degrees) is replaced by
      the previous frame's pose (constant position) and reported invalid.
    """
    max_gap: int = 1
    lag: int = 0
    hold_invalid: bool = True
    max_step: float = 0.1
    max_step_deg: float = 10.0

    @classmethod
    def frame_to_frame(cls, **changes) -> "TrackConfig":
        """The paper's chaining: every frame against the one before it (the default)."""
        return cls(max_gap=1, lag=0, **changes)

    @classmethod
    def keyframes(cls, max_gap: int = 6, lag: Optional[int] = None, **changes) -> "TrackConfig":
        """References up to ``max_gap`` frames back, ``lag`` (default max_gap // 2) after a move."""
        return cls(max_gap=max_gap, lag=max_gap // 2 if lag is None else lag, **changes)

    def validate(self) -> None:
        if int(self.max_gap) < 1:
            raise ValueError(f"track config: max_gap must be >= 1, got {self.max_gap}")
        if not 0 <= int(self.lag) < int(self.max_gap):
            raise ValueError(f"track config: lag must lie in [0, max_gap), got lag={self.lag}, "
                             f"max_gap={self.max_gap}")
        if not (self.max_step > 0 and self.max_step_deg > 0):
            raise ValueError("track config: max_step and max_step_deg must be > 0")


class Track(NamedTuple):
    """Result of :func:`track`.

    poses: (N, 4, 4) float64 T_world_cam, the first frame at ``T_world_first`` (identity by default).
    relative: (N-1, 4, 4) float64 T_cur_ref of each consecutive pair (frame i -> i+1), from the poses.
    inlier_ratio, valid: (N-1,) of the estimate of frame i+1 (valid False: it failed and was held).
    reference: (N-1,) int, the index of the frame that frame i+1 was estimated against.
    """
    poses: np.ndarray
    relative: np.ndarray
    inlier_ratio: np.ndarray
    valid: np.ndarray
    reference: np.ndarray


class TrackStep(NamedTuple):
    """What :func:`track` passes to its callback after each frame.

    frame: index of the frame just estimated (>= 1). reference: index of the frame it was
    estimated against (``estimate.inlier_mask`` lies on that frame's pixels).
    estimate: the :class:`MotionEstimate` (T_cur_ref = T_frame_reference).
    T_world_cur: (4, 4) float64 pose given to the frame. valid: False if the estimate failed
    and the pose was held (see :class:`TrackConfig`).
    """
    frame: int
    reference: int
    estimate: MotionEstimate
    T_world_cur: np.ndarray
    valid: bool


def _rigid(T) -> np.ndarray:
    """float64 copy of a float32 estimate with its rotation re-orthonormalised, so that
    chaining thousands of them (and inverting by transpose) stays rigid."""
    T = np.array(T, np.float64)
    if np.all(np.isfinite(T)):
        T[:3, :3] = geometry.project_to_so3(T[:3, :3])
    return T


def track(frames: Iterable[Frame], camera: Camera, config: Optional[Config] = None, key=None,
          T_world_first=None, callback=None, policy: Optional[TrackConfig] = None) -> Track:
    """Run :func:`estimate_motion` along a sequence and chain the results into poses.

    Frames may be any iterable (e.g. a lazy sequence); only the last ``policy.max_gap``
    frames are kept. Frame j (j >= 1) is estimated against a reference frame chosen by
    ``policy`` (default :class:`TrackConfig`: frame to frame, the paper's chaining;
    ``TrackConfig.keyframes()`` for dynamic scenes) with key
    ``jax.random.fold_in(key, j - 1)``. Poses accumulate on the host in float64:
    ``T_world_cur = T_world_ref @ inv(T_cur_ref)``.
    ``callback(step)`` is called with a :class:`TrackStep` after each frame (e.g. to write
    the trajectory as it grows). The estimator compiles once; each result is pulled to
    the host before the next frame is dispatched, because the next reference and initial
    pose depend on it (measured: overlapping the two saved < 2 % per frame).
    """
    config = Config() if config is None else config
    policy = TrackConfig() if policy is None else policy
    policy.validate()
    key = jax.random.key(0) if key is None else key
    pose = np.eye(4) if T_world_first is None else np.asarray(T_world_first, np.float64)
    poses, ratios, valids, refs = [pose], [], [], []
    it = iter(frames)
    try:
        first = next(it)
    except StopIteration:
        raise ValueError("track needs at least one frame") from None
    window = {0: first}           # frames that may still serve as reference
    ref = 0
    max_step_rad = np.radians(policy.max_step_deg)

    for j, frame in enumerate(it, start=1):
        window[j] = frame
        T_ref_prev = geometry.inverse(poses[ref]) @ poses[j - 1]
        est = estimate_motion(window[ref], frame, camera, config, jax.random.fold_in(key, j - 1),
                              init=geometry.inverse(T_ref_prev))
        T, ratio, ok = jax.device_get((est.T_cur_ref, est.inlier_ratio, est.valid))  # one transfer
        T = _rigid(T)
        valid = bool(ok) and bool(np.all(np.isfinite(T)))
        if valid:
            step = T @ T_ref_prev                          # T_cur_prev
            valid = (np.linalg.norm(step[:3, 3]) <= policy.max_step
                     and geometry.rotation_angle(step[:3, :3]) <= max_step_rad)
        pose_j = poses[j - 1].copy() if not valid and policy.hold_invalid else poses[ref] @ geometry.inverse(T)
        poses.append(pose_j)
        ratios.append(float(ratio))
        valids.append(valid)
        refs.append(ref)
        if callback is not None:
            callback(TrackStep(j, ref, est, pose_j, valid))
        if j - ref >= policy.max_gap:
            # the latest frame at least `lag` back whose own estimate succeeded: a failed
            # (held) frame has no trustworthy pose and must not become a reference
            good = [i for i in range(ref + 1, j - policy.lag + 1) if valids[i - 1]]
            if good:
                ref = good[-1]
            elif j - ref >= 4 * policy.max_gap:
                ref = j - policy.lag  # lost for long: restart from the held poses
        for old in [i for i in window if i < ref]:
            del window[old]
    P = np.stack(poses)
    rel = np.stack([geometry.inverse(P[i + 1]) @ P[i] for i in range(len(P) - 1)]) if len(P) > 1 \
        else np.zeros((0, 4, 4))
    return Track(P, rel, np.asarray(ratios), np.asarray(valids, bool), np.asarray(refs, int))
