"""The reference policy of the streaming Odometry, on its own: which reference each frame is
estimated against, and how the poses of new references are made (fusion and smoothing).

The estimator is replaced by an exact one with independent noise per (reference, frame) pair,
so that these tests pin the policy's bookkeeping and its statistics, not the estimator's.
"""
from __future__ import annotations

import numpy as np
import pytest

from jaxvo import geometry
from jaxvo.evaluation import metrics
from jaxvo.tracking import odometry as O
from jaxvo.camera import DEFAULT
from jaxvo.frame import Frame
from jaxvo.config import TrackConfig
from jaxvo.estimator import MotionEstimate
from jaxvo.tracking.odometry import Odometry

CAM = DEFAULT.at_level(2)          # 160x120: the frames only carry their index
N = 240
FAIL: set = set()                  # frames whose estimates the fake estimator reports failed


def _truth(n=N):
    """A smooth hand-held-like T_world_cam path: ~1 cm and ~0.3 deg per frame."""
    t = np.arange(n) / 30.0
    xi = np.stack([0.05 * np.sin(1.3 * t), 0.08 * np.sin(0.7 * t), 0.02 * t,
                   0.3 * t, 0.1 * np.sin(2.0 * t), 0.05 * t], 1)
    return geometry.exp(xi)


def _frames(n=N):
    out = []
    for i in range(n):
        img = np.zeros((CAM.height, CAM.width), np.float32)
        img[0, 0] = i
        out.append(Frame(img, np.ones_like(img)))
    return out


#: The fake estimates' information matrix: 1 mm and 1 mrad standard deviations, a well-determined
#: estimate (the tracking trusts none that leaves over MAX_POSITION_SD).
INFO = 1e6 * np.eye(6)


def _index(frame) -> int:
    """The frame index written into pixel (0, 0) of a frame, or of a prepared frame's frame (what
    the odometry passes to the estimator)."""
    return int(getattr(frame, "frame", frame).intensity[0, 0])


@pytest.fixture
def noisy_estimator(monkeypatch):
    """estimate_motion -> the true T_cur_ref times exp(noise), noise ~ N(0, 3 mm / 0.1 deg), fixed per pair."""
    return _fake_estimator(monkeypatch, _truth())


def _fake_estimator(monkeypatch, truth, passes=lambda r, c: c not in FAIL):
    """The noisy exact estimator for the path ``truth``; an estimate of frame c against frame r
    reports failure where ``passes(r, c)`` is False. Returns (truth, the (r, c) pairs estimated)."""
    calls = []

    def fake(ref, cur, camera, config, key, init=None, weights=None):
        r, c = _index(ref), _index(cur)
        calls.append((r, c))
        rng = np.random.default_rng(1000 * r + c)
        noise = np.concatenate([rng.normal(0, np.radians(0.1), 3), rng.normal(0, 0.003, 3)])
        T = geometry.inverse(truth[c]) @ truth[r] @ geometry.exp(noise)
        z = np.zeros((CAM.height, CAM.width), bool)
        return MotionEstimate(T.astype(np.float32), noise, z, z, 0.9, 0, 0, passes(r, c), INFO, 1.0)

    monkeypatch.setattr(O, "estimate_motion", fake)
    return truth, calls


def _run(policy):
    odo = Odometry(CAM, policy=policy)
    for f in _frames():
        odo.add(f)
    return odo


def _rpe1s(truth, poses):
    stamps = np.arange(len(poses)) / 30.0
    return metrics.rpe(stamps, truth, stamps, poses, delta=1.0).trans_stats.rmse


def test_fused_and_smoothed_references_drift_less(noisy_estimator):
    truth, calls = noisy_estimator
    plain = _run(TrackConfig.keyframes(6, fuse=False, smooth=False))
    n_plain = len(calls)
    best = _run(TrackConfig.keyframes(6))
    n_best = len(calls) - n_plain
    e_plain, e_best = _rpe1s(truth, plain.result().poses), _rpe1s(truth, best.result().poses)
    # gap 6 / lag 3: every reference but the first was estimated against the reference
    # before the current one, so each move costs one extra estimate, and the two
    # interleaved chains are tied together (measured: 0.0129 -> 0.0093 m/s)
    assert n_plain == N - 1
    switches = len(set(best.references)) - 1
    assert n_best == N - 1 + switches - 1
    assert e_best < 0.8 * e_plain, (e_best, e_plain)


