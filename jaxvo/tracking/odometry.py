"""Streaming odometry: :class:`Odometry` (frames in, poses out) and :func:`track`, a loop over it."""
from __future__ import annotations

import functools
import threading
from typing import Iterable, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from jaxvo import geometry
from jaxvo.camera import Camera
from jaxvo.config import Config, TrackConfig
from jaxvo.frame import Frame
from jaxvo.estimator import MotionEstimate, as_float32, checked_config, checked_key, estimate_motion, pixel_counts
from jaxvo.runtime import aot
from jaxvo.tracking import segmentation

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
    """What :class:`Odometry` returns for each frame and :func:`track` passes to its callback.

    frame: index of the frame just added. reference: index of the frame it was
    estimated against (``estimate.inlier_mask`` and ``static_mask`` lie on that frame's
    pixels); -1 for the first frame. estimate: the :class:`MotionEstimate`
    (T_cur_ref = T_frame_reference), None for the first frame.
    T_world_cur: (4, 4) float64 pose given to the frame. valid: False if the estimate failed
    and the pose was held (see :class:`TrackConfig`).
    static_mask: (H, W) bool, the reference pixels the segmentation trusted as static for
    this estimate (all True without segmentation).
    """
    frame: int
    reference: int
    estimate: Optional[MotionEstimate]
    T_world_cur: np.ndarray
    valid: bool
    static_mask: Optional[np.ndarray] = None


def _rigid(T) -> np.ndarray:
    """float64 copy of a float32 estimate with its rotation re-orthonormalised, so that
    chaining thousands of them (and inverting by transpose) stays rigid."""
    T = np.array(T, np.float64)
    if np.all(np.isfinite(T)):
        T[:3, :3] = geometry.project_to_so3(T[:3, :3])
    return T


@jax.jit
def _map_inputs(intensity, depth, max_depth):
    """A frame's inputs of the segmentation, one program: (map-level depth (votes, propagation,
    regions), cue-level (intensity, depth) for the motion test). The cue level is one halving
    below the map level, and XLA shares the depth's first halving between the two."""
    return segmentation.map_depth(depth, max_depth), segmentation.cue_images(intensity, depth, max_depth)


@functools.partial(jax.jit, static_argnames=("shape",))
def _trust(L, flags, shape):
    return segmentation.upsample(segmentation.static_weight(segmentation.flagged(L, flags)), shape)


def _occluded(est: MotionEstimate):
    """The estimate's occluded mask, or no pixel hidden where it was made without one."""
    return jnp.zeros_like(est.valid_mask) if est.occluded_mask is None else est.occluded_mask


@jax.jit
def _trust_ratios(inlier_mask, valid_mask, occluded_mask, weights):
    """(inlier ratio over the reference pixels the segmentation trusts (weight >= 0.5),
    fraction of the valid reference pixels it does not trust, fraction of them it trusts and
    the current frame does not hide (``occluded_mask``), inlier ratio over those)."""
    trusted = (weights >= 0.5)[: inlier_mask.shape[0], : inlier_mask.shape[1]]
    seen = valid_mask & trusted & ~occluded_mask
    valid, inl_trusted, valid_trusted, valid_untrusted, n_seen, inl_seen = pixel_counts(
        valid_mask, inlier_mask & trusted, valid_mask & trusted, valid_mask & ~trusted, seen, inlier_mask & seen)
    return (inl_trusted / jnp.maximum(valid_trusted, 1), valid_untrusted / jnp.maximum(valid, 1),
            n_seen / jnp.maximum(valid, 1), inl_seen / jnp.maximum(n_seen, 1))


@functools.partial(jax.jit, static_argnames=("shape",))
def _unexplained(inlier_mask, valid_mask, occluded_mask, shape):
    """The estimate's outliers that are not hidden in the current frame (occluded: they say
    nothing), at the map level (``shape``): :func:`segmentation.photometric_outliers`."""
    return segmentation.photometric_outliers(valid_mask & ~inlier_mask & ~occluded_mask, valid_mask, shape)


