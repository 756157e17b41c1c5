"""Plain-data settings: :class:`Config` (the estimator, traced numeric fields) and
:class:`TrackConfig` (the host-side tracking policy of :func:`jaxvo.tracking.odometry.track`).

Both are pytrees of plain values, so a ``jax.vmap`` over a numeric ``Config`` field is a
hyperparameter sweep compiled once.

Each field is declared once, with its type, its validation rule (:mod:`jaxvo.validation`) and,
for ``Config``, whether it is *static*, in one ``Annotated`` annotation; the comment above it
says what it means. Why a default is what it is: ``docs/decisions/`` (one note per default
that departs from the paper or was chosen by measurement).
"""
import dataclasses
import json
from typing import Annotated, Any, NamedTuple, Optional, Tuple

import jax
import numpy as np

from jaxvo.validation import Rule, check_fields, check_names, choice, flag, integer, positive_ints, real

__all__ = ["METHODS", "Config", "TrackConfig"]

METHODS = ("classic", "huber", "ransac")

#: Marks a ``Config`` field as static: it fixes shapes or control flow of the compiled
#: estimator, is pytree metadata rather than a leaf, and changing it recompiles.
STATIC = "static"


def _declared(cls):
    """``({field: Rule}, [static fields])`` from the ``Annotated`` annotations of ``cls``, in
    field order; a field without a Rule is an error."""
    rules, static = {}, []
    for name, hint in cls.__annotations__.items():
        meta = getattr(hint, "__metadata__", ())
        found = [m for m in meta if isinstance(m, Rule)]
        if len(found) != 1:
            raise TypeError(f"{cls.__name__}.{name} must declare exactly one validation rule")
        rules[name] = found[0]
        if STATIC in meta:
            static.append(name)
    return rules, static


