"""TUM text files: frame lists (``rgb.txt`` / ``depth.txt``: ``timestamp filename``) and pose files
(``timestamp tx ty tz qx qy qz qw``), ``#`` comment lines in both.

Timestamps are float64 seconds; poses are (N, 4, 4) float64 as stored. Every problem raises
:class:`jaxvo.data.errors.DatasetError` naming the file (and the line).
"""
from __future__ import annotations

from pathlib import Path
from typing import List, Tuple

import numpy as np

from jaxvo import geometry
from jaxvo.data.errors import DatasetError

__all__ = ["read_file_list", "read_pose_file"]


def _data_lines(path: Path):
    """Yield (line number, stripped line) for non-empty, non-comment lines of a text file."""
    try:
        with open(path, "r", encoding="utf-8", errors="replace") as fh:
            for n, line in enumerate(fh, 1):
                s = line.strip()
                if s and not s.startswith("#"):
                    yield n, s
    except FileNotFoundError:
        raise DatasetError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise DatasetError(f"{path}: is a folder, expected a text file") from None
    except OSError as e:
        raise DatasetError(f"{path}: cannot read file ({e.strerror or e})") from None


def _short(s: str, n: int = 60) -> str:
    return s if len(s) <= n else s[: n - 3] + "..."


def read_file_list(path) -> Tuple[np.ndarray, List[str]]:
    """Read a TUM ``rgb.txt`` / ``depth.txt``: ``timestamp filename`` per line, ``#`` comments.

    Returns (timestamps (N,) float64 sorted ascending, filenames (N,) relative to the folder).
    Extra columns after the filename are ignored (as TUM's associate.py does).

    Raises DatasetError: missing file, malformed line (with its line number), no entry,
    duplicate timestamp.
    """
    path = Path(path)
    stamps, names = [], []
    for n, s in _data_lines(path):
        parts = s.replace(",", " ").split()
        try:
            if len(parts) < 2:
                raise ValueError
            t = float(parts[0])
            if not np.isfinite(t):
                raise ValueError
        except ValueError:
            raise DatasetError(f"{path}:{n}: malformed line {_short(s)!r} (expected 'timestamp filename')") from None
        stamps.append(t)
        # the rest of the line is the name when such a file exists (a name with spaces);
        # otherwise extra columns after the first are ignored
        rest = s.split(None, 1)[1].strip()
        names.append(rest if rest != parts[1] and (path.parent / rest).is_file() else parts[1])
    if not stamps:
        raise DatasetError(f"{path}: no entries (only comments or empty)")
    t = np.asarray(stamps, dtype=np.float64)
    order = np.argsort(t, kind="stable")
    t = t[order]
    names = [names[i] for i in order]
    if np.any(np.diff(t) == 0):
        i = int(np.nonzero(np.diff(t) == 0)[0][0])
        raise DatasetError(f"{path}: duplicate timestamp {t[i]:.6f}")
    return t, names


def read_pose_file(path, what: str = "trajectory", duplicates: str = "first") -> Tuple[np.ndarray, np.ndarray]:
    """Read a TUM pose file (``timestamp tx ty tz qx qy qz qw`` per line, ``#`` comments).

    Returns (timestamps (N,) float64 ascending, poses (N, 4, 4) float64) exactly as stored
    (no Bonn conversion). Unsorted lines are sorted by time. Of lines with the same
    timestamp, ``duplicates="first"`` keeps the first (the original freiburg2_desk ground
    truth has one such duplicate); ``"error"`` raises naming both lines (an estimate must not
    give one frame two poses). Quaternions are normalised.

    Raises DatasetError: missing file, malformed line (number of fields, non-numeric,
    non-finite, zero quaternion; with its line number), empty file.
    """
    path = Path(path)
    rows, lines, texts = [], [], []
    line_of = {}

    def check_values() -> None:
        # the values' checks, over the rows read so far at once (a ground truth holds ~10^4
        # lines), raising for the first bad one in file order
        a = np.asarray(rows, dtype=np.float64).reshape(-1, 8)
        bad_value = ~np.isfinite(a).all(axis=1)
        with np.errstate(invalid="ignore", over="ignore"):
            zero_q = ~bad_value & (np.linalg.norm(a[:, 4:8], axis=1) < 1e-6)
        if (bad_value | zero_q).any():
            i = int(np.argmax(bad_value | zero_q))
            n, s = lines[i], texts[i]
            if bad_value[i]:
                raise DatasetError(f"{path}:{n}: non-finite value in line {_short(s)!r}")
            raise DatasetError(f"{path}:{n}: quaternion has zero norm in line {_short(s)!r}")

    for n, s in _data_lines(path):
        parts = s.replace(",", " ").split()
        if len(parts) != 8:
            check_values()
            raise DatasetError(f"{path}:{n}: malformed line {_short(s)!r} "
                               f"(expected 8 fields 'timestamp tx ty tz qx qy qz qw', got {len(parts)})")
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            check_values()
            raise DatasetError(f"{path}:{n}: malformed line {_short(s)!r} (non-numeric field)") from None
        rows.append(vals)
        lines.append(n)
        texts.append(s)
        if duplicates == "error" and vals[0] in line_of:
            check_values()
            raise DatasetError(f"{path}:{n}: timestamp {parts[0]} repeats line {line_of[vals[0]]} "
                               f"(one pose per timestamp)")
        line_of.setdefault(vals[0], n)
    if not rows:
        raise DatasetError(f"{path}: no poses in {what} file (only comments or empty)")
    check_values()
    a = np.asarray(rows, dtype=np.float64)
    order = np.argsort(a[:, 0], kind="stable")
    a = a[order]
    keep = np.concatenate([[True], np.diff(a[:, 0]) > 0])
    a = a[keep]
    T = geometry.transform_from_quat_trans(a[:, 4:8], a[:, 1:4])
    return a[:, 0].copy(), np.ascontiguousarray(T, dtype=np.float64)
