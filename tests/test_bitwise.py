"""Trajectories of ``jaxvo run`` pinned bit for bit.

``tests/fixtures/bitwise/`` holds the trajectories that ``jaxvo run`` wrote, on this project's
CI machine, for the freiburg2_desk and Bonn crowd excerpts with the defaults, ``--method
classic`` and ``--paper``, seeds 0-2, each over the stretch of frames its ``# sequence:`` line
records: the whole excerpts for the defaults and classic on freiburg2_desk and the defaults on
Bonn, shorter stretches (people, an exposure change, failed frames) for the rest (see
``tests/fixtures/bitwise/README.md``). A change that only moves code must reproduce every
pose line and the settings it records byte for byte. A change that is meant to alter the
estimates regenerates the files with the command in that README and says so in its commit.

XLA's CPU code depends on the processor, so the files hold on the machine that wrote them: the
test compares where the recorded machine matches this one, and skips with a message elsewhere.
"""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from jaxvo.data import TumSequence
from jaxvo.data.layouts import data_root
from jaxvo.runtime import machine

FIXTURES = Path(__file__).resolve().parent / "fixtures" / "bitwise"
SEQUENCES = {"rgbd_dataset_freiburg2_desk": "tum", "rgbd_bonn_crowd": "bonn"}
MODES = {"default": [], "classic": ["--method", "classic"], "paper": ["--paper"]}
COMPARED = ("# method:", "# seed:", "# config:", "# track:")


def _split(text: str):
    """(the settings lines compared, the pose lines) of a trajectory file."""
    lines = text.splitlines()
    return [l for l in lines if l.startswith(COMPARED)], [l for l in lines if not l.startswith("#")]


def _recorded(text: str, field: str) -> dict:
    """The JSON of the ``# field:`` header line (machine, sequence, ...)."""
    line = next(l for l in text.splitlines() if l.startswith(f"# {field}:"))
    return json.loads(line.split(":", 1)[1])


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
    for seed in (0, 1, 2):
        pinned = (FIXTURES / f"{name}_{mode}_s{seed}.txt").read_text()
        rec = _recorded(pinned, "machine")
        if (rec["cpu"], rec["jax"], rec["jaxlib"]) != (here["cpu"], here["jax"], here["jaxlib"]):
            pytest.skip(f"pinned on {rec['cpu']} with jax {rec['jax']}; this is {here['cpu']} with jax {here['jax']}")
        result, out = jaxvo_run(seq, *MODES[mode], "--seed", seed, *_frame_options(seq, pinned))
        assert result.exit_code == 0, result.output
        got_settings, got_poses = _split(out.read_text())
        want_settings, want_poses = _split(pinned)
        assert got_settings == want_settings, f"{name} {mode} seed {seed}: settings differ"
        diff = [i for i, (a, b) in enumerate(zip(got_poses, want_poses)) if a != b]
        assert len(got_poses) == len(want_poses) and not diff, \
            f"{name} {mode} seed {seed}: {len(diff)} of {len(want_poses)} poses differ, first at line {diff[:1]}"
