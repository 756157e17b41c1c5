"""jaxvo.pipelines: what each command does, called from Python, each result a frozen dataclass."""
from __future__ import annotations

import dataclasses
import json

import pytest

from jaxvo.camera import DEFAULT, LENSES, NO_LENS
from jaxvo.config import Config, TrackConfig
from jaxvo.data import DatasetError, TumSequence
from jaxvo.data.trajectory import write_tum_trajectory
from jaxvo.pipelines.mapping import KeptPoses, MapRun, map_sequence, read_kept_poses
from jaxvo.pipelines.masks import MasksRun, write_hindsight_masks
from jaxvo.pipelines.run import RunPlan, RunReport, SequenceRun, execute_run, expand_sequences, plan_run
from jaxvo.pipelines.settings import ReaderOptions, RunSettings, RunSetup, read_run_settings, run_header, setup_run

CAM = DEFAULT.at_level(2)   # 160x120: fast to render and to track


@pytest.fixture(scope="module")
def seqs(tmp_path_factory):
    """A folder holding two synthetic sequences, and the ground truth of the first as a trajectory."""
    from jaxvo.synthetic import generate

    root = tmp_path_factory.mktemp("pipelines") / "many"
    a = generate("seq1", root / "a", frames=4, seed=0, camera=CAM)
    b = generate("seq0", root / "b", frames=3, seed=1, camera=CAM)
    return root, a, b


def _frozen(obj):
    field = dataclasses.fields(obj)[0].name
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(obj, field, None)


def test_read_run_settings_gives_a_frozen_record(tmp_path, seqs):
    _, a, _ = seqs
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"p": 0.9}))
    s = read_run_settings(cfg)
    assert s == RunSettings(config={"p": 0.9}) and s.seed is None and s.track is None and s.machine is None
    _frozen(s)
    seq = TumSequence(a, camera=CAM, start=1, max_frames=2)
    traj = tmp_path / "t.txt"
    traj.write_text("\n".join(run_header(Config(method="huber"), TrackConfig.keyframes(3), 7, seq)) + "\n")
    s = read_run_settings(traj)
    assert s.seed == 7 and s.config["method"] == "huber" and s.track["max_gap"] == 3
    assert s.sequence["start"] == 1 and s.sequence["frames"] == 2 and isinstance(s.machine, dict)


def test_setup_run_merges_a_trajectory_header_under_the_options_given(tmp_path, seqs):
    _, a, _ = seqs
    seq = TumSequence(a, camera=CAM, start=1, max_frames=2, max_dt=0.03)
    traj = tmp_path / "t.txt"
    traj.write_text("\n".join(run_header(Config(method="huber"), TrackConfig.keyframes(3), 7, seq)) + "\n")
    s = setup_run(traj)
    assert isinstance(s, RunSetup) and s.seed == 7 and s.config.method == "huber" and s.policy.max_gap == 3
    assert s.reader == ReaderOptions(fx=CAM.fx, fy=CAM.fy, cx=CAM.cx, cy=CAM.cy, depth_scale=5000.0, max_dt=0.03,
                                     start=1, max_frames=2, camera_from=f"the header of {traj}", lens=NO_LENS)
    # a lens the run read with is read back with its header; one given overrides it
    lensed = tmp_path / "lens.txt"
    lensed.write_text("\n".join(run_header(Config(), TrackConfig(), 0, TumSequence(a, camera=CAM, lens="fr2")))
                      + "\n")
    assert setup_run(lensed).reader.lens == LENSES["fr2"]
    assert setup_run(lensed, lens=LENSES["bonn"]).reader.lens == LENSES["bonn"]
    assert setup_run(lensed).reader.open(a).lens == LENSES["fr2"]
    assert s.machine_differences == () and s.missing == () and s.header_sequence == str(a)
    assert f"frames: {traj}" in s.sources and f"camera: {traj}" in s.sources
    _frozen(s)
    given = setup_run(traj, seed=3, start=0, method="classic", camera_preset="fr1")
    assert given.seed == 3 and given.reader.start == 0 and given.config.method == "classic"
    assert given.reader.camera_preset == "fr1" and given.reader.fx is None     # a preset replaces the header's
    assert "start: the command line" in given.sources and "camera: the command line" in given.sources
    many = setup_run(traj, from_header=False)
    assert many.seed == 7 and many.reader == ReaderOptions()
    plain = setup_run(paper=True)
    assert plain.seed == 0 and plain.config == Config.paper("ransac") and plain.policy == TrackConfig.frame_to_frame()


