"""Reproducible runs: Config / TrackConfig JSON round trips and trajectory headers that
`jaxvo run --config TRAJ` reads back to rerun the trajectory bitwise."""
from __future__ import annotations

import json

import jax
import numpy as np
import pytest
from click.testing import CliRunner

import jaxvo
from jaxvo.cli.main import main
from jaxvo.config import Config, TrackConfig
from jaxvo.pipelines.settings import read_run_settings


def test_config_json_round_trip_is_exact_and_generic_over_fields():
    import dataclasses

    c = Config.paper("huber", thresh_lum=12.345678901234, blocks=(2, 1), max_depth=np.float32(3.5))
    back = Config.from_json(c.to_json())
    assert back == c.replace(max_depth=3.5) and isinstance(back.blocks, tuple)
    assert set(json.loads(c.to_json())) == {f.name for f in dataclasses.fields(Config)}
    assert Config.from_json({"method": "classic"}) == Config(method="classic")
    with pytest.raises(ValueError, match="unknown Config field"):
        Config.from_json('{"no_such_field": 1}')
    with pytest.raises(ValueError, match="method"):
        Config.from_json('{"method": "magic"}')
    t = TrackConfig.keyframes(8, hold_invalid=False)
    assert TrackConfig.from_json(t.to_json()) == t
    with pytest.raises(ValueError, match="lag"):
        TrackConfig.from_json('{"max_gap": 2, "lag": 5}')


def test_trajectory_header_round_trip_reproduces_the_file_bitwise(tmp_path):
    from jaxvo.camera import DEFAULT
    from jaxvo.synthetic import generate

    seq = tmp_path / "seq"
    generate("seq1", seq, frames=4, seed=3, camera=DEFAULT.at_level(2))
    first = tmp_path / "first.txt"
    args = ["run", str(seq), "--out", str(first), "--method", "classic", "--seed", "7", "--thresh-lum", "21.5",
            "--keyframe-gap", "2", "--max-frames", "3", "--start", "1", "--no-progress"]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    head = [ln for ln in first.read_text().splitlines() if ln.startswith("#")]
    assert head[0].startswith(f"# jaxvo {jaxvo.__version__}")
    s = read_run_settings(first)
    assert s.seed == 7 and s.config["method"] == "classic" and s.config["thresh_lum"] == 21.5
    assert s.track["max_gap"] == 2 and s.sequence["start"] == 1 and s.sequence["frames"] == 3

    again = tmp_path / "again.txt"
    r = CliRunner().invoke(main, ["run", str(seq), "--config", str(first), "--out", str(again), "--no-progress"])
    assert r.exit_code == 0, r.output
    assert again.read_bytes() == first.read_bytes()
    # a different seed on the command line overrides the header and shows in the new header
    other = tmp_path / "other.txt"
    r = CliRunner().invoke(main, ["run", str(seq), "--config", str(first), "--seed", "8", "--out", str(other),
                                  "--no-progress"])
    assert r.exit_code == 0 and read_run_settings(other).seed == 8


def test_config_file_errors_are_one_line(tmp_path):
    bad = tmp_path / "t.txt"
    bad.write_text("# just a comment\n0 0 0 0 0 0 0 1\n")
    r = CliRunner().invoke(main, ["run", str(tmp_path), "--config", str(bad)])
    assert r.exit_code == 2 and r.output.startswith("error:") and "no '# config:" in r.output


def test_header_records_the_machine_and_a_rerun_elsewhere_says_so(tmp_path):
    """The header names what decides the floats (jaxvo.runtime.machine: CPU, usable cores, jax/jaxlib,
    device); rerunning a file made on this machine prints no note and gives the same bytes,
    one whose record differs gets a note that names each difference."""
    import os

    from jaxvo.runtime import machine
    from jaxvo.camera import DEFAULT
    from jaxvo.synthetic import generate

    seq = tmp_path / "seq"
    generate("seq1", seq, frames=3, seed=1, camera=DEFAULT.at_level(2))
    first = tmp_path / "first.txt"
    r = CliRunner().invoke(main, ["run", str(seq), "--out", str(first), "--method", "classic", "--no-progress"])
    assert r.exit_code == 0, r.output
    rec = read_run_settings(first).machine
    assert rec == machine.record()
    assert rec["cores"] == len(os.sched_getaffinity(0)) >= 1 and rec["jax"] == jax.__version__
    again = tmp_path / "again.txt"
    r = CliRunner().invoke(main, ["run", str(seq), "--config", str(first), "--out", str(again), "--no-progress"])
    assert r.exit_code == 0 and "another machine" not in r.output
    assert again.read_bytes() == first.read_bytes()

    other = dict(rec, cores=rec["cores"] + 6, cpu="Some Other CPU")
    lines = first.read_text().splitlines()
    elsewhere = tmp_path / "elsewhere.txt"
    elsewhere.write_text("\n".join(f"# machine: {json.dumps(other)}" if ln.startswith("# machine:") else ln
                                   for ln in lines) + "\n")
    r = CliRunner().invoke(main, ["run", str(seq), "--config", str(elsewhere), "--out", str(tmp_path / "t.txt"),
                                  "--no-progress"])
    assert r.exit_code == 0, r.output
    note = [ln for ln in r.output.splitlines() if ln.startswith("note:")]
    assert len(note) == 1 and f"cores: {rec['cores'] + 6} -> {rec['cores']}" in note[0]
    assert f"cpu: Some Other CPU -> {rec['cpu']}" in note[0] and "jaxlib" not in note[0]
    # a file from before this header line: no note; a malformed one: one error line
    older = tmp_path / "older.txt"
    older.write_text("\n".join(ln for ln in lines if not ln.startswith("# machine:")) + "\n")
    r = CliRunner().invoke(main, ["run", str(seq), "--config", str(older), "--out", str(tmp_path / "o.txt"),
                                  "--no-progress"])
    assert r.exit_code == 0 and "note:" not in r.output
    bad = tmp_path / "bad.txt"
    bad.write_text("\n".join("# machine: [1, 2]" if ln.startswith("# machine:") else ln for ln in lines) + "\n")
    r = CliRunner().invoke(main, ["run", str(seq), "--config", str(bad), "--out", str(tmp_path / "b.txt")])
    assert r.exit_code == 2 and r.output.startswith("error:") and "'# machine:' header" in r.output


