"""Mask images on disk, read in one place.

Two kinds of mask PNG:

* **user masks** (``mask_dir`` of a sequence reader): one 8-bit PNG per colour frame, nonzero =
  the pixel may be used (e.g. 0 on a detector's people), named like the colour image or
  ``<timestamp>.png``; matched to frames by :func:`match_masks`, read by :func:`read_frame_mask`.
* **moving-pixel masks** (a sequence's true ``masks/`` as ``jaxvo synth`` and ``jaxvo augment``
  write them, listed by timestamp in ``masks.txt``; or the outlier masks ``jaxvo run`` saves):
  value > 127 = moving; listed by :func:`true_masks` / :func:`read_mask_dir`, read by
  :func:`load_mask` / :func:`load_mask_of_size`.

Masks are (H, W) arrays on the image's pixel grid (row = v, column = u); timestamps are float64
seconds. A mask that does not decode or has the wrong size raises
:class:`jaxvo.data.errors.DatasetError` naming the file.
"""
from __future__ import annotations

from pathlib import Path
from typing import List, Optional, Sequence, Tuple

import numpy as np

from jaxvo.data.errors import DatasetError
from jaxvo.data.stamps import associate
from jaxvo.data.textfiles import read_file_list

__all__ = ["read_mask_dir", "true_masks", "load_mask", "load_mask_of_size", "match_masks", "read_frame_mask"]


def _imread(p: Path, flags: int, why: str) -> np.ndarray:
    """The decoded image at ``p`` (cv2 ``flags``); DatasetError naming it (``why`` in brackets) when it does not decode."""
    import cv2

    m = cv2.imread(str(p), flags)
    if m is None:
        raise DatasetError(f"{p}: mask image does not decode ({why})")
    return m


# ----------------------------------------------------------------------------- moving-pixel masks

def read_mask_dir(folder: Path):
    """(stamps, paths) of ``<timestamp>.png`` files in a folder (sorted by time), or of the masks
    its index ``masks.txt`` lists (``timestamp file ...`` per line, a timestamp may repeat: the
    per-pair masks of ``jaxvo run --save-masks``, each on its reference frame's pixels)."""
    index = Path(folder) / "masks.txt"
    if index.is_file():
        rows = [ln.split() for ln in index.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
        items = sorted((float(r[0]), Path(folder) / r[1]) for r in rows if len(r) >= 2)
        return np.asarray([t for t, _ in items], np.float64), [p for _, p in items]
    items = []
    for p in folder.glob("*.png"):
        try:
            items.append((float(p.stem), p))
        except ValueError:
            continue
    items.sort()
    return np.asarray([t for t, _ in items], np.float64), [p for _, p in items]


def true_masks(seq_dir) -> Optional[Tuple[np.ndarray, list]]:
    """(stamps, paths) of a sequence's true moving-pixel masks (masks.txt, else masks/*.png named by
    timestamp); None if absent."""
    seq_dir = Path(seq_dir)
    if (seq_dir / "masks.txt").is_file():
        t, names = read_file_list(seq_dir / "masks.txt")
        return t, [seq_dir / n for n in names]
    if (seq_dir / "masks").is_dir():
        t, p = read_mask_dir(seq_dir / "masks")
        if t.size:
            return t, p
    return None


def load_mask(p: Path) -> np.ndarray:
    """(H, W) bool mask from a PNG (value > 127 = moving; the first channel of a colour PNG)."""
    import cv2

    m = _imread(p, cv2.IMREAD_UNCHANGED, "corrupt or not an image file")
    if m.ndim == 3:
        m = m[..., 0]
    return m > 127


def load_mask_of_size(p, shape) -> np.ndarray:
    """(H, W) bool moving-pixel mask from an 8-bit PNG (value > 127 = moving); DatasetError naming the
    file if it does not decode or its size is not ``shape`` (H, W)."""
    import cv2

    p = Path(p)
    m = _imread(p, cv2.IMREAD_UNCHANGED, "missing, corrupt or not an image file")
    if m.ndim == 3:
        m = m[..., 0]
    if m.shape != tuple(shape):
        raise DatasetError(f"{p}: mask size {m.shape[1]}x{m.shape[0]} does not match the images' "
                           f"{shape[1]}x{shape[0]}")
    return m > 127


# ----------------------------------------------------------------------------- user masks

def match_masks(mask_dir: Path, rgb_paths: Sequence[Path], timestamps, max_dt: float) -> List[Optional[Path]]:
    """Per frame, the PNG in ``mask_dir`` with the colour image's file name (stem), else the one
    named ``<timestamp>.png`` nearest the frame's timestamp (within ``max_dt`` seconds); None where
    there is none (every pixel usable). ``rgb_paths`` and ``timestamps`` (N,) are the frames'.
    DatasetError when the folder is missing or matches no frame."""
    d = mask_dir
    if not d.is_dir():
        raise DatasetError(f"{d}: mask folder does not exist")
    files = {p.stem: p for p in d.iterdir() if p.suffix.lower() == ".png"}
    stamped = {}
    for stem, p in files.items():
        try:
            stamped[float(stem)] = p
        except ValueError:
            pass
    st = np.asarray(sorted(stamped), np.float64)
    ia, ib = associate(timestamps, st, max_dt) if st.size else (np.zeros(0, int), np.zeros(0, int))
    by_time = {int(i): stamped[float(st[j])] for i, j in zip(ia, ib)}
    out = [files.get(rp.stem, by_time.get(i)) for i, rp in enumerate(rgb_paths)]
    if not any(p is not None for p in out):
        raise DatasetError(f"{d}: no mask PNG matches a frame (expected the colour images' file names, e.g. "
                           f"{rgb_paths[0].stem}.png, or <timestamp>.png)")
    return out


def read_frame_mask(p: Path, shape: Tuple[int, int]) -> np.ndarray:
    """A user mask as (H, W) uint8 greyscale (nonzero = usable); DatasetError naming the file if it
    does not decode or its size is not the image's ``shape`` (H, W)."""
    import cv2

    mask = _imread(p, cv2.IMREAD_GRAYSCALE, "corrupt or not an image file")
    if mask.shape != shape:
        h, w = shape
        raise DatasetError(f"{p}: mask size {mask.shape[1]}x{mask.shape[0]} does not match the image "
                           f"size {w}x{h}")
    return mask
