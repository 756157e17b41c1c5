"""Score trajectories and outlier masks against ground truth: the library side of ``jaxvo eval``.

:func:`evaluate` compares an estimate (a TUM file or arrays) with ground truth (a file, a
sequence folder, a sequence object or arrays) under one of two :data:`PROTOCOLS`:

* ``"nearest"``: each estimate pose is paired with the ground-truth pose of the nearest
  timestamp within ``max_dt`` s (TUM's associate.py, evo; what ``jaxvo eval`` prints);
* ``"interpolated"``: the ground truth is interpolated at each estimate timestamp inside its span
  (linear in translation, slerp in rotation), as the paper's Table I and ``experiments/`` do.

The two differ in the third digit on real data. :func:`trajectory_errors` gives the summary
errors ``jaxvo run`` prints; :func:`score_masks` pools mask scores of saved outlier masks
against true moving-pixel masks. Poses are T_world_cam, timestamps seconds, errors in metres
and degrees (see :mod:`jaxvo.evaluation.metrics`).
"""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Optional, Tuple

import numpy as np

from jaxvo.data import DatasetError, interpolate_poses, is_bonn_sequence, read_groundtruth
from jaxvo.data.masks import load_mask, read_mask_dir, true_masks
from jaxvo.evaluation.metrics import ATEResult, MaskScores, RPEResult

__all__ = ["PROTOCOLS", "Evaluation", "TrajectoryErrors", "evaluate", "trajectory_errors", "score_masks",
           "true_masks", "load_mask", "read_mask_dir", "load_groundtruth"]

#: How :func:`evaluate` pairs estimate poses with ground truth.
PROTOCOLS = ("nearest", "interpolated")


@dataclasses.dataclass(frozen=True)
class TrajectoryErrors:
    """The summary errors of a run (:func:`trajectory_errors`), None where they cannot be formed.

    rpe_1f: RPE over 1 frame (m/frame, deg/frame); rpe_1s: over 1 s (m/s, deg/s), only for a
    run that spans about a second; ate: after rigid alignment (m), from 3 poses on.
    """
    rpe_1f: Optional[RPEResult] = None
    rpe_1s: Optional[RPEResult] = None
    ate: Optional[ATEResult] = None


def trajectory_errors(gt, stamps, poses, max_dt=0.02) -> TrajectoryErrors:
    """RPE (1 frame, and 1 s where the run is long enough) and ATE of a trajectory, poses paired
    with ``gt`` = (stamps (M,), T_world_cam (M, 4, 4)) by nearest timestamp within ``max_dt`` s;
    skips what cannot be formed."""
    from jaxvo.evaluation.metrics import ate, rpe

    gt_t, gt_T = gt
    out = {}
    if len(stamps) >= 2:
        try:
            out["rpe_1f"] = rpe(gt_t, gt_T, stamps, poses, 1, "f", max_dt)
        except ValueError:
            pass
    if len(stamps) >= 2 and stamps[-1] - stamps[0] >= 1.0 - max_dt:
        try:
            out["rpe_1s"] = rpe(gt_t, gt_T, stamps, poses, 1.0, "s", max_dt)
        except ValueError:
            pass
    if len(stamps) >= 3:
        try:
            out["ate"] = ate(gt_t, gt_T, stamps, poses, max_dt)
        except ValueError:
            pass
    return TrajectoryErrors(**out)


def score_masks(pred_dir, true_stamps, true_paths, max_dt: float = 0.02):
    """Pooled :func:`jaxvo.evaluation.metrics.mask_scores` of saved outlier masks against true moving masks,
    matched by timestamp; returns (MaskScores, number of matched frames)."""
    import cv2

    from jaxvo.evaluation.metrics import associate, mask_scores

    pred_dir = Path(pred_dir)
    if not pred_dir.is_dir():
        raise DatasetError(f"{pred_dir}: mask folder does not exist")
    ps, pp = read_mask_dir(pred_dir)
    if ps.size == 0:
        raise DatasetError(f"{pred_dir}: no <timestamp>.png mask files")
    ia, ib = associate(ps, true_stamps, max_dt)
    if ia.size == 0:
        raise DatasetError(f"{pred_dir}: no saved mask within {max_dt} s of a true mask's timestamp")
    tp = fp = fn = tn = 0
    for i, j in zip(ia, ib):
        pred, true = load_mask(pp[i]), load_mask(true_paths[j])
        if pred.shape != true.shape:
            pred = cv2.resize(pred.astype(np.uint8), true.shape[::-1], interpolation=cv2.INTER_NEAREST) > 0
        s = mask_scores(pred, true)
        tp, fp, fn, tn = tp + s.tp, fp + s.fp, fn + s.fn, tn + s.tn
    r = lambda a, b: a / b if b else float("nan")  # noqa: E731
    return MaskScores(r(tp, tp + fp), r(tp, tp + fn), r(tp, tp + fp + fn), r(tn, tn + fp + fn),
                      r(tp + tn, tp + fp + fn + tn), tp, fp, fn, tn), int(ia.size)


