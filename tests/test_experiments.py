"""The experiment scripts run end to end on tiny inputs (``--quick``: 2-3 frames) and write their outputs.

The scripts are called in-process through ``main(argv)`` so that the estimator is
compiled once for all three (the compile dominates the cost): every script uses
the ``classic`` method here, plus OpenCV's RGB odometry as the peer.
"""
from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from jaxvo.camera import LENSES, NO_LENS
from jaxvo.config import Config, TrackConfig
from jaxvo.tracking.segmentation import SegmentParams
from jaxvo.data import data_root
from jaxvo.runtime.machine import instruction_set

REPO = Path(__file__).resolve().parents[1]
EXP = REPO / "experiments"
STATIC = data_root() / "tum" / "rgbd_dataset_freiburg2_desk"
DYNAMIC = data_root() / "bonn" / "rgbd_bonn_crowd"


def _require(*paths):
    for p in paths:
        if not p.is_dir():
            pytest.skip(f"real data missing: {p} (set JAXVO_DATA to the data root)")


DIAGNOSTICS = ("error_stretches", "exposure", "levers", "map_poses", "mask_limits", "pair_floor", "suite_compiles",
               "variants")


def _script(name):
    """The script as a module: ``experiments/<name>.py`` as its command line imports it (its folder
    first on the path), a diagnostic as ``experiments.diagnostics.<name>`` from the repository root."""
    for folder in (EXP, REPO):
        if str(folder) not in sys.path:
            sys.path.insert(0, str(folder))
    return importlib.import_module(f"experiments.diagnostics.{name}" if name in DIAGNOSTICS else name)


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("aug-cache")


@pytest.mark.parametrize("name", ["table1", "speed", "sweep", "failure_flag", "startup", "variants", "kernel_profile",
                                  "hindsight_masks", "pair_floor", "error_stretches", "suite_compiles"])
