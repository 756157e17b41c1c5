"""Plain-data settings: :class:`Config` (the estimator, traced numeric fields) and
:class:`TrackConfig` (the host-side tracking policy of :func:`jaxvo.tracking.odometry.track`).

Both are pytrees of plain values, so a ``jax.vmap`` over a numeric ``Config`` field is a
hyperparameter sweep compiled once.
"""
from __future__ import annotations

import dataclasses
import json
from typing import Any, NamedTuple, Optional, Tuple

import jax
import numpy as np

from jaxvo.validation import check_fields, check_names, choice, flag, integer, positive_ints, real

__all__ = ["METHODS", "Config", "TrackConfig"]

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
    min_depth_agreement, min_photometric_agreement: the estimate is also flagged invalid when
      fewer of the overlapping pixels agree in depth, or fewer of the textured pixels that
      agree in depth agree in luminance too (see jaxvo.estimator.motion.TrustStats; measured with
      experiments/failure_flag.py).
      min_inlier_ratio 0.12 and min_depth_agreement 0.2 (from 0.2 and 0.35): where people cover
      two thirds of the view, the estimates against the keyframe are right (5-20 mm over 3-6
      frames on Bonn crowd frames 104-112, in a scratch per-frame trace of seed 0) while most
      pixels move, so the stricter rule failed them, the pose was held and the next estimates
      started from ever worse guesses. With the default tracking (and ``TrackConfig.restart``
      16), Bonn crowd seeds 0-11: RPE 1 s 0.049 against 0.065 m/s, ATE 0.042 against 0.050 m
      (experiments/results/bonn_default.md against policy_restart24.md; the restart's share:
      see TrackConfig.restart). As a classifier of wrong estimates (experiments/failure_flag.py) the rule stays at precision
      1.000, recall 0.973 (0.982 before: one more Bonn pair 30 frames apart passes); with
      ``score_depth_power`` 2, precision 0.991, recall 0.982 (see the README).
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
    ransac_finest: *static*, the finest level on which RANSAC (the prior fit, the hypotheses)
      runs; each finer level only refines on the consensus set of the pose carried up from the
      coarser level (0: RANSAC on every level, the paper). Default 1: level 0's hypotheses
      (54-pixel fits at 640x480) rarely beat the pose carried up from level 1, and dropping
      them (105.5 -> 77.7 hypotheses per Bonn pair, experiments/results/speed.md) costs no
      accuracy beyond the seed-to-seed spread (numbers under prior_candidate; experiments/results/ransac_finest*.md
      and augmented_*.md).
    blocks: *static*, per level (index 0 = finest): the refinement uses one reference
      pixel per b x b tile, the one with the strongest intensity gradient (b = 1: every
      pixel). The current image is always sampled at that level's full resolution. Missing
      entries mean 1. Default (4, 4, 2, 1) for every method: 4800 points at each of the
      three finest levels of 640x480. Measured on one machine against RANSAC's previous
      (4, 2, 1, 1), seeds 0-11 with the default tracking: Bonn crowd RPE 1 s 0.060 against
      0.073 m/s, ATE 0.047 against 0.048 m; fr2_desk with two synthetic persons ATE 0.054
      against 0.059 m (experiments/results/blocks_*.md); and faster per pair
      (experiments/results/variants_blocks.md). Classic and Huber had it before: as accurate
      as (4, 2, 1, 1) at two thirds of the time.
    max_score_pixels: *static*, RANSAC scores hypotheses on at most about this many
      reference pixels per level (a regular subgrid); the paper scores all pixels.
    depth_weight: luminance units per metre of depth residual where a joint RGB-D
      cost is used (600 = 30 / 0.05: the two inlier thresholds weigh the same).
    terms: *static*, "photometric" (the paper) or "rgbd" (photometric + depth residual,
      the depth term scaled by depth_weight): the cost every refinement minimises.
    hypothesis_terms: *static*, "photometric" (the paper) or "rgbd": the residuals each
      RANSAC hypothesis is fitted on.
    scoring: *static*, "count" (the paper: most inliers) or "msac" (truncated quadratic).
    score_depth_power: RANSAC weighs each scoring pixel's contribution to a hypothesis's
      quality by z^score_depth_power (z: its reference depth; 0 = every pixel alike, the paper).
      A pixel at depth z images z^2 / (fx fy) m^2 of a surface facing the camera, so with 2
      the quality counts the scene *surface* a hypothesis explains, not the pixels: a person
      1 m away covers four times the pixels of the same area of wall 2 m behind, and where
      people walk with the camera and cover 40-50 % of the view the pixel count makes "the
      camera followed them" the largest consensus before the segmentation knows anything.
      The inlier ratio (``valid``) still counts pixels; RANSAC stops early on either share
      (jaxvo.estimator.ransac.ransac_level). fr2_desk + 2 synthetic
      persons, default tracking, seeds 0-11 (experiments/results/augmented_default.md against
      augmented_power0.md, the same command with ``--config '{"score_depth_power": 0}' --policy
      '{"retry": false}'``): ATE 0.035 m against 0.048 m, mask precision 0.705 against 0.670 at
      about the same recall (0.404 against 0.408), below RANSAC's ATE on 11 of 12 seeds against
      10 (power 1: 0.037 m, power 3: 0.033 m, augmented_power1.md / augmented_power3.md).
      Bonn crowd within the seed-to-seed spread (bonn_default.md against bonn_power0.md: RPE
      1 s 0.039 against 0.038 m/s, ATE 0.032 against 0.031 m, seeds 0-11); fr2_desk and the
      synthetic seq1-3 as before.
    prior_candidate: *static*, the pose RANSAC scores first and starts every hypothesis
      from: "raw" (the previous level's result as it is) or "refined" (that pose after a
      plain least-squares fit of this level): where the scene is mostly static the
      refined pose is the best candidate, and sampled patches rarely beat it; "both"
      (default): the refined pose, with the raw one scored beside it, because a mover can drag
      the plain fit away (on the synthetic pair of tests/test_odometry.py, with ransac_finest=1:
      2.2 mm with "both", 14.8 mm with "refined"). Default tracking, 12 seeds each, mean
      (``experiments/keyframes.py BONN --gaps default --methods ransac --seeds 0,...,11`` and
      ``experiments/paper_sequences.py --sequences '' --augment tum --methods default --seeds
      0,...,11``, each with ``--config``): Bonn crowd RPE 1 s / ATE, fr2_desk + 2 synthetic
      persons ATE: ransac_finest=1 "both" 0.064 m/s / 0.045 m, 0.054 m; ransac_finest=0
      "both" 0.069 / 0.049, 0.053; 0 "refined" (the previous default) 0.066 / 0.049, 0.057; 1
      "refined" augmented 0.061. Seed-to-seed spread: 0.033-0.079 m/s on Bonn, 0.010-0.11 m
      on the augmentation.
    consensus_weights: *static*, the RANSAC refinement on the consensus set: "binary"
      (least squares on the inliers, the paper) or "huber" (Huber IRLS on the inliers,
      which also discounts the moving pixels that happen to pass the thresholds).
    sample_gate: metres; RANSAC draws no sample centre whose depth residual at the level's
      starting pose exceeds this (0: off, the paper). A person who stepped in front of the
      static background since the reference covers pixels the segmentation of the
      reference cannot know about; at the previous frame's pose their depth is off by far
      more than any static pixel's, so samples there are wasted draws. If fewer than 10 % of
      the trusted pixels pass, the gate is not applied. Off by default: 0.2 m gave no gain
      on Bonn crowd with the default tracking (RPE 1 s 0.079 against 0.076 m/s, seeds 0-5).
    score_selection: *static*, which pixels score a hypothesis when there are more than
      max_score_pixels: "grid" (a regular subgrid) or "gradient" (the strongest-gradient
      pixel of each tile, so textureless areas that agree with any pose do not dilute it).
    brightness: *static*, "offset" (default) or "none" (the paper: luminance compared as it is).
      "offset": each level first fits the exposure change I_cur ~ I_ref + offset on the pixels
      whose depth agrees at its starting pose, and shifts the reference by it when it exceeds
      thresh_lum / 3 (jaxvo.estimator.brightness). Kinect-class cameras set their exposure
      automatically, and people in light clothes filling the view change it by ~36 grey levels
      (Bonn crowd frames 109 -> 120, experiments/exposure.py). Bonn crowd, default tracking,
      seeds 0-11: RPE 1 s 0.028 m/s, ATE 0.024 m, 0.60 deg/s against 0.039 / 0.032 / 1.14 with
      "none" (experiments/results/bonn_default.md against bonn_brightness_none.md), the fr2_desk
      augmentation (one seed of 12 differs) and fr2_desk as with "none"; it costs about 1.1x / 1.05x the time per static /
      Bonn pair (experiments/results/variants_brightness.md). Before hypotheses were ranked by
      surface (score_depth_power) it measured no gain there (brightness_*.md of 2026-11-23).
    scan_levels: *static*, RANSAC only: run consecutive RANSAC levels as one ``lax.scan`` over
      one level body (images padded to the group's largest level, point lists and scoring grids
      to the longest) instead of one copy of the code per level, as far as the padded points stay
      within 10 % of all levels' refinement points (levels 3-1 with the default tiles, 4800
      points each; levels 3-2 in ``Config.paper()``); the other levels run per level. Default
      True: XLA compiles the estimator in 9.3 instead of 14.2 s, with the same poses to
      float32 rounding, at 1.00x (static) / 1.13x (Bonn) the time per pair of the per-level
      code in the same run (``python experiments/variants.py --methods ransac --pairs 10
      --repeats 5``, experiments/results/scan_levels.md; an earlier run gave 1.21x / 1.00x:
      within the run-to-run spread of this machine). False is worth it for long runs in one
      process (the compiled program is cached across processes anyway). Classic and Huber
      are not scanned: their levels compile in about a second each, and scanned (all four
      levels as one group) classic took 1.37x / 1.23x the time per pair, Huber 1.01x / 0.85x,
      for 0.9-1.1 s less compilation (experiments/results/scan_levels.md at commit d68e5a6).
    """
    method: str = "ransac"
    p: Any = 0.99
    w: Any = 0.3
    thresh_lum: Any = 30.0
    thresh_depth: Any = 0.05
    early_exit_ratio: Any = 0.9
    huber_k: Any = 1.345
    max_depth: Any = 4.0
    min_inlier_ratio: Any = 0.12
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
    ransac_finest: int = 1
    blocks: Tuple[int, ...] = (4, 4, 2, 1)
    max_score_pixels: int = 10000
    depth_weight: Any = 600.0
    terms: str = "photometric"
    hypothesis_terms: str = "rgbd"
    scoring: str = "msac"
    score_depth_power: Any = 2.0
    score_selection: str = "grid"
    consensus_weights: str = "huber"
    prior_candidate: str = "both"
    min_depth_agreement: Any = 0.2
    min_photometric_agreement: Any = 0.65
    sample_gate: Any = 0.0
    brightness: str = "offset"
    scan_levels: bool = True

    @classmethod
    def paper(cls, method: str = "ransac", **changes) -> "Config":
        """The seed paper's algorithm as published: hypotheses fitted on the photometric
        residual only, ranked by inlier count, scored on every pixel of every level, and
        every pixel used in the refinement, plain least squares on the consensus set.
        RANSAC runs on every level, and luminance is compared as it is. The defaults differ from it
        in these nine places (measured to be more accurate or faster; see the README)."""
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
        """Raise ValueError naming the first field whose value breaks its rule in ``_RULES``
        (type, finiteness, range), e.g. ``Config.p must be a number in (0, 1), got 1.5``."""
        check_fields(self, _RULES, "Config")


# One rule per field (jaxvo.validation): a new field needs a line here, or validate() fails.
_RULES = {
    "method": choice(*METHODS),
    "p": real(0, 1, lo_open=True, hi_open=True),
    "w": real(0, 1, hi_open=True),
    "thresh_lum": real(0, lo_open=True),
    "thresh_depth": real(0, lo_open=True),
    "early_exit_ratio": real(0, 1, lo_open=True),
    "huber_k": real(0, lo_open=True),
    "max_depth": real(0, lo_open=True),
    "min_inlier_ratio": real(0, 1),
    "n_points": integer(1),
    "patch_radius": integer(0),
    "max_hypotheses": integer(1),
    "batch_size": integer(1),
    "num_levels": integer(1, 16, none_means="halve down to about 80x60"),
    "finest_level": integer(0, "num_levels", hi_open=True),
    "max_iterations": integer(1),
    "hypothesis_iterations": integer(1),
    "irls_rounds": integer(1),
    "irls_iterations": integer(1),
    "refine_rounds": integer(1),
    "ransac_finest": integer(0),
    "blocks": positive_ints(),
    "max_score_pixels": integer(1),
    "depth_weight": real(0, lo_open=True),
    "terms": choice("photometric", "rgbd"),
    "hypothesis_terms": choice("photometric", "rgbd"),
    "scoring": choice("count", "msac"),
    "score_depth_power": real(0),
    "score_selection": choice("grid", "gradient"),
    "consensus_weights": choice("binary", "huber"),
    "prior_candidate": choice("raw", "refined", "both"),
    "min_depth_agreement": real(0, 1),
    "min_photometric_agreement": real(0, 1),
    "sample_gate": real(0),
    "brightness": choice("none", "offset"),
    "scan_levels": flag(),
}

_STATIC = ["method", "n_points", "patch_radius", "max_hypotheses", "batch_size", "num_levels", "finest_level",
           "max_iterations", "hypothesis_iterations", "irls_rounds", "irls_iterations", "refine_rounds", "blocks",
           "ransac_finest", "max_score_pixels", "terms", "hypothesis_terms", "scoring", "score_selection",
           "consensus_weights", "prior_candidate", "brightness", "scan_levels"]
jax.tree_util.register_dataclass(
    Config, data_fields=[f.name for f in dataclasses.fields(Config) if f.name not in _STATIC], meta_fields=_STATIC)


class TrackConfig(NamedTuple):
    """How :func:`jaxvo.tracking.odometry.track` (and :class:`jaxvo.tracking.odometry.Odometry`) chooses each
    frame's reference, keeps its static/dynamic segmentation, and treats failed estimates
    (host-side policy).

    Frame j is estimated against a reference frame k < j (a keyframe), starting from
    frame j-1's pose relative to k. After frame j the reference moves once
    ``j - k >= max_gap``, or earlier when the estimate says the reference no longer
    serves (its inlier ratio over trusted reference pixels fell under ``switch_ratio``,
    or the camera moved more than ``switch_baseline`` metres / ``switch_deg`` degrees
    from it). It moves to the latest successful frame at least ``lag`` back.

    The default is jaxvo's robust tracking: keyframes (gap 6, lag 3) with a
    segmentation that persists across frames (``segment``, see
    :mod:`jaxvo.tracking.segmentation`), frame to frame while the segmentation sees nothing move
    (``calm_fraction``), and the pose of each new reference made from more than its own
    estimate (``fuse``, ``smooth``). :meth:`frame_to_frame` is the paper's chaining
    (no segmentation), :meth:`keyframes` the keyframes alone.

    Why keyframes: between consecutive frames (33 ms) people who walk at ~1 m/s move
    ~3 cm, under the 5 cm depth threshold, so no inlier test can tell them from the
    static scene and every estimator partly follows them. Against a reference a few
    frames back they have moved far more than the camera and fail the thresholds.
    Why the segmentation: where people cover much of the picture for seconds, the
    frames around the reference have seen the room behind them; a reference pixel
    whose 3-D point lies in space another frame saw through is dynamic, and that
    evidence is kept and carried from reference to reference.

    max_gap: frames between the reference and the current frame before the reference
      moves (>= 1).
    lag: after a move the reference is this many frames behind the current frame
      (0 <= lag < max_gap; 0 = the current frame becomes the reference). Frames whose
      estimate failed are skipped: the reference moves to the latest successful frame at
      least ``lag`` back, or stays where it is. With lag < max_gap / 2 every regular move
      lands on a frame estimated against the current reference, so ``fuse`` never needs its
      extra estimate; on Bonn crowd (seeds 0-11) that is less accurate: lag 2 RPE 1 s 0.061 m/s,
      ATE 0.047 m; lag 2 with max_gap 5 0.077 / 0.049, against 0.049 / 0.042
      (``experiments/results/policy_lag2.md``, ``policy_lag2_gap5.md``).
    coast: with ``hold_invalid``, a failed frame gets the previous frame's pose moved on at
      the camera's recent velocity (its mean over the last 10 frames) instead of the previous pose,
      for up to this many failed frames in a row; then the pose is held (0: always held).
      People who cover the picture for a second make every estimate fail while a
      hand-held camera keeps moving; holding turns that motion into a permanent offset.
      Off by default: on Bonn crowd (seeds 0-5) it was worse (RPE 1 s 0.102 against
      0.076 m/s), as the estimates just before such a stretch are already pulled by the
      people and give a wrong velocity.
    coast_window: frames over which the coasting velocity is averaged. With ``coast=30`` and
      a 2 s window (60), Bonn crowd seeds 0-11 give RPE 1 s 0.063 against the default's 0.049
      m/s, ATE 0.049 against 0.042 m and rotation 2.14 against 1.16 deg/s
      (``experiments/keyframes.py --policy '{"coast": 30, "coast_window": 60}'``,
      experiments/results/policy_coast60.md, against bonn_default.md; with the defaults of
      2026-11-23 it gave ATE 0.040 against 0.047 m), so coasting stays off.
    hold_invalid: an estimate that is not ``valid`` or implies an implausible step from the
      previous frame (beyond ``max_step`` metres or ``max_step_deg`` degrees) is replaced by
      the previous frame's pose (constant position) and reported invalid. 0.05 m and 5 deg
      per frame (1.5 m/s, 150 deg/s at 30 Hz) is beyond hand-held motion; the paper's chaining
      (:meth:`frame_to_frame`) keeps jaxvo's earlier 0.1 m / 10 deg.
    catch_up: after held frames the guess is that many frames old, so the step limits grow by
      the camera's mean per-frame motion before them for each held frame (see
      ``Odometry._stale_allowance``). With the plain limits a camera moving faster than the
      limit over the frames since its last pose is never caught again: the default held 18-88
      of the 89 frames of the synthetic handheld-fast (seeds 0-3: ATE 0.12-0.16 m, against
      0.009-0.145 m with it). It trusts the estimator's own failure flag over the stale guess,
      which only RANSAC's flag earns, so it applies to ``Config.method`` "ransac" only: on Bonn
      crowd (seeds 0-2, ``experiments/keyframes.py``) RANSAC with this policy was unchanged,
      but classic with it went from RPE 1 s 0.072 to 0.140 m/s and the unsegmented keyframes
      (gap 6) from 0.19 to 0.28 m/s (RANSAC) and 0.39 to 0.72 m/s (classic), their estimates
      dragged by the people yet flagged valid. Default True; :meth:`keyframes` and
      :meth:`frame_to_frame` leave it off.
    retry: an estimate that fails (not ``valid``, or an implausible step) is made once more from
      another guess: the previous frame's pose moved on by the motion between the two frames
      before it (when both were estimated), and that estimate is kept if it passes. The first
      guess assumes the camera stood still since the previous frame; a camera that turns
      3-4 degrees per frame while a person covers 55-65 % of the reference leaves the
      estimator's basin, and held frames only make the guess staler: on the synthetic
      handheld-fast (seed 0) 15 frames failed and the default's ATE was 0.144 m, 0.005 m with
      the retry (seeds 1-3 unchanged). At most one more estimate per run of failed frames (the
      retry needs the two previous frames estimated). Bonn crowd, the fr2_desk augmentation
      and fr2_desk move within the seed-to-seed spread (numbers in README and docs/results.md).
      Every frame started from the constant-velocity guess (scratch) was worse on the
      augmentation (seeds 0-11: ATE 0.038 against 0.035 m), hence only as a retry. Off in
      :meth:`frame_to_frame` and :meth:`keyframes`.
    rescue, rescue_support: with ``segment`` and ``Config.method`` "ransac", an estimate that
      RANSAC's failure flag fails is kept when at least ``rescue`` of the reference pixels the
      segmentation trusts and the current frame does not hide (``MotionEstimate.occluded_mask``)
      are inliers, and those pixels are at least ``rescue_support`` of the valid ones (the step
      limits still apply; 0: off). The flag counts every pixel, and where people cover half of
      the reference and walk in front of most of the rest, a right estimate fails it: on the
      synthetic handheld-fast (seed 2, a scratch per-frame trace against the ground truth) the
      estimates of 7 frames in a row were right to 0-2 mm at inlier ratio 0.04-0.31 (depth
      agreement 0.05-0.49), the held pose then fell behind the camera, the next 9 estimates were
      wrong and the run ended at ATE 0.077 m. Over the trusted, unhidden pixels the 7 right
      estimates had 0.90-1.00 inliers on 3-24 % of the pixels, the wrong ones 0.18-0.67; none of the
      trusted pixels was moving. With it: handheld-fast seeds 1 and 2 ATE 0.010 and 0.006 m
      against 0.072 and 0.077 m, Bonn crowd (seeds 0-11) RPE 1 s 0.029 against 0.031 m/s, ATE
      0.024 against 0.026 m, the fr2_desk augmentation (seeds 0-11) ATE 0.015 against 0.018 m at
      pooled masks 0.81 / 0.80 against 0.81 / 0.82 (scratch runs of the experiments' code; the
      results files hold the reruns). Counting only trusted pixels in the flag itself had hidden
      wrong estimates on Bonn with the segmentation of 2026-11-24 (``odometry._final_counts``);
      as a second look at failed estimates only, it did not there.
    segment: keep the static/dynamic segmentation of the reference and pass it to the
      estimator as per-pixel trust (``estimate_motion(weights=)``).
    switch_ratio: move the reference early when the estimate's inlier ratio over trusted
      reference pixels falls under this (0 = never).
    switch_baseline, switch_deg: move the reference early once the current frame is this
      far (metres, degrees) from it: overlap shrinks with the baseline.
    fuse: when the new reference was estimated against an earlier reference than the
      current one (with ``lag >= max_gap / 2`` every other reference is), estimate it
      against the current reference too and chain later frames from the average of the two
      poses. Without it the references form two interleaved chains that drift apart (their
      difference shows as a zig-zag of a few cm on Bonn crowd); costs one extra estimate per
      reference move.
    calm_fraction: with the segmentation, while the reference has fewer than this fraction
      of its valid pixels marked dynamic and the estimate succeeded, every frame becomes the
      next reference and is estimated without the map's weights (frame to frame, as the
      paper: on a static scene the shortest baseline is the most accurate, and the ~1 % of
      pixels the map marks dynamic there are depth edges); the keyframes and the weights take
      over as soon as the map sees more move. 0: keyframes always. fr2_desk: 0.0179 m/s, as
      frame to frame (0.0185 with the weights, 0.0190 at 1 %); Bonn crowd unchanged.
    smooth: the pose of a new reference comes from a smooth fit (twists quadratic in time)
      to all the estimates against its own reference, not from its estimate alone.
    history: how many earlier frames (at offsets 2, 4, 8, ...) vote on a new reference's
      segmentation, beside the frames between it and the current frame.
    restart: after this many frames in a row whose estimates failed (so that the reference
      could not move), the frame ``lag`` back becomes the reference anyway, at its held
      pose (>= max_gap): a chain restarted from a guessed pose, rather than a reference that
      no longer overlaps the view. On Bonn crowd (seeds 0-11, ``experiments/keyframes.py
      --policy '{"restart": N}'``) with the failure flag's current thresholds
      (``Config.min_inlier_ratio`` 0.12, ``min_depth_agreement`` 0.2): 12 frames RPE 1 s
      0.052 m/s, ATE 0.044 m; 16 frames 0.049, 0.042 (experiments/results/bonn_default.md);
      20 frames 0.057, 0.045; 24 frames (the earlier default) 0.063, 0.050 (seeds 0-5). With
      the earlier thresholds, 12 frames gave 0.053, 0.045 and 24 frames 0.065, 0.050
      (experiments/results/policy_restart*.md). Differences under ~0.005 m/s are within what
      float32 rounding alone moves a crowd run (see ``Config.scan_levels``), so 16 is the
      middle of a flat region, not a sharp optimum. ``keyframes`` keeps 4 x max_gap.
    """
    max_gap: int = 6
    lag: int = 3
    hold_invalid: bool = True
    coast: int = 0
    max_step: float = 0.05
    max_step_deg: float = 5.0
    segment: bool = True
    switch_ratio: float = 0.5
    switch_baseline: float = 0.15
    switch_deg: float = 8.0
    history: int = 4
    fuse: bool = True
    smooth: bool = True
    calm_fraction: float = 0.03
    restart: int = 16
    coast_window: int = 10
    catch_up: bool = True
    retry: bool = True
    rescue: float = 0.9
    rescue_support: float = 0.03

    @classmethod
    def frame_to_frame(cls, **changes) -> "TrackConfig":
        """The paper's chaining: every frame against the one before it, no segmentation."""
        return cls(**{"max_gap": 1, "lag": 0, "segment": False, "max_step": 0.1, "max_step_deg": 10.0, "coast": 0,
                      "restart": 4, "catch_up": False, "retry": False,
                      **changes})

    @classmethod
    def keyframes(cls, max_gap: int = 6, lag: Optional[int] = None, **changes) -> "TrackConfig":
        """References up to ``max_gap`` frames back, ``lag`` (default max_gap // 2) after a move;
        no segmentation unless ``segment=True`` is passed."""
        return cls(**{"max_gap": max_gap, "lag": max_gap // 2 if lag is None else lag, "segment": False,
                      "max_step": 0.1, "max_step_deg": 10.0, "restart": 4 * max_gap, "catch_up": False,
                      "retry": False, **changes})

    def to_json(self) -> str:
        """Every field as one line of JSON; :meth:`from_json` reads it back exactly."""
        return _to_json(self, list(self._fields))

    @classmethod
    def from_json(cls, text) -> "TrackConfig":
        """A validated TrackConfig from :meth:`to_json`'s output (JSON string or dict)."""
        return _from_json(cls, text, list(cls._fields))

    def validate(self) -> None:
        """Raise ValueError naming the first field that breaks its rule (see ``_TRACK_RULES``)."""
        check_fields(self, _TRACK_RULES, "TrackConfig")


_TRACK_RULES = {
    "max_gap": integer(1),
    "lag": integer(0, "max_gap", hi_open=True),
    "hold_invalid": flag(),
    "catch_up": flag(),
    "retry": flag(),
    "coast": integer(0),
    "max_step": real(0, lo_open=True),
    "max_step_deg": real(0, 180, lo_open=True),
    "segment": flag(),
    "switch_ratio": real(0, 1, hi_open=True),
    "switch_baseline": real(0, lo_open=True),
    "switch_deg": real(0, 180, lo_open=True),
    "history": integer(0, 6),
    "fuse": flag(),
    "smooth": flag(),
    "calm_fraction": real(0, 1),
    "restart": integer("max_gap"),
    "coast_window": integer(1),
    "rescue": real(0, 1),
    "rescue_support": real(0, 1),
}


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
