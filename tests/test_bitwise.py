"""Trajectories of ``jaxvo run`` pinned bit for bit.

``tests/fixtures/bitwise/<machine>/`` holds the trajectories that ``jaxvo run`` wrote, on the
machines this project's CI runs on (one folder each), for the freiburg2_desk and Bonn crowd excerpts with the defaults, ``--method
classic`` and ``--paper``, seeds 0-2, each over the stretch of frames its ``# sequence:`` line
records: the whole excerpts for the defaults and classic on freiburg2_desk and the defaults on
Bonn, shorter stretches (people, an exposure change, failed frames) for the rest (see
``tests/fixtures/bitwise/README.md``). A change that only moves code must reproduce every
pose line and the settings it records byte for byte. A change that is meant to alter the
estimates regenerates the files with the command in that README and says so in its commit.

XLA's CPU code depends on the processor, so the files hold on the machine that wrote them: the
test compares the folder whose recorded machine (``# machine:``: CPU model, instruction set,
jax and jaxlib) is this one, and skips with a message where none is. The folder written before
the instruction set was recorded (its files' machine lines have no ``isa``) stands for the
machines with its CPU model name that no folder with an ``isa`` covers.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import pytest

from jaxvo.data import TumSequence
from jaxvo.data.layouts import data_root
from jaxvo.runtime import machine

FIXTURES = Path(__file__).resolve().parent / "fixtures" / "bitwise"
SEQUENCES = {"rgbd_dataset_freiburg2_desk": "tum", "rgbd_bonn_crowd": "bonn"}
MODES = {"default": [], "classic": ["--method", "classic"], "paper": ["--paper"]}
COMPARED = ("# method:", "# seed:", "# config:", "# track:")
#: What a pinned file's ``# machine:`` record must share with this machine for its floats to hold.
MATCHED = ("cpu", "isa", "jax", "jaxlib")


def _split(text: str):
    """(the settings lines compared, the pose lines) of a trajectory file."""
    lines = text.splitlines()
    return [l for l in lines if l.startswith(COMPARED)], [l for l in lines if not l.startswith("#")]


def _recorded(text: str, field: str) -> dict:
    """The JSON of the ``# field:`` header line (machine, sequence, ...)."""
    line = next(l for l in text.splitlines() if l.startswith(f"# {field}:"))
    return json.loads(line.split(":", 1)[1])


def pinned_folder(here: dict, folders) -> Optional[Path]:
    """The folder of ``folders`` whose files were written on a machine like ``here`` (every field
    of MATCHED equal): one whose files record an ``isa`` first, else one written before the
    instruction set was recorded whose other fields match; None if none is."""
    legacy = None
    for folder in folders:
        files = sorted(folder.glob("*.txt"))
        if not files:
            continue
        rec = _recorded(files[0].read_text(), "machine")
        if all(rec.get(f) == here.get(f) for f in MATCHED if f != "isa"):
            if rec.get("isa") == here.get("isa"):
                return folder
            if "isa" not in rec and legacy is None:
                legacy = folder
    return legacy


def _frame_options(seq: Path, pinned: str):
    """--start / --max-frames of the pinned stretch (its ``# sequence:`` line), none where it is
    the whole excerpt: the whole-excerpt runs are then the argument lists that
    tests/cli/test_cli.py evaluates, and the session runs each once (conftest.jaxvo_run)."""
    rec = _recorded(pinned, "sequence")
    start, frames = rec["start"], rec["frames"]
    return ["--start", start, "--max-frames", frames] if start or frames < len(TumSequence(seq)) else []


@pytest.mark.parametrize("mode", list(MODES))
@pytest.mark.parametrize("name", list(SEQUENCES))
def test_run_reproduces_the_pinned_trajectories(jaxvo_run, name, mode):
    seq = data_root() / SEQUENCES[name] / name
    if not seq.is_dir():
        pytest.skip(f"{seq} is missing (set JAXVO_DATA to the folder holding tum/ and bonn/)")
    here = machine.record()
    folders = sorted(d for d in FIXTURES.iterdir() if d.is_dir())
    folder = pinned_folder(here, folders)
    if folder is None:
        pytest.skip(f"pinned on {', '.join(d.name for d in folders)}; none is this machine "
                    f"({here['cpu']}, {here['isa']}, jax {here['jax']}): see tests/fixtures/bitwise/README.md")
    for seed in (0, 1, 2):
        pinned = (folder / f"{name}_{mode}_s{seed}.txt").read_text()
        result, out = jaxvo_run(seq, *MODES[mode], "--seed", seed, *_frame_options(seq, pinned))
        assert result.exit_code == 0, result.output
        got_settings, got_poses = _split(out.read_text())
        want_settings, want_poses = _split(pinned)
        assert got_settings == want_settings, f"{name} {mode} seed {seed}: settings differ"
        diff = [i for i, (a, b) in enumerate(zip(got_poses, want_poses)) if a != b]
        assert len(got_poses) == len(want_poses) and not diff, \
            f"{folder.name}/{name} {mode} seed {seed}: {len(diff)} of {len(want_poses)} poses differ, first at line {diff[:1]}"


def _record_line(rec: dict) -> str:
    return f"# machine: {json.dumps(rec)}\npose lines\n"


def test_pinned_folder_is_the_one_of_this_machines_instruction_set(tmp_path):
    here = {"cpu": "AMD EPYC", "isa": "x86_64 family 25 model 17: avx avx512f", "cores": 2, "jax": "0.10.2",
            "jaxlib": "0.10.2"}
    folders = {}
    for name, changes in {"legacy": {"isa": None}, "avx2": {"isa": "x86_64 family 23 model 49: avx avx2"},
                          "avx512": {}, "other-jax": {"jax": "0.10.1"}}.items():
        rec = {k: v for k, v in {**here, **changes}.items() if v is not None}
        folders[name] = tmp_path / name
        folders[name].mkdir()
        (folders[name] / "a_default_s0.txt").write_text(_record_line(rec))
    every = sorted(folders.values())
    assert pinned_folder(here, every) == folders["avx512"]
    # a machine of the same model name with an instruction set no folder records: the legacy files
    assert pinned_folder({**here, "isa": "x86_64 family 25 model 1: avx avx2"}, every) == folders["legacy"]
    assert pinned_folder({**here, "isa": "x86_64 family 23 model 49: avx avx2"}, every) == folders["avx2"]
    # another jax, or another CPU model, and no folder of its own: nothing to compare
    assert pinned_folder({**here, "jax": "0.11.0"}, every) is None
    assert pinned_folder({**here, "cpu": "Intel Xeon"}, every) is None
    assert pinned_folder(here, [folders["avx2"], folders["other-jax"]]) is None