def test_smoothing_helps_where_the_reference_is_inside_the_fit():
    """gap 6 / lag 2: a new reference lies inside the span of the estimates against its
    reference, so the fit averages their noise (measured: 0.0169 -> 0.0109 m/s)."""
    with pytest.MonkeyPatch.context() as mp:
        truth, _ = noisy_estimator.__wrapped__(mp)
        plain = _rpe1s(truth, _run(TrackConfig.keyframes(6, lag=2, fuse=False, smooth=False)).result().poses)
        smooth = _rpe1s(truth, _run(TrackConfig.keyframes(6, lag=2, fuse=False)).result().poses)
    assert smooth < 0.8 * plain, (smooth, plain)


def test_frame_to_frame_is_untouched(noisy_estimator):
    """With every frame the next reference there is nothing to fuse or smooth: the poses are
    exactly the chained estimates."""
    truth, calls = noisy_estimator
    odo = _run(TrackConfig.frame_to_frame())
    assert calls == [(i, i + 1) for i in range(N - 1)]
    P = odo.result().poses
    for i in (1, 50, N - 1):
        T = geometry.inverse(truth[i]) @ truth[i - 1]
        rng = np.random.default_rng(1000 * (i - 1) + i)
        noise = np.concatenate([rng.normal(0, np.radians(0.1), 3), rng.normal(0, 0.003, 3)])
        np.testing.assert_allclose(geometry.inverse(P[i]) @ P[i - 1], T @ geometry.exp(noise), atol=2e-6)


def test_failed_frames_coast_at_the_recent_velocity(noisy_estimator, monkeypatch):
    """People covering the picture for 20 frames: every estimate fails. Coasting keeps the
    camera moving at its velocity before the gap; holding freezes it, and the distance it
    travelled meanwhile stays in the trajectory as an offset."""
    truth, _ = noisy_estimator
    monkeypatch.setattr(f"{__name__}.FAIL", set(range(100, 120)))
    coast = _run(TrackConfig.keyframes(6, coast=30))
    hold = _run(TrackConfig.keyframes(6))                 # the default: held
    assert not any(coast.valid[99:119]) and not any(hold.valid[99:119])
    np.testing.assert_allclose(hold.poses[119], hold.poses[99], atol=0)

    def err(odo, i):   # position error of frame i relative to frame 99, the last good one
        E = geometry.inverse(geometry.inverse(truth[99]) @ truth[i]) @ (geometry.inverse(odo.poses[99]) @ odo.poses[i])
        return np.linalg.norm(E[:3, 3])

    moved = np.linalg.norm((geometry.inverse(truth[99]) @ truth[119])[:3, 3])
    assert err(hold, 119) > 0.9 * moved
    assert err(coast, 119) < 0.5 * err(hold, 119), (err(coast, 119), err(hold, 119))   # measured 0.075 vs 0.217 m
    # past `coast` failed frames in a row the pose is held
    monkeypatch.setattr(f"{__name__}.FAIL", set(range(100, 140)))
    short = _run(TrackConfig.keyframes(6, coast=5))
    np.testing.assert_allclose(short.poses[130], short.poses[104], atol=0)
    assert not np.allclose(short.poses[104], short.poses[99])


def test_a_fast_camera_is_caught_again_after_failed_frames(monkeypatch):
    """A camera at 4 cm per frame, under the 5 cm step limit, whose estimates fail for frames
    100-103 (held poses). The next estimates are right, but 5 frames of motion (20 cm) away from
    the held guess: the limit grows by the recent speed per held frame, so they are accepted
    and the track goes on (``TrackConfig.catch_up``; a fixed limit holds every frame after the gap)."""
    t = np.arange(N) / 30.0
    fast = geometry.exp(np.stack([0.1 * np.sin(t), 0.2 * t, 0.0 * t, 1.2 * t, 0.2 * np.sin(2 * t), 0 * t], 1))
    assert 0.035 < np.linalg.norm((geometry.inverse(fast[99]) @ fast[100])[:3, 3]) < 0.045
    _fake_estimator(monkeypatch, fast)
    monkeypatch.setattr(f"{__name__}.FAIL", set(range(100, 104)))
    odo = _run(TrackConfig.keyframes(6, catch_up=True))
    assert not any(odo.valid[99:103]) and all(odo.valid[103:])
    E = geometry.inverse(geometry.inverse(fast[99]) @ fast[-1]) @ (geometry.inverse(odo.poses[99]) @ odo.poses[-1])
    assert np.linalg.norm(E[:3, 3]) < 0.2 * np.linalg.norm((geometry.inverse(fast[99]) @ fast[-1])[:3, 3])
    # without it (the keyframes preset's setting) every frame after the gap is held
    stuck = _run(TrackConfig.keyframes(6))
    assert not any(stuck.valid[99:])
    assert TrackConfig().catch_up and not TrackConfig.frame_to_frame().catch_up


