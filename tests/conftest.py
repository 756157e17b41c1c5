"""Session-wide test settings."""
from __future__ import annotations

import atexit
import os
import shutil
import tempfile

# Before jaxvo is imported (importing it switches the compilation cache on): the tests, in
# process and in the subprocesses they start, keep JAX's persistent compilation cache in a
# temporary folder of the session, never in the user's ~/.cache; a test that needs its own
# folder sets JAXVO_CACHE_DIR itself. The folder is removed at exit, after the background
# compilations (jaxvo.tracking.static_map) that may still write to it have finished.
if "JAXVO_CACHE_DIR" not in os.environ:
    os.environ["JAXVO_CACHE_DIR"] = tempfile.mkdtemp(prefix="jaxvo-test-cache-")
    atexit.register(shutil.rmtree, os.environ["JAXVO_CACHE_DIR"], ignore_errors=True)

from jaxvo.runtime import cache  # noqa: E402

assert cache.ENV == "JAXVO_CACHE_DIR"
