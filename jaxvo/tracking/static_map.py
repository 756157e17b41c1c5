"""The reference's static/dynamic segmentation as one object: :class:`StaticMap` holds its state
(the log-odds map of the reference, its flagged regions, the recent frames' map-level depths and
motion-test images) and runs its compiled programs; :class:`NoStaticMap` is its no-op counterpart
when ``TrackConfig.segment`` is False. :class:`jaxvo.tracking.odometry.Odometry` calls either the same
way: :meth:`~StaticMap.add` each frame, :meth:`~StaticMap.trust` for an estimate's weights,
:meth:`~StaticMap.read` its result, :meth:`~StaticMap.update` after a valid estimate,
:meth:`~StaticMap.new_reference` when the reference changes, :meth:`~StaticMap.forget` old frames.

The maths is :mod:`jaxvo.tracking.segmentation`; here are the programs it is compiled into (one
``jax.jit`` each, compiled ahead in a thread at the first frame; the three map programs through
their exported programs, :class:`jaxvo.runtime.aot.Program`, so that a process that finds them in
the cache folder loads them instead of tracing) and the host-side bookkeeping.
"""
from __future__ import annotations

import functools
import operator
import threading
from typing import Callable, NamedTuple, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxvo import geometry
from jaxvo.camera import Camera
from jaxvo.estimator import MotionEstimate, as_float32, pixel_counts
from jaxvo.frame import Frame
from jaxvo.runtime import aot
from jaxvo.tracking import segmentation

__all__ = ["NoStaticMap", "Reading", "StaticMap"]


@jax.jit
def _map_inputs(intensity, depth, max_depth):
    """A frame's inputs of the segmentation, one program: (map-level depth (votes, propagation,
    regions), cue-level (intensity, depth) for the motion test). The cue level is one halving
    below the map level, and XLA shares the depth's first halving between the two."""
    return segmentation.map_depth(depth, max_depth), segmentation.cue_images(intensity, depth, max_depth)


@functools.partial(jax.jit, static_argnames=("shape",))
def _trust(L, flags, gain, share, shape):
    return segmentation.upsample(segmentation.static_weight(segmentation.flagged(L, flags), gain, share), shape)


@jax.jit
def _trusted(weights):
    return weights >= 0.5


def _occluded(est: MotionEstimate):
    """The estimate's occluded mask, or no pixel hidden where it was made without one."""
    return jnp.zeros_like(est.valid_mask) if est.occluded_mask is None else est.occluded_mask