def test_a_failed_estimate_is_retried_from_the_constant_velocity_guess(monkeypatch):
    """A camera that turns ever faster, up to 4 deg per frame, and an estimator that converges only
    from a guess within 2.5 deg of the truth. From the first guess (the camera stood still since
    the previous frame) the estimates fail once it turns faster than that; made once more from
    the guess that it kept turning as between the two frames before (``TrackConfig.retry``),
    they pass, and the track follows the camera to the end."""
    n = 60
    yaw = np.cumsum(np.radians(np.minimum(0.25 * np.arange(n), 4.0)))
    truth = geometry.exp(np.stack([0 * yaw, yaw, 0 * yaw, 0.01 * np.arange(n), 0 * yaw, 0 * yaw], 1))
    tried = []

    def fake(ref, cur, camera, config, key, init=None, weights=None):
        r, c = _index(ref), _index(cur)
        T = geometry.inverse(truth[c]) @ truth[r]
        ok = geometry.rotation_angle((np.asarray(init, np.float64) @ geometry.inverse(T))[:3, :3]) < np.radians(2.5)
        tried.append((r, c, ok))
        z = np.zeros((CAM.height, CAM.width), bool)
        return MotionEstimate(T.astype(np.float32), np.zeros(6), z, z, 0.9, 0, 0, ok, INFO, 1.0)

    monkeypatch.setattr(O, "estimate_motion", fake)

    def run(policy):
        tried.clear()
        odo = Odometry(CAM, policy=policy)
        for f in _frames(n):
            odo.add(f)
        return odo

    odo = run(TrackConfig.keyframes(6, retry=True))
    assert all(odo.valid)
    retried = [(r, c) for (r, c, ok), (r2, c2, ok2) in zip(tried, tried[1:]) if (r, c) == (r2, c2) and not ok and ok2]
    assert len(retried) > 5
    E = geometry.inverse(truth[-1]) @ odo.poses[-1]
    assert np.linalg.norm(E[:3, 3]) < 1e-4 and geometry.rotation_angle(E[:3, :3]) < 1e-4
    # without it (the keyframes preset's setting) the track loses the camera once it turns fast
    assert not all(run(TrackConfig.keyframes(6)).valid)
    assert TrackConfig().retry and not TrackConfig.frame_to_frame().retry and not TrackConfig.keyframes().retry


@pytest.mark.parametrize("restart", [6, 10, 24])
def test_reference_restarts_after_restart_failed_frames(noisy_estimator, monkeypatch, restart):
    """Every estimate fails from frame 100 on. The reference moves once more, to frame 99, the
    last frame whose estimate succeeded, and cannot move to a failed frame after that: it stays
    there until ``restart`` frames after it, then jumps to the frame ``lag`` (3) back at its
    held pose."""
    monkeypatch.setattr(f"{__name__}.FAIL", set(range(100, 160)))
    odo = _run(TrackConfig.keyframes(6, restart=restart))
    refs = np.asarray(odo.references)          # refs[j - 1]: the reference of frame j
    j = 99 + restart                            # the restart happens after frame j
    assert refs[j - 1] == 99 and refs[j - 2] == 99
    assert refs[j] == j - 3
    assert not odo.valid[j - 3 - 1]             # the new reference is a failed (held) frame
    with pytest.raises(ValueError, match="restart"):
        TrackConfig.keyframes(6, restart=5).validate()


