"""Tracking end to end on a synthetic pair with exact ground truth: :func:`jaxvo.track` chains
camera-to-world poses, chooses references and holds the pose over a failed estimate.

The pair is a static room rendered at 640x480 by jaxvo.synthetic, the camera moving a few cm
and degrees between the two frames.
"""
from __future__ import annotations

import jax
import numpy as np
import pytest

from jaxvo import geometry
from jaxvo.camera import DEFAULT
from jaxvo.config import Config, TrackConfig
from jaxvo.frame import Frame
from jaxvo.synthetic import make_room, render
from jaxvo.tracking.odometry import Odometry, track

CAM = DEFAULT
# T_cur_ref of the pair: 1.5/-2/1 deg and 2/-1/3 cm
MOTION = geometry.exp(np.array([np.radians(1.5), np.radians(-2.0), np.radians(1.0), 0.02, -0.01, 0.03]))


@pytest.fixture(scope="module")
def static_pair():
    scene = make_room(0)
    return render(scene, CAM, np.eye(4), t=0.0), render(scene, CAM, np.linalg.inv(MOTION), t=1.0)


def test_track_chains_camera_to_world_poses(static_pair):
    a, b = static_pair
    frames = [a.frame(), b.frame(), a.frame()]
    tr = track(frames, CAM, Config(method="classic"), jax.random.key(0))
    assert tr.poses.shape == (3, 4, 4) and tr.poses.dtype == np.float64
    np.testing.assert_allclose(tr.poses[0], np.eye(4))
    # T_world_cur = T_world_ref @ inv(T_cur_ref): frame 1 sits at inv(MOTION)
    np.testing.assert_allclose(tr.poses[1], np.linalg.inv(MOTION), atol=3e-3)
    # going back to frame a closes the loop
    np.testing.assert_allclose(tr.poses[2], np.eye(4), atol=3e-3)
    assert tr.valid.all()


def test_track_keyframe_references_and_poses(static_pair):
    """Each frame is estimated against a reference up to max_gap frames back; after a move the
    reference is `lag` frames behind. Poses are right whatever the reference."""
    a, b = static_pair
    frames = [a.frame(), b.frame()] * 4
    steps = []
    # the frames jump back and forth, which no camera does: no smoothing of reference poses;
    # the scene is static, so calm_fraction 0 keeps the keyframes
    tr = track(frames, CAM, Config(method="classic"), jax.random.key(0),
               policy=TrackConfig(max_gap=3, lag=1, smooth=False, calm_fraction=0.0), callback=steps.append)
    # frames 1-3 against 0; after frame 3 (gap 3) the reference moves to 3 - 1 = 2; after 5 to 4; ...
    assert tr.reference.tolist() == [0, 0, 0, 2, 2, 4, 4]
    assert [s.reference for s in steps] == tr.reference.tolist() and [s.frame for s in steps] == list(range(1, 8))
    for j in range(8):
        want = np.eye(4) if j % 2 == 0 else np.linalg.inv(MOTION)
        np.testing.assert_allclose(tr.poses[j], want, atol=3e-3)
    assert tr.valid.all() and tr.relative.shape == (7, 4, 4)
    # the relative motions are those of consecutive poses
    np.testing.assert_allclose(tr.relative[2], np.linalg.inv(tr.poses[3]) @ tr.poses[2], atol=1e-12)


def test_track_frame_to_frame_paths_agree(static_pair):
    """Frame to frame with and without failure handling give the same poses when nothing fails."""
    a, b = static_pair
    frames = [a.frame(), b.frame(), a.frame()]
    cfg = Config(method="classic")
    fast = track(frames, CAM, cfg, jax.random.key(0), policy=TrackConfig.frame_to_frame(hold_invalid=False))
    slow = track(frames, CAM, cfg, jax.random.key(0), policy=TrackConfig.frame_to_frame())
    np.testing.assert_allclose(fast.poses, slow.poses, atol=1e-6)
    assert fast.reference.tolist() == slow.reference.tolist() == [0, 1]


def test_track_holds_the_pose_over_a_failed_estimate(static_pair):
    """A frame the estimator cannot register (noise) keeps the previous pose and is reported invalid."""
    a, b = static_pair
    rng = np.random.default_rng(1)
    noise = Frame(rng.uniform(0, 255, (480, 640)).astype(np.float32),
                  rng.uniform(0.5, 3.0, (480, 640)).astype(np.float32))
    frames = [a.frame(), b.frame(), noise, b.frame()]
    tr = track(frames, CAM, Config(method="ransac"), jax.random.key(0), policy=TrackConfig.frame_to_frame())
    assert tr.valid.tolist() == [True, False, True]
    np.testing.assert_allclose(tr.poses[2], tr.poses[1], atol=0)
    # the failed frame never serves as a reference: frame 3 is estimated against frame 1
    assert tr.reference.tolist() == [0, 1, 1]
    np.testing.assert_allclose(tr.poses[3], np.linalg.inv(MOTION), atol=3e-3)
    # without failure handling the noise frame's estimate is chained as it is
    raw = track(frames, CAM, Config(method="ransac"), jax.random.key(0),
                policy=TrackConfig.frame_to_frame(hold_invalid=False))
    assert not np.allclose(raw.poses[2], raw.poses[1], atol=1e-9)


@pytest.mark.parametrize("policy, match", [
    (TrackConfig(max_gap=0, lag=0), "max_gap"),
    (TrackConfig(max_gap=4, lag=4), "lag"),
    (TrackConfig(max_step=0.0), "max_step"),
])
def test_track_config_is_validated(static_pair, policy, match):
    a, b = static_pair
    with pytest.raises(ValueError, match=match):
        track([a.frame(), b.frame()], CAM, Config(method="classic"), policy=policy)


def test_timings_profile_the_estimates_without_changing_poses(static_pair):
    """``Odometry.timings``: every estimate timed under its purpose, the poses bitwise those of
    an odometry that does not time."""
    a, b = static_pair
    frames = [a.frame(), b.frame(), a.frame(), b.frame()]
    plain, timed = (Odometry(CAM, Config(method="classic"), jax.random.key(0)) for _ in range(2))
    timed.timings = {}
    for f in frames:
        plain.add(f)
        timed.add(f)
    np.testing.assert_array_equal(np.stack(plain.poses), np.stack(timed.poses))
    assert plain.timings is None
    estimates = {k: v for k, v in timed.timings.items() if k.startswith("estimate: ")}
    # each frame after the first is estimated against its reference once; the window's new
    # keyframes and the other purposes add theirs
    assert len(estimates["estimate: track"]) == len(frames) - 1
    assert set(estimates) <= {f"estimate: {p}" for p in ("track", "retry", "recover", "window", "fuse")}
    assert all(t > 0 for ts in timed.timings.values() for t in ts)


@pytest.mark.parametrize("T, match", [
    (np.eye(3), "T_world_first must be a 4x4 matrix"),
    (np.full((4, 4), np.nan), "T_world_first contains NaN or inf"),
    (np.diag([2.0, 2.0, 2.0, 1.0]), "T_world_first must be a rigid transform"),
])
def test_a_first_pose_that_is_not_rigid_is_refused_by_name(T, match):
    """Not taken silently (a NaN or scaled first pose would put every pose of the run off)."""
    with pytest.raises(ValueError, match=match):
        Odometry(CAM, T_world_first=T)
    with pytest.raises(ValueError, match=match):
        track(iter(()), CAM, T_world_first=T)