def load_groundtruth(path: Path, bonn: Optional[bool]):
    path = Path(path)
    if path.is_dir():
        gt_file = path / "groundtruth.txt"
        if not gt_file.is_file():
            raise DatasetError(f"{gt_file}: file not found (the sequence folder has no ground truth)")
        seq_dir = path
    elif path.exists():
        gt_file, seq_dir = path, None
    else:
        raise DatasetError(f"{path}: ground truth file or sequence folder does not exist")
    if bonn is None:
        bonn = is_bonn_sequence(path if path.is_dir() else path.parent)
    t, T = read_groundtruth(gt_file, bonn=bonn)
    return gt_file, seq_dir, (t, T)


@dataclasses.dataclass(frozen=True)
class Evaluation:
    """A trajectory scored against ground truth (:func:`evaluate`).

    protocol: how estimate poses were paired with ground truth (:data:`PROTOCOLS`).
    rpe: relative pose error over ``delta`` ``delta_unit`` (translation m, rotation deg; the
    drift per second or per frame in ``rpe.trans_drift`` / ``rpe.rot_drift``).
    ate: absolute trajectory error (m) after the least-squares rigid alignment.
    delta, delta_unit: the spacing the RPE was taken over ("s" or "f").
    gt: (stamps (M,) s, T_world_cam (M, 4, 4)) of the ground truth compared: as read for
    "nearest", interpolated at the covered estimate stamps for "interpolated".
    est: (stamps (N,) s, T_world_cam (N, 4, 4)) of the estimate.
    gt_file: the ground-truth file (None for ground truth given as arrays).
    masks: pooled outlier-mask scores (``masks_dir``), else None; mask_frames: frames matched.
    """
    protocol: str
    rpe: RPEResult
    ate: ATEResult
    delta: float
    delta_unit: str
    gt: Tuple[np.ndarray, np.ndarray]
    est: Tuple[np.ndarray, np.ndarray]
    gt_file: Optional[Path] = None
    masks: Optional[MaskScores] = None
    mask_frames: int = 0


def _groundtruth_of(groundtruth, bonn: Optional[bool]):
    """(gt_file or None, sequence folder or None, (stamps, T_world_cam)) of a path, a sequence
    object (its ``groundtruth``) or a (stamps, poses) pair."""
    if isinstance(groundtruth, (str, Path)):
        return load_groundtruth(Path(groundtruth), bonn)
    if hasattr(groundtruth, "groundtruth") and hasattr(groundtruth, "path"):
        gt = groundtruth.groundtruth
        if gt is None:
            raise DatasetError(f"{groundtruth.groundtruth_path}: file not found (the sequence folder has no "
                               f"ground truth)")
        return groundtruth.groundtruth_path, Path(groundtruth.path), gt
    t, T = groundtruth
    return None, None, (np.asarray(t, np.float64), np.asarray(T, np.float64))


