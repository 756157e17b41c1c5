"""Streaming odometry: :class:`Odometry` (frames in, poses out) and :func:`track`, a loop over it."""
from __future__ import annotations

import time
from typing import Iterable, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from jaxvo import geometry
from jaxvo.camera import Camera
from jaxvo.config import Config, TrackConfig
from jaxvo.frame import Frame, check_frame, has_depth
from jaxvo.estimator import MIN_CONDITIONING, MotionEstimate, PreparedFrame, checked_config, checked_key, conditioning, \
    estimate_motion, num_levels, position_sd, prepare_frame
from jaxvo.tracking import depth_time, segmentation, window
from jaxvo.tracking.static_map import NoStaticMap, StaticMap

class Track(NamedTuple):
    """Result of :func:`track`.

    poses: (N, 4, 4) float64 T_world_cam, the first frame at ``T_world_first`` (identity by default):
    ``refined`` (``TrackConfig.poses`` "refined", the default) or ``tracked`` ("tracked").
    relative: (N-1, 4, 4) float64 T_cur_ref of each consecutive pair (frame i -> i+1), from the poses.
    inlier_ratio, valid: (N-1,) of the estimate of frame i+1 (valid False: it failed, or the frame
    has no depth, and was held; inlier ratio 0 without depth).
    reference: (N-1,) int, the index of the frame that frame i+1 was estimated against.
    refined: (N, 4, 4) float64 T_world_cam refined in hindsight (:meth:`Odometry.refined_poses`):
    each frame on the latest anchor of the reference it was posed on, a frame that became a
    reference at its anchor.
    tracked: (N, 4, 4) float64 T_world_cam as tracked: each frame's pose as :meth:`Odometry.add`
    returned it (``TrackStep.T_world_cur``).
    """
    poses: np.ndarray
    relative: np.ndarray
    inlier_ratio: np.ndarray
    valid: np.ndarray
    reference: np.ndarray
    refined: Optional[np.ndarray] = None
    tracked: Optional[np.ndarray] = None


class TrackStep(NamedTuple):
    """What :class:`Odometry` returns for each frame and :func:`track` passes to its callback.

    frame: index of the frame just added. reference: index of the frame it was
    estimated against (``estimate.inlier_mask`` and ``static_mask`` lie on that frame's
    pixels: the estimate's masks at its finest level, coarser for the calm mode's estimates where
    ``TrackConfig.calm_min_width`` is set; :func:`jaxvo.pipelines.mapping.outlier_mask` brings them
    to full size); -1 for the first frame. estimate: the :class:`MotionEstimate`
    (T_cur_ref = T_frame_reference), None for the first frame and for a frame without depth (a
    covered sensor, :func:`jaxvo.frame.has_depth`), which is held.
    T_world_cur: (4, 4) float64 pose given to the frame. valid: False if the estimate failed
    (or the frame has no depth) and the pose was held (see :class:`TrackConfig`).
    static_mask: (H, W) bool, the reference pixels the segmentation trusted as static for
    this estimate (all True without segmentation).
    settled: frames [0, settled) hold their final pose in ``Track.poses``: with
    ``TrackConfig.poses`` "refined" (the default), those whose refined pose can no longer change
    (:meth:`Odometry.settled`); with "tracked", every frame so far.
    refined: with ``TrackConfig.poses`` "refined", frame index -> (4, 4) float64 refined pose of
    the frames from the previous step's ``settled`` to this one (final below ``settled``, the
    others as they stand now); None with "tracked".
    """
    frame: int
    reference: int
    estimate: Optional[MotionEstimate]
    T_world_cur: np.ndarray
    valid: bool
    static_mask: Optional[np.ndarray] = None
    settled: int = 0
    refined: Optional[dict] = None


#: Two estimates of a frame against different keyframes that its guess makes jumps agree when
#: their poses lie within this fraction of the per-frame step limits (TrackConfig.max_step,
#: max_step_deg) of each other (Odometry._agreeing).
AGREEMENT = 0.25
#: TrackConfig.second_opinion asks the window's next-older keyframe only where that keyframe's
#: static mask trusts at least this much more of its pixels than the reference's
#: (Odometry._second_opinion): a keyframe that sees no more of the static scene adds no evidence.
SECOND_MARGIN = 0.1
#: An estimate whose information matrix leaves its translation less certain than this (the largest
#: standard deviation, metres: :func:`jaxvo.estimator.position_sd`) is not trusted, whatever its
#: flag: the pixels that constrain it lie in a small part of the image (a current frame with
#: depth only in a corner), and RANSAC's hypotheses then agree with them centimetres off.
#: docs/decisions/failure-flag.md.
MAX_POSITION_SD = 0.01


def fuse_poses(P1: np.ndarray, I1: np.ndarray, P2: np.ndarray, I2: np.ndarray) -> np.ndarray:
    """Two estimates of one pose fused by their information: (4, 4) float64 ``P1 exp(xi)`` with
    ``xi = (I1 + I2)^-1 I2 log(inv(P1) P2)``, the Gauss-Newton step from P1 of
    ``|log(inv(P1) P)|^2_I1 + |log(inv(P2) P)|^2_I2`` (right perturbations, twist order (w, v)).
    P1, P2: (4, 4) poses; I1, I2: (6, 6) information matrices of their right perturbations."""
    e = np.asarray(geometry.log(geometry.inverse(np.asarray(P1, np.float64)) @ np.asarray(P2, np.float64)), np.float64)
    xi = np.linalg.solve(np.asarray(I1, np.float64) + np.asarray(I2, np.float64), np.asarray(I2, np.float64) @ e)
    return np.asarray(P1, np.float64) @ np.asarray(geometry.exp(xi), np.float64)


def _within(T: np.ndarray, metres: float, degrees: float) -> bool:
    """The rigid motion T (4, 4) moves at most ``metres`` and turns at most ``degrees``."""
    return bool(np.linalg.norm(T[:3, 3]) <= metres and geometry.rotation_angle(T[:3, :3]) <= np.radians(degrees))


def _tracking_config(config: Config, policy: TrackConfig) -> Config:
    """The Config of the tracking's estimates: with the segmentation, ``Config.w`` =
    ``TrackConfig.outliers`` (where not None) and ``Config.adaptive_hypotheses`` on where
    ``TrackConfig.adaptive`` is; without it ``config`` as given (docs/decisions/hypothesis-count.md)."""
    if not policy.segment:
        return config
    config = _with_outliers(config, policy.outliers)
    return config.replace(adaptive_hypotheses=True) if policy.adaptive and not config.adaptive_hypotheses else config