def test_help(name):
    command = ["-m", f"experiments.diagnostics.{name}"] if name in DIAGNOSTICS else [str(EXP / f"{name}.py")]
    r = subprocess.run([sys.executable, *command, "--help"], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert r.returncode == 0, r.stderr
    assert "usage:" in r.stdout and "--quick" in r.stdout


def test_table1_quick(tmp_path, cache):
    _require(STATIC)
    out = tmp_path / "table1.md"
    _script("table1").main([str(STATIC), "--quick", "--methods", "classic,opencv-rgb", "--cache", str(cache),
                            "--out", str(out)])
    text = out.read_text()
    assert "python experiments/table1.py" in text and "CPUs" in text and "jax " in text
    # the reader's default: fr2's published lens and depth correction on the real frames; the
    # augmentation (its own info.json intrinsics) as written
    assert "| rgbd_dataset_freiburg2_desk | 3 | 5155 | fr2 | classic |" in text and "| 3 | 5000 | none | classic |" in text
    assert "opencv-rgb" in text and "Dynamic augmentations" in text
    data = json.loads(out.with_suffix(".json").read_text())
    rows = {(r["kind"], r["method"]): r for r in data["rows"]}
    assert set(rows) == {("real", "classic"), ("real", "opencv-rgb"),
                         ("augmented", "classic"), ("augmented", "opencv-rgb")}
    for r in rows.values():
        assert r["rpef_t"] is not None and 0 <= r["rpef_t"] < 0.05  # m per frame, sane
        assert r["ate"] is not None
        assert r["rpe1s_t"] is None  # 3 frames span < 1 s


def test_table1_augments_a_sequence_whose_ground_truth_starts_late(tmp_path, cache):
    """fr3_long_office's ground truth starts 0.07 s after its first frame: the augmentation leaves
    out the 2 frames it has no pose for (it could not augment the sequence at all before), and
    the augmented rows are measured on as many frames as the real ones."""
    fr3 = data_root() / "tum" / "rgbd_dataset_freiburg3_long_office_household"
    _require(fr3)
    out = tmp_path / "table1.md"
    _script("table1").main([str(fr3), "--quick", "--methods", "classic", "--cache", str(cache), "--out", str(out)])
    data = json.loads(out.with_suffix(".json").read_text())
    assert [(r["kind"], r["method"]) for r in data["rows"]] == [("real", "classic"), ("augmented", "classic")]
    assert not data["not_augmented"]
    aug = data["rows"][1]
    assert aug["frames"] == data["rows"][0]["frames"] == 3 and aug["ate"] is not None


def test_table1_goes_on_past_a_sequence_it_cannot_augment(tmp_path, cache, monkeypatch):
    """A sequence the augmentation refuses is named in the output, and the real rows are still
    written (the script stopped there once)."""
    _require(STATIC)
    table1 = _script("table1")

    def refuse(real_dir, *args, **kwargs):
        raise table1.common.datasets.DatasetError(f"{real_dir}/groundtruth.txt: no ground truth at any frame")

    monkeypatch.setattr(table1.common, "augmented_sequence", refuse)
    out = tmp_path / "table1.md"
    table1.main([str(STATIC), "--quick", "--methods", "classic", "--cache", str(cache), "--out", str(out)])
    text = out.read_text()
    assert f"Not augmented: {STATIC.name} (cannot augment:" in text
    data = json.loads(out.with_suffix(".json").read_text())
    assert [(r["kind"], r["method"]) for r in data["rows"]] == [("real", "classic")]
    assert data["not_augmented"] and "ground truth" in data["not_augmented"][0]


def test_speed_quick(tmp_path):
    _require(STATIC, DYNAMIC)
    out = tmp_path / "speed.md"
    _script("speed").main(["--quick", "--methods", "classic", "--batch", "1", "--default-frames", "-1", "--out", str(out)])
    text = out.read_text()
    assert "python experiments/speed.py" in text and "CPUs" in text
    data = json.loads(out.with_suffix(".json").read_text())
    assert {(r["method"], r["set"]) for r in data["methods"]} == {("classic", "static"), ("classic", "dynamic")}
    for r in data["methods"]:
        assert r["median_ms"] > 0 and r["fps"] > 0
    assert data["methods"][0]["compile_s"] > 0
    stages = {(r["set"], r["level"], r["stage"]) for r in data["stages"]}
    assert ("static", "all", "pyramid") in stages and ("dynamic", 0, "solve") in stages
    for r in data["stages"]:
        if r["stage"] == "max |T - estimate|":
            assert r["value"] < 1e-4  # the stage replay reaches the estimator's pose
    assert data["default"] == []  # skipped here: it compiles the full ransac estimator
    assert data["levels"] and data["levels"][0]["level"] == 3
    assert [r["method"] for r in data["peers"]] == ["opencv-rgb", "opencv-rgb"]
    assert "opencv-rgb" in data["ratios"][0]
    assert {r["device"] for r in data["batch"]} >= {"cpu"}
    assert all(r["max_dev_vs_loop"] < 1e-3 for r in data["batch"])
    assert [r["frames"] for r in data["track_memory"]] == [3, 6]
    assert data["peak_rss_mb"] > 0


def test_speed_times_the_default_odometry_against_opencv(tmp_path):
    """speed.py's section on the default odometry over whole sequences (skipped by --quick above):
    per-frame wall and CPU time of both policies beside OpenCV's over the same pairs, their
    ratios, and the profiled pass's breakdown, whose parts add up to the pass."""
    speed = _script("speed")
    if not speed.common.peer_available("opencv-rgb"):
        pytest.skip("OpenCV is not installed")
    seq = speed.common.open_sequence(speed.common.synthetic_sequence(tmp_path / "seq", 5))
    rows, parts = speed.time_default({"dynamic": (seq, speed.common.load_frames(seq))}, 1, jax.random.key(0))
    assert [r["method"] for r in rows] == [label for label, _ in speed.DEFAULT_POLICIES]
    for r in rows:
        assert r["frames"] == 5 and r["mean_ms"] > 0 and r["cpu_ms"] > 0 and r["opencv_cpu_ms"] > 0
        assert r["ratio_mean"] == pytest.approx(r["mean_ms"] / r["opencv_mean_ms"])
        mine = [p for p in parts if p["method"] == r["method"]]
        total = [p for p in mine if p["part"] == "profiled pass, all"][0]["ms_per_frame"]
        assert sum(p["ms_per_frame"] for p in mine if p["part"] != "profiled pass, all") == pytest.approx(total)
        assert any(p["part"] == "estimate: track" for p in mine)


def test_sweep_quick(tmp_path, cache):
    _require(STATIC)
    out = tmp_path / "sweep.md"
    _script("sweep").main([str(STATIC), "--quick", "--method", "classic", "--cache", str(cache),
                           "--out", str(out)])
    assert out.with_suffix(".png").stat().st_size > 1000
    text = out.read_text()
    assert "python experiments/sweep.py" in text and "CPUs" in text
    data = json.loads(out.with_suffix(".json").read_text())
    assert [r["label"] for r in data["results"]] == ["real", "augmented"]
    for r in data["results"]:
        assert r["cells"] == 2 * 2 + 2 and len(r["scores"]) == r["cells"]
        assert r["max_abs_diff"] < 1e-3  # the vmapped grid equals separate calls
        assert all(s["rpef_t"] is not None for s in r["scores"])


def test_paper_sequences_quick(tmp_path):
    out = tmp_path / "paper_sequences.md"
    _script("paper_sequences").main(["--quick", "--size", "160x120", "--methods", "classic", "--sequences", "seq1",
                                     "--cache", str(tmp_path / "cache"), "--out", str(out)])
    text = out.read_text()
    assert "python experiments/paper_sequences.py" in text and "20 cm and 30 degrees" in text
    assert "| seq1 |" in text and "![seq1 translational_error]" in text
    data = json.loads(out.with_suffix(".json").read_text())
    (row,) = data["rows"]
    assert row["method"] == "classic" and row["frames"] == 4 and row["ate"] is not None
    assert 0 <= row["rpef_t"] < 0.05 and row["fps"] > 0 and 0 < row["inlier_ratio"] <= 1
    assert row["mask_precision"] is None or 0 <= row["mask_precision"] <= 1
    for f in data["figures"]["seq1"].values():
        assert Path(f).stat().st_size > 1000


def test_paper_sequences_augmented_real_sequence(tmp_path):
    """--augment runs a real TUM sequence with synthetic persons composited in, next to (here:
    instead of) the synthetic sequences, with the mask scores against the exact masks."""
    _require(STATIC)
    out = tmp_path / "aug.md"
    _script("paper_sequences").main(["--quick", "--methods", "classic", "--sequences", "", "--augment", str(STATIC),
                                     "--cache", str(tmp_path / "cache"), "--out", str(out)])
    data = json.loads(out.with_suffix(".json").read_text())
    (row,) = data["rows"]
    assert row["sequence"] == "freiburg2_desk+persons" and row["frames"] == 4
    assert 15 < row["moving_pct"] < 45 and row["ate"] is not None and row["mask_counts"]["tp"] + row["mask_counts"]["fn"] > 0
    text = out.read_text()
    assert "Dynamic augmentations (freiburg2_desk)" in text and "Synthetic sequences (" not in text


def test_mask_limits_free_space_and_mask_by_stage(tmp_path):
    """mask_limits: the share of the moving pixels that free space (true poses) sees through grows
    with the baseline while the share it sees in place shrinks (a person walking past a fixed
    camera); both appearance tests flag more of the moving pixels than of the static ones, at the
    true and at the estimated poses; and the default odometry's mask counts come split into the
    first pairs and the rest."""
    out = tmp_path / "ml.md"
    _script("mask_limits").main(["--sequences", "seq1", "--augment", "", "--frames", "6", "--seeds", "0",
                                 "--early", "2", "--cache", str(tmp_path / "cache"), "--out", str(out)])
    (row,) = json.loads(out.with_suffix(".json").read_text())["rows"]
    fs = {int(b): v for b, v in row["free_space"].items()}
    assert fs[8] == [None, None, 0] and fs[16][2] == 0 and fs[1][2] == 5 and fs[4][2] == 2
    for b in (1, 2, 4):
        behind, seen, _ = fs[b]
        assert 0 <= behind and 0 <= seen and behind + seen <= 1
    assert fs[4][0] > fs[1][0] > 0 and fs[4][1] < fs[1][1]
    for poses in ("appearance_true", "appearance_estimated"):
        ap = {int(b): v for b, v in row[poses].items()}
        assert ap[8] == [None] * 4
        for b in (1, 2, 4):
            moving_rejected, static_rejected, moving_changed, static_changed = ap[b]
            assert 0 <= static_rejected < moving_rejected <= 1 and 0 <= static_changed < moving_changed <= 1
    early, late = np.array(row["early_counts"]), np.array(row["late_counts"])
    assert early.shape == late.shape == (4,) and early.sum() > 0 and late.sum() > 0
    text = out.read_text()
    assert "python -m experiments.diagnostics.mask_limits" in text and "| seq1 |" in text and "| precision 1-2 |" in text


def test_map_poses_swaps_only_the_motion_tests_pose(tmp_path):
    """map_poses: the odometry asks ``Odometry.view_pose`` for each motion test's pose, the
    "true" variant's subclass answers with the ground truth's relative pose and the library's class
    is left as it is; the "chained" variant is the library's run itself (the same mask counts as
    paper_sequences.run_default); the table has a row per variant."""
    import jax
    from jaxvo import geometry
    from jaxvo.tracking import odometry
    mp, ps = _script("map_poses"), _script("paper_sequences")
    (job,) = ps.sequence_jobs(["seq2"], [], [0], 7, cache=tmp_path / "cache")
    ((name, seed, seq, true_masks, frames),) = ps.opened_jobs([job])
    ok, G = seq.groundtruth_at_frames()
    asked = []
    original = odometry.Odometry.view_pose

    class Spy(mp.odometry_with("true", G)):
        def view_pose(self, view, new, T_world_new):
            T = super().view_pose(view, new, T_world_new)
            asked.append((view, new, T))
            return T
    ps.run_default(seq, frames, true_masks, jax.random.key(0), odometry=Spy)
    assert odometry.Odometry.view_pose is original
    assert mp.odometry_with("chained") is odometry.Odometry
    assert asked, "no motion test asked for its pose"
    for view, new, T in asked:
        assert view < new and T.dtype == np.float32
        np.testing.assert_allclose(T, geometry.inverse(G[view]) @ G[new], atol=1e-6)
    out = tmp_path / "mp.md"
    mp.main(["--sequences", "seq2", "--augment", "", "--frames", "7", "--seeds", "0", "--variants", "chained,true",
             "--cache", str(tmp_path / "cache"), "--out", str(out)])
    rows = json.loads(out.with_suffix(".json").read_text())["rows"]
    assert [r["variant"] for r in rows] == ["chained", "true"]
    plain = ps.run_default(seq, frames, true_masks, jax.random.key(0))["mask"]
    assert rows[0]["counts"] == [plain["tp"], plain["fp"], plain["fn"]]
    text = out.read_text()
    assert "python -m experiments.diagnostics.map_poses" in text and "| seq2 | true |" in text


def test_hindsight_masks_quick(tmp_path):
    """hindsight_masks --quick: one seq1 row with the online, estimated- and true-pose counts; the
    hindsight counts cover every valid-depth pixel of the 8 frames; the table names the command."""
    out = tmp_path / "hm.md"
    _script("hindsight_masks").main(["--quick", "--cache", str(tmp_path / "cache"), "--out", str(out)])
    (row,) = json.loads(out.with_suffix(".json").read_text())["rows"]
    assert row["sequence"] == "seq1" and row["frames"] == 8
    est, true = np.array(row["estimated"]), np.array(row["true"])
    assert est.sum() == true.sum() > 8 * 640 * 480 // 2
    for c in (est, true, np.array(row["online"])):
        assert c.shape == (4,) and c[0] > 0 and (c >= 0).all()
    text = out.read_text()
    assert "python experiments/hindsight_masks.py --quick" in text and "| seq1 | 1 |" in text


def test_paper_sequences_policy_is_checked(capsys):
    with pytest.raises(SystemExit) as e:
        _script("paper_sequences").main(["--quick", "--policy", '{"restrt": 9}'])
    assert e.value.code == 2 and "did you mean 'restart'" in capsys.readouterr().err


def test_paper_sequences_config_and_seeds_are_checked(capsys):
    for args, msg in ((["--config", '{"ransac_finst": 0}'], "did you mean 'ransac_finest'"),
                      (["--config", "[1]"], "expected a JSON object"),
                      (["--seeds", "0,x"], "--seeds: expected a comma list of integers")):
        with pytest.raises(SystemExit) as e:
            _script("paper_sequences").main(["--quick"] + args)
        assert e.value.code == 2 and msg in capsys.readouterr().err, args


def test_variants_quick(tmp_path):
    """variants.py: one row per (variant, pair set), the baseline's ratio 1 and pose difference 0,
    a variant that changes the estimate differs from it; a misspelt field stops with its name."""
    _require(STATIC, DYNAMIC)
    out = tmp_path / "variants.md"
    _script("variants").main(["--quick", "--methods", "classic", "--out", str(out),
                              "--variants", '{"base": {"finest_level": 2}, "coarser": {"finest_level": 3}}'])
    rows = json.loads(out.with_suffix(".json").read_text())["rows"]
    assert [(r["variant"], r["pairs"]) for r in rows] == [
        ("base", "static"), ("base", "dynamic"), ("coarser", "static"), ("coarser", "dynamic")]
    assert all(r["ratio"] == 1.0 and r["max_dT"] == 0.0 for r in rows[:2])
    assert all(r["max_dT"] > 0 and r["compile_s"] > 0 and r["ms"] > 0 for r in rows[2:])
    assert "| classic | coarser | dynamic |" in out.read_text()
    with pytest.raises(SystemExit, match="coarse: .*did you mean 'finest_level'"):
        _script("variants").main(["--quick", "--variants", '{"coarse": {"finest_levl": 3}}'])


def _rotation(axis, angle):
    """Rodrigues' formula: the (3, 3) rotation by ``angle`` rad about the unit vector ``axis``."""
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def test_pair_floor_smoothing_keeps_a_steady_turn_and_removes_jitter():
    """The ground truth's orientations averaged over +-k samples: a turn at constant angular
    velocity is left as it is (to rounding), its second difference is 0; jitter of 0.3 deg per
    sample added to it shows as that second difference, and mostly goes with the smoothing."""
    pf = _script("pair_floor")
    t = np.arange(60) / 30.0
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    T = np.tile(np.eye(4), (60, 1, 1))
    T[:, :3, :3] = [_rotation(axis, 0.004 * k) for k in range(60)]
    T[:, :3, 3] = np.outer(t, [0.1, 0.0, 0.05])
    np.testing.assert_allclose(pf.smoothed_orientations(t, T, 0.1), T, atol=1e-12)
    assert pf.rotation_jerk(T) < 1e-5
    rng = np.random.default_rng(0)
    noisy = T.copy()
    for k in range(60):
        v = rng.normal(size=3)
        noisy[k, :3, :3] = _rotation(v / np.linalg.norm(v), np.radians(0.3)) @ T[k, :3, :3]
    raw, smooth = pf.rotation_jerk(noisy), pf.rotation_jerk(pf.smoothed_orientations(t, noisy, 0.1))
    assert 0.5 < raw < 1.5 and smooth < 0.25 * raw, (raw, smooth)
    np.testing.assert_array_equal(pf.smoothed_orientations(t, noisy, 0.1)[:, :3, 3], noisy[:, :3, 3])


def test_pair_floor_quick(tmp_path):
    """pair_floor.py: a row per (stretch, method), errors against the ground truth and against
    its smoothed orientations; the Bonn marker's orientation jitters from sample to sample and
    the smoothing takes most of it out; a bad stretch stops with its name."""
    _require(STATIC, DYNAMIC)
    out = tmp_path / "pair_floor.md"
    _script("pair_floor").main(["--quick", "--methods", "classic", "--out", str(out)])
    data = json.loads(out.with_suffix(".json").read_text())
    assert [(r["stretch"], r["method"], r["pairs"]) for r in data["rows"]] == [
        ("Bonn crowd, empty room", "classic", 4), ("Bonn crowd, people", "classic", 4), ("fr2/desk", "classic", 4)]
    assert all(0 < r["trans_mm"] < 100 and 0 < r["rot_deg"] < 5 and 0 < r["rot_smooth_deg"] < 5
               for r in data["rows"])
    bonn = data["ground_truth"][0]
    assert round(bonn["rate_hz"]) == 30 and bonn["jerk_smooth_deg"] < 0.5 * bonn["jerk_deg"]
    assert "| Bonn crowd, people | classic | 4 |" in out.read_text()
    # --config reaches the estimates (a coarser finest level changes them)
    coarse = tmp_path / "coarse.md"
    _script("pair_floor").main(["--quick", "--methods", "classic", "--config", '{"finest_level": 3}', "--out",
                                str(coarse)])
    rows = json.loads(coarse.with_suffix(".json").read_text())["rows"]
    assert [r["trans_mm"] for r in rows] != [r["trans_mm"] for r in data["rows"]]
    assert '`{"finest_level": 3}`' in coarse.read_text()
    with pytest.raises(SystemExit, match="still: expected"):
        _script("pair_floor").main(["--stretches", '{"still": ["bonn/rgbd_bonn_crowd", 5, 5]}'])
    with pytest.raises(SystemExit, match="--config: .*finest_levl"):
        _script("pair_floor").main(["--config", '{"finest_levl": 3}'])


def test_error_stretches_finds_the_stretch_that_holds_a_jump():
    """A trajectory that follows the ground truth except for one 5 cm jump between frames 12 and 13:
    only the stretch holding it errs, by the jump; the next stretch starts at the last frame of one."""
    from jaxvo import geometry

    es = _script("error_stretches")
    rng = np.random.default_rng(0)
    G = np.stack([geometry.exp(np.concatenate([0.01 * k * np.ones(3), [0.02 * k, 0.0, 0.005 * k]]))
                  for k in range(25)]).astype(np.float64)
    G = np.einsum("ij,njk->nik", geometry.exp(rng.normal(size=6)), G)      # anywhere in the world
    jump = np.eye(4)
    jump[:3, 3] = [0.05, 0.0, 0.0]
    P = np.stack([G[k] if k <= 12 else jump @ G[k] for k in range(25)])  # a 5 cm step of the world
    rows = es.stretch_errors(P, G, 10)
    assert [(r["first"], r["last"]) for r in rows] == [(0, 10), (10, 20), (20, 24)]
    assert rows[0]["err_mm"] < 1e-6 and rows[2]["err_mm"] < 1e-6
    assert abs(rows[1]["err_mm"] - 50.0) < 1e-6 and rows[1]["err_deg"] < 1e-6
    assert abs(rows[1]["gt_mm"] - 1000 * np.linalg.norm((geometry.inverse(G[10]) @ G[20])[:3, 3])) < 1e-9


def test_error_stretches_costs_put_a_jump_where_it_is(tmp_path):
    """stretch_costs: a trajectory that is the ground truth but for a 5 cm jump between frames 12 and
    13 scores ATE and RPE 1 s 0 once the stretch holding the jump is replaced by the ground truth,
    and keeps its error where any other stretch is."""
    es = _script("error_stretches")
    seq = es.common.open_sequence(es.common.synthetic_sequence(tmp_path / "seq", 40))
    ok, G = seq.groundtruth_at_frames()
    assert ok.all()
    jump = np.eye(4)
    jump[:3, 3] = [0.05, 0.0, 0.0]
    P = np.stack([G[k] if k <= 12 else jump @ G[k] for k in range(len(G))])
    stretches = es.stretch_errors(P, G, 10)
    costs = es.stretch_costs(seq, P, G, stretches)
    assert [c["first"] for c in costs] == [None, 0, 10, 20, 30]
    assert costs[0]["ate"] > 0.01 and costs[0]["rpe1s"] > 0.01          # the jump, as estimated
    assert costs[2]["ate"] < 1e-6 and costs[2]["rpe1s"] < 1e-6          # frames 10-20 exact: no error left
    for c in (costs[1], costs[3], costs[4]):
        assert abs(c["ate"] - costs[0]["ate"]) < 1e-9 and abs(c["rpe1s"] - costs[0]["rpe1s"]) < 1e-9


def test_error_stretches_quick(tmp_path):
    """error_stretches.py on the first Bonn frames: a row per stretch with the static share and
    inlier ratio of its frames, the worst frames, and a bad option stops with its name."""
    _require(DYNAMIC)
    out = tmp_path / "es.md"
    data = _script("error_stretches").main(["--quick", "--seeds", "0,1", "--worst", "3", "--out", str(out)])
    assert [(r["first"], r["last"]) for r in data["stretches"]] == [(0, 4), (4, 8), (8, 11)]
    assert all(0 <= r["err_mm"] < 50 and 0.5 < r["static"] <= 1 and 0 < r["inliers"] <= 1
               for r in data["stretches"])
    assert len(data["worst"]) == 6 and {w["seed"] for w in data["worst"]} == {0, 1}
    assert "## Stretches of 4 frames" in out.read_text() and out.with_suffix(".json").is_file()
    assert [c["stretch"] for c in data["costs"]] == ["none (as estimated)", "0-4", "4-8", "8-11"]
    assert all(c["ate"] is not None and c["rpe1s"] is None for c in data["costs"])   # 12 frames: under 1 s
    with pytest.raises(SystemExit):
        _script("error_stretches").main(["--policy", '{"windw": 2}'])


def test_levers_variants_take_json_lists_and_name_a_bad_field():
    """levers --variants: a JSON list is a tuple field's value (blocks), validated as Config's own
    parser does; a bad value or a misspelt field stops with the variant's name."""
    levers = _script("levers")
    v = levers.parse_variants('{"base": {}, "tiles": {"config": {"blocks": [2, 4, 2, 1]}, "policy": {"window": 1}},'
                              ' "lens": {"lens": "bonn"}}')
    assert v["base"] == (Config(), TrackConfig(), None, None, SegmentParams()) and v["lens"][2] == LENSES["bonn"]
    assert v["tiles"][0] == Config(blocks=(2, 4, 2, 1)) and v["tiles"][1].window == 1
    with pytest.raises(SystemExit, match="tiles: .*blocks"):
        levers.parse_variants('{"tiles": {"config": {"blocks": [0, 4]}}}')
    with pytest.raises(SystemExit, match="slow: .*windw"):
        levers.parse_variants('{"slow": {"policy": {"windw": 2}}}')
    assert levers.parse_variants('{"own": {"lens": "folder"}}')["own"][2] == "folder"
    # the segmentation's parameters too (JSON's Infinity turns a test off); a misspelt or a
    # non-numeric one stops with the variant's name
    seg = levers.parse_variants('{"no test": {"segment": {"motion_gain": Infinity}}}')["no test"][4]
    assert seg.motion_gain == float("inf") and seg.margin == SegmentParams().margin
    for bad in ('{"m": {"segment": {"motion_gian": 1}}}', '{"m": {"segment": {"margin": "wide"}}}'):
        with pytest.raises(SystemExit, match="m:"):
            levers.parse_variants(bad)
    with pytest.raises(SystemExit, match="bent: lens must be"):
        levers.parse_variants('{"bent": {"lens": [0.1, 0.2]}}')
    assert [levers.parse_variants(f'{{"d": {{"depth_scale": {s}}}}}')["d"][3] for s in ('"folder"', '"fr2"', 5155)] \
        == ["folder", "fr2", 5155]
    # the files as they are: no lens, the layout's scale
    raw = levers.parse_variants('{"raw": {"lens": "none", "depth_scale": "recorded"}}')["raw"]
    assert raw[2] == NO_LENS and raw[3] == "recorded"
    for bad in ('"fr9"', "-1"):
        with pytest.raises(SystemExit, match="far: .*depth_scale must be"):
            levers.parse_variants(f'{{"far": {{"depth_scale": {bad}}}}}')


def test_perturbed_inputs_are_sub_grey_level_and_reproducible():
    """common.perturbed: draw 0 is the frames themselves; another draw adds the same noise every
    time, within +-0.25 grey levels, to the luminance only; draws differ from each other."""
    from jaxvo.frame import Frame
    common = _script("common")
    rng = np.random.default_rng(0)
    frames = [Frame(rng.uniform(0, 255, (6, 8)).astype(np.float32), rng.uniform(1, 2, (6, 8)).astype(np.float32),
                    np.ones((6, 8), bool)) for _ in range(3)]
    assert common.perturbed(frames, 0) is frames
    a, b, c = common.perturbed(frames, 1), common.perturbed(frames, 1), common.perturbed(frames, 2)
    for f, x, y, z in zip(frames, a, b, c):
        d = x.intensity - f.intensity
        assert x.intensity.dtype == np.float32 and 0 < np.abs(d).max() <= 0.25 + 1e-4
        np.testing.assert_array_equal(x.intensity, y.intensity)
        assert not np.array_equal(x.intensity, z.intensity)
        assert x.depth is f.depth and x.mask is f.mask
    with pytest.raises(SystemExit, match="--perturb"):
        _script("levers").main(["--perturb", "0"])


def test_paper_sequences_seeds_and_config(tmp_path):
    """--seeds: one full run per seed (its own scene), a row per seed and a mean-and-range table;
    --config reaches the estimator (a coarser finest level changes the estimate)."""
    args = ["--quick", "--size", "160x120", "--methods", "classic", "--sequences", "seq1",
            "--cache", str(tmp_path / "cache")]
    out = tmp_path / "s.md"
    _script("paper_sequences").main(args + ["--seeds", "0,1", "--out", str(out)])
    data = json.loads(out.with_suffix(".json").read_text())
    assert data["seeds"] == [0, 1] and [r["seed"] for r in data["rows"]] == [0, 1]
    a, b = (r["ate"] for r in data["rows"])
    assert a != b    # two scenes, not one scene twice
    text = out.read_text()
    assert "## Mean and range over the 2 seeds" in text and "seed each of 0, 1" in text
    summary = [ln for ln in text.splitlines() if ln.startswith("| seq1 | classic | 2 |")]
    assert len(summary) == 1 and f"{(a + b) / 2:.4f} ({min(a, b):.4f} - {max(a, b):.4f})" in summary[0]
    out2 = tmp_path / "c.md"
    _script("paper_sequences").main(args + ["--config", '{"finest_level": 1}', "--out", str(out2)])
    (row,) = json.loads(out2.with_suffix(".json").read_text())["rows"]
    assert row["ate"] != a and "Mean and range" not in out2.read_text()


def test_exposure_at_the_true_pose(tmp_path):
    """A consecutive pair of the empty room: most pixels agree in depth at the true pose, with no
    exposure offset to speak of."""
    _require(DYNAMIC)
    out = tmp_path / "exposure.md"
    _script("exposure").main([str(DYNAMIC), "--pairs", "0-1", "--out", str(out)])
    (row,) = json.loads(out.with_suffix(".json").read_text())["rows"]
    assert row["pair"] == "0->1" and row["depth_agree"] > 0.5 and abs(row["lum_offset"]) < 5 and row["lum_ok"] > 0.8
    assert row["err_mm_none"] < 30 and row["valid_none"]
    with pytest.raises(SystemExit):
        _script("exposure").main([str(DYNAMIC), "--pairs", "0-900", "--out", str(out)])


def test_keyframes_small(tmp_path):
    _require(STATIC)
    out = tmp_path / "kf.md"
    _script("keyframes").main([str(STATIC), "--max-frames", "6", "--gaps", "1,3,default", "--seeds", "0,1",
                               "--methods", "classic,ransac", "--policy", '{"calm_fraction": 0}', "--out", str(out)])
    text = out.read_text()
    assert "python experiments/keyframes.py" in text and "standing still" in text
    data = json.loads(out.with_suffix(".json").read_text())
    rows = {(r["method"], r["chaining"], r["seed"]): r for r in data["rows"]}
    # ransac once per seed, classic (no random numbers) once
    dflt = 'default (segmented keyframes) {"calm_fraction": 0}'    # --policy changes the default's name
    assert set(rows) == {("standing still", "-", None), ("classic", "frame to frame", None),
                         ("classic", "keyframes 3", None), ("ransac", "frame to frame", 0),
                         ("ransac", "frame to frame", 1), ("ransac", "keyframes 3", 0), ("ransac", "keyframes 3", 1),
                         ("classic", dflt, None), ("ransac", dflt, 0), ("ransac", dflt, 1)}
    assert data["args"]["policy"] == '{"calm_fraction": 0}'

    for key, r in rows.items():
        if key[0] != "standing still":
            assert r["failures"] == 0 and 0 <= r["rpef_t"] < 0.02, (key, r)
    same = {c["chaining"]: c for c in data["same_policy"]}
    assert set(same) == {"frame to frame", "keyframes 3", dflt}
    for chaining, c in same.items():
        mean = np.mean([rows[("ransac", chaining, s)]["ate"] for s in (0, 1)])
        assert c["ransac_ate_mean"] == pytest.approx(mean)
        assert c["ratio_ate"] == pytest.approx(mean / rows[("classic", chaining, None)]["ate"])
    assert "same policy" in text


def test_figures_small(tmp_path):
    """experiments/figures.py: the default odometry's overlay, the hindsight masks and the map on a few
    real frames."""
    _require(DYNAMIC)
    import cv2
    out = _script("figures").main([str(DYNAMIC), "--max-frames", "10", "--frames", "7,9", "--out-dir",
                                   str(tmp_path), "--ply", str(tmp_path / "map.ply")])
    seg = cv2.imread(str(out / "bonn_segmentation.png"))
    assert seg is not None and seg.shape == (240, 640, 3)    # two 640x480 panels side by side, halved
    hs = cv2.imread(str(out / "bonn_hindsight.png"))
    assert hs is not None and hs.shape == seg.shape
    assert cv2.imread(str(out / "bonn_map.png")) is not None
    from jaxvo.data.ply import read_ply
    pts, cols = read_ply(tmp_path / "map.ply")
    assert len(pts) > 1000 and cols.shape == (len(pts), 3)


def test_kernel_profile_attributes_the_kernels_to_stages(tmp_path):
    """experiments/kernel_profile.py on a synthetic sequence: XLA's kernels of the default
    estimator are found in the profiler's trace and attributed to the estimator's stages (named
    scopes), the stage times add up to the kernel total, and little is left unattributed."""
    out = tmp_path / "kernel_profile.md"
    _script("kernel_profile").main(["--quick", "--out", str(out)])
    data = json.loads(out.with_suffix(".json").read_text())
    (r,) = data["results"]
    stages = {s["stage"]: s for s in r["stages"]}
    assert {"pyramid", "points", "prior fit", "RANSAC sampling", "RANSAC scoring", "refinement",
            "final masks and statistics"} <= set(stages), sorted(stages)
    assert all(s["ms"] > 0 for s in r["stages"])
    assert sum(s["ms"] for s in r["stages"]) == pytest.approx(r["kernel_ms"])
    # Which kernels fall outside every named scope is a property of the compiled program, so
    # it is pinned on the count of distinct kernels. Their share of the time is only bounded
    # loosely: the many small unattributed kernels (loop conditions, copies) gain the most when
    # the cores are shared, as they are under xdist.
    other = stages.get("other", {"share": 0.0, "kernels": 0})
    assert other["kernels"] < 0.3 * sum(s["kernels"] for s in r["stages"]), r["stages"]
    assert other["share"] < 0.5, r["stages"]
    # the jaxvo source line of a kernel comes from the compiled program's stack frames
    assert r["kernels"] and sum(k["source"] != "?" for k in r["kernels"]) >= len(r["kernels"]) // 2
    assert "| stage | kernel ms / pair | passes: min - max | share | kernels |" in out.read_text()


def test_startup_reads_xla_compile_log_by_stage():
    """The compile-time breakdown of startup.py: XLA's timing lines between the child's marks,
    each LLVM module attributed to the stage of its kernel (named scope in the op_name)."""
    startup = _script("startup")
    log = "\n".join([
        "I1125 cpu_compiler.cc:1269] Running HLO passes on [jit_other] for CPU time: 9 s (9 us)",
        "ir_compiler.cc:293] Compiled LLVM module: __compute_module_before_kernel_module time: 5 s (1 us)",
        "jaxvo-codegen-start",
        "I1125 cpu_compiler.cc:1269] Running HLO passes on [jit__estimate] for CPU time: 1.5 s (1500000 us)",
        "ir_compiler.cc:293] Compiled LLVM module: __compute_module_add_fusion.3_kernel_module time: 20 ms (20000 us)",
        "ir_compiler.cc:293] Compiled LLVM module: __compute_module___compute_module_dot.4 time: 500 us (500 us)",
        "ir_compiler.cc:293] Compiled LLVM module: __compute_module_dot.7_elemental_kernel_module time: 1.5 ms (1 us)",
        "ir_compiler.cc:293] Compiled LLVM module: __compute_module_mystery_kernel_module time: 3 ms (3000 us)",
        "I1125 cpu_compiler.cc:2094] Compiling [jit__estimate] for CPU using JIT time: 4.25 s (4250000 us)",
        "jaxvo-codegen-end",
    ])
    kernels = {"add_fusion.3": ("jit(_estimate)/refinement/while/body/add", [("solvers.py", "_system", 84)]),
               "dot.4": ("jit(_estimate)/pyramid/dot_general", []),
               "dot.7": ("jit(_estimate)/ransac_sampling/x/refinement/dot_general", [])}
    out = startup.parse_codegen_log(log, kernels)
    assert out["hlo_passes_s"] == 1.5 and out["codegen_s"] == 4.25 and out["modules"] == 4
    assert abs(out["llvm_cpu_s"] - 0.025) < 1e-12
    assert out["stages"]["refinement"] == (2, pytest.approx(0.0215))  # the innermost named scope decides
    assert out["stages"]["pyramid"] == (1, pytest.approx(0.0005))
    assert out["stages"]["other"] == (1, pytest.approx(0.003))
    assert out["top"][0] == (0.02, "add_fusion.3", "refinement", "solvers.py:_system:84")
    assert startup.parse_codegen_log("no timing lines", kernels) is None


def test_startup_times_the_clis_first_pose_at_frame_1s_line(tmp_path):
    """``jaxvo run``'s first pose, timed from the process's start, is its trajectory's line for
    frame 1, under the ``.partial`` name while it runs: not the header, not frame 0's start pose."""
    startup = _script("startup")
    out = tmp_path / "traj.txt"
    watched = (tmp_path / "traj.txt.partial", out)
    watched[0].write_text("# jaxvo\n# method: ransac\n")
    assert not startup._has_pose(watched)
    watched[0].write_text("# jaxvo\n0.0 0 0 0 0 0 0 1\n")
    assert not startup._has_pose(watched)
    watched[0].write_text("# jaxvo\n0.0 0 0 0 0 0 0 1\n# held 0.1\n0.1 0 0 0 0 0 0 1\n")
    assert startup._has_pose(watched)
    watched[0].rename(out)
    assert startup._has_pose(watched)


def test_rerun_reads_the_commands_of_the_bash_blocks():
    """rerun.py: each line of a bash block is one command, a trailing comment dropped, ``python``
    this interpreter and ``jaxvo`` its ``-m jaxvo``; text outside the blocks is not run; another
    program in a block is refused, naming the line."""
    rerun = _script("rerun")
    text = ("Intro `python not_this.py`.\n\n```bash\npython experiments/x.py --out a/b.md   # a note\n\n"
            "python -m experiments.diagnostics.y --seeds 0,1 --variants '{\"a b\": {}}'\n```\n\n"
            "```python\nprint('not a command')\n```\n\n```bash\njaxvo demo\n```\n")
    cmds = rerun.commands(text)
    assert [c.argv for c in cmds] == [
        [sys.executable, "experiments/x.py", "--out", "a/b.md"],
        [sys.executable, "-m", "experiments.diagnostics.y", "--seeds", "0,1", "--variants", '{"a b": {}}'],
        [sys.executable, "-m", "jaxvo", "demo"]]
    assert [c.index for c in cmds] == [1, 2, 3] and [c.script for c in cmds] == ["x", "y", "jaxvo-demo"]
    assert [c.out for c in cmds] == ["a/b.md", None, None]
    with pytest.raises(ValueError, match="'rm -rf results'"):
        rerun.commands("```bash\nrm -rf results\n```\n")


def test_rerun_lists_the_results_commands_and_stops_at_a_failure(tmp_path, capsys):
    """Every command of docs/results.md names a script or diagnostic of experiments/ (or a jaxvo
    command); a run goes in order, logs each command, stops at the first failure with exit status
    1 (the rest with --keep-going), and skips the GPU's command unless asked."""
    rerun = _script("rerun")
    cmds = rerun.commands((REPO / "docs" / "results.md").read_text())
    assert len(cmds) >= 15
    for c in cmds:
        words = c.argv[1:]
        if words[0] == "-m" and words[1] != "jaxvo":
            assert (REPO / (words[1].replace(".", "/") + ".py")).is_file(), c.line
        elif words[0] != "-m":
            assert (REPO / words[0]).is_file(), c.line
    assert rerun.main(["--list"]) == 0
    listed = capsys.readouterr().out
    assert f"{len(cmds)} commands" in listed and "experiments/gpu.py" in listed and "(needs a CUDA GPU)" in listed

    md = tmp_path / "r.md"
    md.write_text("```bash\npython -c \"print('one')\"\npython -c \"import sys; sys.exit(3)\"\n"
                  "python -c \"print('three')\"\npython experiments/gpu.py --out x\n```\n")
    logs = tmp_path / "logs"
    assert rerun.main(["--results", str(md), "--log-dir", str(logs)]) == 1
    assert sorted(p.name for p in logs.iterdir()) == ["01-python.log", "02-python.log"]
    assert "one" in (logs / "01-python.log").read_text()
    out = capsys.readouterr()
    assert "2. exit 3" in out.out and "command 2 failed" in out.err and "4. skipped (needs a CUDA GPU" in out.out
    assert rerun.main(["--results", str(md), "--log-dir", str(logs), "--keep-going", "--only", "2,3"]) == 1
    assert "three" in (logs / "03-python.log").read_text()
    assert rerun.main(["--results", str(md), "--dry-run", "--match", "one"]) == 0
    assert "1. would run: python -c" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="no command numbered 9"):
        rerun.main(["--results", str(md), "--only", "9"])
    with pytest.raises(SystemExit, match="cannot read"):
        rerun.main(["--results", str(tmp_path / "missing.md"), "--list"])


