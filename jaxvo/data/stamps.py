"""Matching in time: one-to-one timestamp association (as TUM's ``associate.py``) and poses
interpolated at query timestamps.

Timestamps are float64 seconds; poses are (N, 4, 4) float64 ``T_world_cam``.
"""
from __future__ import annotations

from typing import Optional, Tuple

import numpy as np

from jaxvo import geometry
from jaxvo.data.errors import DatasetError

__all__ = ["associate", "interpolate_poses"]


def associate(stamps_a, stamps_b, max_dt: float = 0.02) -> Tuple[np.ndarray, np.ndarray]:
    """One-to-one association of two timestamp lists, as TUM's ``associate.py``.

    All candidate pairs with ``|a - b| <= max_dt`` are taken greedily in order of increasing
    ``|a - b|``, each stamp used at most once. Returns index arrays ``(ia, ib)`` (int64,
    same length M, possibly 0), sorted by ``stamps_a[ia]``. Inputs need not be sorted.
    """
    a = np.asarray(stamps_a, dtype=np.float64).reshape(-1)
    b = np.asarray(stamps_b, dtype=np.float64).reshape(-1)
    if a.size == 0 or b.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    ob = np.argsort(b, kind="stable")
    bs = b[ob]
    lo = np.searchsorted(bs, a - max_dt, side="left")
    hi = np.searchsorted(bs, a + max_dt, side="right")
    counts = hi - lo
    ia = np.repeat(np.arange(a.size), counts)
    if ia.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    offs = np.arange(ia.size) - np.repeat(np.cumsum(counts) - counts, counts)
    jb = ob[np.repeat(lo, counts) + offs]
    diff = np.abs(a[ia] - b[jb])
    ok = diff <= max_dt
    ia, jb, diff = ia[ok], jb[ok], diff[ok]
    order = np.lexsort((jb, ia, diff))
    used_a = np.zeros(a.size, bool)
    used_b = np.zeros(b.size, bool)
    out_a, out_b = [], []
    for k in order:
        i, j = ia[k], jb[k]
        if not used_a[i] and not used_b[j]:
            used_a[i] = used_b[j] = True
            out_a.append(i)
            out_b.append(j)
    out_a = np.asarray(out_a, dtype=np.int64)
    out_b = np.asarray(out_b, dtype=np.int64)
    s = np.argsort(a[out_a], kind="stable")
    return out_a[s], out_b[s]



def interpolate_poses(stamps, T_world_cam, query_stamps, tol: float = 1e-6,
                      max_gap: Optional[float] = None) -> np.ndarray:
    """Poses at ``query_stamps`` by interpolation: linear in translation, slerp in rotation.

    Args:
      stamps: (N,) float64 seconds, strictly increasing, N >= 1.
      T_world_cam: (N, 4, 4) poses at ``stamps``.
      query_stamps: (M,) seconds.
      tol: queries up to ``tol`` seconds outside ``[stamps[0], stamps[-1]]`` get the end pose.
      max_gap: if given, a query whose two bracketing poses are more than ``max_gap`` s
        apart raises (e.g. a motion-capture dropout).

    Returns (M, 4, 4) float64 T_world_cam. Raises DatasetError (a ValueError) when a
    query lies outside the covered span.
    """
    t = np.asarray(stamps, dtype=np.float64).reshape(-1)
    T = np.asarray(T_world_cam, dtype=np.float64)
    q = np.asarray(query_stamps, dtype=np.float64).reshape(-1)
    if T.shape != (t.size, 4, 4) or t.size == 0:
        raise ValueError(f"interpolate_poses: need (N,) stamps and (N, 4, 4) poses with N >= 1, "
                         f"got {t.shape} and {T.shape}")
    if t.size > 1 and not np.all(np.diff(t) > 0):
        raise ValueError("interpolate_poses: stamps must be strictly increasing")
    out_lo, out_hi = q < t[0] - tol, q > t[-1] + tol
    if np.any(out_lo | out_hi):
        bad = q[out_lo | out_hi]
        raise DatasetError(f"interpolate_poses: {bad.size} query time(s) outside the covered span "
                           f"{t[0]:.6f} .. {t[-1]:.6f} (first: {bad[0]:.6f})")
    qc = np.clip(q, t[0], t[-1])
    if t.size == 1:
        return np.repeat(T, q.size, axis=0)
    i1 = np.clip(np.searchsorted(t, qc, side="right"), 1, t.size - 1)
    i0 = i1 - 1
    if max_gap is not None:
        gap = t[i1] - t[i0]
        exact = (qc == t[i0]) | (qc == t[i1])
        if np.any((gap > max_gap) & ~exact):
            k = int(np.nonzero((gap > max_gap) & ~exact)[0][0])
            raise DatasetError(f"interpolate_poses: query {q[k]:.6f} falls in a {gap[k]:.3f} s gap "
                               f"(more than max_gap {max_gap} s)")
    a = (qc - t[i0]) / (t[i1] - t[i0])
    R0, R1 = T[i0, :3, :3], T[i1, :3, :3]
    w = geometry.log_so3(np.swapaxes(R0, -1, -2) @ R1)
    R = R0 @ geometry.exp_so3(a[:, None] * w)
    out = np.zeros((q.size, 4, 4))
    out[:, :3, :3] = R
    out[:, :3, 3] = (1 - a)[:, None] * T[i0, :3, 3] + a[:, None] * T[i1, :3, 3]
    out[:, 3, 3] = 1.0
    return out
