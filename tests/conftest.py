"""Session-wide test settings.

The suite runs on every core the process may use (``-n auto`` in pyproject.toml, pytest-xdist):
most of its time is XLA compiling one program at a time on one thread, so two workers on two
cores take about half the time. The workers share one compilation cache (below), so a program
that both need is compiled once, and the tests that share the ``jaxvo_run`` fixture run on one
worker, which runs each of those runs once (pytest_xdist_make_scheduler)."""
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


@pytest.hookimpl(optionalhook=True)   # a hook of pytest-xdist
def pytest_xdist_auto_num_workers(config):
    """``-n auto``: one worker per core this process may run on, at most MAX_WORKERS."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:   # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, MAX_WORKERS))


#: The test modules that read the ``jaxvo_run`` fixture: xdist runs them on one worker, which
#: makes each run once (pytest_xdist_make_scheduler); pytest_collection_modifyitems keeps the list true.
JAXVO_RUN_MODULES = ("tests/test_bitwise.py", "tests/cli/test_cli.py")


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """Each test is its own unit of work (as xdist's ``load``), except the modules of
    JAXVO_RUN_MODULES, which are one unit together. (xdist's ``loadgroup`` marks do not reach its
    scheduler with pytest 9.2, which keeps node ids elsewhere than xdist writes its group names.)"""
    from xdist.scheduler import LoadScopeScheduling

    class Scheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid):
            return "jaxvo_run" if nodeid.split("::")[0] in JAXVO_RUN_MODULES else nodeid

    return Scheduling(config, log)


def pytest_collection_modifyitems(config, items):
    """A test that reads ``jaxvo_run`` outside JAXVO_RUN_MODULES is an error: it would repeat runs."""
    for item in items:
        path = item.nodeid.split("::")[0]
        if "jaxvo_run" in getattr(item, "fixturenames", ()) and path not in JAXVO_RUN_MODULES:
            raise pytest.UsageError(f"{item.nodeid} reads jaxvo_run: add {path} to JAXVO_RUN_MODULES in tests/conftest.py")


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


@pytest.fixture
def aot_restored():
    """For a test that points jaxvo.runtime.aot at a folder of its own (or none): the session's
    folder is put back afterwards, so that the later tests of the worker run the exported
    programs, as the commands do, and do not compile the plain jit path of each program again."""
    from jaxvo.runtime import aot

    before = aot.folder()
    yield
    aot.enable(before)
