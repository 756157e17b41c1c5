"""Tests for jaxvo.evaluation.metrics with hand-computable answers."""
from __future__ import annotations

import json

import numpy as np
import pytest

from jaxvo import geometry as G
from jaxvo.evaluation.metrics import align_umeyama, associate, ate, mask_scores, rpe, summarize


def straight(n, step, dt=0.1, t0=0.0):
    """n poses moving ``step`` m per frame along world x, identity rotation; stamps t0 + k*dt."""
    P = np.tile(np.eye(4), (n, 1, 1))
    P[:, 0, 3] = step * np.arange(n)
    return t0 + dt * np.arange(n), P


def test_summarize():
    s = summarize([3.0, 4.0])
    assert s.rmse == pytest.approx(np.sqrt(12.5)) and s.mean == 3.5 and s.median == 3.5
    assert s.min == 3.0 and s.max == 4.0 and s.n == 2 and s.std == pytest.approx(0.5)
    assert summarize([]).to_dict()["rmse"] is None


def test_associate():
    ia, ib = associate([0.0, 1.0, 2.0], [1.005, 2.5, 0.019], 0.02)
    assert ia.tolist() == [0, 1] and ib.tolist() == [2, 0]


def test_rpe_constant_drift_seconds_and_frames():
    # gt moves 1 cm per frame, estimate 1.1 cm per frame, 10 frames per second
    tg, G_ = straight(51, 0.010)
    te, E = straight(51, 0.011)
    r = rpe(tg, G_, te, E, delta=1.0, delta_unit="s")
    # pairs (i, i+10) for i = 0..40: error 10 * 1 mm = 1 cm, no rotation
    assert r.n == 41 and np.all(r.j - r.i == 10)
    assert np.allclose(r.trans, 0.01) and np.allclose(r.rot, 0.0, atol=1e-6)
    assert r.trans_stats.rmse == pytest.approx(0.01) and r.trans_stats.max == pytest.approx(0.01)
    assert r.trans_drift.rmse == pytest.approx(0.01)  # m/s with delta = 1 s
    assert np.allclose(r.dt, 1.0)
    r2 = rpe(tg, G_, te, E, delta=2.0, delta_unit="s")
    assert r2.n == 31 and r2.trans_stats.mean == pytest.approx(0.02)
    assert r2.trans_drift.mean == pytest.approx(0.01)  # still 1 cm/s
    rf = rpe(tg, G_, te, E, delta=1, delta_unit="f")
    assert rf.n == 50 and np.allclose(rf.trans, 0.001)
    assert rf.trans_drift.mean == pytest.approx(0.001)  # m per frame
    rf10 = rpe(tg, G_, te, E, delta=10, delta_unit="f")
    assert np.array_equal(rf10.i, r.i) and np.allclose(rf10.trans, r.trans)
    d = json.loads(json.dumps(r.to_dict()))
    assert d["pairs"] == 41 and d["trans_m_per_s"]["rmse"] == pytest.approx(0.01)


def test_rpe_pure_rotation():
    # gt rotates 1 deg per frame about the camera y axis; estimate 1.2 deg per frame; no translation
    n = 21
    t = np.arange(n) * 0.1
    Gt = np.tile(np.eye(4), (n, 1, 1))
    Es = np.tile(np.eye(4), (n, 1, 1))
    Gt[:, :3, :3] = G.exp_so3(np.radians(1.0) * np.arange(n)[:, None] * [0, 1, 0])
    Es[:, :3, :3] = G.exp_so3(np.radians(1.2) * np.arange(n)[:, None] * [0, 1, 0])
    r = rpe(t, Gt, t, Es, delta=1.0, delta_unit="s")
    assert r.n == 11
    assert np.allclose(r.rot, 2.0) and np.allclose(r.trans, 0.0, atol=1e-12)
    assert r.rot_drift.mean == pytest.approx(2.0)  # deg/s
    r1 = rpe(t, Gt, t, Es, delta=1, delta_unit="f")
    assert np.allclose(r1.rot, 0.2)


def test_rpe_invariant_to_world_frame_and_uses_time_association():
    tg, Gt = straight(200, 0.001, dt=0.01)            # gt at 100 Hz
    te, E = straight(60, 0.0033, dt=1 / 30, t0=0.0)    # estimate at 30 Hz, ~ the same motion
    W = G.exp(np.array([0.3, -1.0, 0.2, 5.0, 1.0, -2.0]))
    r1 = rpe(tg, Gt, te, E, delta=1.0)
    r2 = rpe(tg, Gt, te, W @ E, delta=1.0)
    assert np.allclose(r1.trans, r2.trans, atol=1e-9)
    # estimate frame k at k/30 s matched to gt at round(k*100/30)/100 s (within 0.02 s)
    assert r1.n > 0 and r1.trans_stats.max < 0.01


def test_rpe_errors():
    t, P = straight(5, 0.01)
    with pytest.raises(ValueError, match="no pair"):
        rpe(t, P, t + 100.0, P, delta=1.0)
    with pytest.raises(ValueError, match="delta_unit"):
        rpe(t, P, t, P, delta_unit="m")
    with pytest.raises(ValueError, match="no pair"):
        rpe(t, P, t, P, delta=10.0)  # sequence shorter than the delta
    bad = t.copy()
    bad[2] = np.nan                  # not matched to nothing in silence
    with pytest.raises(ValueError, match="estimate: stamps contain NaN or inf"):
        ate(t, P, bad, P)
    with pytest.raises(ValueError, match="ground truth: stamps contain NaN or inf"):
        rpe(bad, P, t, P, delta=1, delta_unit="f")