# a program of its own, not fused into _unexplained: as one program the two ran 0.9 ms on the
# 2-core CPU, as two 0.25 ms (320x240 map; XLA's CPU code for the fused loop is slower)
@jax.jit
def _update_map(L, ref_md, cur_md, T_cur_ref, unexplained, camera, params):
    return segmentation.add_current_vote(L, ref_md, cur_md, T_cur_ref, unexplained, camera, params)


@jax.jit
def _new_reference_map(L_old, old_md, new_md, T_old_new, view_mds, T_views_new, view_ok, camera, params,
                       new_cue, cue_view, T_cue_new, cue_ok, cue_camera):
    L = segmentation.propagate(L_old, old_md, new_md, T_old_new, camera, params)
    L = segmentation.add_votes(L, new_md, view_mds, T_views_new, view_ok, camera, params)
    return _motion_tested(L, new_md, new_cue, cue_view, T_cue_new, cue_ok, camera, cue_camera, params)


def _motion_tested(L, md, ref_cue, view_cue, T_view_ref, ok, camera, cue_camera, params):
    """(evidence, flags) of :func:`segmentation.reference_map` for a reference with log-odds
    ``L`` and map-level depth ``md``, after the motion test against a view (applied where
    ``ok``)."""
    labels = segmentation.region_labels(md, camera)
    moved = segmentation.motion_regions(*labels, ref_cue, view_cue, T_view_ref, cue_camera, params)
    return segmentation.reference_map(L, md, labels, moved & ok, params)


@jax.jit
def _later_motion_test(L, flags, ref_md, ref_cue, cur_cue, T_cur_ref, camera, params, cue_camera):
    """The reference's map after the motion test against a later frame (``_CUE_AHEAD``): the
    moving regions join the evidence and, with the coherent regions they make, the flags."""
    evidence, new_flags = _motion_tested(L, ref_md, ref_cue, cur_cue, T_cur_ref, True, camera, cue_camera, params)
    return evidence, flags | new_flags


def _compile_map_programs(L, md, cue, shape, camera, cue_camera, params) -> threading.Thread:
    """Compile the segmentation's programs that the first pair runs after its estimate
    (:func:`_trust_ratios`, :func:`_unexplained`, :func:`_update_map`, :func:`_new_reference_map`
    with few views, and the stack of those views), in a background thread started at the first
    frame; returns the thread.

    In a new process the first pair is mostly the estimator's compilation: first its trace
    (Python, one core), then XLA (both cores, after a serial phase). These programs, compiled
    one after the other behind it, added about a second; compiled beside the trace they are
    ready when it needs them. The calls later find them in JAX's caches (or, if one is not done
    yet, compile it themselves); an error here is left for that call to raise. Not a daemon
    thread: an interpreter that exits while XLA compiles in a daemon thread may crash.

    L: (h, w) float32 map-level log-odds; md: (h, w) float32 map-level depth; cue: a frame's
    :func:`segmentation.cue_images`; shape: the frames' (H, W); camera, cue_camera: the map
    level's and the cue level's camera."""
    def abstract(x, lead=()):
        return jax.ShapeDtypeStruct(lead + tuple(x.shape), x.dtype)

    def compile_all():
        Lz, mz = abstract(L), abstract(md)
        T = jax.ShapeDtypeStruct((4, 4), jnp.float32)
        n = _FEW_VIEWS
        # the estimate's masks: committed to the device where they come from an exported program
        # (jaxvo.runtime.aot), not where they come from the jit; another sharding is another compilation
        shardings = (None, aot.sharding())
        weights = jax.eval_shape(_trust, Lz, jax.ShapeDtypeStruct(md.shape, jnp.bool_), shape)
        views = (abstract(md, (n,)), jax.ShapeDtypeStruct((n, 4, 4), jnp.float32), jax.ShapeDtypeStruct((n,), jnp.bool_))
        masks = [jax.ShapeDtypeStruct(shape, jnp.bool_, sharding=s) for s in shardings]
        todo = [(_trust_ratios, (m, m, m, weights)) for m in masks]
        todo += [(_unexplained, (m, m, m, tuple(md.shape))) for m in masks]
        todo += [(_update_map, (Lz, mz, mz, T, jax.ShapeDtypeStruct(md.shape, jnp.bool_), camera, params)),
                 (_new_reference_map, (Lz, mz, mz, T) + views + (camera, params)
                  + ((abstract(cue[0]), abstract(cue[1])),) * 2
                  + (T, jax.ShapeDtypeStruct((), jnp.bool_), cue_camera)),
                 (_later_motion_test, (Lz, jax.ShapeDtypeStruct(md.shape, jnp.bool_), mz,
                                       (abstract(cue[0]), abstract(cue[1])), (abstract(cue[0]), abstract(cue[1])),
                                       T, camera, params, cue_camera))]
        for fn, args in todo:
            try:
                fn.lower(*args).compile()
            except Exception:  # noqa: BLE001 - the real call compiles it and raises what is wrong
                return
        # and the stack of the views' depths (Odometry._set_reference), run once to compile it
        jnp.stack([jnp.zeros(md.shape, jnp.float32)] * n)

    thread = threading.Thread(target=compile_all, name="jaxvo-compile-map")
    thread.start()
    return thread