def test_result_files_name_the_processor_generation_and_vector_unit():
    """Machines of one model name ("AMD EPYC") differ in speed and floats; a result file's machine
    line names the generation and the widest vector unit the instruction set offers."""
    common = _script("common")
    assert common.isa_summary("x86_64 family 25 model 17: avx avx2 avx512bw avx512f fma") == \
        "x86_64 family 25 model 17, AVX-512"
    assert common.isa_summary("x86_64 family 23 model 49: avx avx2 fma sse4_2") == "x86_64 family 23 model 49, AVX2"
    assert common.isa_summary("aarch64: asimd") == "aarch64, ASIMD"
    assert common.isa_summary("arm64") == "arm64"
    line = next(l for l in common.provenance_md("t", "experiments/speed.py", []) if l.startswith("Machine:"))
    assert common.isa_summary(instruction_set()) in line


def test_drift_quick_with_a_policy_change(tmp_path):
    """drift.py on a short synthetic crowd: both trackings' rows, the --policy change applied to both
    (the single reference keeps window 1), and a bad field named in one line."""
    drift = _script("drift")
    window, single = drift._policies('{"second_opinion": 0}').values()
    assert window.second_opinion == 0 and single.second_opinion == 0 and single.window == 1 and window.window > 1
    out = tmp_path / "drift.md"
    flags = os.environ.get("XLA_FLAGS")
    drift.main(["--frames", "40", "--size", "160x120", "--seeds", "0", "--policy", '{"second_opinion": 0}',
                "--poses", "both", "--out", str(out)])
    text = out.read_text()
    assert "--policy" in text and "| synthetic crowd 40 frames 160x120 | window | 1 |" in text
    assert "| synthetic crowd 40 frames 160x120 | single | 1 |" in text
    assert "| synthetic crowd 40 frames 160x120 | window, tracked | 1 |" in text
    rows = json.loads(out.with_suffix(".json").read_text())["rows"]
    assert {r["policy"] for r in rows} == {"window", "single", "window, tracked", "single, tracked"}
    assert all(np.isfinite(r["ate"]) for r in rows)
    # the single-thread flag is for the script's own process and its workers, not its caller's
    assert os.environ.get("XLA_FLAGS") == flags
    # --scene: the same rows for the sequence with persons standing close
    close = drift.run_crowd((0, 12, "160x120", None, "refined", "crowd-close"))
    assert [r["data"] for r in close] == ["synthetic crowd-close 12 frames 160x120"] * 2
    assert all(np.isfinite(r["ate"]) for r in close) and close[0]["moving_max"] > 0


