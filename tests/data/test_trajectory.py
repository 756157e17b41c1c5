"""Tests for jaxvo.data.trajectory: chaining, TUM trajectory I/O, crash-safe writer."""
from __future__ import annotations

import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from jaxvo import geometry as G
from jaxvo.data.errors import DatasetError
from jaxvo.data.textfiles import read_pose_file
from jaxvo.data.trajectory import (HEADER, TrajectoryWriter, chain, format_pose_line, read_tum_trajectory,
                              write_tum_trajectory)


def _random_rel(n, seed=0):
    rng = np.random.default_rng(seed)
    xi = rng.normal(size=(n, 6)) * np.array([0.02, 0.02, 0.02, 0.01, 0.01, 0.01])
    return G.exp(xi)


def test_chain_definition():
    rel = _random_rel(5)
    start = G.exp(np.array([0.1, -0.2, 0.3, 1.0, 2.0, 3.0]))
    P = chain(rel, start)
    assert P.shape == (6, 4, 4) and P.dtype == np.float64
    assert np.allclose(P[0], start)
    for k in range(5):
        # T_cur_ref = inv(T_world_cur) @ T_world_ref
        assert np.allclose(G.inverse(P[k + 1]) @ P[k], rel[k], atol=1e-12)
    assert np.allclose(chain([])[0], np.eye(4))
    assert np.allclose(chain(rel)[0], np.eye(4))


def test_chain_camera_moving_forward():
    # camera moves +10 cm along its own z: a static point 1 m ahead is 0.9 m ahead next frame
    T_cur_ref = np.eye(4)
    T_cur_ref[2, 3] = -0.1
    P = chain([T_cur_ref] * 3)
    assert np.allclose(P[:, :3, 3], [[0, 0, 0], [0, 0, 0.1], [0, 0, 0.2], [0, 0, 0.3]])


def test_write_read_round_trip(tmp_path):
    rel = _random_rel(20, seed=3)
    P = chain(rel, G.exp(np.array([0.5, 0.1, -2.0, 0.3, -0.2, 1.5])))
    t = 1311868164.363181 + np.arange(21) / 30.0
    p = tmp_path / "traj.txt"
    write_tum_trajectory(p, t, P)
    assert p.read_text().splitlines()[0].startswith("#")
    t2, P2 = read_tum_trajectory(p)
    assert np.allclose(t2, t, atol=1e-6, rtol=0)
    assert np.allclose(P2, P, atol=1e-8)


def test_writer_matches_chain_and_batch_writer(tmp_path):
    rel = _random_rel(10, seed=4)
    start = G.exp(np.array([0.0, 0.3, 0.0, 1.0, 0.0, 0.0]))
    t = 100.0 + np.arange(11) * 0.05
    p = tmp_path / "w.txt"
    with TrajectoryWriter(p, start_pose=start) as w:
        w.write_first(t[0])
        for k in range(10):
            w.step(t[k + 1], rel[k])
        assert w.count == 11
    lines = p.read_text().splitlines()
    assert lines[0] == HEADER and len(lines) == 12
    assert len(lines[1].split()) == 8
    t2, P2 = read_tum_trajectory(p)
    assert np.allclose(P2, chain(rel, start), atol=1e-8)
    q = tmp_path / "batch.txt"
    write_tum_trajectory(q, t, chain(rel, start))
    assert q.read_text() == p.read_text()


def test_format_pose_line_precision():
    T = np.eye(4)
    T[:3, 3] = [1.123456789, -2.0, 3.5]
    s = format_pose_line(1548339826.81269, T)
    f = s.split()
    assert f[0] == "1548339826.812690" and f[1] == "1.123456789" and f[4:] == ["0.000000000"] * 3 + ["1.000000000"]