# views that vote on a new reference's segmentation: one of two fixed numbers, so that the
# map update compiles at most twice (missing views are padding with valid = False)
_VIEWS = 12
_FEW_VIEWS = 4
# how far back the view of the motion test (segmentation.motion_regions) may lie: 8 frames
# (a quarter of a second) let a walking person move a few pixels at the test's level
_CUE_BACK = 8
# a reference whose test had no view at least this many frames back (the first references,
# chosen frame to frame while the empty map saw nothing move) is tested once more against the
# first frame at least this many frames after it whose estimate succeeded, at that estimate.
# Persons who moved 0-2 pixels at the test's level in the 2 frames before such a reference went
# unflagged for every frame estimated against it: on fr2_desk with two synthetic persons (seeds
# 0-11) the estimates against references 1-3 held 36 % of the missed moving pixels (recall
# 0.40 there), and the pooled mask precision / recall was 0.794 / 0.790; with this test 0.810 /
# 0.809 and ATE 0.016 against 0.018 m (seeds 12-23, held out: 0.792 / 0.837 -> 0.808 / 0.846,
# ATE 0.016 -> 0.013 m; Bonn crowd unchanged; README "The default tracking"). A second test at
# 6 frames after, or tests at 2, 4 and 6, were worse (0.797 / 0.806 and 0.747 / 0.772).
_CUE_AHEAD = 3
# the test's shifts and regions are sized for 160x120 at its level (a 640x480 camera); on the
# 80x60 of a 320x240 camera a region is a few dozen pixels, many of them mixed depths at its
# edges, and it flagged parts of a static synthetic room at the true poses: there it is off
_CUE_MIN_WIDTH = 160


class PairInputs(NamedTuple):
    """The inputs of one estimate of :class:`Odometry` (from :meth:`Odometry.prepare`):
    ``estimate_motion(ref, cur, camera, config, key, init=init, weights=weights)``.
    T_ref_prev: (4, 4) float64, the previous frame's pose relative to the reference (host).
    trust: (H, W) the segmentation's static weight of the reference (None without one); the
    estimate gets it as ``weights`` except in the calm mode (see TrackConfig.calm_fraction)."""
    ref: Frame
    cur: Frame
    key: jnp.ndarray
    init: np.ndarray
    weights: Optional[jnp.ndarray]
    T_ref_prev: np.ndarray
    trust: Optional[jnp.ndarray] = None