def test_a_failed_ransac_estimate_is_rescued_by_the_trusted_pixels_it_still_sees(monkeypatch):
    """Every estimate is right but RANSAC's flag fails it, as where people cover half of the
    reference and stand in front of the rest: three quarters of the reference hidden in the
    current frame (``occluded_mask``), every pixel still seen an inlier. ``TrackConfig.rescue``
    keeps them and the track follows the camera; with nothing hidden (the same inliers are then
    a quarter of what the frame sees), with ``rescue`` 0 or with classic, the frames are held."""
    n = 12
    truth = _truth(n)
    h, w = CAM.height, CAM.width
    hidden = np.zeros((h, w), bool)
    hidden[:, : 3 * w // 4] = True

    def fake_with(occluded):
        def fake(ref, cur, camera, config, key, init=None, weights=None):
            r, c = _index(ref), _index(cur)
            T = geometry.inverse(truth[c]) @ truth[r]
            ones = np.ones((h, w), bool)
            return MotionEstimate(T.astype(np.float32), np.zeros(6), ~hidden, ones, 0.25, 0, 0, False, INFO, 1.0,
                                  occluded)
        return fake

    def run(occluded, policy=TrackConfig(), config=O.Config()):
        monkeypatch.setattr(O, "estimate_motion", fake_with(occluded))
        odo = Odometry(CAM, config, policy=policy)
        for f in _frames(n):
            odo.add(f)
        return odo

    odo = run(hidden)
    assert all(odo.valid)
    E = geometry.inverse(truth[-1]) @ odo.poses[-1]
    assert np.linalg.norm(E[:3, 3]) < 1e-4
    assert not any(run(np.zeros((h, w), bool)).valid)
    assert not any(run(hidden, TrackConfig(rescue=0.0)).valid)
    assert not any(run(hidden, config=O.Config(method="classic")).valid)
    assert TrackConfig().rescue > 0


def test_estimates_that_agree_outweigh_a_wrong_guess(monkeypatch):
    """Frame 100's estimates are 4.5 cm off the truth, against the camera's motion: under the 5 cm
    step limit, so its pose is kept. Frame 101's estimates (3 mm / 0.1 deg noise) are then 5.5 cm
    from their guess, frame 100's pose: jumps against its reference and against the window's older
    keyframes alike. They put frame 101 at one pose, so it is kept (``Odometry._agreeing``) and the
    track goes on from the truth; without ``recover`` (one estimate alone) frame 101 is held."""
    truth = _truth()
    step = (geometry.inverse(truth[100]) @ truth[101])[:3, 3]
    bias = geometry.exp(np.concatenate([np.zeros(3), -0.045 * step / np.linalg.norm(step)]))

    def fake(ref, cur, camera, config, key, init=None, weights=None):
        r, c = _index(ref), _index(cur)
        rng = np.random.default_rng(1000 * r + c)
        noise = np.concatenate([rng.normal(0, np.radians(0.1), 3), rng.normal(0, 0.003, 3)])
        T_world_cur = truth[c] @ bias if c == 100 else truth[c]
        T = geometry.inverse(T_world_cur) @ truth[r] @ geometry.exp(noise)
        z = np.zeros((CAM.height, CAM.width), bool)
        return MotionEstimate(T.astype(np.float32), noise, z, z, 0.9, 0, 0, True, INFO, 1.0)

    monkeypatch.setattr(O, "estimate_motion", fake)
    policy = TrackConfig(calm_fraction=0.0)          # keyframes throughout: the reference is not frame 100
    odo = _run(policy)
    assert odo.valid[99] and odo.references[99] != 100     # frame 100 kept, with its error
    assert odo.valid[100]                                   # frame 101: the agreeing estimates

    def error(P, i):   # position error of frame i relative to frame 99
        E = geometry.inverse(geometry.inverse(truth[99]) @ truth[i]) @ (geometry.inverse(P[99]) @ P[i])
        return np.linalg.norm(E[:3, 3])

    assert error(odo.poses, 100) > 0.035
    assert error(odo.poses, 101) < 0.015, error(odo.poses, 101)
    assert all(odo.valid[100:110])
    held = _run(policy._replace(recover=False))
    assert not held.valid[100]


def test_a_failed_frame_moves_the_reference_at_once_and_is_estimated_against_it(monkeypatch):
    """From frame 100 on an estimate fails against a reference more than 3 frames back (people
    have moved since it, as in a crowd), else it is right (3 mm / 0.1 deg noise). With ``refresh``
    a frame that fails moves the reference to the latest successful frame ``lag`` (3) back and is
    estimated against it: no frame is held and the track stays on the truth. Without it the
    frames 4 and 5 after a reference are held until the reference moves on its own."""
    truth, calls = _fake_estimator(monkeypatch, _truth(), passes=lambda r, c: c < 100 or c - r <= 3)
    odo = _run(TrackConfig.keyframes(6, refresh=True))
    assert all(odo.valid)
    refs = np.asarray(odo.references)
    assert np.all(np.arange(1, N)[99:] - refs[99:] <= 3)
    assert any(c >= 100 and c - r > 3 for r, c in calls)   # estimates did fail and were made again
    E = geometry.inverse(truth[-1]) @ odo.poses[-1]
    assert np.linalg.norm(E[:3, 3]) < 0.05
    held = _run(TrackConfig.keyframes(6))
    assert not all(held.valid[99:])
    assert not TrackConfig.frame_to_frame().refresh and not TrackConfig.keyframes().refresh
