"""Session-wide test settings."""
from __future__ import annotations

import os
import shutil
import tempfile

import pytest

# Before jaxvo is imported (importing it switches the compilation cache on): the tests, in
# process and in the subprocesses they start, keep JAX's persistent compilation cache in a
# temporary folder of the session, never in the user's ~/.cache; a test that needs its own
# folder sets JAXVO_CACHE_DIR itself.
_OWN_FOLDER = None
if "JAXVO_CACHE_DIR" not in os.environ:
    _OWN_FOLDER = tempfile.mkdtemp(prefix="jaxvo-test-cache-")
    os.environ["JAXVO_CACHE_DIR"] = _OWN_FOLDER

from jaxvo.runtime import cache  # noqa: E402

assert cache.ENV == "JAXVO_CACHE_DIR"


@pytest.fixture(scope="session", autouse=True)
def _compilation_cache_in_tmp():
    """The session's cache folder is removed at the end (one that JAXVO_CACHE_DIR named is kept)."""
    yield
    if _OWN_FOLDER is not None:
        shutil.rmtree(_OWN_FOLDER, ignore_errors=True)