def _with_outliers(config: Config, outliers: Optional[float]) -> Config:
    """``config`` with ``Config.w`` = ``outliers`` (None: unchanged). The same compiled program:
    w is a traced leaf, and an array keeps the config's dtype, so the program's signature stays."""
    if outliers is None:
        return config
    w = config.w
    return config.replace(w=float(outliers) if isinstance(w, (int, float)) else np.asarray(outliers, np.asarray(w).dtype))


def _window_levels(config: Config, ransac_finest: Optional[int]) -> Config:
    """The Config of a new keyframe's estimates against the window's older keyframes, as far as
    its levels go: ``config`` with ``Config.ransac_finest`` = ``ransac_finest``
    (``TrackConfig.window_ransac_finest``) where it is RANSAC's and that is set, else ``config``."""
    if config.method != "ransac" or ransac_finest is None or ransac_finest == config.ransac_finest:
        return config
    return config.replace(ransac_finest=int(ransac_finest))


def _window_method_config(config: Config, method: str) -> Config:
    """The Config of a new keyframe's estimates against the window's older keyframes that carry
    static weights: ``config`` with ``Config.method`` = ``method`` (``TrackConfig.window_method``)
    where it is RANSAC's, else ``config`` (a classic or Huber tracking keeps its method).

    Such an estimate starts from the chained pose, and the keyframe's static weights already
    leave out what the segmentation saw move; a Huber estimate there takes half of RANSAC's time
    (docs/decisions/window.md)."""
    if config.method != "ransac" or method == "ransac":
        return config
    return config.replace(method=method)


def _calm_config(config: Config, policy: TrackConfig, camera: Camera) -> Config:
    """The Config of the tracking's estimates without static weights: with the segmentation and
    RANSAC, ``config`` with ``Config.finest_level`` at the coarsest level of ``camera``'s pyramid
    at least ``TrackConfig.calm_min_width`` pixels wide (never finer than config's); else ``config``.

    Without weights the reference is the previous frame of a scene the segmentation sees as static
    (docs/decisions/calm-mode.md): a baseline that short is resolved at a Kinect-class camera's half
    resolution as well as at its full one, where the finest level costs most of the estimate's time."""
    if not policy.segment or config.method != "ransac" or policy.calm_min_width is None:
        return config
    levels = num_levels(config, camera.width, camera.height)
    level = max([lv for lv in range(levels) if camera.at_level(lv).width >= policy.calm_min_width] + [0])
    level = max(level, config.finest_level)
    return config if level == config.finest_level else config.replace(finest_level=level)


def _rigid(T) -> np.ndarray:
    """float64 copy of a float32 estimate with its rotation re-orthonormalised, so that
    chaining thousands of them (and inverting by transpose) stays rigid."""
    T = np.array(T, np.float64)
    if np.all(np.isfinite(T)):
        T[:3, :3] = geometry.project_to_so3(T[:3, :3])
    return T


class Judgement(NamedTuple):
    """What :meth:`Odometry._judge` makes of an estimate (host values).

    T: (4, 4) float64 T_cur_ref, its rotation re-orthonormalised. ratio: the inlier ratio.
    ratio_static: the inlier ratio over the pixels the segmentation trusts (``ratio`` without one).
    valid: the estimate is trusted and a plausible step from its initial guess.
    dynamic: the fraction of the reference's valid pixels the segmentation does not trust (1.0
    without one).
    trusted: the estimate is trusted (the estimator's flag, or the rescue) and finite, whatever
    its step from the guess.
    """
    T: np.ndarray
    ratio: float
    ratio_static: float
    valid: bool
    dynamic: float
    trusted: bool = False


class PairInputs(NamedTuple):
    """The inputs of one estimate of :class:`Odometry` (from :meth:`Odometry.prepare`):
    ``estimate_motion(ref, cur, camera, config, key, init=init, weights=weights)``.
    T_ref_prev: (4, 4) float64, the previous frame's pose relative to the reference (host).
    trust: (H, W) the segmentation's static weight of the reference (None without one); the
    estimate gets it as ``weights`` except in the calm mode (see TrackConfig.calm_fraction).
    depth: False for a current frame without depth (:func:`jaxvo.frame.has_depth`): there is
    nothing to estimate, and :meth:`Odometry.finish` takes None for its estimate and holds the frame."""
    ref: Frame
    cur: Frame
    key: jnp.ndarray
    init: np.ndarray
    weights: Optional[jnp.ndarray]
    T_ref_prev: np.ndarray
    trust: Optional[jnp.ndarray] = None
    depth: bool = True


