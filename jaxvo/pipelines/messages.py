"""One-line error messages: what a command prints after ``error:`` and what a pipeline adds to an
error it passes on (where the finished work was kept)."""
from __future__ import annotations

from jaxvo.data import DatasetError

__all__ = ["one_line", "one_line_text"]


def one_line_text(msg: str) -> str:
    """``msg`` with its lines stripped and joined by single spaces."""
    return " ".join(ln.strip() for ln in str(msg).splitlines() if ln.strip())


def one_line(e: BaseException) -> str:
    """The message of an exception on one line: ``file: reason`` for an OSError with both, else its
    text, else the exception's type name."""
    if isinstance(e, OSError) and not isinstance(e, DatasetError) and e.filename and e.strerror:
        msg = f"{e.filename}: {e.strerror}"
    else:
        msg = str(e) or type(e).__name__
    return one_line_text(msg) or type(e).__name__