@dataclasses.dataclass(frozen=True)
class Config:
    """Estimator settings. Numeric fields are pytree leaves (traceable, vmappable); ``STATIC``
    fields fix shapes or control flow and trigger a recompile when changed.

    Luminance is in 0-255 units, depth and distances in metres. Pyramid levels count from 0
    (full resolution) upwards. :meth:`paper` gives the seed paper's algorithm as published.
    """
    #: "classic" (least squares on every pixel), "huber" (Huber IRLS) or "ransac" (the paper's method).
    method: Annotated[str, choice(*METHODS), STATIC] = "ransac"
    #: RANSAC success probability and assumed outlier fraction: the hypothesis count k follows
    #: from p, w and n_points (capped by max_hypotheses). docs/decisions/hypothesis-count.md.
    p: Annotated[Any, real(0, 1, lo_open=True, hi_open=True)] = 0.99
    w: Annotated[Any, real(0, 1, hi_open=True)] = 0.3
    #: True: each level also stops once its draws would have found an all-inlier sample with
    #: probability p had w been 1 - the best hypothesis's inlier ratio so far (adaptive RANSAC,
    #: Hartley & Zisserman, Alg. 4.5); k from w stays the cap. False: always k (the paper). The
    #: tracking can turn it on for its estimates (``TrackConfig.adaptive``). docs/decisions/hypothesis-count.md.
    adaptive_hypotheses: Annotated[bool, flag(), STATIC] = False
    #: Inlier threshold on |luminance residual|, 0-255 units (the paper's value).
    thresh_lum: Annotated[Any, real(0, lo_open=True)] = 30.0
    #: Inlier threshold on |depth residual|, metres (the paper's value).
    thresh_depth: Annotated[Any, real(0, lo_open=True)] = 0.05
    #: RANSAC stops early once a hypothesis's inlier share exceeds this, in (0, 1].
    early_exit_ratio: Annotated[Any, real(0, 1, lo_open=True)] = 0.9
    #: Huber threshold in units of the robust (MAD) scale estimate.
    huber_k: Annotated[Any, real(0, lo_open=True)] = 1.345
    #: Depth beyond this (metres) is ignored.
    max_depth: Annotated[Any, real(0, lo_open=True)] = 4.0
    #: Failure flag: below this final inlier ratio, in [0, 1], the estimate is flagged invalid.
    #: docs/decisions/failure-flag.md.
    min_inlier_ratio: Annotated[Any, real(0, 1)] = 0.12
    #: Pixels per RANSAC sample (the paper's n = 6).
    n_points: Annotated[int, integer(1), STATIC] = 6
    #: Neighbourhood radius around each sampled pixel (1: 3x3 patches).
    patch_radius: Annotated[int, integer(0), STATIC] = 1
    #: Hard cap on the hypothesis count k per level. docs/decisions/hypothesis-count.md.
    max_hypotheses: Annotated[int, integer(1), STATIC] = 64
    #: Hypotheses solved together (vmapped) between early-exit checks.
    batch_size: Annotated[int, integer(1), STATIC] = 8
    #: Batches fitted in one vmapped call, the early exit still tested after each in turn: the
    #: same estimate as one batch per call, in fewer, larger programs (5 x 8 covers k = 37).
    #: docs/decisions/hypothesis-count.md.
    batches_per_trip: Annotated[int, integer(1), STATIC] = 5
    #: Pyramid levels, 1-16; None halves down to about 80x60 (4 levels for 640x480).
    #: docs/decisions/pyramid.md.
    num_levels: Annotated[Optional[int], integer(1, 16, none_means="halve down to about 80x60"), STATIC] = None
    #: Stop after this level (0: full resolution), < num_levels. docs/decisions/pyramid.md.
    finest_level: Annotated[int, integer(0, "num_levels", hi_open=True), STATIC] = 0
    #: Levenberg-Marquardt iterations per level (classic, and RANSAC's refinement).
    max_iterations: Annotated[int, integer(1), STATIC] = 6
    #: Levenberg-Marquardt iterations per RANSAC hypothesis. docs/decisions/hypothesis-count.md.
    hypothesis_iterations: Annotated[int, integer(1), STATIC] = 6
    #: Huber re-weighting rounds per level (huber, and RANSAC's consensus refinement with
    #: consensus_weights="huber").
    irls_rounds: Annotated[int, integer(1), STATIC] = 2
    #: Levenberg-Marquardt iterations per re-weighting round.
    irls_iterations: Annotated[int, integer(1), STATIC] = 2
    #: RANSAC consensus -> refine rounds per level.
    refine_rounds: Annotated[int, integer(1), STATIC] = 1
    #: The finest level on which RANSAC runs (prior fit and hypotheses); finer levels only
    #: refine on the consensus set carried up (0: every level, the paper).
    #: docs/decisions/ransac-finest-and-prior.md.
    ransac_finest: Annotated[int, integer(0), STATIC] = 1
    #: Per level (index 0 = finest; missing entries mean 1): the refinement uses the
    #: strongest-gradient reference pixel of each b x b tile (1: every pixel, the paper).
    #: docs/decisions/blocks.md.
    blocks: Annotated[Tuple[int, ...], positive_ints(), STATIC] = (4, 4, 2, 1)
    #: RANSAC scores hypotheses on at most about this many reference pixels per level (the
    #: paper scores all). docs/decisions/hypothesis-scoring.md.
    max_score_pixels: Annotated[int, integer(1), STATIC] = 10000
    #: Luminance units per metre of depth residual in a joint RGB-D cost (600 = 30 / 0.05:
    #: the two inlier thresholds weigh the same). docs/decisions/hypothesis-scoring.md.
    depth_weight: Annotated[Any, real(0, lo_open=True)] = 600.0
    #: The cost every refinement minimises: "photometric" (the paper) or "rgbd" (plus the
    #: depth residual scaled by depth_weight).
    terms: Annotated[str, choice("photometric", "rgbd"), STATIC] = "photometric"
    #: The residuals each RANSAC hypothesis is fitted on: "photometric" (the paper) or "rgbd".
    #: docs/decisions/hypothesis-scoring.md.
    hypothesis_terms: Annotated[str, choice("photometric", "rgbd"), STATIC] = "rgbd"
    #: Hypothesis quality: "count" (most inliers, the paper) or "msac" (truncated quadratic).
    #: docs/decisions/hypothesis-scoring.md.
    scoring: Annotated[str, choice("count", "msac"), STATIC] = "msac"
    #: Each scoring pixel counts z^power (z: its reference depth, metres; 0: every pixel alike,
    #: the paper; 2: the scene surface it images). >= 0. docs/decisions/depth-weighting.md.
    score_depth_power: Annotated[Any, real(0)] = 2.0
    #: Which pixels score when there are more than max_score_pixels: "grid" (a regular
    #: subgrid) or "gradient" (each tile's strongest gradient). docs/decisions/hypothesis-scoring.md.
    score_selection: Annotated[str, choice("grid", "gradient"), STATIC] = "grid"
    #: RANSAC's refinement on the consensus set: "binary" (least squares, the paper) or
    #: "huber" (Huber IRLS). docs/decisions/consensus-weights.md.
    consensus_weights: Annotated[str, choice("binary", "huber"), STATIC] = "huber"
    #: The pose RANSAC scores first and starts every hypothesis from: "raw" (the coarser
    #: level's result, the paper), "refined" (after a least-squares fit here) or "both".
    #: docs/decisions/ransac-finest-and-prior.md.
    prior_candidate: Annotated[str, choice("raw", "refined", "both"), STATIC] = "both"
    #: Failure flag: the estimate is also invalid when fewer of the overlapping pixels agree in
    #: depth, or fewer of the textured depth-agreeing pixels agree in luminance, in [0, 1].
    #: docs/decisions/failure-flag.md.
    min_depth_agreement: Annotated[Any, real(0, 1)] = 0.2
    min_photometric_agreement: Annotated[Any, real(0, 1)] = 0.65
    #: Metres: RANSAC draws no sample centre whose depth residual at the level's starting pose
    #: exceeds this (0: off, the paper). docs/decisions/sample-gate.md.
    sample_gate: Annotated[Any, real(0)] = 0.0
    #: "offset": each level first fits and removes the exposure change (I_cur ~ I_ref + offset);
    #: "none": luminance compared as it is (the paper). docs/decisions/brightness.md.
    brightness: Annotated[str, choice("none", "offset"), STATIC] = "offset"
    #: RANSAC only: consecutive levels of similar size run as one ``lax.scan`` (faster to
    #: compile, the same poses to float32 rounding). docs/decisions/scan-levels.md.
    scan_levels: Annotated[bool, flag(), STATIC] = True

    @classmethod
    def paper(cls, method: str = "ransac", **changes) -> "Config":
        """The seed paper's algorithm as published: hypotheses fitted on the photometric
        residual only, ranked by inlier count, scored on every pixel of every level, and
        every pixel used in the refinement, plain least squares on the consensus set.
        RANSAC runs on every level, and luminance is compared as it is. The defaults differ from it
        in these nine places, each measured to be more accurate or faster (docs/decisions/)."""
        return cls(method=method, hypothesis_terms="photometric", scoring="count", score_depth_power=0.0,
                   brightness="none",
                   consensus_weights="binary", prior_candidate="raw", ransac_finest=0,
                   max_score_pixels=1 << 30, blocks=(1, 1, 1, 1)).replace(**changes)

    @classmethod
    def from_dict(cls, values, base: Optional["Config"] = None) -> "Config":
        """``base`` (default ``Config()``) with the fields in ``values`` (e.g. parsed JSON) changed,
        lists turned into tuples (``blocks``), and validated. Unknown names and bad values raise
        ValueError naming them."""
        return _from_json(cls, values, [f.name for f in dataclasses.fields(cls)], base)

    def replace(self, **changes) -> "Config":
        check_names(changes, _RULES, "Config")
        return dataclasses.replace(self, **changes)

    def to_json(self) -> str:
        """Every field as one line of JSON (tuples as lists); :meth:`from_json` reads it back exactly."""
        return _to_json(self, [f.name for f in dataclasses.fields(self)])

    @classmethod
    def from_json(cls, text) -> "Config":
        """A validated Config from :meth:`to_json`'s output (a JSON string or an already parsed dict).
        Missing fields keep their defaults; unknown fields or invalid values raise ValueError."""
        return _from_json(cls, text, [f.name for f in dataclasses.fields(cls)])

    def validate(self) -> None:
        """Raise ValueError naming the first field whose value breaks its declared rule
        (type, finiteness, range), e.g. ``Config.p must be a number in (0, 1), got 1.5``."""
        check_fields(self, _RULES, "Config")