def test_drift_policy_is_checked(capsys):
    with pytest.raises(SystemExit) as e:
        _script("drift").main(["--frames", "12", "--policy", '{"second_opinon": 0}'])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "--policy" in err and "second_opinion" in err


def test_drift_stats_of_a_short_sequence():
    """Under 1 s of frames: the ATE, no RPE 1 s (n/a in the summary) rather than an error."""
    drift = _script("drift")
    stamps = np.arange(20) / 30.0
    gt = np.tile(np.eye(4), (20, 1, 1))
    gt[:, 0, 3] = 0.01 * np.arange(20)
    est = gt.copy()
    est[:, 1, 3] = 0.002 * np.arange(20)
    stats = drift.drift_stats(stamps, gt, est)
    assert set(stats) == {"ate"} and 0 < stats["ate"] < 0.02
    md = drift.summary_md([{"data": "d", "seed": 0, "policy": p, "held": 0, **stats} for p in ("window", "single")])
    assert "| d | window | 1 | " in "\n".join(md) and "n/a" in "\n".join(md)
    longer = np.arange(40) / 30.0
    gt40 = np.tile(np.eye(4), (40, 1, 1))
    assert {"ate", "rpe1s_t", "rpe1s_r"} == set(drift.drift_stats(longer, gt40, gt40))


