"""Trajectory and mask metrics as the TUM RGB-D benchmark defines them.

* :func:`rpe` — relative pose error with a fixed delta (TUM ``evaluate_rpe.py
  --fixed_delta``): for each estimate frame i and the frame j that lies ``delta``
  later (seconds or frames),
  ``E_ij = inv(inv(Q_i) Q_j) @ inv(P_i) P_j`` with Q ground truth and P the
  estimate (T_world_cam); translational error ``|trans(E_ij)|`` (m), rotational
  error ``angle(E_ij)`` (deg).
* :func:`ate` — absolute trajectory error (TUM ``evaluate_ate.py``): positions
  associated by timestamp, the estimate aligned to the ground truth by the
  least-squares rigid transform (Horn / Umeyama, rotation + translation, no
  scale), error = distance between aligned estimate and ground-truth positions (m).
* :func:`mask_scores` — precision / recall / IoU of a predicted outlier (moving)
  mask against the true moving-pixel mask.

Poses are (N, 4, 4) float64 T_world_cam, timestamps (N,) float64 seconds.
Result objects are small dataclasses with ``to_dict()`` (JSON-ready, NaN -> None).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from jaxvo import geometry
from jaxvo.data.stamps import associate as _associate

__all__ = ["Stats", "RPEResult", "ATEResult", "MaskScores", "associate", "rpe", "ate",
           "align_umeyama", "mask_scores", "summarize"]


def _clean(x):
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


@dataclasses.dataclass(frozen=True)
class Stats:
    """Summary of a set of errors (units of the errors): rmse, mean, median, std, min, max, n."""
    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    n: int

    def to_dict(self) -> dict:
        return {k: _clean(v) for k, v in dataclasses.asdict(self).items()}


def summarize(errors) -> Stats:
    """Stats of a 1-D array of errors (NaN everywhere when it is empty)."""
    e = np.asarray(errors, dtype=np.float64).reshape(-1)
    if e.size == 0:
        nan = float("nan")
        return Stats(nan, nan, nan, nan, nan, nan, 0)
    return Stats(rmse=float(np.sqrt(np.mean(e * e))), mean=float(np.mean(e)), median=float(np.median(e)),
                 std=float(np.std(e)), min=float(np.min(e)), max=float(np.max(e)), n=int(e.size))


def associate(stamps_a, stamps_b, max_dt: float = 0.02):
    """One-to-one timestamp association (TUM associate.py): index arrays ``(ia, ib)``,
    ``|stamps_a[ia] - stamps_b[ib]| <= max_dt``, greedy nearest-first, sorted by ``stamps_a[ia]``."""
    return _associate(stamps_a, stamps_b, max_dt)


def _check_traj(stamps, poses, what):
    s = np.asarray(stamps, dtype=np.float64).reshape(-1)
    P = np.asarray(poses, dtype=np.float64)
    if P.shape != (s.size, 4, 4):
        raise ValueError(f"{what}: need (N,) stamps and (N, 4, 4) poses, got {s.shape} and {P.shape}")
    if not np.all(np.isfinite(P)):
        raise ValueError(f"{what}: poses contain NaN or inf")
    if not np.all(np.isfinite(s)):
        raise ValueError(f"{what}: stamps contain NaN or inf")
    order = np.argsort(s, kind="stable")
    return s[order], P[order]


# ----------------------------------------------------------------------------- RPE

@dataclasses.dataclass(frozen=True)
class RPEResult:
    """Relative pose error over pairs (i, j) of estimate frames ``delta`` apart.

    Per pair (P,) arrays: ``i``, ``j`` (indices into the time-sorted estimate),
    ``stamps_i``, ``stamps_j`` (estimate timestamps, s), ``dt`` (= stamps_j - stamps_i, s),
    ``trans`` (translational error of the pair, m), ``rot`` (rotational error, deg).

    ``trans_stats`` / ``rot_stats``: Stats of ``trans`` (m) and ``rot`` (deg), i.e. error per
    delta, exactly what TUM evaluate_rpe.py reports.
    ``trans_drift`` / ``rot_drift``: the same errors divided by the nominal delta: per
    second (m/s, deg/s) for ``delta_unit="s"``, per frame (m/frame, deg/frame) for "f".
    With delta = 1 s they equal ``trans_stats`` / ``rot_stats`` (the paper's Table I
    drift in m/s and deg/s). ``drift_unit`` names the unit ("s" or "frame").
    """
    delta: float
    delta_unit: str
    i: np.ndarray
    j: np.ndarray
    stamps_i: np.ndarray
    stamps_j: np.ndarray
    dt: np.ndarray
    trans: np.ndarray
    rot: np.ndarray
    trans_stats: Stats
    rot_stats: Stats
    trans_drift: Stats
    rot_drift: Stats

    @property
    def n(self) -> int:
        return int(self.trans.size)

    @property
    def drift_unit(self) -> str:
        return "s" if self.delta_unit == "s" else "frame"

    def to_dict(self, per_pair: bool = False) -> dict:
        d = {
            "delta": self.delta, "delta_unit": self.delta_unit, "pairs": self.n,
            "trans_m": self.trans_stats.to_dict(), "rot_deg": self.rot_stats.to_dict(),
            f"trans_m_per_{self.drift_unit}": self.trans_drift.to_dict(),
            f"rot_deg_per_{self.drift_unit}": self.rot_drift.to_dict(),
        }
        if per_pair:
            d["per_pair"] = {"stamp_i": self.stamps_i.tolist(), "stamp_j": self.stamps_j.tolist(),
                             "trans_m": self.trans.tolist(), "rot_deg": self.rot.tolist()}
        return d


def _relative_errors(Q_i, Q_j, P_i, P_j):
    """Translational (m) and rotational (deg) parts of inv(inv(Q_i) Q_j) @ (inv(P_i) P_j)."""
    dQ = geometry.inverse(Q_i) @ Q_j
    dP = geometry.inverse(P_i) @ P_j
    E = geometry.inverse(dQ) @ dP
    trans = np.linalg.norm(E[..., :3, 3], axis=-1)
    rot = np.degrees(geometry.rotation_angle(E[..., :3, :3]))
    return trans, rot


def rpe(gt_stamps, gt_poses, est_stamps, est_poses, delta: float = 1.0, delta_unit: str = "s",
        max_dt: float = 0.02) -> RPEResult:
    """Relative pose error with a fixed delta (TUM evaluate_rpe.py ``--fixed_delta``).

    Args:
      gt_stamps, gt_poses: ground truth, (M,) s and (M, 4, 4) T_world_cam.
      est_stamps, est_poses: estimate, (N,) s and (N, 4, 4) T_world_cam.
      delta: pair spacing; seconds for ``delta_unit="s"``, frames (integer) for "f".
      max_dt: each estimate frame is matched to a ground-truth pose by one-to-one nearest
        timestamp within ``max_dt`` s (:func:`associate`); frames without a match are skipped.

    Pairs: for every estimate frame i (time-sorted), "s": j is the estimate frame whose
    timestamp is closest to ``t_i + delta`` (pairs whose target ``t_i + delta`` lies more
    than ``max_dt`` beyond the last estimate frame are dropped); "f": ``j = i + delta``.
    A pair is used when both i and j have ground truth and j > i. (TUM's script also drops
    every pair whose j is the last frame; this keeps those.) Error per pair:
    ``E = inv(inv(Q_i) Q_j) @ (inv(P_i) P_j)``, trans = |t(E)| in m, rot = angle(E) in deg.

    Raises ValueError if no pair can be formed.
    """
    if delta_unit not in ("s", "f"):
        raise ValueError(f"delta_unit must be 's' (seconds) or 'f' (frames), got {delta_unit!r}")
    if not delta > 0:
        raise ValueError(f"delta must be > 0, got {delta}")
    gs, gP = _check_traj(gt_stamps, gt_poses, "ground truth")
    es, eP = _check_traj(est_stamps, est_poses, "estimate")
    ie, ig = _associate(es, gs, max_dt)
    gt_of = np.full(es.size, -1, dtype=np.int64)
    gt_of[ie] = ig
    idx = np.arange(es.size)
    if delta_unit == "f":
        if float(delta) != int(delta):
            raise ValueError(f"delta in frames must be an integer, got {delta}")
        j = idx + int(delta)
        ok = j < es.size
    else:
        target = es + float(delta)
        k = np.searchsorted(es, target)
        lo = np.clip(k - 1, 0, es.size - 1)
        hi = np.clip(k, 0, es.size - 1)
        j = np.where(np.abs(es[hi] - target) < np.abs(es[lo] - target), hi, lo)
        ok = target <= es[-1] + max_dt
    i = idx[ok]
    j = j[ok]
    keep = (j > i) & (gt_of[i] >= 0) & (gt_of[np.clip(j, 0, es.size - 1)] >= 0)
    i, j = i[keep], j[keep]
    if i.size == 0:
        raise ValueError(f"rpe: no pair of estimate frames {delta} {delta_unit} apart with ground truth "
                         f"within {max_dt} s (estimate {es[0]:.3f} .. {es[-1]:.3f}, "
                         f"ground truth {gs[0]:.3f} .. {gs[-1]:.3f}, {ie.size} frames matched)")
    trans, rot = _relative_errors(gP[gt_of[i]], gP[gt_of[j]], eP[i], eP[j])
    d = float(delta)
    return RPEResult(delta=d, delta_unit=delta_unit, i=i, j=j, stamps_i=es[i], stamps_j=es[j],
                     dt=es[j] - es[i], trans=trans, rot=rot,
                     trans_stats=summarize(trans), rot_stats=summarize(rot),
                     trans_drift=summarize(trans / d), rot_drift=summarize(rot / d))


# ----------------------------------------------------------------------------- ATE

@dataclasses.dataclass(frozen=True)
class ATEResult:
    """Absolute trajectory error after rigid alignment.

    ``stats``: Stats of ``errors`` (m). ``errors`` (M,): distance between aligned estimate and
    ground-truth positions of the M associated frames; ``stamps`` (M,) their estimate
    timestamps; ``gt_index`` / ``est_index`` (M,) the association. ``T_gt_est`` (4, 4):
    the alignment (maps estimate world into ground-truth world). ``aligned`` (N, 4, 4):
    the whole (time-sorted) estimate mapped by ``T_gt_est`` (T_world_cam in gt world);
    ``est_stamps`` (N,) its timestamps. ``scale``: the scale s of the least-squares similarity
    alignment of the same positions (gt ~ s R est + t, Umeyama; reported, not applied): 1 for a
    metric trajectory; an RGB-D trajectory whose depth reads a factor k too far comes out about
    k times too long (s about 1 / k); NaN where the ground truth's positions spread less than
    ``SCALE_MIN_SPREAD`` (a camera that stays put has no length to scale).
    """
    stats: Stats
    errors: np.ndarray
    stamps: np.ndarray
    gt_index: np.ndarray
    est_index: np.ndarray
    T_gt_est: np.ndarray
    aligned: np.ndarray
    est_stamps: np.ndarray
    scale: float

    @property
    def rmse(self) -> float:
        return self.stats.rmse

    def to_dict(self, per_frame: bool = False) -> dict:
        d = {"trans_m": self.stats.to_dict(), "pairs": self.stats.n,
             "T_gt_est": self.T_gt_est.tolist(), "scale": _clean(self.scale)}
        if per_frame:
            d["per_frame"] = {"stamp": self.stamps.tolist(), "trans_m": self.errors.tolist()}
        return d


def align_umeyama(src, dst, with_scale: bool = False):
    """Least-squares similarity / rigid transform with ``dst ~= s R src + t`` (Horn / Umeyama).

    src, dst: (M, 3) points, M >= 1 (M >= 3 non-collinear for a unique rotation).
    Returns (R (3, 3), t (3,), s float); s = 1 unless ``with_scale``.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    C = xd.T @ xs / src.shape[0]
    U, D, Vt = np.linalg.svd(C)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = 1.0
    if with_scale:
        var = np.mean(np.sum(xs * xs, 1))
        s = float(np.trace(np.diag(D) @ S) / var) if var > 0 else 1.0
    t = mu_d - s * R @ mu_s
    return R, t, s