def test_writer_keeps_lines_after_kill(tmp_path):
    """A run killed with SIGKILL mid-way keeps every pose written before the kill."""
    out = tmp_path / "killed.txt"
    code = textwrap.dedent(f"""
        import os, signal, sys, numpy as np
        from jaxvo.data.trajectory import TrajectoryWriter
        w = TrajectoryWriter({str(out)!r}).open()
        w.write_first(0.0)
        T = np.eye(4); T[2, 3] = -0.01
        for k in range(1, 7):
            w.step(k / 30.0, T)
        print("wrote", w.count, flush=True)
        os.kill(os.getpid(), signal.SIGKILL)
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == -signal.SIGKILL, r.stderr
    assert "wrote 7" in r.stdout
    t, P = read_tum_trajectory(out)
    assert t.size == 7
    assert np.allclose(P[:, 2, 3], np.arange(7) * 0.01)


def test_writer_fsync_and_append(tmp_path):
    p = tmp_path / "a.txt"
    with TrajectoryWriter(p, fsync=True) as w:
        w.write(1.0, np.eye(4))
    with TrajectoryWriter(p, append=True, header="") as w:
        w.write(2.0, np.eye(4))
    t, _ = read_tum_trajectory(p)
    assert t.tolist() == [1.0, 2.0]
    with pytest.raises(ValueError, match="NaN"):
        with TrajectoryWriter(p) as w:
            w.write(1.0, np.full((4, 4), np.nan))


def test_read_errors(tmp_path):
    with pytest.raises(DatasetError, match=r"nope\.txt: file not found"):
        read_tum_trajectory(tmp_path / "nope.txt")
    p = tmp_path / "bad.txt"
    p.write_text("# header\n0.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 1\n")
    with pytest.raises(DatasetError, match=r"bad\.txt:3: malformed line .*expected 8 fields"):
        read_tum_trajectory(p)
    p.write_text("0.0 0 0 x 0 0 0 1\n")
    with pytest.raises(DatasetError, match=r"bad\.txt:1: malformed line .*non-numeric"):
        read_tum_trajectory(p)
    p.write_text("0.0 0 0 0 0 0 0 0\n")
    with pytest.raises(DatasetError, match=r"bad\.txt:1: quaternion has zero norm"):
        read_tum_trajectory(p)
    p.write_text("0.0 0 0 nan 0 0 0 1\n")
    with pytest.raises(DatasetError, match=r"bad\.txt:1: non-finite"):
        read_tum_trajectory(p)
    p.write_text("# nothing\n")
    with pytest.raises(DatasetError, match=r"bad\.txt: no poses"):
        read_tum_trajectory(p)
    # several bad lines: the first in the file is named, whichever its fault (the values are
    # checked over many lines at once, the fields line by line)
    for text, first in [("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 0\n2 0 0\n", r":2: quaternion has zero norm"),
                        ("0 0 0 0 0 0 0 1\n1 inf 0 0 0 0 0 1\n0 0 0 0 0 0 0 1\n", r":2: non-finite"),
                        ("0 0 0 0 0 0 0 1\n0 0 0 0 0 0 0 1\n2 nan 0 0 0 0 0 1\n", r":2: timestamp 0 repeats line 1"),
                        ("0 0 0 0 0 0 0 1\n1 0 x 0 0 0 0 1\n2 nan 0 0 0 0 0 1\n", r":2: malformed line .*non-numeric")]:
        p.write_text(text)
        with pytest.raises(DatasetError, match=r"bad\.txt" + first):
            read_tum_trajectory(p)


def test_read_sorts_and_refuses_duplicate_stamps(tmp_path):
    p = tmp_path / "t.txt"
    p.write_text("2.0 2 0 0 0 0 0 1\n1.0 1 0 0 0 0 0 1\n")
    t, P = read_tum_trajectory(p)
    assert t.tolist() == [1.0, 2.0] and P[:, 0, 3].tolist() == [1.0, 2.0]
    # an estimate giving one frame two poses is an error naming the line; ground truth keeps the first
    p.write_text("2.0 2 0 0 0 0 0 1\n1.0 1 0 0 0 0 0 1\n1.0 9 0 0 0 0 0 1\n")
    with pytest.raises(ValueError, match=r"t.txt:3: timestamp 1.0 repeats line 2"):
        read_tum_trajectory(p)
    t, P = read_pose_file(p, duplicates="first")
    assert t.tolist() == [1.0, 2.0] and P[:, 0, 3].tolist() == [1.0, 2.0]


def test_held_poses_are_marked_and_read_back(tmp_path):
    """A held pose gets a '# held <stamp>' line before it: read_held returns its stamp, and the pose
    readers (which skip comments) still read every pose."""
    from jaxvo.data.trajectory import TrajectoryWriter, read_held, read_tum_trajectory
    p = tmp_path / "t.txt"
    with TrajectoryWriter(p) as w:
        w.write_first(1.0)
        w.write(1.033333, np.eye(4), held=True)
        w.write(1.066667, np.eye(4))
    assert np.allclose(read_held(p), [1.033333])
    t, T = read_tum_trajectory(p)
    assert np.allclose(t, [1.0, 1.033333, 1.066667]) and T.shape == (3, 4, 4)
    assert read_held(tmp_path / "t.txt").dtype == np.float64
    q = tmp_path / "plain.txt"
    q.write_text("1.0 0 0 0 0 0 0 1\n")
    assert read_held(q).size == 0
