"""Trajectories: chaining frame-to-frame motions and TUM trajectory files.

Conventions: a trajectory is ``(stamps (N,) float64 seconds, poses (N, 4, 4) float64)``
with ``poses[i] = T_world_cam`` of frame i (camera-to-world, as TUM files). The
estimator returns ``T_cur_ref`` (maps reference-camera points into the current camera),
so ``T_world_cur = T_world_ref @ inv(T_cur_ref)``; chaining is done on the host in
float64.

TUM trajectory file: one line per pose, ``timestamp tx ty tz qx qy qz qw``
(translation in metres, unit quaternion scalar-last), ``#`` comment lines.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Iterable, Optional, Tuple

import numpy as np

from jaxvo import geometry
from jaxvo.data.errors import DatasetError
from jaxvo.data.outputs import write_error, writing
from jaxvo.data.textfiles import read_pose_file

__all__ = ["chain", "read_tum_trajectory", "write_tum_trajectory", "format_pose_line",
           "TrajectoryWriter", "HEADER", "HELD_MARK", "read_held"]

# the comment line before a pose whose estimate failed (the previous pose kept): ``# held <stamp>``
HELD_MARK = "# held"
HEADER = "# timestamp tx ty tz qx qy qz qw  (T_world_cam: camera-to-world, metres, quaternion scalar-last)"


def chain(T_cur_ref_list: Iterable, T_world_first=None) -> np.ndarray:
    """Accumulate frame-to-frame motions into camera poses.

    Args:
      T_cur_ref_list: N transforms (sequence of 4x4 or an (N, 4, 4) array, NumPy or JAX);
        element k maps points of camera k into camera k+1 (``T_cur_ref`` of the pair (k, k+1)).
      T_world_first: pose T_world_cam of frame 0 (default identity).

    Returns:
      (N+1, 4, 4) float64 T_world_cam, ``out[k+1] = out[k] @ inv(T_cur_ref_list[k])``.
    """
    T0 = np.eye(4) if T_world_first is None else geometry.checked_transform(T_world_first, "T_world_first")
    rel = [np.asarray(T, dtype=np.float64) for T in T_cur_ref_list]
    out = np.empty((len(rel) + 1, 4, 4))
    out[0] = T0
    for k, T in enumerate(rel):
        if T.shape != (4, 4):
            raise ValueError(f"T_cur_ref_list[{k}] must be 4x4, got shape {T.shape}")
        out[k + 1] = out[k] @ geometry.inverse(T)
    return out


def format_pose_line(stamp: float, T_world_cam) -> str:
    """One TUM line ``timestamp tx ty tz qx qy qz qw`` (timestamp to 1e-6 s, 9 digits otherwise)."""
    return _pose_line(stamp, geometry.checked_transform(T_world_cam, "pose"))


def _pose_line(stamp: float, T: np.ndarray) -> str:
    """:func:`format_pose_line` of an already checked (4, 4) float64 pose."""
    q, t = geometry.quat_trans_from_transform(T)
    return (f"{float(stamp):.6f} " + " ".join(f"{x:.9f}" for x in t) + " "
            + " ".join(f"{x:.9f}" for x in q))


def read_tum_trajectory(path) -> Tuple[np.ndarray, np.ndarray]:
    """Read a TUM trajectory file -> (stamps (N,) float64, T_world_cam (N, 4, 4) float64).

    Lines are sorted by time. Raises DatasetError (a ValueError) with file, line number and
    problem: missing file, wrong number of fields, non-numeric or non-finite value, zero
    quaternion, a timestamp given twice, no pose at all.
    (No Bonn conversion here: use :func:`jaxvo.data.groundtruth.read_groundtruth` for ground truth.)
    """
    return read_pose_file(path, what="trajectory", duplicates="error")


def read_held(path) -> np.ndarray:
    """(M,) float64 timestamps of the poses a trajectory file marks as held (``# held <stamp>``
    lines, :meth:`TrajectoryWriter.write`); empty for files without them."""
    held = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            if line.startswith(HELD_MARK + " "):
                try:
                    held.append(float(line[len(HELD_MARK):].split()[0]))
                except (ValueError, IndexError):
                    continue
    return np.asarray(held, np.float64)


def write_tum_trajectory(path, stamps, poses, header: str = HEADER) -> None:
    """Write (N,) stamps and (N, 4, 4) T_world_cam poses as a TUM trajectory file: under its
    ``.partial`` name, renamed to ``path`` when complete (replacing it). An OS error (disk full)
    raises DatasetError naming ``path``."""
    stamps = np.asarray(stamps, dtype=np.float64).reshape(-1)
    poses = np.asarray(poses, dtype=np.float64)
    if poses.shape != (stamps.size, 4, 4):
        raise ValueError(f"need (N,) stamps and (N, 4, 4) poses, got {stamps.shape} and {poses.shape}")
    text = "".join(format_pose_line(s, T) + "\n" for s, T in zip(stamps, poses))
    if header:
        text = header.rstrip("\n") + "\n" + text
    writing(path, lambda p: Path(p).write_text(text), keep_suffix=False)


class TrajectoryWriter:
    """Write a TUM trajectory one pose at a time, so an interrupted run keeps every finished frame.

    The file is created (truncated, or appended to with ``append=True``) on entry and gets
    a header comment line; every pose is written as one complete line and flushed at once
    (``fsync=True`` also forces it to disk, surviving a power cut, at some cost).

    Usage::

        with TrajectoryWriter("traj.txt") as w:
            w.write_first(t0)                       # start_pose (identity by default)
            for t, T_cur_ref in ...:
                w.step(t, T_cur_ref)                # T_world_cur = T_world_ref @ inv(T_cur_ref)

    ``write(stamp, T_world_cam)`` writes an absolute pose instead. ``count`` is the number
    of poses written, ``last_pose`` the latest T_world_cam (4x4 float64).
    """

    def __init__(self, path, start_pose=None, append: bool = False, fsync: bool = False,
                 header: str = HEADER):
        self.path = Path(path)
        self.start_pose = np.eye(4) if start_pose is None else geometry.checked_transform(start_pose, "start_pose")
        self.append = append
        self.fsync = fsync
        self.header = header
        self.count = 0
        self.last_pose: Optional[np.ndarray] = None
        self.last_stamp: Optional[float] = None
        self._fh = None

    def open(self) -> "TrajectoryWriter":
        if self._fh is None:
            try:
                self._fh = open(self.path, "a" if self.append else "w", buffering=1)
            except OSError as e:
                raise DatasetError(f"{self.path}: cannot open trajectory file for writing "
                                   f"({e.strerror or e})") from None
            if self.header:
                self._write_line(self.header.rstrip("\n"))
        return self

    def __enter__(self) -> "TrajectoryWriter":
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self._fh is not None:
            fh, self._fh = self._fh, None
            try:
                fh.flush()
            except OSError:
                pass                       # reported by the write that failed
            finally:
                try:
                    fh.close()
                except OSError:
                    pass

    def _write_line(self, line: str) -> None:
        if self._fh is None:
            raise RuntimeError("TrajectoryWriter is not open (use it as a context manager)")
        try:
            self._fh.write(line + "\n")
            self._fh.flush()
            if self.fsync:
                os.fsync(self._fh.fileno())
        except OSError as e:
            raise write_error(self.path, e) from None

    def write(self, stamp: float, T_world_cam, held: bool = False) -> np.ndarray:
        """Write one absolute pose (4x4 T_world_cam) at ``stamp`` seconds; returns it. ``held``: the
        pose is a guess (its estimate failed and the previous pose was kept): a comment line
        ``# held <stamp>`` before it says so (:func:`read_held`), which TUM readers skip."""
        T = geometry.checked_transform(T_world_cam, "T_world_cam")
        line = _pose_line(stamp, T)
        if held:
            self._write_line(f"{HELD_MARK} {line.split()[0]}")
        self._write_line(line)
        self.count += 1
        self.last_pose, self.last_stamp = T.copy(), float(stamp)
        return T

    def write_first(self, stamp: float) -> np.ndarray:
        """Write the first frame's pose (``start_pose``, identity by default)."""
        return self.write(stamp, self.start_pose)

    def step(self, stamp: float, T_cur_ref) -> np.ndarray:
        """Chain a motion estimate: write ``T_world_cur = last_pose @ inv(T_cur_ref)``; returns it.

        If nothing was written yet, the start pose is used as the reference pose (but
        not written: call :meth:`write_first` for the first frame's line).
        """
        ref = self.start_pose if self.last_pose is None else self.last_pose
        T = geometry.checked_transform(T_cur_ref, "T_cur_ref")
        return self.write(stamp, ref @ geometry.inverse(T))