#: The RMS distance (m) of the associated ground-truth positions from their mean under which
#: :class:`ATEResult`'s similarity scale is undefined (NaN): with the camera in one place, the
#: fitted scale is the ratio of two noise levels, not a length.
SCALE_MIN_SPREAD = 1e-3


def ate(gt_stamps, gt_poses, est_stamps, est_poses, max_dt: float = 0.02) -> ATEResult:
    """Absolute trajectory error (TUM evaluate_ate.py): associate by timestamp (one-to-one,
    within ``max_dt`` s), align estimate positions to ground truth with the least-squares
    rigid transform (no scale), report translational errors in metres.

    Raises ValueError with fewer than 2 associated frames.
    """
    gs, gP = _check_traj(gt_stamps, gt_poses, "ground truth")
    es, eP = _check_traj(est_stamps, est_poses, "estimate")
    ie, ig = _associate(es, gs, max_dt)
    if ie.size < 2:
        raise ValueError(f"ate: only {ie.size} estimate frame(s) have ground truth within {max_dt} s "
                         f"(estimate {es[0]:.3f} .. {es[-1]:.3f}, ground truth {gs[0]:.3f} .. {gs[-1]:.3f})")
    R, t, _ = align_umeyama(eP[ie, :3, 3], gP[ig, :3, 3])
    g = gP[ig, :3, 3]
    spread = float(np.sqrt(np.mean(np.sum((g - g.mean(0)) ** 2, 1))))
    scale = align_umeyama(eP[ie, :3, 3], g, with_scale=True)[2] if spread >= SCALE_MIN_SPREAD else float("nan")
    A = np.eye(4)
    A[:3, :3], A[:3, 3] = R, t
    aligned = A @ eP
    err = np.linalg.norm(aligned[ie, :3, 3] - gP[ig, :3, 3], axis=-1)
    return ATEResult(stats=summarize(err), errors=err, stamps=es[ie], gt_index=ig, est_index=ie,
                     T_gt_est=A, aligned=aligned, est_stamps=es, scale=scale)