class Odometry:
    """Streaming odometry: push frames one at a time, get each frame's pose at once.

    ``odo = Odometry(camera, config, key); step = odo.add(frame)``: ``step.T_world_cur``
    is the frame's camera-to-world pose (float64), ``odo.poses`` all poses so far. It holds
    what must persist between frames: the recent frames that can still serve as reference,
    the reference choice (:class:`TrackConfig`), and the reference's static/dynamic
    segmentation (``static_map``: a :class:`jaxvo.tracking.static_map.StaticMap`, a log-odds map
    at half resolution, or its no-op counterpart with ``TrackConfig.segment`` False), which is
    carried from reference to reference with the estimated motion and updated from every
    estimate. :func:`track` and ``jaxvo run`` are loops over :meth:`add`.

    The keyframe window (``TrackConfig.window`` keyframes, default 3): a new reference joins it,
    is estimated against its other keyframes, and the window's poses are refined as a pose graph
    (:mod:`jaxvo.tracking.window`), so the poses later frames chain from rest on several estimates,
    not one. A frame that fails against its reference is estimated against the window's older
    keyframes before it is held (``TrackConfig.recover``), and kept where two of those estimates agree
    on its pose even if they are jumps from its guess. A frame without depth (a person covering the
    sensor) is held without an estimate and never becomes a reference; the frames after it are
    estimated from its held pose as after a failed estimate. Poses already returned never change;
    :meth:`refined_poses` (``Track.refined``) gives them refined in hindsight, each on its
    reference's latest anchor.

    Frame j (j >= 1) is estimated with key ``jax.random.fold_in(key, j - 1)``; the same key
    and frames give bitwise the same poses. Each result is pulled to the host before the
    next frame (the next reference and initial pose depend on it).
    """

    def __init__(self, camera: Camera, config: Optional[Config] = None, key=None, policy: Optional[TrackConfig] = None,
                 T_world_first=None, segment_params: Optional[segmentation.SegmentParams] = None):
        self.camera = camera
        self.config = checked_config(config, camera)
        self.policy = TrackConfig() if policy is None else policy
        if not isinstance(self.policy, TrackConfig):
            raise ValueError(f"policy must be a jaxvo.TrackConfig, got {type(self.policy).__name__}")
        self.policy.validate()
        #: The Config of the tracking's estimates: ``config`` with ``Config.w`` set to
        #: ``TrackConfig.outliers`` (where not None) and the adaptive hypothesis count
        #: (``TrackConfig.adaptive``) where the segmentation is on.
        self.estimate_config = _tracking_config(self.config, self.policy)
        # the estimates against the window's older keyframes (TrackConfig.window_outliers,
        # window_ransac_finest), and those of them against keyframes with static weights
        # (TrackConfig.window_method)
        self._window_config = _window_levels(_with_outliers(self.estimate_config, self.policy.window_outliers),
                                             self.policy.window_ransac_finest)
        self._window_weighted_config = _window_method_config(self._window_config, self.policy.window_method)
        # the estimates without static weights (TrackConfig.calm_min_width)
        self._calm_config = _calm_config(self.estimate_config, self.policy, camera)
        self._window_calm_config = _calm_config(self._window_config, self.policy, camera)
        self.key = checked_key(key)
        self.params = segmentation.SegmentParams() if segment_params is None else segment_params
        self.static_map = StaticMap(camera, self.config.max_depth, self.params, self.policy.trust_gain,
                                    self.policy.trust_share, self.policy.motion_retest) \
            if self.policy.segment else NoStaticMap()
        self._first = np.eye(4) if T_world_first is None else geometry.checked_transform(T_world_first, "T_world_first")
        self.poses: list = []
        self.valid: list = []          # per frame >= 1: its estimate succeeded
        self.inlier_ratio: list = []
        self.references: list = []
        self._frames: dict = {}         # index -> Frame that may still serve as reference
        self._pyramids: dict = {}       # index -> its PreparedFrame, while the frame is held
        self._ref = 0
        self._anchor: dict = {}         # reference index -> the pose later frames chain from
        self._rel: dict = {}            # frame index -> its valid estimate T_cur_ref (float64)
        self._calm = False              # the reference was chosen in the calm mode (frame to frame)
        self._window: list = []         # the keyframe window (policy.window > 1), oldest first
        self._edges: dict = {}          # (a, b) keyframes -> (T_b_a float64, information (6, 6))
        self._key_trust: dict = {}      # keyframe -> (static weights, calm) when it stopped being the reference
        self._info: dict = {}           # frame index -> information of its valid estimate (device array)
        self._chained: dict = {}        # reference -> its chained pose, until a frame is posed from its refined one
        # for refined_poses, kept for the whole run (a 4x4 per frame): frame j >= 1 -> (the reference
        # it was posed on, that reference's anchor then); reference -> its latest anchor
        self._posed_on: dict = {}
        self._last_anchor: dict = {}
        self._settled = 1               # frames whose refined pose can no longer change (settled())
        #: None, or a dict that profiles where the time goes: set ``odo.timings = {}`` and every
        #: estimate is blocked on and its wall time (s) appended under ``"estimate: <purpose>"``
        #: (track: against the reference; retry; recover: against an older keyframe; window: a new
        #: keyframe against the window's; fuse: a new reference against the old one), the window's
        #: refinement under ``"window refinement"``, each frame's pyramid under ``"frame pyramid"``.
        #: Poses are the same with or without it.
        self.timings: Optional[dict] = None

    def __len__(self) -> int:
        return len(self.poses)

    @property
    def reference(self) -> int:
        """Index of the frame the next frame will be estimated against."""
        return self._ref

    def add(self, frame: Frame) -> TrackStep:
        """Add the next frame; returns its :class:`TrackStep` (pose, estimate, reference)."""
        pair = self.prepare(frame)
        if pair is None:
            return TrackStep(0, -1, None, self._first, True, None, settled=1)
        if not pair.depth:
            return self.finish(pair, None)
        j = len(self.poses)
        return self.finish(pair, self._estimate("track", self._ref, j, pair.key, pair.init, pair.weights))

    def prepare(self, frame: Frame) -> Optional["PairInputs"]:
        """The first half of :meth:`add`: record the frame and return the inputs of its estimate
        (None for the first frame, whose pose is set). Pass the estimate of those inputs to
        :meth:`finish` before the next frame (e.g. estimates of several sequences as one batch),
        or None where the inputs say the frame has no depth (``PairInputs.depth`` False).

        A frame without depth (a covered sensor: :func:`jaxvo.frame.has_depth`) is held as a failed
        estimate is, and never becomes a reference; the first frame must have depth (ValueError)."""
        check_frame(frame)   # ValueError naming what was passed (e.g. a (timestamp, Frame) pair)
        j = len(self.poses)
        if not has_depth(frame, f"frame {j}"):
            if j == 0:
                raise ValueError("frame 0: depth has no valid pixel (all zero, negative or NaN): the odometry "
                                 "starts from a frame with depth")
            T_ref_prev = self._ref_prev(j)
            return PairInputs(self._frames[self._ref], frame, jax.random.fold_in(self.key, j - 1),
                              geometry.inverse(T_ref_prev), None, T_ref_prev, None, depth=False)
        self._frames[j] = frame
        # its pyramid, which every estimate it takes part in reads, and which holds the segmentation's inputs
        start = time.perf_counter()
        self._pyramids[j] = prepare_frame(frame, self.camera, self.config, f"frame {j}")
        if self.timings is not None:
            jax.block_until_ready(self._pyramids[j].levels)
            self.timings.setdefault("frame pyramid", []).append(time.perf_counter() - start)
        self.static_map.add(j, frame, self._pyramids[j].levels)
        if j == 0:
            self.poses.append(self._first)
            if self.policy.window > 1:
                self._window = [0]
            return None
        if j == 2 and self.policy.window > 1:
            # the pose graph is first needed at a window join, frames later: made ready once the
            # first pose is out, so that on a new machine its compilation does not share the cores
            # with the estimator's before it, nor its loading a warm one's (docs/decisions/start-up.md)
            window.compile_ahead(self.policy.window)
        T_ref_prev = self._ref_prev(j)
        trust = self.static_map.trust(tuple(frame.depth.shape))
        # calm mode: the few pixels the map marks dynamic on a static scene are depth edges,
        # and leaving them out costs accuracy (docs/decisions/calm-mode.md)
        weights = None if self._calm else trust
        return PairInputs(self._frames[self._ref], frame, jax.random.fold_in(self.key, j - 1),
                          geometry.inverse(T_ref_prev), weights, T_ref_prev, trust)

    def _ref_prev(self, j: int) -> np.ndarray:
        """(4, 4) float64 T_ref_prev: frame j - 1's pose relative to the reference, both from one
        chain: until a frame is posed from the reference's refined anchor, the previous poses rest
        on the anchor it had before the window moved it (:meth:`_windowed_anchor`)."""
        T_world_ref = self._chained.get(self._ref, self._chain_pose(self._ref))
        return geometry.inverse(T_world_ref) @ self.poses[j - 1]

    def finish(self, pair: "PairInputs", est: Optional[MotionEstimate]) -> TrackStep:
        """The second half of :meth:`add`: chain the estimate of :meth:`prepare`'s inputs and
        update the policy and segmentation; returns the frame's :class:`TrackStep`. ``est`` is
        None for a frame without depth (``pair.depth`` False): it is held (as a failed estimate
        is: ``TrackStep.estimate`` None, ``valid`` False)."""
        if not pair.depth:
            return self._without_depth()
        j, frame, T_ref_prev, weights = len(self.poses), pair.cur, pair.T_ref_prev, pair.trust
        policy, ref, poses = self.policy, self._ref, self.poses
        T_world_ref = self._chain_pose(ref)
        # the guess is the previous frame's pose, held where its estimate failed, while the camera
        # moved on; only RANSAC's failure flag is trusted over that stale guess (TrackConfig.catch_up)
        extra = self._stale_allowance() if policy.catch_up and self.config.method == "ransac" else (0.0, 0.0)
        judged = self._judge(est, T_ref_prev, weights, extra)
        ref_mask = None     # the reference's static mask on the host, made once (it is returned below)
        if judged.valid and policy.second_opinion > 0 and policy.window > 1 and weights is not None:
            ref_mask = self.static_map.static_mask(weights, frame.depth.shape)
            est, judged = self._second_opinion(pair, est, judged, extra, float(np.mean(ref_mask)))
        if not judged.valid and policy.retry:
            est, judged = self._retry(pair, est, judged, extra)
        used = ref
        if not judged.valid and policy.recover and policy.window > 1:
            used, est, judged = self._recover(pair, est, judged, extra)
        if not judged.valid and policy.refresh:
            refreshed = self._refresh(pair, extra)
            if refreshed is not None:
                est, judged, weights = refreshed
                ref = used = self._ref
                T_world_ref = self._chain_pose(ref)
                ref_mask = None
        T, ratio, ratio_static, valid, dynamic = judged.T, judged.ratio, judged.ratio_static, judged.valid, judged.dynamic
        pose = self._held(j) if not valid and policy.hold_invalid else self._chain_pose(used) @ geometry.inverse(T)
        poses.append(pose)
        self._posed_on[j] = (used, self._chain_pose(used))
        self.valid.append(valid)
        self.inlier_ratio.append(ratio)
        self.references.append(used)
        if valid:
            self._chained.clear()
            self._rel[j] = T
            self._info[j] = est.information
        static_mask = (ref_mask if ref_mask is not None and used == ref else
                       self.static_map.static_mask(weights if used == ref else self._key_trust[used][0],
                                                   frame.depth.shape))
        if valid and used == ref:  # the current frame's view of the reference, at the estimated pose
            self.static_map.update(est, ref, j, T)
        result = TrackStep(j, used, est, pose, valid, static_mask)
        if used != ref:   # the switch tests read the motion from the current reference
            T = geometry.inverse(pose) @ T_world_ref
        self._maybe_switch(j, T, ratio_static, dynamic)
        return self._settle(result)

    def _without_depth(self) -> TrackStep:
        """The step of the current frame, which has no depth: no estimate, its pose held
        (:meth:`_held`), its reference unchanged, and the reference choice as after a failed estimate."""
        j, ref = len(self.poses), self._ref
        pose = self._held(j)
        self.poses.append(pose)
        self._posed_on[j] = (ref, self._chain_pose(ref))
        self.valid.append(False)
        self.inlier_ratio.append(0.0)
        self.references.append(ref)
        self._maybe_switch(j, geometry.inverse(pose) @ self._chain_pose(ref), 0.0, 1.0)
        return self._settle(TrackStep(j, ref, None, pose, False, None))

    def _settle(self, result: TrackStep) -> TrackStep:
        """``result`` (the step of the frame just posed) with the frames it settles, and their refined poses."""
        j = result.frame
        if self.policy.poses == "tracked":
            return result._replace(settled=j + 1)
        first = self._settled
        return result._replace(settled=self.settled(), refined={i: self._refined_pose(i) for i in range(first, j + 1)})

    def _second_opinion(self, pair: "PairInputs", est: MotionEstimate, judged: Judgement, extra, share: float):
        """(estimate, judgement) of a frame whose valid estimate rests on a reference that trusts
        under ``TrackConfig.second_opinion`` of its pixels: the frame is also estimated against the window's next-older keyframe, from its guess and with
        that keyframe's static weights, where that keyframe trusts at least ``SECOND_MARGIN`` more
        of its pixels. Where that estimate stays within the step limits of the guess (its failure
        flag is not asked: with people over most of the view it fails right estimates), the two
        poses of the frame are fused by the estimates' information matrices and the reference's
        estimate takes the fused pose (judged again); else both are returned as they were. share:
        the share of the reference's pixels its static mask (``pair.trust``) trusts.

        Both information matrices are of a left perturbation of ``T_cur_ref``, i.e. of a right
        perturbation of ``T_world_cur`` (``T_world_ref inv(T_cur_ref)``), in the same frame: the
        fused pose is ``P1 exp(xi)``, ``xi = (I1 + I2)^-1 I2 log(inv(P1) P2)``, the Gauss-Newton
        step of the sum of the two quadratic costs from P1 (docs/decisions/second-opinion.md)."""
        j, ref, policy = len(self.poses), self._ref, self.policy
        shape = pair.cur.depth.shape
        older = [k for k in reversed(self._window) if k != ref and k in self._key_trust]
        if share >= policy.second_opinion or not older:
            return est, judged
        k = older[0]
        trust, calm = self._key_trust[k]
        if float(np.mean(self.static_map.static_mask(trust, shape))) < share + SECOND_MARGIN:
            return est, judged
        guess = self._chain_pose(ref) @ pair.T_ref_prev        # T_world_guess: the previous frame's pose
        T_k_prev = geometry.inverse(self._chain_pose(k)) @ guess
        key = jax.random.fold_in(jax.random.fold_in(pair.key, 5), 0)   # apart from the frame's other keys
        other = self._estimate("second opinion", k, j, key, geometry.inverse(T_k_prev), None if calm else trust)
        judged_other = self._judge(other, T_k_prev, trust, extra)
        infos = [np.asarray(e.information, np.float64) for e in (est, other)]
        if not (all(np.all(np.isfinite(I)) for I in infos)
                and _within(judged_other.T @ T_k_prev, policy.max_step + extra[0], policy.max_step_deg + extra[1])):
            return est, judged
        fused = fuse_poses(self._chain_pose(ref) @ geometry.inverse(judged.T), infos[0],   # T_world_cur, each way
                           self._chain_pose(k) @ geometry.inverse(judged_other.T), infos[1])
        est = est._replace(T_cur_ref=np.asarray(geometry.inverse(fused) @ self._chain_pose(ref), np.float32))
        return est, self._judge(est, pair.T_ref_prev, pair.trust, extra)

    def _recover(self, pair: "PairInputs", est: MotionEstimate, judged: Judgement, extra):
        """(reference, estimate, judgement) for a frame whose estimate against the reference failed
        (``TrackConfig.recover``): the frame estimated against the window's older keyframes, newest
        first, from its guessed pose, each with the keyframe's static weights; the first that
        passes is kept. A frame that a person hides from the reference may still see what an
        earlier keyframe saw, and its pose then needs no coasting.

        Where none passes but two of these estimates (the reference's among them) are trusted and
        put the frame at the same pose (:meth:`_agreeing`), the newer reference's is kept: the
        guess, the previous frame's pose, is then what is off, and holding it would keep every
        later frame as far from its guess. (ref, est, judged) as they were otherwise."""
        j, ref = len(self.poses), self._ref
        guess = self._chain_pose(ref) @ pair.T_ref_prev        # T_world_guess: the previous frame's pose
        keys = jax.random.fold_in(pair.key, 3)   # apart from the frame's own key (and the retry's)
        jumps = [(ref, est, judged)] if judged.trusted else []
        for n, k in enumerate(reversed([k for k in self._window if k != ref and k in self._key_trust])):
            key = jax.random.fold_in(keys, n)
            T_k_prev = geometry.inverse(self._chain_pose(k)) @ guess
            trust, calm = self._key_trust[k]
            again = self._estimate("recover", k, j, key, geometry.inverse(T_k_prev),
                                   None if calm else trust)
            judged_again = self._judge(again, T_k_prev, trust, extra)
            if judged_again.valid:
                return k, again, judged_again
            if judged_again.trusted:
                jumps.append((k, again, judged_again))
        agreed = self._agreeing(jumps, guess, extra)
        return agreed if agreed is not None else (ref, est, judged)

    def _refresh(self, pair: "PairInputs", extra):
        """(estimate, judgement, the new reference's static weights) of a frame whose estimates
        all failed (``TrackConfig.refresh``), or None where there is no newer reference to move
        to: the reference moves now to the latest successful frame at least ``lag`` back (the
        frame a switch after this one would choose), with its map made as a switch makes it, and
        the frame is estimated against it from its guess, the previous frame's pose. The estimate
        may fail too; the reference has moved either way.

        A frame fails against its reference mostly where people have moved since it: the reference
        chosen after the failure is closer in time, so fewer of its pixels have moved and its
        map is fresher, and the frame need not wait for the next switch to use it."""
        j, ref = len(self.poses), self._ref
        good = self._latest_good(j)
        if good is None:
            return None
        guess = self._chain_pose(ref) @ pair.T_ref_prev        # T_world_guess: the previous frame's pose
        self._set_reference(good, j - 1)
        self._calm = False
        new = self._ref
        trust = self.static_map.trust(tuple(pair.cur.depth.shape))
        T_new_prev = geometry.inverse(self._chain_pose(new)) @ guess
        key = jax.random.fold_in(pair.key, 4)   # apart from the frame's other keys
        est = self._estimate("refresh", new, j, key, geometry.inverse(T_new_prev), trust)
        return est, self._judge(est, T_new_prev, trust, extra), trust

    def _agreeing(self, jumps, guess: np.ndarray, extra):
        """The first of ``jumps`` (reference, estimate, judgement; trusted estimates of the current
        frame judged too far from the guess, newest reference first) that a later one confirms,
        with its judgement made valid; None if no two agree.

        Two estimates against different keyframes agree when the poses they give the frame lie
        within ``AGREEMENT`` of the per-frame step limits of each other, and both lie within twice
        those limits (plus ``extra``, the stale guess's allowance) of the guess ``guess``
        (T_world_guess). Each keyframe sees the frame through its own pixels and its own static
        weights, so a pose that two of them give independently is not one person's motion followed
        by chance (docs/decisions/window.md)."""
        policy = self.policy
        near_m, near_deg = 2 * (policy.max_step + extra[0]), 2 * (policy.max_step_deg + extra[1])
        poses = []
        for k, est, judged in jumps:
            P = self._chain_pose(k) @ geometry.inverse(judged.T)          # T_world_cur
            step = geometry.inverse(guess) @ P
            if _within(step, near_m, near_deg):
                poses.append((k, est, judged, P))
        for a, (k, est, judged, P) in enumerate(poses):
            for _, _, _, Q in poses[a + 1:]:
                if _within(geometry.inverse(P) @ Q, AGREEMENT * policy.max_step, AGREEMENT * policy.max_step_deg):
                    return k, est, judged._replace(valid=True)
        return None

    def _retry(self, pair: "PairInputs", est: MotionEstimate, judged: Judgement, extra):
        """(estimate, :meth:`_judge` of it) for a frame whose estimate ``est`` failed: the pair
        estimated once more from the guess that the camera kept the motion between the two
        previous frames (``TrackConfig.retry``), if both were estimated and that one passes;
        ``est`` and ``judged`` as they were otherwise."""
        j = len(self.poses)
        if j < 3 or not (self.valid[-1] and self.valid[-2]):
            return est, judged
        guess = pair.T_ref_prev @ geometry.inverse(self.poses[j - 2]) @ self.poses[j - 1]   # T_ref_guess
        again = self._estimate("retry", self._ref, j, pair.key, geometry.inverse(guess), pair.weights)
        judged_again = self._judge(again, pair.T_ref_prev, pair.trust, extra)
        return (again, judged_again) if judged_again.valid else (est, judged)

    def _held(self, j: int) -> np.ndarray:
        """Pose of frame j whose estimate failed: the previous pose, moved on at the mean velocity
        of the last ``policy.coast_window`` frames while fewer than ``policy.coast`` frames in a
        row have failed (a mean over 1/3 s: single estimates are off by several mm)."""
        P = self.poses
        motion, n = self._recent_motion(j - 1)
        if self._failed_run() >= self.policy.coast or n < 1:
            return P[j - 1].copy()
        return P[j - 1] @ geometry.exp(geometry.log(motion) / n)

    def _recent_motion(self, end: int):
        """(T_start_end (4, 4), n): the motion over the last n = min(``coast_window``, end) frames
        up to frame ``end`` (the identity and n = 0 at the first frame)."""
        n = min(self.policy.coast_window, end)
        return geometry.inverse(self.poses[end - n]) @ self.poses[end], n

    def _failed_run(self) -> int:
        """How many of the latest frames in a row failed (and were held)."""
        failed = 0
        while failed < len(self.valid) and not self.valid[-1 - failed]:
            failed += 1
        return failed

    def _prepared(self, i: int) -> PreparedFrame:
        """Frame i made ready for estimates (its pyramid, made by :meth:`prepare`)."""
        return self._pyramids[i]

    def config_for(self, purpose: str, weights) -> Config:
        """The Config of an estimate made for ``purpose`` (see :attr:`timings`) with ``weights``
        (a reference's static weights, or None): :attr:`estimate_config`, for "window" with
        ``TrackConfig.window_outliers`` as ``Config.w``, ``TrackConfig.window_ransac_finest`` as
        ``Config.ransac_finest`` and, with weights, ``TrackConfig.window_method`` as its method;
        without weights (the calm mode) at ``TrackConfig.calm_min_width``'s level."""
        if purpose == "window":
            return self._window_calm_config if weights is None else self._window_weighted_config
        return self._calm_config if weights is None else self.estimate_config

    def _estimate(self, purpose: str, ref: int, cur: int, key, init, weights) -> MotionEstimate:
        """The estimate of frame ``cur`` against frame ``ref`` (indices) with this odometry's camera
        and :meth:`config_for`'s Config, from their pyramids (:meth:`_prepared`: a frame's pyramid
        serves every estimate it takes part in); with :attr:`timings` set (a dict), blocked on and
        its wall time appended under ``purpose`` (see :attr:`timings`)."""
        config = self.config_for(purpose, weights)
        if self.timings is None:
            return estimate_motion(self._prepared(ref), self._prepared(cur), self.camera, config, key, init=init,
                                   weights=weights)
        start = time.perf_counter()
        est = jax.block_until_ready(estimate_motion(self._prepared(ref), self._prepared(cur), self.camera, config,
                                                    key, init=init, weights=weights))
        self.timings.setdefault(f"estimate: {purpose}", []).append(time.perf_counter() - start)
        return est

    def _estimate_against(self, purpose: str, ref: int, frame: int, key, T_ref_prev: np.ndarray, weights,
                          trust=None):
        """Estimate frame ``frame`` against reference ``ref`` (indices) from the initial guess ``T_ref_prev``
        (float64 T_ref_guess) with ``weights`` (:meth:`_estimate` under ``purpose``). Returns
        (estimate, :meth:`_judge` of it with the reference's static weights ``trust``, default
        ``weights``)."""
        est = self._estimate(purpose, ref, frame, key, geometry.inverse(T_ref_prev), weights)
        return est, self._judge(est, T_ref_prev, weights if trust is None else trust)

    def _stale_allowance(self):
        """(metres, degrees) the camera may have moved beyond one frame's step while the latest
        frames were held: for each failed frame in a row, the mean per-frame motion over the
        ``coast_window`` frames before them (the camera kept its recent speed), or the per-frame
        limits themselves where no motion was measured yet; 0 when none failed.

        Without it a camera faster than ``max_step`` divided by the frames since its last pose
        could never be caught again: the guess stays at the held pose, so every later estimate
        is a bigger step from it and fails too (docs/decisions/catch-up.md)."""
        failed = self._failed_run()
        if failed == 0:
            return 0.0, 0.0
        # up to the latest frame whose pose was estimated
        d, n = self._recent_motion(len(self.poses) - 1 - failed)
        if n < 1:   # no motion measured yet: the per-frame limits themselves
            return failed * self.policy.max_step, failed * self.policy.max_step_deg
        return (failed * np.linalg.norm(d[:3, 3]) / n,
                failed * np.degrees(geometry.rotation_angle(d[:3, :3])) / n)

    def _judge(self, est: MotionEstimate, T_ref_prev: np.ndarray, weights, extra=(0.0, 0.0)) -> Judgement:
        """The :class:`Judgement` of an estimate from the initial guess ``T_ref_prev`` with the
        reference's static ``weights``; valid also requires a plausible step from the guess: within
        the policy's per-frame limits plus ``extra`` (metres, degrees) for a stale guess."""
        policy = self.policy
        r = self.static_map.read(est, weights)
        ok = r.ok
        # TrackConfig.rescue: RANSAC's flag counts every pixel, and where people cover most of
        # the reference and stand in front of the rest, a right estimate fails it. Its fractions
        # are of the pixels with both residuals, which a current frame with almost no depth makes
        # a handful: the rescue overrides the flag's agreement tests, never its conditioning
        if not ok and policy.rescue > 0 and self.config.method == "ransac":
            ok = (r.seen >= policy.rescue_support and r.ratio_seen >= policy.rescue
                  and conditioning(np.asarray(r.information, np.float64), np) > MIN_CONDITIONING)
        T = _rigid(r.T)
        valid = bool(ok) and bool(np.all(np.isfinite(T))) and position_sd(r.information) <= MAX_POSITION_SD
        trusted = valid
        if valid:
            valid = _within(T @ T_ref_prev, policy.max_step + extra[0], policy.max_step_deg + extra[1])  # T_cur_guess
        return Judgement(T, float(r.ratio), float(r.ratio_static), valid, float(r.dynamic), trusted)

    def _smoothed(self, new: int) -> np.ndarray:
        """Pose of ``new`` from a smooth fit to all estimates against its reference.

        The frames estimated against the same reference have independent errors of several
        mm while a hand-held camera moves smoothly over a few frames, so a least-squares fit of
        the twists log(T_ref_f) with a t + b t^2 (t: frames after the reference, through zero at
        the reference itself) is a better pose for a new reference than its own estimate."""
        pose = self.poses[new]
        parent = self.references[new - 1]
        if not self.policy.smooth or new not in self._rel:
            return pose
        fs = [f for f in self._rel if f > parent and self.references[f - 1] == parent]
        if len(fs) < 3:
            return pose
        T_parent_new = geometry.fit_motion(np.array(fs) - parent, geometry.inverse(np.stack([self._rel[f] for f in fs])),
                                           new - parent)
        return self._chain_pose(parent) @ T_parent_new

    def _fused_anchor(self, new: int, j: int) -> np.ndarray:
        """The pose later frames chain from when ``new`` becomes the reference.

        ``new`` was estimated against ``self.references[new - 1]``; if that is not the
        current reference (the references would form interleaved chains), estimate it
        against the current reference as well and average the two poses (midpoint on SE(3))."""
        old, pose = self._ref, self._smoothed(new)
        parent = self.references[new - 1]
        if not self.policy.fuse or parent == old or new <= old:
            return pose
        T_world_old = self._chain_pose(old)
        weights = self.static_map.trust(tuple(self._frames[new].depth.shape))
        key = jax.random.fold_in(jax.random.fold_in(self.key, new - 1), 1)   # apart from frame new's own key
        _, judged = self._estimate_against("fuse", old, new, key, geometry.inverse(T_world_old) @ pose,
                                           weights)
        if not judged.valid:
            return pose
        other = T_world_old @ geometry.inverse(judged.T)
        return geometry.interpolate(pose, other, 0.5)

    def _maybe_switch(self, j: int, T_cur_ref: np.ndarray, ratio_static: float, dynamic: float) -> None:
        policy, ref = self.policy, self._ref
        far = (np.linalg.norm(T_cur_ref[:3, 3]) > policy.switch_baseline
               or geometry.rotation_angle(T_cur_ref[:3, :3]) > np.radians(policy.switch_deg))
        # never without the segmentation (dynamic 1.0, calm_fraction <= 1)
        calm = self.valid[-1] and dynamic < policy.calm_fraction
        self._calm = calm
        if calm:      # nothing moves: frame to frame, the shortest baseline
            self._set_reference(j, j)
        elif j - ref >= policy.max_gap or (self.valid[-1] and (ratio_static < policy.switch_ratio or far)):
            good = self._latest_good(j)
            if good is not None:
                self._set_reference(good, j)
            elif j - ref >= policy.restart:
                # lost for long: restart from the held poses, at a frame with depth (one kept)
                held = [i for i in range(ref + 1, j - policy.lag + 1) if i in self._frames]
                if held:
                    self._set_reference(held[-1], j)
        keep_depth = self._ref - (1 << policy.history) if policy.history else self._ref
        for old in [i for i in self._frames if i < self._ref and i not in self._window]:
            del self._frames[old]
            self._pyramids.pop(old, None)
        for old in [i for i in self._info if i < self._ref - 2 * policy.max_gap]:
            del self._info[old]
        for old in [i for i in self._key_trust if i not in self._window]:
            del self._key_trust[old]
        self.static_map.forget(keep_depth)
        for d in (self._anchor, self._rel):   # estimates against the last references only
            for old in [i for i in d if i < keep_depth and i < self._ref - 2 * policy.max_gap and i not in self._window]:
                del d[old]

    def _latest_good(self, j: int) -> Optional[int]:
        """The frame a move of the reference at frame j goes to: the latest frame after the
        reference and at least ``lag`` before j whose own estimate succeeded (a failed, held frame
        has no trustworthy pose and must not become a reference), among the frames posed so far;
        None if there is none."""
        posed = len(self.valid) + 1          # the frames before this one are posed (frame i >= 1: valid[i - 1])
        good = [i for i in range(self._ref + 1, min(j - self.policy.lag + 1, posed)) if self.valid[i - 1]]
        return good[-1] if good else None

    def _set_reference(self, new: int, j: int) -> None:
        old = self._ref
        if self.policy.retime_depth:
            self._depth_at_colour_time(new)
        if old in self._window:   # its weights serve the estimates against it while it stays in the window
            self._key_trust[old] = (self.static_map.trust(tuple(self._frames[old].depth.shape)), self._calm)
        # a held frame (restart) has no pose of its own to refine and must not push keyframes out
        if self.policy.window > 1 and self.valid[new - 1] and new - self._window[-1] >= self.policy.lag:
            self._anchor[new] = self._windowed_anchor(new)
        else:
            self._anchor[new] = self._fused_anchor(new, j)
        self._last_anchor[new] = self._anchor[new]
        self._ref = new
        self.static_map.new_reference(old, new, j, self.policy.history, self._chain_pose, self.valid,
                                      self.view_pose)

    def _depth_at_colour_time(self, new: int) -> None:
        """Frame ``new``, about to become the reference, with its depth moved to its colour image's
        time (``TrackConfig.retime_depth``, :mod:`jaxvo.tracking.depth_time`): the camera then is
        interpolated along the twist between its pose and the posed frame next to it on the side
        of its depth's time (the one before it where there is none after it yet), and its pyramid
        made anew; as it is where either capture time is unknown or they are the same."""
        # the frames from the reference on are all kept (_maybe_switch), its neighbours among them
        def taken(i):
            return getattr(self._frames.get(i), "time", None)
        frame, n = self._frames[new], len(self.poses)
        depth_taken = getattr(frame, "depth_time", None)
        if taken(new) is None or depth_taken is None or float(depth_taken) == float(taken(new)) or new < 1:
            return
        a, b = (new, new + 1) if depth_taken > taken(new) and new + 1 < n else (new - 1, new)
        if taken(a) is None or taken(b) is None:
            return
        T = depth_time.depth_motion(self.poses[a], self.poses[b], taken(a), taken(b), self.poses[new], depth_taken)
        if T is None:
            return
        frame = frame._replace(depth=depth_time.retimed_depth(frame.depth, T, self.camera))
        self._frames[new] = frame
        self._pyramids[new] = prepare_frame(frame, self.camera, self.config, f"frame {new}")

    def _windowed_anchor(self, new: int) -> np.ndarray:
        """The pose later frames chain from when ``new`` becomes the reference and joins the
        keyframe window (``TrackConfig.window``), which then drops its oldest keyframe if full.

        ``new`` is estimated against every keyframe of the window except its own reference (whose
        estimate is already there: the chained, smoothed pose, :meth:`_smoothed`), each with that
        keyframe's static weights, from the chained pose; the ones that pass :meth:`_judge` join
        the window's edges. Then the window's poses are refined as a pose graph
        (:func:`jaxvo.tracking.window.refine`, the oldest keyframe fixed) and each keyframe's
        anchor replaced by its refined pose. One bad estimate between two keyframes is then
        outweighed by the others, and the chain's error grows per window rather than per keyframe."""
        policy = self.policy
        pose = self._smoothed(new)
        # the keyframes that stay in the window beside new
        members = [k for k in self._window[-(policy.window - 1):] if k in self._key_trust]
        edges = {}
        if members and new in self._info:
            # the chain back to a keyframe of the window: frame new's own estimate (smoothed, fitted
            # with its neighbours) where its reference is one, else through the references between
            # (frame to frame while calm), each hop adding an error like new's own
            f, hops = new, 0
            while f > members[0] and f not in members:
                f, hops = self.references[f - 1], hops + 1
            if f in members:
                edges[(f, new)] = (geometry.inverse(pose) @ self._chain_pose(f), self._info[new] / hops)
        keys = jax.random.fold_in(jax.random.fold_in(self.key, new - 1), 2)   # apart from frame new's own key
        for n, k in enumerate(reversed(members)):
            if (k, new) in edges:
                continue
            key = jax.random.fold_in(keys, n)
            T_k_new = geometry.inverse(self._chain_pose(k)) @ pose
            trust, calm = self._key_trust[k]
            est, judged = self._estimate_against("window", k, new, key, T_k_new, None if calm else trust, trust)
            if judged.valid:
                edges[(k, new)] = (judged.T, est.information)
        self._edges.update({e: (Z, np.asarray(info, np.float64)) for e, (Z, info) in edges.items()})
        self._window = (self._window + [new])[-policy.window:]
        nodes = self._window
        index = {k: i for i, k in enumerate(nodes)}
        graph_edges = {(index[a], index[b]): v for (a, b), v in self._edges.items() if a in index and b in index}
        for e in [e for e in self._edges if e[0] not in index]:
            del self._edges[e]
        if len(nodes) < 2 or not graph_edges:
            return pose
        anchors = [self._chain_pose(k) for k in nodes[:-1]] + [pose]
        start = time.perf_counter()
        refined = window.refine(anchors, graph_edges, policy.window)   # host arrays: complete on return
        if self.timings is not None:
            self.timings.setdefault("window refinement", []).append(time.perf_counter() - start)
        # the frames after new start from the previous frame's pose relative to new's anchor: a
        # correction near the per-frame step limits would make their estimates look like jumps and
        # fail, so a window that disagrees that much with its chain is left as chained
        moved = geometry.inverse(pose) @ refined[-1]
        if not _within(moved, 0.5 * policy.max_step, 0.5 * policy.max_step_deg):
            return pose
        for k, P in zip(nodes[:-1], refined[:-1]):
            if k != nodes[0]:
                self._anchor[k] = self._last_anchor[k] = P
        self._chained = {new: pose}
        return refined[-1]

    def view_pose(self, view: int, new: int, T_world_new: np.ndarray) -> np.ndarray:
        """T_view_new (4, 4) float32, the pose at which the new reference ``new`` (camera-to-world
        ``T_world_new``) is tested for motion against the earlier frame ``view``
        (:meth:`jaxvo.tracking.static_map.StaticMap.new_reference`): from the chained poses.

        A seam: a subclass (or an assignment to ``Odometry.view_pose``) may return another pose
        there, e.g. the ground truth or one estimated between the two frames, to measure what the
        masks reach with it (``experiments/diagnostics/map_poses.py``); the map reads the frames' motion-test
        images from ``self.static_map.cues`` at ``self.static_map.cue_camera``."""
        return (geometry.inverse(self._chain_pose(view)) @ T_world_new).astype(np.float32)

    def _chain_pose(self, i: int) -> np.ndarray:
        """T_world_cam that frames estimated against frame i chain from: its anchor (fused and
        smoothed when it became a reference) where set, else its own pose."""
        return self._anchor.get(i, self.poses[i])

    def refined_poses(self) -> np.ndarray:
        """(N, 4, 4) float64 T_world_cam of the frames added so far, refined in hindsight.

        Frame j was posed on its reference r's anchor A_then (``T_world_j = A_then @ inv(T_j_r)``);
        a window refinement may move r's anchor after that (:meth:`_windowed_anchor`), which moves
        the frames posed on r later but not frame j as returned. Here frame j is posed on r's
        latest anchor instead: ``A_latest @ inv(A_then) @ T_world_j``, the same pose relative to
        its reference; a frame that became a reference is at its own latest anchor (smoothed,
        fused or refined: the pose later frames chain from). A frame posed on an anchor that never
        moved keeps its pose as tracked, bitwise, and frame 0 its given pose. The first
        :meth:`settled` frames' refined poses change no more."""
        return np.stack([self._refined_pose(j) for j in range(len(self.poses))]) if self.poses \
            else np.zeros((0, 4, 4))

    def _refined_pose(self, j: int) -> np.ndarray:
        """Frame j's refined pose (:meth:`refined_poses`)."""
        if j == 0:
            return self.poses[0]
        if j in self._last_anchor:
            return self._last_anchor[j]
        ref, then = self._posed_on[j]
        latest = self._last_anchor.get(ref, then)
        return self.poses[j] if latest is then else latest @ geometry.inverse(then) @ self.poses[j]

    def settled(self) -> int:
        """How many of the first frames have a refined pose (:meth:`refined_poses`) that can no
        longer change: a frame up to the current reference (a later frame may still become a
        reference) whose anchor (its own if it became a reference, else its reference's) is not
        one the window can still refine (a keyframe of the window but its oldest)."""
        open_anchors = set(self._window[1:]) if self.policy.window > 1 else set()
        n = self._settled
        while n < len(self.poses) and n <= self._ref:
            if (n if n in self._last_anchor else self._posed_on[n][0]) in open_anchors:
                break
            n += 1
        self._settled = n
        return n

    def result(self) -> "Track":
        """The :class:`Track` of the frames added so far."""
        refined = self.refined_poses()
        tracked = np.stack(self.poses) if self.poses else np.zeros((0, 4, 4))
        P = refined if self.policy.poses == "refined" else tracked
        rel = geometry.consecutive_motions(P)
        return Track(P, rel, np.asarray(self.inlier_ratio), np.asarray(self.valid, bool),
                     np.asarray(self.references, int), refined, tracked)


