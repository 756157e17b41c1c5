"""Session-wide test settings.

The suite runs on every core the process may use (``-n auto`` in pyproject.toml, pytest-xdist):
most of its time is XLA compiling one program at a time on one thread, so two workers on two
cores take about half the time. The workers share one compilation cache (below), so a program
that both need is compiled once, and the tests that share the ``jaxvo_run`` fixture run on one
worker (``--dist loadgroup``), which runs each of those runs once."""
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
# Set in the controlling process before it starts the xdist workers, which inherit it.
if "JAXVO_CACHE_DIR" not in os.environ:
    os.environ["JAXVO_CACHE_DIR"] = tempfile.mkdtemp(prefix="jaxvo-test-cache-")
    atexit.register(shutil.rmtree, os.environ["JAXVO_CACHE_DIR"], ignore_errors=True)

from jaxvo.runtime import cache  # noqa: E402

assert cache.ENV == "JAXVO_CACHE_DIR"

import pytest  # noqa: E402

#: Workers at most: each holds its own compiled programs (a few GB by the end of the suite).
MAX_WORKERS = 4


def pytest_xdist_auto_num_workers(config):
    """``-n auto``: one worker per core this process may run on, at most MAX_WORKERS."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:   # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, MAX_WORKERS))


def pytest_collection_modifyitems(config, items):
    """The tests that read ``jaxvo_run`` form one xdist group: one worker, each run once."""
    for item in items:
        if "jaxvo_run" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.xdist_group("jaxvo_run"))


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