def test_ate_zero_for_rigidly_moved_copy():
    rng = np.random.default_rng(0)
    rel = G.exp(rng.normal(size=(30, 6)) * 0.05)
    Gt = np.empty((31, 4, 4))
    Gt[0] = np.eye(4)
    for k in range(30):
        Gt[k + 1] = Gt[k] @ rel[k]
    t = np.arange(31) / 30.0
    A = G.exp(np.array([0.4, -0.7, 1.1, 2.0, -3.0, 0.5]))
    Est = A @ Gt
    r = ate(t, Gt, t + 0.005, Est)
    assert r.stats.rmse < 1e-9 and r.stats.n == 31
    assert np.allclose(r.T_gt_est, G.inverse(A), atol=1e-9)
    assert np.allclose(r.aligned, Gt, atol=1e-9)
    assert json.loads(json.dumps(r.to_dict()))["trans_m"]["n"] == 31
    assert r.scale == pytest.approx(1.0, abs=1e-9)


def test_ate_scale_of_a_trajectory_too_long_by_a_factor():
    """An estimate whose translations are all 1.05 times the truth (as from depth read 5 % too far),
    in another world frame: the similarity scale is 1 / 1.05; the rigid ATE is not zero."""
    rng = np.random.default_rng(1)
    Gt = np.tile(np.eye(4), (40, 1, 1))
    for k in range(1, 40):
        Gt[k] = Gt[k - 1] @ G.exp(rng.normal(size=6) * 0.05)
    Est = G.exp(np.array([0.3, -0.2, 0.9, 1.0, 2.0, -0.5])) @ Gt
    Est[:, :3, 3] *= 1.05
    r = ate(np.arange(40.0), Gt, np.arange(40.0), Est)
    assert r.scale == pytest.approx(1 / 1.05, rel=1e-9)
    assert r.stats.rmse > 1e-3 and json.loads(json.dumps(r.to_dict()))["scale"] == pytest.approx(1 / 1.05)


def test_ate_scale_is_undefined_where_the_ground_truth_stays_put():
    """A camera that turns in place (ground-truth positions within 0.1 mm): the similarity scale
    would be the ratio of two noise levels, so it is NaN (None in JSON); a camera that moves
    2 mm RMS gets its scale."""
    rng = np.random.default_rng(2)
    Gt = np.stack([G.exp(np.r_[rng.normal(size=3) * 0.1, rng.normal(size=3) * 1e-4]) for _ in range(30)])
    Est = Gt.copy()
    Est[:, :3, 3] += rng.normal(size=(30, 3)) * 1e-3
    r = ate(np.arange(30.0), Gt, np.arange(30.0), Est)
    assert np.isnan(r.scale) and json.loads(json.dumps(r.to_dict()))["scale"] is None
    Gt[:, :3, 3] = rng.normal(size=(30, 3)) * 2e-3 / np.sqrt(3)
    Est[:, :3, 3] = 1.1 * Gt[:, :3, 3]
    assert ate(np.arange(30.0), Gt, np.arange(30.0), Est).scale == pytest.approx(1 / 1.1, rel=1e-9)


def test_ate_known_value():
    # gt on a straight line; estimate offset by +-1 cm perpendicular in the pattern
    # + - - + (zero mean, uncorrelated with position along the line): the best alignment is
    # the identity and every error is 1 cm
    t, Gt = straight(20, 0.05)
    Est = Gt.copy()
    Est[:, 1, 3] += 0.01 * np.tile([1.0, -1.0, -1.0, 1.0], 5)
    r = ate(t, Gt, t, Est)
    assert r.stats.rmse == pytest.approx(0.01, rel=1e-6)
    assert r.stats.min == pytest.approx(0.01, rel=1e-6)


def test_align_umeyama_scale():
    rng = np.random.default_rng(2)
    X = rng.normal(size=(50, 3))
    R = G.exp_so3(np.array([0.1, 0.2, -0.3]))
    Y = 2.0 * X @ R.T + [1, 2, 3]
    R2, t2, s2 = align_umeyama(X, Y, with_scale=True)
    assert np.allclose(R2, R) and np.allclose(t2, [1, 2, 3]) and s2 == pytest.approx(2.0)


def test_mask_scores():
    pred = np.array([[1, 1, 0, 0], [1, 0, 0, 0]], bool)
    true = np.array([[1, 0, 0, 0], [1, 1, 0, 0]], bool)
    m = mask_scores(pred, true)
    assert (m.tp, m.fp, m.fn, m.tn) == (2, 1, 1, 4)
    assert m.precision == pytest.approx(2 / 3) and m.recall == pytest.approx(2 / 3)
    assert m.iou_outlier == pytest.approx(0.5) and m.iou_inlier == pytest.approx(4 / 6)
    assert m.accuracy == pytest.approx(6 / 8)
    valid = np.ones_like(pred)
    valid[0, 1] = False  # drop the false positive
    mv = mask_scores(pred, true, valid)
    assert mv.precision == 1.0 and mv.fp == 0 and mv.n == 7
    empty = mask_scores(np.zeros((2, 2), bool), np.zeros((2, 2), bool))
    assert np.isnan(empty.precision) and empty.iou_inlier == 1.0
    assert json.loads(json.dumps(empty.to_dict()))["precision"] is None
    with pytest.raises(ValueError, match="shapes differ"):
        mask_scores(pred, true[:1])