def test_expand_and_plan_group_sequences_by_image_size(tmp_path, seqs):
    root, a, b = seqs
    assert expand_sequences([root]) == [a, b]
    assert expand_sequences([a]) == [a]
    plan = plan_run([a, b], setup_run(method="classic"), out_dir=tmp_path / "trajs")
    assert isinstance(plan, RunPlan) and plan.batches == ((0, 1),) and (tmp_path / "trajs").is_dir()
    assert plan.outputs == (tmp_path / "trajs" / "a.txt", tmp_path / "trajs" / "b.txt")
    _frozen(plan)
    with pytest.raises(DatasetError, match="lies inside the input"):
        plan_run([a], setup_run(), out=a / "t.txt")
    with pytest.raises(DatasetError, match="only 1 frame"):
        plan_run([a], setup_run(max_frames=1), out=tmp_path / "t.txt")


def test_execute_run_writes_the_trajectory_and_reports_its_errors(tmp_path, seqs):
    _, a, _ = seqs
    out = tmp_path / "t.txt"
    seen = []
    plan = plan_run([a], setup_run(method="classic", seed=2), out=out)
    report = execute_run(plan, on_pair=lambda k, step: seen.append((k, step.frame)))
    assert isinstance(report, RunReport) and not report.interrupted and len(report.runs) == 1
    run = report.runs[0]
    assert isinstance(run, SequenceRun) and run.trajectory == out and out.is_file()
    assert seen == [(0, 1), (0, 2), (0, 3)] and run.result.pairs == 3 and run.result.method == "classic"
    assert run.errors.rpe_1f is not None and run.errors.ate is not None
    assert read_run_settings(out).seed == 2
    _frozen(report)
    _frozen(run.result)


def test_map_and_masks_pipelines_leave_held_poses_out(tmp_path, seqs):
    _, a, _ = seqs
    seq = TumSequence(a, camera=CAM)
    stamps, poses = seq.timestamps, seq.groundtruth_at_frames()[1]
    traj = tmp_path / "traj.txt"
    write_tum_trajectory(traj, stamps, poses)
    text = traj.read_text().splitlines()
    data = [i for i, ln in enumerate(text) if ln and not ln.startswith("#")]
    text.insert(data[2], f"# held {text[data[2]].split()[0]}")
    traj.write_text("\n".join(text) + "\n")
    kept = read_kept_poses(traj)
    assert isinstance(kept, KeptPoses) and kept.held == 1 and len(kept.stamps) == 3

    started = []
    run = map_sequence(a, traj, tmp_path / "m.ply", every=1, labels="masks", preview=tmp_path / "m.png",
                       on_start=lambda s, held: started.append(held))
    assert isinstance(run, MapRun) and started == [1] and run.held == 1 and run.labels == "masks"
    assert run.ply.is_file() and run.preview.is_file() and len(run.map.frames) == 3 and run.map.cloud.moving.any()
    _frozen(run)
    _frozen(run.map)
    with pytest.raises(DatasetError, match="no pixel with valid depth"):
        map_sequence(a, traj, tmp_path / "n.ply", labels=None, max_depth=1e-3)

    masks = write_hindsight_masks(a, traj, tmp_path / "masks", offsets=[-1, 1])
    assert isinstance(masks, MasksRun) and masks.posed == 3 and masks.held == 1 and masks.moving.shape == (3,)
    assert sorted(p.name for p in (tmp_path / "masks").iterdir()) == \
        sorted(f"{seq.timestamps[i]:.6f}.png" for i in (0, 1, 3))
    _frozen(masks)