def evaluate(groundtruth, estimate, delta: float = 1.0, delta_unit: str = "s", max_dt: float = 0.02,
             masks_dir=None, bonn: Optional[bool] = None, slack: Optional[float] = 0.1,
             short_frames: bool = False, protocol: str = "nearest") -> Evaluation:
    """Score a trajectory against ground truth: RPE over ``delta``, ATE, optionally mask scores.

    Args:
      groundtruth: a TUM ground-truth file, a sequence folder (its groundtruth.txt; Bonn marker
        poses converted to camera poses, see ``bonn``), a sequence object (its ``groundtruth``)
        or a pair (stamps (M,) s, T_world_cam (M, 4, 4)).
      estimate: a TUM trajectory file or a pair (stamps (N,) s, T_world_cam (N, 4, 4)).
      delta, delta_unit: RPE pair spacing, seconds ("s") or frames ("f").
      max_dt: "nearest": the largest estimate/ground-truth stamp difference paired (s);
        "interpolated": how far outside the ground truth's span an estimate stamp still gets
        the end pose (s).
      masks_dir: folder of outlier masks (``jaxvo run --save-masks``) to score against the
        sequence's true moving-pixel masks (needs a sequence folder or object as groundtruth).
      slack: an estimate pose more than ``max(max_dt, slack)`` s outside the ground truth's
        span raises DatasetError (a wrong ground-truth file); None skips the check.
      short_frames: an estimate that spans less than ``delta`` seconds is measured over 1 frame
        instead (as ``jaxvo run`` does: a 14-frame excerpt has no pair 1 s apart), not refused.
      protocol: "nearest" or "interpolated" (:data:`PROTOCOLS`).

    Raises DatasetError / ValueError naming the file on bad input, and when fewer than 2
    estimate poses have ground truth.
    """
    from jaxvo.data.trajectory import read_tum_trajectory
    from jaxvo.evaluation.metrics import ate, rpe

    if protocol not in PROTOCOLS:
        raise ValueError(f"protocol must be one of {', '.join(PROTOCOLS)}, got {protocol!r}")
    gt_file, seq_dir, gt = _groundtruth_of(groundtruth, bonn)
    gt_label = gt_file if gt_file is not None else "ground truth"
    if isinstance(estimate, (str, Path)):
        est_label = est_path = Path(estimate)
        if est_path.is_dir():
            raise DatasetError(f"{est_path}: is a folder, expected a trajectory file")
        es, eP = read_tum_trajectory(est_path)
    else:
        est_label = "estimate"
        es, eP = (np.asarray(a, np.float64) for a in estimate)
    gs = gt[0]
    if slack is not None:
        sl = max(max_dt, slack)
        outside = int(np.sum((es < gs[0] - sl) | (es > gs[-1] + sl)))
        if outside:
            raise DatasetError(f"{gt_label}: ground truth ({gs[0]:.6f} .. {gs[-1]:.6f}) does not cover the "
                               f"estimate {est_label} ({es[0]:.6f} .. {es[-1]:.6f}): {outside} of {es.size} "
                               f"poses are more than {sl:g} s outside it")
    if protocol == "interpolated":
        covered = (es >= gs[0] - max_dt) & (es <= gs[-1] + max_dt)
        if covered.sum() < 2:
            raise DatasetError(f"{gt_label}: ground truth covers {int(covered.sum())} of the {es.size} poses of "
                               f"{est_label}, need at least 2")
        gt = (es[covered], interpolate_poses(gt[0], gt[1], es[covered], tol=max_dt))
    if short_frames and delta_unit == "s" and es.size > 1 and es[-1] - es[0] < delta:
        delta, delta_unit = 1.0, "f"
    try:
        r = rpe(gt[0], gt[1], es, eP, delta, delta_unit, max_dt)
    except ValueError as e:
        hint = " (the estimate is shorter than the delta: try --delta-unit f)" if delta_unit == "s" else ""
        raise ValueError(f"{est_label}: {e}{hint}") from None
    try:
        a = ate(gt[0], gt[1], es, eP, max_dt)
    except ValueError as e:
        raise ValueError(f"{est_label}: {e}") from None
    masks = None
    n_masks = 0
    if masks_dir is not None:
        tm = true_masks(seq_dir) if seq_dir is not None else None
        if tm is None:
            if seq_dir is None:
                raise DatasetError(f"{gt_label}: --masks-dir needs the sequence folder as GROUNDTRUTH (its masks/ "
                                   f"hold the true moving pixels), not a ground-truth file")
            raise DatasetError(f"{seq_dir}: no true moving-pixel masks (masks.txt / masks/) to score --masks-dir "
                               f"against (jaxvo synth and jaxvo augment write them)")
        masks, n_masks = score_masks(masks_dir, tm[0], tm[1], max_dt)
    return Evaluation(protocol, r, a, delta, delta_unit, gt, (es, eP), gt_file, masks, n_masks)
