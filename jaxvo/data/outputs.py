"""Safe outputs: never write over an input, never leave a half-written file under the final name.

* :func:`check_output` refuses an output path that equals an input file or folder or lies
  inside an input folder (unless ``force``), and one whose parent is a file.
* :func:`partial_path` is where a file or folder is written until it is complete;
  :func:`finish` moves it to its final name (``os.replace``, atomic on one file system).
  A run that fails half way leaves its work under the ``.partial`` name, so a previous
  result under the final name is never clobbered by an incomplete one.

* :func:`writing` wraps a writer: the file goes to its ``.partial`` name and is renamed when
  the writer returns; an OS error (disk full, no permission) names the path
  (:func:`write_error`); :func:`write_text` writes a small text file that way.
* :func:`check_own_folder` refuses to replace a folder the command did not create.

Errors are :class:`jaxvo.data.errors.DatasetError` with one line naming the path.
"""
from __future__ import annotations

import contextlib
import os
import shutil
from pathlib import Path
from typing import Callable, Iterable

from jaxvo.data.errors import DatasetError

__all__ = ["check_output", "check_output_folder", "partial_path", "finish", "write_error", "write_text",
           "writing", "write_errors", "check_own_folder"]


def _inside(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def check_output(out, inputs: Iterable = (), force: bool = False, option: str = "") -> Path:
    """Check that writing ``out`` cannot destroy an input; returns ``Path(out)``.

    ``inputs`` are files or folders the command reads (None entries are skipped). Raises
    DatasetError when ``out`` is one of them or lies inside one of the folders (unless
    ``force``), when ``out`` is an existing folder, or when a parent of ``out`` is a file.
    ``option`` (e.g. ``"--out"``) names the option in the message.
    """
    out = Path(out)
    label = f"{option} {out}" if option else str(out)
    target = out.resolve()
    for parent in target.parents:
        if parent.exists():
            if not parent.is_dir():
                raise DatasetError(f"{label}: cannot write there, {parent} is a file, not a folder")
            break
    if not force:
        for inp in inputs:
            if inp is None:
                continue
            src = Path(inp).resolve()
            if target == src or (src.is_dir() and _inside(target, src)):
                what = "is" if target == src else "lies inside"
                raise DatasetError(f"{label}: {what} the input {inp}; writing there would overwrite or mix with "
                                   f"it (choose another path, or pass --force)")
    return out


def check_output_folder(out, inputs: Iterable = (), force: bool = False, option: str = "") -> Path:
    """:func:`check_output` for an output folder, which also must not exist with files in it
    (unless ``force``: then it is replaced once the new one is complete)."""
    out = check_output(out, inputs, force, option)
    label = f"{option} {out}" if option else str(out)
    if out.exists() and not out.is_dir():
        raise DatasetError(f"{label}: exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise DatasetError(f"{label}: folder exists and is not empty (choose another folder, or pass --force "
                           f"to replace it)")
    return out


def partial_path(out, keep_suffix: bool = False, fresh: bool = False) -> Path:
    """``out`` + ``.partial`` (``name.partial.ext`` with ``keep_suffix``, for writers that pick the
    format by extension). ``fresh`` removes an old partial folder, so an attempt starts clean."""
    out = Path(out)
    p = out.with_name(f"{out.stem}.partial{out.suffix}") if keep_suffix and out.suffix else \
        out.with_name(out.name + ".partial")
    if fresh and p.is_dir():
        shutil.rmtree(p)
    return p


def finish(partial, out) -> Path:
    """Move the complete ``partial`` to ``out`` (a folder ``out`` is replaced); returns ``Path(out)``."""
    partial, out = Path(partial), Path(out)
    if out.is_dir() and partial.is_dir():
        shutil.rmtree(out)
    try:
        os.replace(partial, out)
    except OSError as e:
        raise DatasetError(f"{out}: cannot move the finished {partial} there ({e.strerror or e})") from None
    return out


def write_error(path, e: OSError) -> DatasetError:
    """The one-line error of a failed write of ``path`` (disk full, no permission, ...): the OS
    message alone names no file."""
    return DatasetError(f"{path}: cannot write ({e.strerror or e})")


@contextlib.contextmanager
def write_errors(path):
    """Inside: an OSError that names no file (disk full while writing: ``[Errno 28] No space
    left on device``) raises :func:`write_error` naming ``path`` (the output being written)."""
    try:
        yield
    except OSError as e:
        if isinstance(e, DatasetError) or e.filename:
            raise
        raise write_error(path, e) from None


def writing(out, write: Callable[[Path], object], keep_suffix: bool = True) -> Path:
    """Write ``out`` completely or not at all: ``write(partial)`` writes the file under its
    ``.partial`` name (``name.partial.ext`` with ``keep_suffix``), which then becomes ``out``.
    An OSError of the writer raises :func:`write_error` naming ``out`` (the partial file is
    removed: it is incomplete). Returns ``Path(out)``."""
    out = Path(out)
    tmp = partial_path(out, keep_suffix=keep_suffix)
    try:
        write(tmp)
    except OSError as e:
        try:
            tmp.unlink()
        except OSError:
            pass
        raise write_error(out, e) from None
    return finish(tmp, out)


def write_text(out, text: str) -> Path:
    """Write a small text file ``out`` completely or not at all (:func:`writing`)."""
    return writing(out, lambda p: Path(p).write_text(text), keep_suffix=False)


def check_own_folder(folder, is_ours: Callable[[Path], bool], force: bool = False, option: str = "") -> Path:
    """A folder a command fills and may replace on a later run (the demo's ``sequence/``):
    refused when it exists, holds files and ``is_ours(folder)`` says this command did not make
    it (unless ``force``), so nothing the user put there is deleted. Returns ``Path(folder)``."""
    folder = Path(folder)
    if folder.exists() and not force:
        if not folder.is_dir():
            raise DatasetError(f"{option + ' ' if option else ''}{folder}: exists and is not a folder")
        if any(folder.iterdir()) and not is_ours(folder):
            raise DatasetError(f"{folder}: exists and was not written by jaxvo; it would be replaced (choose "
                               f"another folder, or pass --force)")
    return folder
