"""The ICL-NUIM layout (TUM-compatible release): ``associations.txt`` ("t depth/N.png t rgb/N.png" per
line, either order), depth value / 5000, ground truth ``groundtruth.txt`` or ``*.gt.freiburg``."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from jaxvo.data.errors import DatasetError
from jaxvo.data.textfiles import _data_lines, _short
from jaxvo.data.tum import TumSequence

__all__ = ["IclNuimSequence"]


class IclNuimSequence(TumSequence):
    """An ICL-NUIM sequence in its TUM-compatible release: ``associations.txt`` lines
    ``t depth/N.png t rgb/N.png`` (or rgb first; the column whose path names ``depth`` is the depth),
    16-bit depth / 5000, ground truth ``groundtruth.txt`` or ``*.gt.freiburg`` (TUM pose format).
    Arguments as :class:`TumSequence`."""
    LAYOUT = "ICL-NUIM"

    def _frame_lists(self):
        lst = self.path / "associations.txt"
        t_rgb, t_dep, f_rgb, f_dep = [], [], [], []
        for n, line in _data_lines(lst):
            parts = line.split()
            try:
                if len(parts) < 4:
                    raise ValueError
                ta, tb = float(parts[0]), float(parts[2])
            except ValueError:
                raise DatasetError(f"{lst}:{n}: malformed line {_short(line)!r} "
                                   f"(expected 'timestamp file timestamp file')") from None
            (td, fd), (tr, fr) = ((ta, parts[1]), (tb, parts[3]))
            if "depth" not in fd.lower():
                (td, fd), (tr, fr) = (tr, fr), (td, fd)
            t_rgb.append(tr), t_dep.append(td), f_rgb.append(fr), f_dep.append(fd)
        if not t_rgb:
            raise DatasetError(f"{lst}: no entries (only comments or empty)")
        order = np.argsort(np.asarray(t_rgb), kind="stable")
        return (np.asarray(t_rgb)[order], np.asarray(t_dep)[order], [self.path / f_rgb[i] for i in order],
                [self.path / f_dep[i] for i in order], ("associations.txt", "associations.txt"))

    @property
    def groundtruth_path(self) -> Path:
        p = self.path / "groundtruth.txt"
        if not p.exists():
            found = sorted(self.path.glob("*.gt.freiburg"))
            if found:
                return found[0]
        return p