def test_machine_differences_name_only_fields_both_records_have():
    from jaxvo.runtime.machine import differences

    assert differences({"cpu": "A", "cores": 2}, {"cpu": "A", "cores": 2}) == []
    assert differences({"cpu": "A", "cores": 2, "gone": 1}, {"cpu": "B", "cores": 2, "new": 3}) == ["cpu: A -> B"]


def test_instruction_set_names_the_generation_and_vector_extensions():
    """A virtual machine may name every generation of its processors alike ("AMD EPYC"); the
    record tells them apart by family, model and vector flags, in a fixed order."""
    import platform

    from jaxvo.runtime.machine import instruction_set

    zen4 = ("processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 25\nmodel\t\t: 17\n"
            "model name\t: AMD EPYC\nflags\t\t: fpu sse4_2 avx2 avx512f fma avx lm avx512bw\n\n"
            "processor\t: 1\ncpu family\t: 99\nflags\t\t: fpu\n")
    arch = platform.machine()
    assert instruction_set(zen4) == f"{arch} family 25 model 17: avx avx2 avx512bw avx512f fma sse4_2"
    zen2 = zen4.replace("model\t\t: 17", "model\t\t: 49").replace("cpu family\t: 25", "cpu family\t: 23")
    zen2 = zen2.replace(" avx512f", "").replace(" avx512bw", "")
    assert instruction_set(zen2) == f"{arch} family 23 model 49: avx avx2 fma sse4_2"
    # Arm's /proc/cpuinfo: "Features", no family
    assert instruction_set("processor\t: 0\nFeatures\t: fp asimd sve crc32\n") == f"{arch}: asimd sve"
    assert instruction_set().startswith(arch)


def test_config_from_a_trajectory_says_where_each_setting_came_from(tmp_path):
    """--config TRAJ: a 'settings' line names the file (or the command line) per setting, the
    intrinsics are labelled as the header's, one note lists what an older header lacked (filled
    with today's defaults), one says when the header was written for another sequence. The
    progress bar's last rate is the summary's frames/s."""
    import re

    from jaxvo.camera import DEFAULT
    from jaxvo.synthetic import generate

    seq, other = tmp_path / "seq", tmp_path / "other"
    generate("seq1", seq, frames=4, seed=1, camera=DEFAULT.at_level(2))
    generate("seq1", other, frames=4, seed=2, camera=DEFAULT.at_level(2))
    first = tmp_path / "first.txt"
    r = CliRunner().invoke(main, ["run", str(seq), "--out", str(first), "--method", "classic"])
    assert r.exit_code == 0, r.output
    bar_fps = re.findall(r"fps=([0-9.]+)", r.stderr)[-1]
    assert f"speed         {bar_fps} frames/s" in r.stdout

    lines = first.read_text().splitlines()
    older = tmp_path / "older.txt"
    config = json.loads(next(ln for ln in lines if ln.startswith("# config:")).split(": ", 1)[1])
    del config["n_points"]
    older.write_text("\n".join(f"# config: {json.dumps(config)}" if ln.startswith("# config:") else ln
                               for ln in lines if not ln.startswith("# track:")) + "\n")
    r = CliRunner().invoke(main, ["run", str(seq), "--config", str(older), "--start", "1", "--out",
                                  str(tmp_path / "o.txt"), "--no-progress"])
    assert r.exit_code == 0, r.output
    settings = [ln for ln in r.stderr.splitlines() if ln.startswith("settings")]
    assert len(settings) == 1 and f"frames: {older}" in settings[0] and "start: the command line" in settings[0]
    assert f"camera: {older}" in settings[0]
    assert f"(from the header of {older})" in r.stderr
    notes = [ln for ln in r.stderr.splitlines() if ln.startswith("note:") and "lacks" in ln]
    assert len(notes) == 1 and "config.n_points" in notes[0] and "track.max_gap" in notes[0], r.stderr
    assert "sequence." not in notes[0] and "written for" not in r.stderr

    r = CliRunner().invoke(main, ["run", str(other), "--config", str(first), "--out", str(tmp_path / "x.txt"),
                                  "--no-progress"])
    assert r.exit_code == 0, r.output
    assert f"note: {first} was written for {seq}" in r.stderr and "lacks" not in r.stderr