def track(frames: Iterable[Frame], camera: Camera, config: Optional[Config] = None, key=None,
          T_world_first=None, callback=None, policy: Optional[TrackConfig] = None,
          segment_params: Optional[segmentation.SegmentParams] = None) -> Track:
    """Run the odometry along a sequence: a loop of :meth:`Odometry.add` over ``frames``.

    Frames may be any iterable (e.g. a lazy sequence); only the frames that may still serve
    as reference are kept. ``policy`` (default :class:`TrackConfig`: a window of keyframes refined
    together, with the persistent static/dynamic segmentation; ``TrackConfig(window=1)`` the single
    reference; ``TrackConfig.frame_to_frame()`` the paper's chaining) chooses the references. Frame j is estimated with key
    ``jax.random.fold_in(key, j - 1)``. Poses accumulate on the host in float64:
    ``T_world_cur = T_world_ref @ inv(T_cur_ref)``.
    ``callback(step)`` is called with a :class:`TrackStep` after each frame j >= 1 (e.g. to
    write the trajectory as it grows). ``segment_params``: the segmentation's numbers
    (default :class:`jaxvo.tracking.segmentation.SegmentParams`). ``T_world_first``: the first
    frame's (4, 4) rigid T_world_cam (default identity; ValueError if it is not one).
    """
    odo = Odometry(camera, config, key, policy, T_world_first, segment_params)
    n = 0
    for frame in frames:
        step = odo.add(frame)
        n += 1
        if step.frame > 0 and callback is not None:
            callback(step)
    if n == 0:
        raise ValueError("track needs at least one frame")
    return odo.result()