# ----------------------------------------------------------------------------- masks

@dataclasses.dataclass(frozen=True)
class MaskScores:
    """Pixel classification scores of a predicted outlier mask vs the true moving mask.

    ``precision`` = TP / (TP + FP), ``recall`` = TP / (TP + FN), ``iou_outlier`` =
    TP / (TP + FP + FN), ``iou_inlier`` = TN / (TN + FN + FP) (the static class),
    ``accuracy`` = (TP + TN) / n; the outlier / moving class is the positive one.
    A ratio with a zero denominator is NaN (``to_dict`` gives None).
    """
    precision: float
    recall: float
    iou_outlier: float
    iou_inlier: float
    accuracy: float
    tp: int
    fp: int
    fn: int
    tn: int

    @property
    def n(self) -> int:
        return self.tp + self.fp + self.fn + self.tn

    def to_dict(self) -> dict:
        return {k: _clean(v) for k, v in dataclasses.asdict(self).items()}


def _ratio(a, b) -> float:
    return float(a) / float(b) if b > 0 else float("nan")


def mask_scores(pred_outlier_mask, true_moving_mask, valid=None) -> MaskScores:
    """Scores of ``pred_outlier_mask`` (True = predicted outlier) against ``true_moving_mask``
    (True = pixel on a moving object), over pixels where ``valid`` is True (default all).

    Masks are boolean (or 0/1) arrays of the same shape, any shape (e.g. (H, W) or a batch
    (N, H, W): the counts are pooled over all pixels).
    """
    p = np.asarray(pred_outlier_mask).astype(bool)
    g = np.asarray(true_moving_mask).astype(bool)
    if p.shape != g.shape:
        raise ValueError(f"mask shapes differ: predicted {p.shape}, true {g.shape}")
    v = np.ones(p.shape, bool) if valid is None else np.asarray(valid).astype(bool)
    if v.shape != p.shape:
        raise ValueError(f"valid mask shape {v.shape} differs from the masks' {p.shape}")
    tp = int(np.sum(p & g & v))
    fp = int(np.sum(p & ~g & v))
    fn = int(np.sum(~p & g & v))
    tn = int(np.sum(~p & ~g & v))
    return MaskScores(precision=_ratio(tp, tp + fp), recall=_ratio(tp, tp + fn),
                      iou_outlier=_ratio(tp, tp + fp + fn), iou_inlier=_ratio(tn, tn + fp + fn),
                      accuracy=_ratio(tp + tn, tp + fp + fn + tn), tp=tp, fp=fp, fn=fn, tn=tn)