class Odometry:
    """Streaming odometry: push frames one at a time, get each frame's pose at once.

    ``odo = Odometry(camera, config, key); step = odo.add(frame)``: ``step.T_world_cur``
    is the frame's camera-to-world pose (float64), ``odo.poses`` all poses so far. It holds
    what must persist between frames: the recent frames that can still serve as reference,
    the reference choice (:class:`TrackConfig`), and the reference's static/dynamic
    segmentation (:mod:`jaxvo.tracking.segmentation`, a log-odds map at half resolution), which is
    carried from reference to reference with the estimated motion and updated from every
    estimate. :func:`track` and ``jaxvo run`` are loops over :meth:`add`.

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
        self.key = checked_key(key)
        self.params = segmentation.SegmentParams() if segment_params is None else segment_params
        self._map_cam = camera.at_level(segmentation.MAP_LEVEL)
        self._first = np.eye(4) if T_world_first is None else np.asarray(T_world_first, np.float64)
        self.poses: list = []
        self.valid: list = []          # per frame >= 1: its estimate succeeded
        self.inlier_ratio: list = []
        self.references: list = []
        self._frames: dict = {}         # index -> Frame that may still serve as reference
        self._depths: dict = {}         # index -> map-level depth, for the segmentation's votes
        self._cues: dict = {}           # index -> cue-level (intensity, depth), for its motion test
        self._cue_cam = camera.at_level(segmentation.CUE_LEVEL)
        self._ref = 0
        self._anchor: dict = {}         # reference index -> the pose later frames chain from
        self._rel: dict = {}            # frame index -> its valid estimate T_cur_ref (float64)
        self._L = None                  # dynamic log-odds of the reference, map level (the evidence)
        self._flags = None              # its regions flagged dynamic while it is the reference
        self._calm = False              # the reference was chosen in the calm mode (frame to frame)
        self._tested = 0                # frames between the reference and its motion test's view
        self._compiling = None          # the thread compiling the segmentation's programs ahead

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
            return TrackStep(0, -1, None, self._first, True, None)
        return self.finish(pair, estimate_motion(pair.ref, pair.cur, self.camera, self.config, pair.key,
                                                 init=pair.init, weights=pair.weights))

    def prepare(self, frame: Frame) -> Optional["PairInputs"]:
        """The first half of :meth:`add`: record the frame and return the inputs of its estimate
        (None for the first frame, whose pose is set). Pass the estimate of those inputs to
        :meth:`finish` before the next frame (e.g. estimates of several sequences as one batch)."""
        j = len(self.poses)
        self._frames[j] = frame
        if self.policy.segment:
            self._depths[j], self._cues[j] = _map_inputs(as_float32(frame.intensity), as_float32(frame.depth),
                                                         self.config.max_depth)
        if j == 0:
            self.poses.append(self._first)
            if self.policy.segment:
                self._L = jnp.full(self._depths[0].shape, self.params.prior, jnp.float32)
                self._flags = jnp.zeros(self._depths[0].shape, bool)
                self._compiling = _compile_map_programs(self._L, self._depths[0], self._cues[0],
                                                        tuple(frame.depth.shape), self._map_cam, self._cue_cam,
                                                        self.params)
            return None
        T_world_ref = self._chain_pose(self._ref)
        T_ref_prev = geometry.inverse(T_world_ref) @ self.poses[j - 1]
        trust = _trust(self._L, self._flags, tuple(frame.depth.shape)) if self.policy.segment else None
        # calm mode: the few pixels the map marks dynamic on a static scene are depth edges,
        # and leaving them out costs accuracy (fr2_desk 0.0185 against 0.0179 m/s)
        weights = None if self._calm else trust
        return PairInputs(self._frames[self._ref], frame, jax.random.fold_in(self.key, j - 1),
                          geometry.inverse(T_ref_prev), weights, T_ref_prev, trust)

    def finish(self, pair: "PairInputs", est: MotionEstimate) -> TrackStep:
        """The second half of :meth:`add`: chain the estimate of :meth:`prepare`'s inputs and
        update the policy and segmentation; returns the frame's :class:`TrackStep`."""
        j, frame, T_ref_prev, weights = len(self.poses), pair.cur, pair.T_ref_prev, pair.trust
        policy, ref, poses = self.policy, self._ref, self.poses
        T_world_ref = self._chain_pose(ref)
        # the guess is the previous frame's pose, held where its estimate failed, while the camera
        # moved on; only RANSAC's failure flag is trusted over that stale guess (TrackConfig.catch_up)
        extra = self._stale_allowance() if policy.catch_up and self.config.method == "ransac" else (0.0, 0.0)
        judged = self._judge(est, T_ref_prev, weights, extra)
        if not judged[3] and policy.retry:
            est, judged = self._retry(pair, est, judged, extra)
        T, ratio, ratio_static, valid, dynamic = judged
        pose = self._held(j) if not valid and policy.hold_invalid else T_world_ref @ geometry.inverse(T)
        poses.append(pose)
        self.valid.append(valid)
        self.inlier_ratio.append(ratio)
        self.references.append(ref)
        if valid:
            self._rel[j] = T
        static_mask = None
        if policy.segment:
            static_mask = np.asarray(weights)[: frame.depth.shape[0], : frame.depth.shape[1]] >= 0.5
            if valid:  # the current frame's view of the reference, at the estimated pose
                occluded = _occluded(est)
                # through the host (77 kB at 320x240): from an exported program (jaxvo.runtime.aot) the
                # masks are committed to the device, and a committed input would commit the map
                # and everything computed from it, the estimate's weights included, so the map's
                # programs and the estimator would each compile a second time
                unexplained = np.asarray(_unexplained(est.inlier_mask, est.valid_mask, occluded, self._L.shape))
                self._L = _update_map(self._L, self._depths[ref], self._depths[j], as_float32(T), unexplained,
                                      self._map_cam, self.params)
                if self._tested < _CUE_AHEAD <= j - ref and self._cue_cam.width >= _CUE_MIN_WIDTH:
                    self._L, self._flags = _later_motion_test(self._L, self._flags, self._depths[ref], self._cues[ref],
                                                              self._cues[j], as_float32(T), self._map_cam, self.params,
                                                              self._cue_cam)
                    self._tested = j - ref
        result = TrackStep(j, ref, est, pose, valid, static_mask)
        self._maybe_switch(j, T, ratio_static, dynamic)
        return result

    def _retry(self, pair: "PairInputs", est: MotionEstimate, judged, extra):
        """(estimate, :meth:`_judge` of it) for a frame whose estimate ``est`` failed: the pair
        estimated once more from the guess that the camera kept the motion between the two
        previous frames (``TrackConfig.retry``), if both were estimated and that one passes;
        ``est`` and ``judged`` as they were otherwise."""
        j = len(self.poses)
        if j < 3 or not (self.valid[-1] and self.valid[-2]):
            return est, judged
        guess = pair.T_ref_prev @ geometry.inverse(self.poses[j - 2]) @ self.poses[j - 1]   # T_ref_guess
        again = estimate_motion(pair.ref, pair.cur, self.camera, self.config, pair.key,
                                init=geometry.inverse(guess), weights=pair.weights)
        judged_again = self._judge(again, pair.T_ref_prev, pair.trust, extra)
        return (again, judged_again) if judged_again[3] else (est, judged)

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

    def _estimate(self, ref: int, frame: Frame, key, T_ref_prev: np.ndarray, weights):
        """Estimate ``frame`` against reference ``ref`` from the initial guess ``T_ref_prev``
        (float64 T_ref_guess). Returns (estimate,) + :meth:`_judge` of it."""
        est = estimate_motion(self._frames[ref], frame, self.camera, self.config, key,
                              init=geometry.inverse(T_ref_prev), weights=weights)
        return (est,) + self._judge(est, T_ref_prev, weights)

    def _stale_allowance(self):
        """(metres, degrees) the camera may have moved beyond one frame's step while the latest
        frames were held: for each failed frame in a row, the mean per-frame motion over the
        ``coast_window`` frames before them (the camera kept its recent speed), or the per-frame
        limits themselves where no motion was measured yet; 0 when none failed.

        Without it a camera faster than ``max_step`` divided by the frames since its last pose
        could never be caught again: the guess stays at the held pose, so every later estimate
        is a bigger step from it and fails too (on the synthetic handheld-fast, seeds 0-3, 18 to
        88 of 89 frames held, ATE 0.12-0.16 m)."""
        failed = self._failed_run()
        if failed == 0:
            return 0.0, 0.0
        # up to the latest frame whose pose was estimated
        d, n = self._recent_motion(len(self.poses) - 1 - failed)
        if n < 1:   # no motion measured yet: the per-frame limits themselves
            return failed * self.policy.max_step, failed * self.policy.max_step_deg
        return (failed * np.linalg.norm(d[:3, 3]) / n,
                failed * np.degrees(geometry.rotation_angle(d[:3, :3])) / n)

    def _judge(self, est: MotionEstimate, T_ref_prev: np.ndarray, weights, extra=(0.0, 0.0)):
        """(T_cur_ref float64, inlier ratio, inlier ratio over trusted pixels, valid, dynamic) of an
        estimate from the initial guess ``T_ref_prev``; valid also requires a plausible step from the
        guess: within the policy's per-frame limits plus ``extra`` (metres, degrees) for a stale
        guess. dynamic: the fraction of the reference's valid pixels the map does not trust (1.0
        without the segmentation)."""
        policy = self.policy
        if policy.segment:
            occluded = _occluded(est)
            T, ratio, ok, (ratio_static, dynamic, seen, ratio_seen) = jax.device_get(   # one transfer
                (est.T_cur_ref, est.inlier_ratio, est.valid,
                 _trust_ratios(est.inlier_mask, est.valid_mask, occluded, weights)))
            # TrackConfig.rescue: RANSAC's flag counts every pixel, and where people cover most of
            # the reference and stand in front of the rest, a right estimate fails it
            if not ok and policy.rescue > 0 and self.config.method == "ransac":
                ok = seen >= policy.rescue_support and ratio_seen >= policy.rescue
        else:
            T, ratio, ok = jax.device_get((est.T_cur_ref, est.inlier_ratio, est.valid))
            ratio_static, dynamic = ratio, 1.0
        T = _rigid(T)
        valid = bool(ok) and bool(np.all(np.isfinite(T)))
        if valid:
            step = T @ T_ref_prev                          # T_cur_guess
            valid = (np.linalg.norm(step[:3, 3]) <= policy.max_step + extra[0]
                     and geometry.rotation_angle(step[:3, :3]) <= np.radians(policy.max_step_deg + extra[1]))
        return T, float(ratio), float(ratio_static), valid, float(dynamic)

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
        weights = _trust(self._L, self._flags, tuple(self._frames[new].depth.shape)) if self.policy.segment else None
        key = jax.random.fold_in(jax.random.fold_in(self.key, new - 1), 1)   # apart from frame new's own key
        _, T, _, _, valid, _ = self._estimate(old, self._frames[new], key, geometry.inverse(T_world_old) @ pose,
                                              weights)
        if not valid:
            return pose
        other = T_world_old @ geometry.inverse(T)
        return geometry.interpolate(pose, other, 0.5)

    def _maybe_switch(self, j: int, T_cur_ref: np.ndarray, ratio_static: float, dynamic: float) -> None:
        policy, ref = self.policy, self._ref
        far = (np.linalg.norm(T_cur_ref[:3, 3]) > policy.switch_baseline
               or geometry.rotation_angle(T_cur_ref[:3, :3]) > np.radians(policy.switch_deg))
        calm = policy.segment and self.valid[-1] and dynamic < policy.calm_fraction
        self._calm = calm
        if calm:      # nothing moves: frame to frame, the shortest baseline
            self._set_reference(j, j)
        elif j - ref >= policy.max_gap or (self.valid[-1] and (ratio_static < policy.switch_ratio or far)):
            # the latest frame at least `lag` back whose own estimate succeeded: a failed
            # (held) frame has no trustworthy pose and must not become a reference
            good = [i for i in range(ref + 1, j - policy.lag + 1) if self.valid[i - 1]]
            if good:
                self._set_reference(good[-1], j)
            elif j - ref >= policy.restart:
                self._set_reference(j - policy.lag, j)  # lost for long: restart from the held poses
        keep_depth = self._ref - (1 << policy.history) if policy.history else self._ref
        for old in [i for i in self._frames if i < self._ref]:
            del self._frames[old]
        for old in [i for i in self._depths if i < keep_depth]:
            del self._depths[old]
            self._cues.pop(old, None)
        for d in (self._anchor, self._rel):   # estimates against the last references only
            for old in [i for i in d if i < keep_depth and i < self._ref - 2 * policy.max_gap]:
                del d[old]

    def _set_reference(self, new: int, j: int) -> None:
        old = self._ref
        self._anchor[new] = self._fused_anchor(new, j)
        self._ref = new
        if not self.policy.segment:
            return
        # the poses the map's votes use: anchors where set (looked up per voter, not a copy of
        # every pose so far: in the calm mode this runs every frame)
        T_world_new = self._chain_pose(new)
        # voters: earlier frames at offsets 2, 4, 8, ... and every frame after the new
        # reference up to the current one (all with successful estimates)
        earlier = [new - (2 << k) for k in range(self.policy.history)]
        later = list(range(new + 1, j + 1))
        voters = [i for i in later[::-1] + earlier
                  if i in self._depths and i != new and (i == 0 or self.valid[i - 1])][:_VIEWS]
        shape = self._depths[new].shape
        # padded to one of two sizes: in the calm mode the voters are the 4 earlier frames, and
        # voting for 12 views (8 of them padding) would cost 3x as much
        n = _FEW_VIEWS if len(voters) <= _FEW_VIEWS else _VIEWS
        pad = [jnp.zeros(shape, jnp.float32)] * (n - len(voters))
        mds = jnp.stack([self._depths[i] for i in voters] + pad)   # stays on the device
        Ts = np.tile(np.eye(4, dtype=np.float32), (n, 1, 1))
        ok = np.zeros(n, bool)
        for k, i in enumerate(voters):
            Ts[k] = geometry.inverse(self._chain_pose(i)) @ T_world_new
            ok[k] = True
        T_old_new = (geometry.inverse(self._chain_pose(old)) @ T_world_new).astype(np.float32)
        # the motion test's view: the earliest of the earlier voters at most _CUE_BACK frames back
        back = [i for i in earlier if 0 < new - i <= _CUE_BACK and i in self._cues and (i == 0 or self.valid[i - 1])
                and self._cue_cam.width >= _CUE_MIN_WIDTH]
        cue = self._cues[min(back)] if back else self._cues[new]
        T_cue = self._view_pose(min(back), new, T_world_new) if back else np.eye(4, dtype=np.float32)
        self._tested = new - min(back) if back else 0
        self._L, self._flags = _new_reference_map(self._L, self._depths[old], self._depths[new], T_old_new, mds, Ts, ok,
                                     self._map_cam, self.params, self._cues[new], cue, T_cue, np.bool_(bool(back)),
                                     self._cue_cam)

    def _view_pose(self, view: int, new: int, T_world_new: np.ndarray) -> np.ndarray:
        """T_view_new (4, 4) float32, the pose at which the new reference ``new`` (camera-to-world
        ``T_world_new``) is tested for motion against the earlier frame ``view``: from the chained
        poses. On its own seam so that `experiments/map_poses.py` can measure what the masks reach
        with other poses there (the ground truth, or one estimated between the two frames)."""
        return (geometry.inverse(self._chain_pose(view)) @ T_world_new).astype(np.float32)

    def _chain_pose(self, i: int) -> np.ndarray:
        """T_world_cam that frames estimated against frame i chain from: its anchor (fused and
        smoothed when it became a reference) where set, else its own pose."""
        return self._anchor.get(i, self.poses[i])

    def result(self) -> "Track":
        """The :class:`Track` of the frames added so far."""
        P = np.stack(self.poses) if self.poses else np.zeros((0, 4, 4))
        rel = np.stack([geometry.inverse(P[i + 1]) @ P[i] for i in range(len(P) - 1)]) if len(P) > 1 \
            else np.zeros((0, 4, 4))
        return Track(P, rel, np.asarray(self.inlier_ratio), np.asarray(self.valid, bool),
                     np.asarray(self.references, int))


def track(frames: Iterable[Frame], camera: Camera, config: Optional[Config] = None, key=None,
          T_world_first=None, callback=None, policy: Optional[TrackConfig] = None,
          segment_params: Optional[segmentation.SegmentParams] = None) -> Track:
    """Run the odometry along a sequence: a loop of :meth:`Odometry.add` over ``frames``.

    Frames may be any iterable (e.g. a lazy sequence); only the frames that may still serve
    as reference are kept. ``policy`` (default :class:`TrackConfig`: keyframes with the
    persistent static/dynamic segmentation; ``TrackConfig.frame_to_frame()`` is the paper's
    chaining) chooses the references. Frame j is estimated with key
    ``jax.random.fold_in(key, j - 1)``. Poses accumulate on the host in float64:
    ``T_world_cur = T_world_ref @ inv(T_cur_ref)``.
    ``callback(step)`` is called with a :class:`TrackStep` after each frame j >= 1 (e.g. to
    write the trajectory as it grows). ``segment_params``: the segmentation's numbers
    (default :class:`jaxvo.tracking.segmentation.SegmentParams`).
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
