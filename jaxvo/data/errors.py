"""The one error type of the data package: bad or unusable input on disk."""
from __future__ import annotations

__all__ = ["DatasetError"]


class DatasetError(ValueError):
    """Bad or unusable input data; the message is one line naming the file and the problem."""
