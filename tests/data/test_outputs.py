"""jaxvo.data.outputs: an output is complete under its name or absent, and a failed write names it."""
from __future__ import annotations

import errno

import numpy as np
import pytest

from jaxvo.data import DatasetError
from jaxvo.data.outputs import check_own_folder, write_errors, write_text, writing
from jaxvo.data.trajectory import TrajectoryWriter, write_tum_trajectory


def _disk_full(*_):
    raise OSError(errno.ENOSPC, "No space left on device")


def _half_then_full(p):
    p.write_text("half")
    _disk_full()


@pytest.mark.parametrize("write", [_disk_full, _half_then_full])
def test_a_failed_write_names_the_file_and_keeps_the_previous_one(tmp_path, write):
    out = tmp_path / "r.json"
    out.write_text("previous")
    with pytest.raises(DatasetError, match=f"{out}: cannot write \\(No space left on device\\)"):
        writing(out, write)
    assert out.read_text() == "previous" and sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]
    assert write_text(out, "new").read_text() == "new"


@pytest.mark.parametrize("where", ["writer", "block"])
def test_disk_full_while_writing_a_trajectory_names_it(tmp_path, monkeypatch, where):
    out = tmp_path / "t.txt"
    if where == "block":
        with pytest.raises(DatasetError, match=f"{tmp_path / 'seq'}: cannot write"):
            with write_errors(tmp_path / "seq"):
                _disk_full()
        return
    w = TrajectoryWriter(out).open()
    monkeypatch.setattr(w._fh, "write", _disk_full)
    with pytest.raises(DatasetError, match=f"{out}: cannot write"):
        w.write_first(0.0)
    w.close()


def test_write_tum_trajectory_is_complete_or_absent(tmp_path, monkeypatch):
    out = tmp_path / "t.txt"
    write_tum_trajectory(out, [0.0], np.eye(4)[None])
    before = out.read_text()
    monkeypatch.setattr("pathlib.Path.write_text", _disk_full)
    with pytest.raises(DatasetError, match="cannot write"):
        write_tum_trajectory(out, [0.0, 1.0], np.stack([np.eye(4)] * 2))
    monkeypatch.undo()
    assert out.read_text() == before


@pytest.mark.parametrize("ours, force, refused", [(False, False, True), (True, False, False), (False, True, False)])
def test_a_folder_the_command_did_not_write_is_not_replaced(tmp_path, ours, force, refused):
    d = tmp_path / "sequence"
    d.mkdir()
    (d / "mine.txt").write_text("keep")
    if refused:
        with pytest.raises(DatasetError, match="was not written by jaxvo"):
            check_own_folder(d, lambda p: ours, force)
    else:
        assert check_own_folder(d, lambda p: ours, force) == d