_COMPILING_TESTS = """
import jax
import jax.numpy as jnp
import numpy as np


def test_compiles_two_programs():
    # NumPy inputs: the two jitted functions are the only programs
    jax.jit(lambda x: jnp.sin(x) * 2.0)(np.ones(3, np.float32))
    jax.jit(lambda x: jnp.cos(x) + 1.0)(np.ones(4, np.float32))


def test_compiles_nothing():
    assert 1 + 1 == 2
"""


def test_suite_compiles_records_each_tests_xla_compilations(tmp_path):
    """experiments/diagnostics/suite_compiles.py as a pytest plugin on a file of two tests: the one
    that jits two functions logs two compilations under their names with positive seconds, the
    other none; the summary adds them up per file, per function and per worker, and the report
    names its command."""
    (tmp_path / "test_two.py").write_text(_COMPILING_TESTS)
    log = tmp_path / "log"
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p",
                        "experiments.diagnostics.suite_compiles", "--compile-log", str(log), str(tmp_path / "test_two.py")],
                       capture_output=True, text=True, timeout=300, cwd=REPO,
                       # not named after this test's own xdist worker
                       env={**{k: v for k, v in os.environ.items() if k != "PYTEST_XDIST_WORKER"},
                            "PYTHONPATH": str(REPO)})
    assert r.returncode == 0, r.stdout + r.stderr
    sc = _script("suite_compiles")
    rows = {row["test"].split("::")[-1]: row for row in sc.read_log(log)}
    assert set(rows) == {"test_compiles_two_programs", "test_compiles_nothing"}
    two, none = rows["test_compiles_two_programs"], rows["test_compiles_nothing"]
    assert two["compiles"] == 2 and two["xla_s"] > 0 and sum(n for n, _ in two["by_function"].values()) == 2
    assert all(name.startswith("jit(") for name in two["by_function"]), two["by_function"]
    assert none["compiles"] == 0 and none["xla_s"] == 0 and none["by_function"] == {}
    s = sc.summarise(rows.values())
    assert s["tests"] == 2 and s["compiles"] == 2 and s["xla_s"] == pytest.approx(two["xla_s"])
    (file_row,) = s["files"]
    assert file_row["tests"] == 2 and file_row["compiles"] == 2
    assert [w["name"] for w in s["workers"]] == ["main"] and s["top_tests"][0]["test"].endswith("test_compiles_two_programs")
    out = tmp_path / "sc.md"
    assert sc.main(["--from", str(log), "--out", str(out)]) == 0
    text = out.read_text()
    assert "python -m experiments.diagnostics.suite_compiles --from" in text and "2 tests;" in text
    assert json.loads(out.with_suffix(".json").read_text())["compiles"] == 2
    # a folder that already holds records is not run into, an empty one has nothing to summarise
    assert sc.main(["--log", str(log), "--out", str(out)]) == 2
    (tmp_path / "empty").mkdir()
    assert sc.main(["--from", str(tmp_path / "empty"), "--out", str(out)]) == 2
