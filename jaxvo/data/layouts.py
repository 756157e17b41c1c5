"""Finding and opening sequence folders: the data root, the sequence folders under a root, and
:func:`open_sequence`, which picks the reader from what a folder holds:

* ``rgb.txt`` + ``depth.txt`` (TUM, Bonn RGB-D Dynamic, ETH3D SLAM, jaxvo synthetic):
  :class:`jaxvo.data.tum.TumSequence`;
* ``associations.txt`` (ICL-NUIM): :class:`jaxvo.data.icl_nuim.IclNuimSequence`;
* ``color/`` (or ``image/``) and ``depth/`` folders (Redwood / Open3D):
  :class:`jaxvo.data.redwood.RedwoodSequence`.
"""
from __future__ import annotations

import inspect
import os
from pathlib import Path
from typing import List, Optional, Union

from jaxvo.camera import Camera
from jaxvo.data.calibration import resolve_depth_scale
from jaxvo.data.errors import DatasetError
from jaxvo.data.icl_nuim import IclNuimSequence
from jaxvo.data.redwood import RedwoodSequence
from jaxvo.data.tum import TumSequence, check_reader_options
from jaxvo.validation import check_names

__all__ = ["open_sequence", "find_sequences", "find_sequence", "is_sequence_dir", "data_root"]


def data_root() -> Path:
    """Root of the bundled data: ``$JAXVO_DATA`` if set, else ``<repo>/../shared/data``.

    The TUM excerpts live in ``data_root() / "tum"``, the Bonn ones in ``data_root() / "bonn"``.
    The folder is not required to exist (callers check and report).
    """
    env = os.environ.get("JAXVO_DATA")
    if env:
        return Path(env).expanduser()
    return Path(__file__).resolve().parents[3] / "shared" / "data"


def is_sequence_dir(p: Path) -> bool:
    """True for a folder holding ``rgb.txt`` and ``depth.txt`` (the TUM layout)."""
    return (p / "rgb.txt").is_file() and (p / "depth.txt").is_file()


def find_sequences(root=None, max_depth: int = 4) -> List[Path]:
    """Sorted list of sequence folders (folders holding ``rgb.txt`` and ``depth.txt``) under ``root``.

    ``root`` defaults to :func:`data_root`; it may itself be a sequence folder. The search
    does not descend into sequence folders and stops ``max_depth`` levels below ``root``.
    Returns an empty list when ``root`` does not exist.
    """
    root = Path(root) if root is not None else data_root()
    if not root.is_dir():
        return []
    found = []
    base_depth = len(root.resolve().parts)
    for dirpath, dirnames, _ in os.walk(root):
        p = Path(dirpath)
        if is_sequence_dir(p):
            found.append(p)
            dirnames[:] = []
            continue
        if len(p.resolve().parts) - base_depth >= max_depth:
            dirnames[:] = []
        dirnames.sort()
    return sorted(found)


def find_sequence(name: str, root=None) -> Path:
    """Path of the sequence folder called ``name`` under ``root`` (default :func:`data_root`).

    Raises DatasetError naming the root when it or the sequence is missing.
    """
    root = Path(root) if root is not None else data_root()
    if not root.is_dir():
        raise DatasetError(f"{root}: data folder does not exist (set JAXVO_DATA to the data root)")
    for p in find_sequences(root):
        if p.name == name:
            return p
    raise DatasetError(f"{root}: no sequence folder named {name!r} (with rgb.txt and depth.txt) found")


def open_sequence(path, camera: Optional[Camera] = None, depth_scale: Union[float, str, None] = None,
                  **kwargs) -> TumSequence:
    """Open an RGB-D sequence folder with the reader its content calls for: ``rgb.txt`` + ``depth.txt``
    (TUM, Bonn, ETH3D, jaxvo synthetic) -> :class:`TumSequence`; ``associations.txt`` (ICL-NUIM) ->
    :class:`IclNuimSequence`; ``color/`` (or ``image/``) + ``depth/`` folders (Redwood) ->
    :class:`RedwoodSequence`. ``camera``, ``depth_scale`` (None = the layout's, with the published
    correction of the sensor the folder name identifies where the intrinsics are its preset: TUM
    fr1, fr2, Bonn; ``"recorded"``: the layout's as it is; a sensor name such as ``"fr2"``: the
    layout's with its published depth correction) and ``kwargs`` (max_dt, start, max_frames, bonn,
    lens, ...) go to the reader. So a TUM fr1/fr2 or Bonn folder is read with its dataset's
    published lens and depth correction, as with its intrinsics (``lens="none", depth_scale="recorded"``
    reads the files as they are). Raises DatasetError for anything else,
    and ValueError naming the option and what it may hold for an option of a wrong type or value
    (e.g. ``max_frames="10"``).

    A sequence is lazy: ``seq.frame(i)`` or ``seq[i]`` reads frame i, ``seq[a:b]`` is a sequence of
    the frames a to b - 1, and iterating yields ``(timestamp, Frame)`` pairs (``track`` takes the
    frames: ``(f for _, f in seq)``).
    """
    # a sensor's name is resolved against the layout's scale by the reader
    check_reader_options(path, depth_scale=resolve_depth_scale(depth_scale, 1.0))
    p = Path(path)
    if not p.exists():
        raise DatasetError(f"{p}: sequence folder does not exist")
    if not p.is_dir():
        raise DatasetError(f"{p}: not a folder (expected an RGB-D sequence folder)")
    if is_sequence_dir(p) or (p / "rgb.txt").is_file() or (p / "depth.txt").is_file():
        cls = TumSequence   # with one of the two lists only, TumSequence names the missing one
    elif (p / "associations.txt").is_file():
        cls = IclNuimSequence
    elif (p / "depth").is_dir() and any((p / c).is_dir() for c in RedwoodSequence.COLOR_DIRS):
        cls = RedwoodSequence
    else:
        raise DatasetError(f"{p}: not an RGB-D sequence folder: expected rgb.txt and depth.txt (TUM, Bonn, "
                           f"ETH3D), associations.txt (ICL-NUIM), or color/ and depth/ folders (Redwood)")
    known = {n for c in (TumSequence, cls) for n in inspect.signature(c).parameters} - {"path", "args", "kwargs"}
    check_names(kwargs, known, "open_sequence")
    return cls(p, camera=camera, depth_scale=depth_scale, **kwargs)