@jax.jit
def _trust_ratios(inlier_mask, valid_mask, occluded_mask, weights):
    """(inlier ratio over the reference pixels the segmentation trusts (weight >= 0.5),
    fraction of the valid reference pixels it does not trust, fraction of them it trusts and
    the current frame does not hide (``occluded_mask``), inlier ratio over those).

    The masks lie at the estimate's finest level (``Config.finest_level``), the weights at the
    frames' size: every f-th weight is the one of the mask's pixel (f = 2^finest_level), as the
    weights repeat the map's pixels (f <= 2^MAP_LEVEL)."""
    f = max(1, weights.shape[0] // inlier_mask.shape[0])
    trusted = (weights[::f, ::f] >= 0.5)[: inlier_mask.shape[0], : inlier_mask.shape[1]]
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


# a program of its own, not fused into _unexplained: XLA's CPU code for the fused loop is
# slower than the two apart (docs/decisions/cpu-kernels.md)
def _vote(L, ref_md, cur_md, T_cur_ref, unexplained, camera, params):
    return segmentation.add_current_vote(L, ref_md, cur_md, T_cur_ref, unexplained, camera, params)


def _new_map(L_old, old_md, new_md, T_old_new, view_mds, T_views_new, view_ok, camera, params,
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


def _later_test(L, flags, ref_md, ref_cue, cur_cue, T_cur_ref, camera, params, cue_camera):
    """The reference's map after the motion test against a later frame (``_CUE_AHEAD``): the
    moving regions join the evidence and, with the coherent regions they make, the flags."""
    evidence, new_flags = _motion_tested(L, ref_md, ref_cue, cur_cue, T_cur_ref, True, camera, cue_camera, params)
    return evidence, flags | new_flags


# the map's programs, exported into the cache folder (jaxvo.runtime.aot) like the estimator:
# L (the new log-odds); (evidence, flags); (evidence, flags)
_update_map = aot.Program("update_map", _vote, operator.itemgetter(0))
_new_reference_map = aot.Program("new_reference_map", _new_map)
_later_motion_test = aot.Program("later_motion_test", _later_test)


def _compile_map_programs(L, md, cue, shape, camera, cue_camera, params) -> threading.Thread:
    """Compile the segmentation's programs that the first pair runs after its estimate
    (:func:`_trust_ratios`, :func:`_unexplained`, :data:`_update_map`, :data:`_new_reference_map`
    with few views, :data:`_later_motion_test`, and the stack of those views), in a background
    thread started at the first frame; returns the thread.

    In a new process the first pair is mostly the estimator's compilation: first its trace
    (Python, one core), then XLA (both cores, after a serial phase). These programs, compiled
    one after the other behind it, added about a second; compiled beside the trace they are
    ready when it needs them. The map programs are made ready through their exported programs
    (:meth:`jaxvo.runtime.aot.Program.compile_ahead`): read from the cache folder where an
    earlier process wrote them (no trace), else traced, written and compiled. The calls later
    find them in JAX's caches (or, if one is not done yet, compile it themselves); an error here
    is left for that call to raise. Not a daemon thread, even when started from one (as the
    CLI's job thread is): an interpreter that exits while XLA compiles in a daemon thread may
    crash, and the CLI waits for the thread before it exits, so that the programs are kept.

    L: (h, w) float32 map-level log-odds; md: (h, w) float32 map-level depth; cue: a frame's
    :func:`segmentation.cue_images`; shape: the frames' (H, W); camera, cue_camera: the map
    level's and the cue level's camera."""
    # where the estimate's masks and the map's weights lie: committed to the device while the
    # programs that make them are exported (jaxvo.runtime.aot), not otherwise; another
    # placement is another compilation
    placement = aot.sharding() if aot.folder() is not None else None

    def abstract(x, lead=(), sharding=None):
        return jax.ShapeDtypeStruct(lead + tuple(x.shape), x.dtype, sharding=sharding)

    def compile_all():
        Lz, mz = abstract(L), abstract(md)
        T = jax.ShapeDtypeStruct((4, 4), jnp.float32)
        n = _FEW_VIEWS
        weights = abstract(jax.eval_shape(_trust, Lz, jax.ShapeDtypeStruct(md.shape, jnp.bool_), jnp.float32(1),
                                          jnp.float32(1), shape), sharding=placement)
        views = (abstract(md, (n,)), jax.ShapeDtypeStruct((n, 4, 4), jnp.float32), jax.ShapeDtypeStruct((n,), jnp.bool_))
        mask = jax.ShapeDtypeStruct(shape, jnp.bool_, sharding=placement)
        cues = (abstract(cue[0]), abstract(cue[1]))
        todo = [lambda: _trust_ratios.lower(mask, mask, mask, weights).compile(),
                lambda: _unexplained.lower(mask, mask, mask, tuple(md.shape)).compile(),
                lambda: _update_map.compile_ahead(Lz, mz, mz, T, jax.ShapeDtypeStruct(md.shape, jnp.bool_), camera,
                                                  params),
                lambda: _new_reference_map.compile_ahead(Lz, mz, mz, T, *views, camera, params, cues, cues, T,
                                                         jax.ShapeDtypeStruct((), jnp.bool_), cue_camera),
                lambda: _later_motion_test.compile_ahead(Lz, jax.ShapeDtypeStruct(md.shape, jnp.bool_), mz, cues, cues,
                                                         T, camera, params, cue_camera)]
        for prepare in todo:
            try:
                prepare()
            except Exception:  # noqa: BLE001 - the real call compiles it and raises what is wrong
                return
        # and the stack of the views' depths (StaticMap.new_reference), run once to compile it
        jnp.stack([jnp.zeros(md.shape, jnp.float32)] * n)

    thread = threading.Thread(target=compile_all, name="jaxvo-compile-map", daemon=False)
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
# first frame at least this many frames after it whose estimate succeeded, at that estimate:
# persons who moved 0-2 pixels at the test's level in the 2 frames before such a reference
# would otherwise go unflagged for every frame estimated against it
# (docs/decisions/later-motion-test.md)
_CUE_AHEAD = 3
# the test's shifts and regions are sized for 160x120 at its level (a 640x480 camera); on the
# 80x60 of a 320x240 camera a region is a few dozen pixels, many of them mixed depths at its
# edges, and it flagged parts of a static synthetic room at the true poses: there it is off
_CUE_MIN_WIDTH = 160


class Reading(NamedTuple):
    """An estimate's values on the host, read in one transfer (:meth:`StaticMap.read`).

    T: (4, 4) float32 T_cur_ref. ratio: its inlier ratio; ok: its ``valid`` flag.
    ratio_static: the inlier ratio over the reference pixels the map trusts (weight >= 0.5).
    dynamic: the fraction of the valid reference pixels the map does not trust.
    seen: the fraction of them it trusts and the current frame does not hide (occluded).
    ratio_seen: the inlier ratio over those.
    information: (6, 6) float32, its information matrix (:attr:`MotionEstimate.information`).
    """
    T: np.ndarray
    ratio: float
    ok: bool
    ratio_static: float
    dynamic: float
    seen: float
    ratio_seen: float
    information: np.ndarray


class StaticMap:
    """The static/dynamic segmentation of the current reference, carried from reference to reference.

    camera, cue_camera: the intrinsics at the map level (:data:`segmentation.MAP_LEVEL`) and at the
    motion test's level (:data:`segmentation.CUE_LEVEL`). params: :class:`segmentation.SegmentParams`.
    gain, share: how sharply the evidence sets the static weights, and below which share of trusted
    pixels (:meth:`trust`, ``TrackConfig.trust_gain`` and ``trust_share``). retest: every how many
    frames after the reference an estimate runs the motion test again (``TrackConfig.motion_retest``;
    0: only a reference tested against no earlier view, once).
    L: (h, w) float32 log-odds that each reference pixel is dynamic (the evidence), at the map level;
    flags: (h, w) bool, its regions flagged dynamic while it is the reference.
    depths: frame index -> map-level depth, for the votes; cues: frame index -> motion-test
    (intensity, depth). tested: frames between the reference and its motion test's view.
    compiling: the thread compiling the programs ahead (:func:`_compile_map_programs`).

    The three map programs are class attributes, the seam where a subclass wraps them (e.g.
    ``experiments/speed.py`` times them) without changing what they compute; assign an instance
    of the subclass to ``Odometry.static_map`` before the first frame.
    """

    #: the vote of one valid estimate (:func:`_update_map`)
    update_program = staticmethod(_update_map)
    #: the map of a new reference: carried over, voted, motion-tested (:func:`_new_reference_map`)
    new_reference_program = staticmethod(_new_reference_map)
    #: the later motion test of a reference tested against no earlier view (:func:`_later_motion_test`)
    later_motion_test_program = staticmethod(_later_motion_test)

    def __init__(self, camera: Camera, max_depth: float, params: segmentation.SegmentParams, gain: float = 1.0,
                 share: float = 1.0, retest: int = 0):
        self.params = params
        self.retest = int(retest)
        self.gain, self.share = float(gain), float(share)
        self._gain = self._share = None   # on the device beside L (add)
        self.max_depth = max_depth
        self.camera = camera.at_level(segmentation.MAP_LEVEL)
        self.cue_camera = camera.at_level(segmentation.CUE_LEVEL)
        self.depths: dict = {}
        self.cues: dict = {}
        self.L = None
        self.flags = None
        self.tested = 0
        self.compiling: Optional[threading.Thread] = None

    def add(self, j: int, frame: Frame, levels=None) -> None:
        """Keep frame j's map inputs; the first frame starts an empty map and compiles the programs ahead.

        levels: the frame's pyramid (:class:`jaxvo.estimator.PreparedFrame` ``levels``, built with this
        map's ``max_depth``), whose levels are the map's inputs (the same 2x2 means) where it
        reaches the motion test's level; else they are computed from the frame."""
        if levels is not None and len(levels) > segmentation.CUE_LEVEL:
            cue = levels[segmentation.CUE_LEVEL]
            self.depths[j], self.cues[j] = levels[segmentation.MAP_LEVEL].depth, (cue.intensity, cue.depth)
        else:
            self.depths[j], self.cues[j] = _map_inputs(as_float32(frame.intensity), as_float32(frame.depth),
                                                       self.max_depth)
        if j == 0:
            # placed where the map programs' outputs that replace them will lie (committed to the
            # device while those programs are exported): _trust compiles once
            # the gain and share too, once: a host scalar would be copied to the device at every trust()
            self.L, self.flags, self._gain, self._share = aot.placed(
                (jnp.full(self.depths[0].shape, self.params.prior, jnp.float32), jnp.zeros(self.depths[0].shape, bool),
                 jnp.float32(self.gain), jnp.float32(self.share)))
            self.compiling = _compile_map_programs(self.L, self.depths[0], self.cues[0], tuple(frame.depth.shape),
                                                   self.camera, self.cue_camera, self.params)

    def trust(self, shape):
        """(H, W) float32 static weight of the reference's pixels (``shape``: the frames' (H, W)):
        :func:`segmentation.static_weight` of the evidence with this map's ``gain`` and ``share``."""
        return _trust(self.L, self.flags, self._gain, self._share, shape)

    def read(self, est: MotionEstimate, weights) -> Reading:
        """The :class:`Reading` of ``est`` estimated with the reference's static ``weights`` (:meth:`trust`)."""
        occluded = _occluded(est)
        masks = est.inlier_mask
        if isinstance(weights, jax.Array) and isinstance(masks, jax.Array) \
                and weights.sharding.device_set != masks.sharding.device_set:
            # a batch's estimate lies on several devices (jaxvo.tracking.batch), the map's weights
            # on the one device its exported programs commit their outputs to (jaxvo.runtime.aot):
            # a jit refuses arguments committed to different devices
            weights = jax.device_put(weights, masks.sharding)
        T, ratio, ok, info, (ratio_static, dynamic, seen, ratio_seen) = jax.device_get(   # one transfer
            (est.T_cur_ref, est.inlier_ratio, est.valid, est.information,
             _trust_ratios(est.inlier_mask, est.valid_mask, occluded, weights)))
        return Reading(T, ratio, ok, ratio_static, dynamic, seen, ratio_seen, info)

    def static_mask(self, weights, shape) -> np.ndarray:
        """(H, W) bool on the host: the reference pixels ``weights`` trusts as static (>= 0.5)."""
        return np.asarray(_trusted(weights))[: shape[0], : shape[1]]   # a quarter of the bytes to copy

    def update(self, est: MotionEstimate, ref: int, j: int, T: np.ndarray) -> None:
        """Add the vote of frame j's valid estimate ``est`` against reference ``ref`` (T: float64
        T_cur_ref), and the motion test against frame j at that estimate: once, ``_CUE_AHEAD``
        frames after a reference tested against no earlier view that far back, and from then on
        at every ``retest``-th frame after the reference. A person who stood still while the map
        learnt it as static and then walks is otherwise trusted until the next reference, and
        with people close to the camera the estimates follow it (docs/decisions/motion-retest.md)."""
        occluded = _occluded(est)
        # through the host (77 kB at 320x240): from an exported program (jaxvo.runtime.aot) the
        # masks are committed to the device, and a committed input would commit the map
        # and everything computed from it, the estimate's weights included, so the map's
        # programs and the estimator would each compile a second time
        unexplained = np.asarray(_unexplained(est.inlier_mask, est.valid_mask, occluded, self.L.shape))
        self.L = self.update_program(self.L, self.depths[ref], self.depths[j], as_float32(T), unexplained,
                                     self.camera, self.params)
        due = self.tested < _CUE_AHEAD or (self.retest > 0 and (j - ref) % self.retest == 0)
        if due and _CUE_AHEAD <= j - ref and self.cue_camera.width >= _CUE_MIN_WIDTH:
            self.L, self.flags = self.later_motion_test_program(
                self.L, self.flags, self.depths[ref], self.cues[ref], self.cues[j], as_float32(T), self.camera,
                self.params, self.cue_camera)
            self.tested = max(self.tested, j - ref)

    def new_reference(self, old: int, new: int, j: int, history: int, pose: Callable[[int], np.ndarray],
                      valid: Sequence[bool], view_pose: Callable[[int, int, np.ndarray], np.ndarray]) -> None:
        """The map of the new reference ``new`` (the current frame: j), from the old reference's
        map carried over, the votes of the frames around it and the motion test.

        history: ``TrackConfig.history``; pose(i): the (4, 4) float64 T_world_cam frames estimated
        against frame i chain from; valid[i - 1]: frame i's estimate succeeded;
        view_pose(view, new, T_world_new): the (4, 4) float32 T_view_new of the motion test."""
        # the poses the map's votes use: anchors where set (looked up per voter, not a copy of
        # every pose so far: in the calm mode this runs every frame)
        T_world_new = pose(new)
        # voters: earlier frames at offsets 2, 4, 8, ... and every frame after the new
        # reference up to the current one (all with successful estimates)
        earlier = [new - (2 << k) for k in range(history)]
        later = list(range(new + 1, j + 1))
        voters = [i for i in later[::-1] + earlier
                  if i in self.depths and i != new and (i == 0 or valid[i - 1])][:_VIEWS]
        shape = self.depths[new].shape
        # padded to one of two sizes: in the calm mode the voters are the 4 earlier frames, and
        # voting for 12 views (8 of them padding) would cost 3x as much
        n = _FEW_VIEWS if len(voters) <= _FEW_VIEWS else _VIEWS
        pad = [jnp.zeros(shape, jnp.float32)] * (n - len(voters))
        mds = jnp.stack([self.depths[i] for i in voters] + pad)   # stays on the device
        Ts = np.tile(np.eye(4, dtype=np.float32), (n, 1, 1))
        ok = np.zeros(n, bool)
        for k, i in enumerate(voters):
            Ts[k] = geometry.inverse(pose(i)) @ T_world_new
            ok[k] = True
        T_old_new = (geometry.inverse(pose(old)) @ T_world_new).astype(np.float32)
        # the motion test's view: the earliest of the earlier voters at most _CUE_BACK frames back
        back = [i for i in earlier if 0 < new - i <= _CUE_BACK and i in self.cues and (i == 0 or valid[i - 1])
                and self.cue_camera.width >= _CUE_MIN_WIDTH]
        cue = self.cues[min(back)] if back else self.cues[new]
        T_cue = view_pose(min(back), new, T_world_new) if back else np.eye(4, dtype=np.float32)
        self.tested = new - min(back) if back else 0
        self.L, self.flags = self.new_reference_program(self.L, self.depths[old], self.depths[new], T_old_new, mds,
                                                        Ts, ok, self.camera, self.params, self.cues[new], cue, T_cue,
                                                        np.bool_(bool(back)), self.cue_camera)

    def forget(self, before: int) -> None:
        """Drop the depths and motion-test images of the frames before ``before``."""
        for old in [i for i in self.depths if i < before]:
            del self.depths[old]
            self.cues.pop(old, None)


class NoStaticMap:
    """:class:`StaticMap`'s no-op counterpart, without segmentation: no weights (every pixel
    used as it is), no static mask, nothing kept or updated."""

    def add(self, j: int, frame: Frame, levels=None) -> None:
        pass

    def trust(self, shape) -> None:
        return None

    def read(self, est: MotionEstimate, weights) -> Reading:
        """The :class:`Reading` of ``est`` without a map: the static ratio is the inlier ratio,
        every pixel counts as dynamic (1.0, so the calm mode, ``dynamic < TrackConfig.calm_fraction``
        with calm_fraction <= 1, never starts) and none as seen (0: ``TrackConfig.rescue`` never applies)."""
        T, ratio, ok, info = jax.device_get((est.T_cur_ref, est.inlier_ratio, est.valid, est.information))
        return Reading(T, ratio, ok, ratio, 1.0, 0.0, 0.0, info)

    def static_mask(self, weights, shape) -> None:
        return None

    def update(self, est: MotionEstimate, ref: int, j: int, T: np.ndarray) -> None:
        pass

    def new_reference(self, old: int, new: int, j: int, history: int, pose, valid, view_pose) -> None:
        pass

    def forget(self, before: int) -> None:
        pass
