"""Evaluate trajectories and outlier masks: the library side of ``jaxvo eval``.

:func:`evaluate` compares a trajectory file with a ground-truth file or
sequence folder (RPE, ATE, optionally outlier-mask scores);
:func:`trajectory_errors` gives the summary errors of an in-memory trajectory;
:func:`score_masks` pools mask scores of saved outlier masks against true
moving-pixel masks. Poses are T_world_cam, timestamps seconds, errors in metres
and degrees (see :mod:`jaxvo.evaluation.metrics`).
"""
from __future__ import annotations

from pathlib import Path
from typing import Dict, Optional

import numpy as np

from jaxvo.data.errors import DatasetError
from jaxvo.data.groundtruth import is_bonn_sequence, read_groundtruth
from jaxvo.data.masks import load_mask, read_mask_dir, true_masks

__all__ = ["evaluate", "trajectory_errors", "score_masks", "true_masks", "load_mask", "read_mask_dir",
           "load_groundtruth"]


def trajectory_errors(gt, stamps, poses, max_dt=0.02) -> Dict[str, object]:
    """RPE (1 frame, and 1 s where the run is long enough) and ATE of a trajectory; skips what cannot be formed."""
    from jaxvo.evaluation.metrics import ate, rpe

    gt_t, gt_T = gt
    out: Dict[str, object] = {}
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
    return out



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
    from jaxvo.evaluation.metrics import MaskScores
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


def evaluate(groundtruth, estimate, delta: float = 1.0, delta_unit: str = "s", max_dt: float = 0.02,
             masks_dir=None, bonn: Optional[bool] = None, slack: float = 0.1, short_frames: bool = False) -> dict:
    """The numbers of ``jaxvo eval`` as a dict: ``rpe`` (RPEResult), ``ate`` (ATEResult),
    ``masks`` (MaskScores or None), ``gt`` / ``est`` ((stamps, poses)), ``gt_file``, and
    ``delta`` / ``delta_unit``: the spacing the RPE was taken over.

    short_frames: an estimate that spans less than ``delta`` seconds is measured over 1 frame
    instead (as ``jaxvo run`` does: a 14-frame excerpt has no pair 1 s apart), not refused.

    Raises DatasetError when the ground truth does not cover the estimate: an estimate pose
    more than ``max(max_dt, slack)`` s outside the ground truth's time span.
    """
    from jaxvo.evaluation.metrics import ate, rpe
    from jaxvo.data.trajectory import read_tum_trajectory

    gt_file, seq_dir, gt = load_groundtruth(Path(groundtruth), bonn)
    est_path = Path(estimate)
    if est_path.is_dir():
        raise DatasetError(f"{est_path}: is a folder, expected a trajectory file")
    es, eP = read_tum_trajectory(est_path)
    gs = gt[0]
    sl = max(max_dt, slack)
    outside = int(np.sum((es < gs[0] - sl) | (es > gs[-1] + sl)))
    if outside:
        raise DatasetError(f"{gt_file}: ground truth ({gs[0]:.6f} .. {gs[-1]:.6f}) does not cover the estimate "
                           f"{est_path} ({es[0]:.6f} .. {es[-1]:.6f}): {outside} of {es.size} poses are more "
                           f"than {sl:g} s outside it")
    if short_frames and delta_unit == "s" and es.size > 1 and es[-1] - es[0] < delta:
        delta, delta_unit = 1.0, "f"
    try:
        r = rpe(gt[0], gt[1], es, eP, delta, delta_unit, max_dt)
    except ValueError as e:
        hint = " (the estimate is shorter than the delta: try --delta-unit f)" if delta_unit == "s" else ""
        raise ValueError(f"{est_path}: {e}{hint}") from None
    try:
        a = ate(gt[0], gt[1], es, eP, max_dt)
    except ValueError as e:
        raise ValueError(f"{est_path}: {e}") from None
    masks = None
    n_masks = 0
    if masks_dir is not None:
        tm = true_masks(seq_dir) if seq_dir is not None else None
        if tm is None:
            if seq_dir is None:
                raise DatasetError(f"{gt_file}: --masks-dir needs the sequence folder as GROUNDTRUTH (its masks/ "
                                   f"hold the true moving pixels), not a ground-truth file")
            raise DatasetError(f"{seq_dir}: no true moving-pixel masks (masks.txt / masks/) to score --masks-dir "
                               f"against (jaxvo synth and jaxvo augment write them)")
        masks, n_masks = score_masks(masks_dir, tm[0], tm[1], max_dt)
    return {"rpe": r, "ate": a, "masks": masks, "mask_frames": n_masks, "gt": gt, "est": (es, eP),
            "gt_file": gt_file, "delta": delta, "delta_unit": delta_unit}
