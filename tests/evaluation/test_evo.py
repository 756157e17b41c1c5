"""jaxvo's ATE and frame RPE agree with evo's on a real sequence, given the ground truth that
`jaxvo gt` writes (Bonn marker poses converted to camera poses) and evo's --t_max_diff 0.02."""
from __future__ import annotations

import copy

import numpy as np
import pytest
from click.testing import CliRunner

from jaxvo.cli.main import main
from jaxvo.data import DatasetError, find_sequence
from jaxvo.evaluation.scoring import evaluate
from jaxvo.data.trajectory import read_tum_trajectory


@pytest.fixture(scope="module")
def bonn_crowd():
    try:
        return find_sequence("rgbd_bonn_crowd")
    except DatasetError as e:
        pytest.skip(f"real data missing: {e}")


def test_ate_and_frame_rpe_match_evo(bonn_crowd, tmp_path):
    evo_sync = pytest.importorskip("evo.core.sync", reason="evo is not installed (pip install -e .[test])")
    from evo.core import metrics
    from evo.tools import file_interface

    est, gt = tmp_path / "est.txt", tmp_path / "gt.txt"
    r = CliRunner().invoke(main, ["run", str(bonn_crowd), "--max-frames", "8", "--method", "classic",
                                  "--out", str(est), "--no-progress"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["gt", str(bonn_crowd), "-o", str(gt)])
    assert r.exit_code == 0, r.output
    # the written ground truth is the converted one jaxvo evaluates with
    ours = evaluate(bonn_crowd, est, delta=1, delta_unit="f", max_dt=0.02)
    t, T = read_tum_trajectory(gt)
    np.testing.assert_allclose(T, ours.gt[1], atol=1e-6)

    ref = file_interface.read_tum_trajectory_file(str(gt))
    traj = file_interface.read_tum_trajectory_file(str(est))
    ref, traj = evo_sync.associate_trajectories(ref, traj, max_diff=0.02)
    assert traj.num_poses == ours.ate.stats.n == 8

    def rpe(relation):
        m = metrics.RPE(relation, delta=1, delta_unit=metrics.Unit.frames, all_pairs=False)
        m.process_data((ref, traj))
        return m.get_statistic(metrics.StatisticsType.rmse)

    np.testing.assert_allclose(rpe(metrics.PoseRelation.translation_part), ours.rpe.trans_stats.rmse, rtol=1e-5)
    np.testing.assert_allclose(rpe(metrics.PoseRelation.rotation_angle_deg), ours.rpe.rot_stats.rmse,
                               rtol=1e-4, atol=1e-6)
    scaled = copy.deepcopy(traj)
    assert scaled.align(ref, correct_scale=True)[2] == pytest.approx(ours.ate.scale, rel=1e-6)
    traj.align(ref, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, traj))
    np.testing.assert_allclose(ape.get_statistic(metrics.StatisticsType.rmse), ours.ate.rmse, rtol=1e-5)
