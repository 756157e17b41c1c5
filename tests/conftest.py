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

import pytest  # noqa: E402


@pytest.fixture(scope="session")
def jaxvo_run(tmp_path_factory):
    """``jaxvo_run(sequence, *options)``: ``jaxvo run SEQUENCE OPTIONS --out FILE --no-progress``
    through click's CliRunner, run once per distinct argument list in the session and shared by the
    tests that read it (test_bitwise.py pins trajectories that test_cli.py evaluates). Returns
    (the click Result, the trajectory's Path); the Result's exit code is the caller's to check."""
    from click.testing import CliRunner

    from jaxvo.cli.main import main

    runs = {}

    def run(*args):
        key = tuple(str(a) for a in args)
        if key not in runs:
            out = tmp_path_factory.mktemp("jaxvo_run") / "traj.txt"
            result = CliRunner().invoke(main, ["run", *key, "--out", str(out), "--no-progress"],
                                        catch_exceptions=False)
            runs[key] = result, out
        return runs[key]

    return run