_RULES, _STATIC = _declared(Config)
jax.tree_util.register_dataclass(
    Config, data_fields=[f.name for f in dataclasses.fields(Config) if f.name not in _STATIC], meta_fields=_STATIC)


class TrackConfig(NamedTuple):
    """How :func:`jaxvo.tracking.odometry.track` (and :class:`jaxvo.tracking.odometry.Odometry`) chooses each
    frame's reference, keeps its static/dynamic segmentation, and treats failed estimates
    (host-side policy).

    Frame j is estimated against a reference frame k < j (a keyframe), starting from
    frame j-1's pose relative to k. After frame j the reference moves once
    ``j - k >= max_gap``, or earlier when the estimate says the reference no longer
    serves (``switch_ratio``, ``switch_baseline``, ``switch_deg``). It moves to the latest
    successful frame at least ``lag`` back.

    The default is jaxvo's robust tracking: keyframes with a segmentation that persists across
    frames (``segment``, see :mod:`jaxvo.tracking.segmentation`), frame to frame while the
    segmentation sees nothing move (``calm_fraction``), and the pose of each new reference made
    from more than its own estimate (``fuse``, ``smooth``). :meth:`frame_to_frame` is the
    paper's chaining (no segmentation), :meth:`keyframes` the keyframes alone. Frames and
    distances: frame counts, metres, degrees.
    """
    #: Frames between the reference and the current frame before the reference moves, >= 1.
    #: docs/decisions/keyframes.md.
    max_gap: Annotated[int, integer(1)] = 6
    #: After a move the reference is the latest successful frame at least this many frames
    #: back, 0 <= lag < max_gap (0: the current frame). docs/decisions/keyframes.md.
    lag: Annotated[int, integer(0, "max_gap", hi_open=True)] = 3
    #: A failed estimate (not ``valid``, or a step beyond max_step / max_step_deg) is replaced
    #: by a held pose and reported invalid. docs/decisions/step-limits.md.
    hold_invalid: Annotated[bool, flag()] = True
    #: With hold_invalid: up to this many failed frames in a row move on at the recent
    #: velocity instead of holding (0: always hold). docs/decisions/coasting.md.
    coast: Annotated[int, integer(0)] = 0
    #: Largest plausible step per frame, metres (> 0) and degrees (0, 180].
    #: docs/decisions/step-limits.md.
    max_step: Annotated[float, real(0, lo_open=True)] = 0.05
    max_step_deg: Annotated[float, real(0, 180, lo_open=True)] = 5.0
    #: Keep the reference's static/dynamic segmentation and pass it to the estimator as
    #: per-pixel trust. docs/decisions/segmentation.md.
    segment: Annotated[bool, flag()] = True
    #: Move the reference early when the inlier ratio over its trusted pixels falls under
    #: this, in [0, 1) (0: never). docs/decisions/keyframes.md.
    switch_ratio: Annotated[float, real(0, 1, hi_open=True)] = 0.5
    #: Move the reference early once the current frame is this far from it: metres (> 0) and
    #: degrees (0, 180]. docs/decisions/keyframes.md.
    switch_baseline: Annotated[float, real(0, lo_open=True)] = 0.15
    switch_deg: Annotated[float, real(0, 180, lo_open=True)] = 8.0
    #: Earlier frames (at offsets 2, 4, 8, ...), 0-6, that vote on a new reference's
    #: segmentation beside the frames since it. docs/decisions/segmentation.md.
    history: Annotated[int, integer(0, 6)] = 4
    #: A new reference estimated against an earlier reference is also estimated against the
    #: current one, and later frames chain from the mean. docs/decisions/fuse-and-smooth.md.
    fuse: Annotated[bool, flag()] = True
    #: A new reference's pose comes from a smooth fit (twists quadratic in time) to all the
    #: estimates against its own reference. docs/decisions/fuse-and-smooth.md.
    smooth: Annotated[bool, flag()] = True
    #: With the segmentation: while under this fraction, in [0, 1], of the reference's valid
    #: pixels is dynamic, track frame to frame without weights (0: keyframes always).
    #: docs/decisions/calm-mode.md.
    calm_fraction: Annotated[float, real(0, 1)] = 0.03
    #: After this many failed frames in a row (>= max_gap) the frame ``lag`` back becomes the
    #: reference at its held pose. docs/decisions/restart.md.
    restart: Annotated[int, integer("max_gap")] = 16
    #: Frames over which the coasting velocity is averaged, >= 1. docs/decisions/coasting.md.
    coast_window: Annotated[int, integer(1)] = 10
    #: After held frames the step limits grow by the camera's mean per-frame motion for each
    #: held frame (RANSAC only). docs/decisions/catch-up.md.
    catch_up: Annotated[bool, flag()] = True
    #: A failed estimate is made once more from the constant-velocity guess and kept if it
    #: passes. docs/decisions/retry.md.
    retry: Annotated[bool, flag()] = True
    #: With segment and RANSAC: a flagged estimate is kept when at least ``rescue`` of the
    #: trusted, unhidden reference pixels are inliers and those are at least
    #: ``rescue_support`` of the valid ones, both in [0, 1] (0: off). docs/decisions/rescue.md.
    rescue: Annotated[float, real(0, 1)] = 0.9
    rescue_support: Annotated[float, real(0, 1)] = 0.03
    #: Keyframes in the window, >= 1 (1: the single reference alone). A new reference at least
    #: ``lag`` frames after the window's newest keyframe joins it, is estimated against the
    #: others, and the window's poses are refined as a pose graph. docs/decisions/window.md.
    window: Annotated[int, integer(1)] = 3
    #: With window > 1: a frame whose estimate failed is estimated against the window's older
    #: keyframes before its pose is held; two trusted estimates that agree on its pose are kept
    #: even where its guess makes them jumps. docs/decisions/window.md.
    recover: Annotated[bool, flag()] = True
    #: A frame whose estimate still failed (after ``retry`` and ``recover``) moves the reference
    #: at once to the latest successful frame at least ``lag`` back, as a switch would after it,
    #: and is estimated once more against that. docs/decisions/refresh.md.
    refresh: Annotated[bool, flag()] = True
    #: With window > 1 and RANSAC: the outlier fraction (``Config.w``, in [0, 1)) that the RANSAC
    #: estimates of a new keyframe against the window's older keyframes assume (see
    #: ``window_method``), which sets how many hypotheses they draw; None: as the other estimates
    #: (``outliers``, else ``Config.w``).
    #: docs/decisions/window.md.
    window_outliers: Annotated[Optional[float], real(0, 1, hi_open=True, none_means="as outliers")] = None
    #: With window > 1 and RANSAC: the method of a new keyframe's estimates against the window's
    #: older keyframes that carry static weights (those of the calm mode carry none and are
    #: estimated with RANSAC, as every other estimate): "ransac" (as the tracking's other
    #: estimates), "huber" (Huber IRLS from the chained pose, with that keyframe's static weights:
    #: better and faster on the Bonn crowd, worse where a person moves fast and close) or
    #: "classic". docs/decisions/window.md.
    window_method: Annotated[str, choice("ransac", "huber", "classic")] = "ransac"
    #: With window > 1 and RANSAC: the finest pyramid level on which a new keyframe's estimates
    #: against the window's older keyframes run RANSAC (``Config.ransac_finest`` for them alone,
    #: >= 0; finer levels refine from the pose carried up); None: as the other estimates. They
    #: start from the chained pose, and RANSAC's finest level costs about a quarter of an
    #: estimate: 2 is a lever for speed (a second estimator program to compile), not the default.
    #: docs/decisions/window.md.
    window_ransac_finest: Annotated[Optional[int], integer(0, none_means="as Config.ransac_finest")] = None
    #: With the segmentation (``segment``) and RANSAC: every estimate made without static weights
    #: (the calm mode's frame-to-frame estimates, and a new keyframe's estimates against calm
    #: keyframes) stops at the coarsest pyramid level at least this many pixels wide (>= 1; 640x480
    #: frames: level 1, 320x240; frames narrower than it: level 0), never finer than
    #: ``Config.finest_level``; None (default): at ``Config.finest_level``. 320 is faster on static
    #: 640x480 scenes read with their lens (fr2/desk: RPE 1 s 0.0092 against 0.0097 m/s) and loses
    #: on frames read without it and on some dynamic augmentations. docs/decisions/calm-mode.md.
    calm_min_width: Annotated[Optional[int], integer(1, none_means="at Config.finest_level")] = None
    #: With window > 1 and the segmentation: where the reference's static mask trusts under this
    #: share of its pixels, in [0, 1] (0: off), a valid estimate is fused with one against the
    #: window's next-older keyframe that trusts more. docs/decisions/second-opinion.md.
    second_opinion: Annotated[float, real(0, 1)] = 0.45
    #: With the segmentation (``segment``) and RANSAC: the outlier fraction (``Config.w``, in
    #: [0, 1)) that every estimate of the tracking assumes, which sets how many hypotheses it
    #: draws (the map's static weights leave out of the samples what it saw move); None:
    #: ``Config.w``. A smaller value is faster where people move, less robust on unlucky draws
    #: and lost on some sequences that start with people in view. docs/decisions/hypothesis-count.md.
    outliers: Annotated[Optional[float], real(0, 1, hi_open=True, none_means="Config.w")] = None
    #: With the segmentation (``segment``) and RANSAC, True: every estimate of the tracking stops
    #: drawing hypotheses once its best one's inlier ratio over the trusted pixels makes p
    #: reachable (``Config.adaptive_hypotheses``); False: as the Config says. Faster where people
    #: move, and lost on some sequences that start with people in view.
    #: docs/decisions/hypothesis-count.md.
    adaptive: Annotated[bool, flag()] = False
    #: True: a frame that becomes the reference and records when its colour and its depth image
    #: were taken (``Frame.time``, ``Frame.depth_time``; the sequence readers set both) has its
    #: depth moved to the colour image's time (:mod:`jaxvo.tracking.depth_time`), with the camera's
    #: motion between it and the posed frame next to it. A lever, off: docs/decisions/depth-time.md.
    retime_depth: Annotated[bool, flag()] = False
    #: The poses ``Track.poses`` and ``jaxvo run``'s trajectory hold: "refined" (default), refined
    #: in hindsight (:meth:`jaxvo.Odometry.refined_poses`: each frame on its reference's latest
    #: anchor; the trajectory gets a frame's line once its refined pose can no longer change,
    #: ``TrackStep.settled``, a few frames later, and the rest at the end), or "tracked", each
    #: frame's pose as it was returned (``TrackStep.T_world_cur``; a line per frame as it is
    #: tracked; :meth:`frame_to_frame` and :meth:`keyframes`). docs/decisions/window.md.
    poses: Annotated[str, choice("tracked", "refined")] = "refined"
    #: With the segmentation (``segment``): how sharply its evidence sets the static weight every
    #: estimate gives a reference pixel, sigmoid(-trust_gain * L) of the log-odds L that the pixel
    #: is dynamic (> 0; 1: the map's probability that it is static), where the map trusts under
    #: ``trust_share`` of its pixels; elsewhere the probability. Every gain trusts the same pixels
    #: (weight >= 0.5: RANSAC's samples, the static masks); a larger one leaves the pixels the map
    #: is unsure of (people it has half seen move) less weight in the scoring and the refinements.
    #: docs/decisions/trust-gain.md.
    trust_gain: Annotated[float, real(0, lo_open=True)] = 3.0
    #: The share of the reference's map pixels trusted as static (log-odds <= 0) under which
    #: ``trust_gain`` sharpens the weights: where people cover most of the view. Where the static
    #: scene is the majority the weights stay the map's probability, so a sequence that starts
    #: with people in view, before the map has evidence, is not led onto them.
    trust_share: Annotated[float, real(0, 1)] = 0.4
    #: With the segmentation (``segment``): every this many frames after its reference, a
    #: frame's valid estimate also runs the segmentation's motion test against the reference at
    #: that estimate, so that a region the map trusts and that starts to move (a person who
    #: stood still) is flagged for the next frames; 0: once per reference, where its test had
    #: no earlier view. docs/decisions/motion-retest.md.
    motion_retest: Annotated[int, integer(0)] = 1

    @classmethod
    def frame_to_frame(cls, **changes) -> "TrackConfig":
        """The paper's chaining: every frame against the one before it, no segmentation."""
        return cls(**{"max_gap": 1, "lag": 0, "segment": False, "max_step": 0.1, "max_step_deg": 10.0, "coast": 0,
                      "restart": 4, "catch_up": False, "retry": False, "window": 1, "refresh": False,
                      "poses": "tracked", **changes})

    @classmethod
    def keyframes(cls, max_gap: int = 6, lag: Optional[int] = None, **changes) -> "TrackConfig":
        """References up to ``max_gap`` frames back, ``lag`` (default max_gap // 2) after a move;
        no segmentation unless ``segment=True`` is passed."""
        return cls(**{"max_gap": max_gap, "lag": max_gap // 2 if lag is None else lag, "segment": False,
                      "max_step": 0.1, "max_step_deg": 10.0, "restart": 4 * max_gap, "catch_up": False,
                      "retry": False, "window": 1, "refresh": False, "poses": "tracked", **changes})

    def to_json(self) -> str:
        """Every field as one line of JSON; :meth:`from_json` reads it back exactly."""
        return _to_json(self, list(self._fields))

    @classmethod
    def from_json(cls, text) -> "TrackConfig":
        """A validated TrackConfig from :meth:`to_json`'s output (JSON string or dict)."""
        return _from_json(cls, text, list(cls._fields))

    def validate(self) -> None:
        """Raise ValueError naming the first field that breaks its declared rule."""
        check_fields(self, _TRACK_RULES, "TrackConfig")



