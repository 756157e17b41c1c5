"""jaxvo.evaluation.scoring.evaluate: one function, two association protocols, a frozen result."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from jaxvo import geometry
from jaxvo.camera import DEFAULT
from jaxvo.data import DatasetError, TumSequence
from jaxvo.data.trajectory import write_tum_trajectory
from jaxvo.evaluation import metrics
from jaxvo.evaluation.scoring import PROTOCOLS, Evaluation, TrajectoryErrors, evaluate, trajectory_errors


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    from jaxvo.synthetic import generate

    path = generate("seq0", tmp_path_factory.mktemp("scoring") / "seq0", frames=40, seed=2,
                    camera=DEFAULT.at_level(3))
    return TumSequence(path, camera=DEFAULT.at_level(3))


def _estimate(seq, seed=0):
    """A perturbed chain of the true motions on the frame stamps (T_world_cam, first at identity)."""
    rng = np.random.default_rng(seed)
    _, T = seq.groundtruth_at_frames()
    poses = [np.eye(4)]
    for k in range(len(T) - 1):
        rel = geometry.inverse(T[k + 1]) @ T[k]
        noise = geometry.exp(rng.normal(scale=1e-3, size=6))
        poses.append(poses[-1] @ geometry.inverse(np.asarray(noise) @ rel))
    return seq.timestamps, np.stack(poses)


def _interpolated_by_hand(seq, stamps, poses):
    """The interpolated protocol written out: ground truth interpolated at the frames it covers."""
    mask, gT = seq.groundtruth_at_frames()
    gs, gP = seq.timestamps[mask], gT[mask]
    return (metrics.rpe(gs, gP, stamps, poses, delta=1, delta_unit="f"),
            metrics.rpe(gs, gP, stamps, poses, delta=1.0, delta_unit="s"), metrics.ate(gs, gP, stamps, poses))


def test_interpolated_protocol_gives_the_numbers_of_interpolated_ground_truth(seq):
    stamps, poses = _estimate(seq)
    f_ref, s_ref, a_ref = _interpolated_by_hand(seq, stamps, poses)
    f = evaluate(seq, (stamps, poses), delta=1, delta_unit="f", protocol="interpolated", slack=None)
    s = evaluate(seq, (stamps, poses), delta=1.0, delta_unit="s", protocol="interpolated", slack=None)
    assert isinstance(f, Evaluation) and f.protocol == "interpolated" and (f.delta, f.delta_unit) == (1, "f")
    assert f.rpe.trans_stats == f_ref.trans_stats and f.rpe.rot_stats == f_ref.rot_stats and f.rpe.n == f_ref.n
    assert s.rpe.trans_drift == s_ref.trans_drift and s.rpe.rot_drift == s_ref.rot_drift
    assert f.ate.stats == a_ref.stats
    np.testing.assert_array_equal(f.gt[0], stamps)      # every frame lies inside the ground truth
    with pytest.raises(dataclasses.FrozenInstanceError):
        f.delta = 2.0


def test_nearest_protocol_is_jaxvo_eval_and_accepts_files_arrays_and_sequences(seq, tmp_path):
    stamps, poses = _estimate(seq, seed=1)
    gt = seq.groundtruth
    ref_r = metrics.rpe(gt[0], gt[1], stamps, poses, 1, "f", 0.02)
    ref_a = metrics.ate(gt[0], gt[1], stamps, poses, 0.02)
    traj = tmp_path / "t.txt"
    write_tum_trajectory(traj, stamps, poses)
    from_files = evaluate(seq.path, traj, delta=1, delta_unit="f")
    from_arrays = evaluate(gt, (stamps, poses), delta=1, delta_unit="f")
    from_seq = evaluate(seq, (stamps, poses), delta=1, delta_unit="f", protocol="nearest")
    for ev in (from_files, from_arrays, from_seq):
        assert ev.protocol == "nearest" and ev.masks is None and ev.mask_frames == 0
        np.testing.assert_allclose(ev.rpe.trans_stats.rmse, ref_r.trans_stats.rmse, rtol=1e-6)   # files: 4-6 decimals
        np.testing.assert_allclose(ev.ate.rmse, ref_a.rmse, rtol=1e-6)
    assert from_files.gt_file == seq.path / "groundtruth.txt" and from_arrays.gt_file is None
    assert from_arrays.rpe.trans_stats == ref_r.trans_stats and from_arrays.ate.stats == ref_a.stats
    # the protocols pair differently: the numbers differ, a little
    interp = evaluate(seq, (stamps, poses), delta=1, delta_unit="f", protocol="interpolated")
    assert interp.rpe.n == from_seq.rpe.n and interp.ate.rmse == pytest.approx(from_seq.ate.rmse, rel=0.5)


def test_evaluate_refuses_what_it_cannot_score(seq):
    stamps, poses = _estimate(seq)
    assert PROTOCOLS == ("nearest", "interpolated")
    with pytest.raises(ValueError, match="protocol"):
        evaluate(seq, (stamps, poses), protocol="closest")
    late = stamps + 100.0
    with pytest.raises(DatasetError, match="does not cover"):
        evaluate(seq, (late, poses), protocol="interpolated")
    with pytest.raises(DatasetError, match="need at least 2"):
        evaluate(seq, (late, poses), protocol="interpolated", slack=None)


def test_trajectory_errors_is_a_frozen_record_with_none_for_what_cannot_be_formed(seq):
    stamps, poses = _estimate(seq)
    e = trajectory_errors(seq.groundtruth, stamps, poses)
    assert isinstance(e, TrajectoryErrors) and e.rpe_1f is not None and e.ate is not None
    assert e.rpe_1s is not None    # 40 frames at 30 Hz span more than a second
    short = trajectory_errors(seq.groundtruth, stamps[:2], poses[:2])
    assert short.rpe_1f is not None and short.rpe_1s is None and short.ate is None
