"""The Redwood / Open3D layout: ``color/`` (or ``image/``) and ``depth/`` folders of numbered images
taken in name order at 30 Hz, depth in millimetres (value / 1000), optional ``camera_intrinsic.json``
(Open3D's PinholeCameraIntrinsic)."""
from __future__ import annotations

import numpy as np

from jaxvo.data.errors import DatasetError
from jaxvo.data.tum import TumSequence, check_reader_options

__all__ = ["RedwoodSequence"]


class RedwoodSequence(TumSequence):
    """A Redwood / Open3D RGB-D folder: ``color/`` (or ``image/``) and ``depth/`` hold
    numbered images paired in name order; there are no timestamps, so frame k is at k / fps
    seconds (30 Hz). Depth defaults to millimetres (depth_scale 1000). An optional
    ``groundtruth.txt`` in TUM format (with those timestamps) is read like TUM's.
    Arguments as :class:`TumSequence`, plus ``fps``."""
    LAYOUT = "Redwood"
    DEPTH_SCALE = 1000.0
    COLOR_DIRS = ("color", "image")

    def __init__(self, path, *args, fps: float = 30.0, **kwargs):
        check_reader_options(path, fps=fps)
        self.fps = float(fps)
        super().__init__(path, *args, **kwargs)

    def _frame_lists(self):
        exts = {".png", ".jpg", ".jpeg"}
        col = next((self.path / c for c in self.COLOR_DIRS if (self.path / c).is_dir()), None)
        if col is None or not (self.path / "depth").is_dir():
            raise DatasetError(f"{self.path}: a Redwood folder needs color/ (or image/) and depth/ folders")
        rgb = sorted(p for p in col.iterdir() if p.suffix.lower() in exts)
        dep = sorted(p for p in (self.path / "depth").iterdir() if p.suffix.lower() == ".png")
        if not rgb or len(rgb) != len(dep):
            raise DatasetError(f"{self.path}: {len(rgb)} colour images in {col.name}/ but {len(dep)} depth PNGs "
                               f"in depth/ (they are paired in name order)")
        t = np.arange(len(rgb), dtype=np.float64) / self.fps
        return t, t.copy(), rgb, dep, (f"{col.name}/", "depth/")