_TRACK_RULES, _ = _declared(TrackConfig)


def _plain(v):
    """A field value as plain JSON data: tuples -> lists, NumPy / JAX scalars -> int / float / bool."""
    if isinstance(v, (tuple, list)):
        return [_plain(x) for x in v]
    if v is None or isinstance(v, (bool, int, float, str)):
        return v
    try:
        a = np.asarray(v)
    except Exception:  # a tracer
        raise ValueError(f"cannot write a traced or non-numeric value {v!r} to JSON") from None
    if a.ndim != 0:
        raise ValueError(f"cannot write a non-scalar field value of shape {a.shape} to JSON")
    return a.item()


def _to_json(obj, names) -> str:
    return json.dumps({n: _plain(getattr(obj, n)) for n in names})


def _from_json(cls, text, names, base=None):
    """A validated ``cls`` from JSON text or a parsed dict of fields (lists -> tuples), the other
    fields from ``base`` (default ``cls()``); unknown names and bad values raise ValueError."""
    data = json.loads(text) if isinstance(text, (str, bytes)) else text
    if not isinstance(data, dict):
        raise ValueError(f"{cls.__name__}: expected a JSON object of fields, got {type(data).__name__}")
    check_names(data, names, cls.__name__)
    changes = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}
    obj = cls(**changes) if base is None else \
        (base._replace(**changes) if hasattr(base, "_replace") else dataclasses.replace(base, **changes))
    obj.validate()
    return obj
