"""One-line notes of the library (a compilation about to take a while, a cache entry repaired).

They go to the ``jaxvo`` logger at WARNING level, so that without any logging set up Python
prints each as one line on stderr; ``logging.getLogger("jaxvo").setLevel(logging.ERROR)``
silences them, and a program with its own logging set up gets them there. Each kind of note
is given at most once per process.
"""
from __future__ import annotations

import logging

__all__ = ["LOGGER", "note_once", "suppress"]

LOGGER = logging.getLogger("jaxvo")
_GIVEN: set = set()


def note_once(kind: str, message: str) -> bool:
    """Log ``"note: " + message`` unless a note of this ``kind`` was given in this process;
    returns whether it was given now."""
    if kind in _GIVEN:
        return False
    _GIVEN.add(kind)
    LOGGER.warning("note: %s", message)
    return True


def suppress(kind: str) -> None:
    """Give no note of this ``kind`` in this process (a command said it in its own words)."""
    _GIVEN.add(kind)
