"""Where the test suite's time goes: XLA's compilations of each test, the README's test command.

Most of ``python -m pytest -q`` is XLA compiling programs (docs/decisions/test-suite.md), one
program at a time per xdist worker, so the suite's time follows the number of distinct programs
its tests compile. This diagnostic runs the suite with itself as a pytest plugin, which records
for every test, in every worker: its wall time and each XLA compilation JAX reports
(``jax.monitoring``'s backend-compile event: the compiled function's name and seconds; a cache
hit compiles nothing). It then writes what the suite spent per worker, per test file, per
compiled function and per test.

Programs compiled in a process that a test starts (``tests/test_cache.py``'s new processes,
the CLI subprocesses) are not seen: those tests show as wall time without XLA seconds.

* ``python -m experiments.diagnostics.suite_compiles`` runs the suite (``python -m pytest -q``
  with this plugin, from the repository root; the arguments after ``--`` go to pytest) and
  writes ``--out`` (markdown) and its ``.json`` beside it; ``--log DIR`` keeps the per-worker
  records there (default: a temporary folder).
  It exits with 1 where a test failed (the report is written all the same).
* ``--from DIR`` summarises the records a run left in DIR instead of running the suite.
* As a plugin alone: ``python -m pytest -q -p experiments.diagnostics.suite_compiles
  --compile-log DIR`` writes ``DIR/<worker>.jsonl``, a line per test.

Example::

    python -m experiments.diagnostics.suite_compiles --out experiments/results/suite_compiles/suite_compiles.md
    python -m experiments.diagnostics.suite_compiles --quick     # two test files (smoke test)
"""
from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Dict, Iterable, List, Optional

import pytest

REPO = Path(__file__).resolve().parents[2]
BACKEND_COMPILE = "/jax/core/compile/backend_compile_duration"
#: the test files ``--quick`` runs: quick to compile, with at least one XLA compilation
QUICK = ("tests/test_geometry.py", "tests/estimator/test_pyramid.py")


# ---- the pytest plugin -------------------------------------------------------------------------

class _Recorder:
    """The current test's compilations, filled by JAX's event listener (registered once)."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.counts: collections.Counter = collections.Counter()
        self.seconds: collections.Counter = collections.Counter()

    def on_duration(self, event: str, duration_secs: float, **kwargs) -> None:
        if event == BACKEND_COMPILE:
            name = str(kwargs.get("fun_name", "?"))
            self.counts[name] += 1
            self.seconds[name] += duration_secs

    def write(self, test: str, wall: float) -> None:
        worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
        row = {"test": test, "worker": worker, "wall_s": wall, "compiles": sum(self.counts.values()),
               "xla_s": sum(self.seconds.values()),
               "by_function": {k: [self.counts[k], self.seconds[k]] for k in sorted(self.counts)}}
        with open(self.folder / f"{worker}.jsonl", "a") as f:
            f.write(json.dumps(row) + "\n")
        self.counts.clear()
        self.seconds.clear()


_RECORDER: Dict[str, Optional[_Recorder]] = {"on": None}


def pytest_addoption(parser):
    parser.addoption("--compile-log", metavar="DIR", default=None,
                     help="write each test's wall time and XLA compilations to DIR/<worker>.jsonl "
                          "(experiments.diagnostics.suite_compiles)")


def pytest_configure(config):
    folder = config.getoption("--compile-log")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        from jax import monitoring

        _RECORDER["on"] = _Recorder(Path(folder))
        monitoring.register_event_duration_secs_listener(_RECORDER["on"].on_duration)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    t0 = time.perf_counter()
    yield
    if _RECORDER["on"] is not None:
        _RECORDER["on"].write(item.nodeid, time.perf_counter() - t0)


# ---- the summary -------------------------------------------------------------------------------

def read_log(folder: Path) -> List[dict]:
    """Every test's row of the ``*.jsonl`` files a run wrote in ``folder``."""
    rows = []
    for path in sorted(Path(folder).glob("*.jsonl")):
        rows.extend(json.loads(line) for line in path.read_text().splitlines() if line.strip())
    return rows


def summarise(rows: Iterable[dict], top: int = 25) -> dict:
    """Totals per worker, per test file, per compiled function and the ``top`` tests by XLA seconds.
    Seconds are each test's own (its setup, call and teardown), summed over the workers."""
    rows = list(rows)
    workers = collections.defaultdict(lambda: {"tests": 0, "wall_s": 0.0, "xla_s": 0.0, "compiles": 0})
    files = collections.defaultdict(lambda: {"tests": 0, "wall_s": 0.0, "xla_s": 0.0, "compiles": 0})
    functions = collections.defaultdict(lambda: {"compiles": 0, "xla_s": 0.0, "tests": 0})
    for r in rows:
        for acc in (workers[r["worker"]], files[r["test"].split("::")[0]]):
            acc["tests"] += 1
            acc["wall_s"] += r["wall_s"]
            acc["xla_s"] += r["xla_s"]
            acc["compiles"] += r["compiles"]
        for name, (n, s) in r["by_function"].items():
            functions[name]["compiles"] += n
            functions[name]["xla_s"] += s
            functions[name]["tests"] += 1

    def ranked(d, key):
        return [{"name": k, **v} for k, v in sorted(d.items(), key=lambda kv: (-kv[1][key], kv[0]))]

    tests = sorted(rows, key=lambda r: (-r["xla_s"], -r["wall_s"], r["test"]))
    return {"tests": len(rows), "wall_s": sum(r["wall_s"] for r in rows), "xla_s": sum(r["xla_s"] for r in rows),
            "compiles": sum(r["compiles"] for r in rows), "workers": ranked(workers, "wall_s"),
            "files": ranked(files, "wall_s"), "functions": ranked(functions, "xla_s"),
            "top_tests": [{"test": r["test"], "wall_s": r["wall_s"], "xla_s": r["xla_s"], "compiles": r["compiles"],
                           "functions": ", ".join(f"{k} {n}x {s:.1f} s" for k, (n, s) in
                                                  sorted(r["by_function"].items(), key=lambda kv: -kv[1][1])[:3])}
                          for r in tests[:top]]}


def markdown(summary: dict, suite_wall_s: Optional[float], exit_status: Optional[int] = None) -> List[str]:
    """The summary's tables (the lines after the provenance header); ``exit_status``: pytest's, where
    this process ran the suite."""
    s = summary
    lines = ["Each test's own wall time (setup, call, teardown) and the XLA compilations JAX reported in its "
             "worker while it ran (a persistent-cache hit compiles nothing); seconds are summed over the "
             "workers, which run at once. Compilations in processes a test starts are not seen.", ""]
    total = f"{s['tests']} tests" + (f" in {suite_wall_s:.0f} s wall" if suite_wall_s is not None else "")
    if exit_status is not None:
        total += f" (pytest's exit status {exit_status}" + (": every test passed)" if exit_status == 0 else ": some failed)")
    lines += [f"{total}; test-seconds {s['wall_s']:.0f}, of them XLA {s['xla_s']:.0f} s in {s['compiles']} compilations.",
              "", "| worker | tests | test s | XLA s | compilations |", "| --- | --- | --- | --- | --- |"]
    lines += [f"| {w['name']} | {w['tests']} | {w['wall_s']:.0f} | {w['xla_s']:.0f} | {w['compiles']} |" for w in s["workers"]]
    lines += ["", "## Per test file", "", "| file | tests | test s | XLA s | compilations |", "| --- | --- | --- | --- | --- |"]
    lines += [f"| {f['name']} | {f['tests']} | {f['wall_s']:.1f} | {f['xla_s']:.1f} | {f['compiles']} |"
              for f in s["files"] if f["wall_s"] >= 1.0]
    lines += ["", "## Per compiled function (the 20 with the most XLA time)", "",
              "| function | compilations | XLA s | tests |", "| --- | --- | --- | --- |"]
    lines += [f"| `{f['name']}` | {f['compiles']} | {f['xla_s']:.1f} | {f['tests']} |" for f in s["functions"][:20]]
    lines += ["", f"## The {len(s['top_tests'])} tests with the most XLA time", "",
              "| test | test s | XLA s | compilations | most of it |", "| --- | --- | --- | --- | --- |"]
    lines += [f"| `{t['test']}` | {t['wall_s']:.1f} | {t['xla_s']:.1f} | {t['compiles']} | {t['functions']} |"
              for t in s["top_tests"]]
    return lines


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=REPO / "experiments" / "results" / "suite_compiles" / "suite_compiles.md")
    ap.add_argument("--log", type=Path, default=None, help="keep the per-worker records here (default: a temporary folder)")
    ap.add_argument("--from", dest="source", type=Path, default=None,
                    help="summarise the records of an earlier run in this folder; run nothing")
    ap.add_argument("--quick", action="store_true", help=f"run only {', '.join(QUICK)} (smoke test)")
    ap.add_argument("pytest_args", nargs="*", help="after --: more arguments for pytest")
    args = ap.parse_args(argv)

    from experiments import common

    suite_wall = rc = None
    if args.source is not None:
        folder = args.source
        if not folder.is_dir():
            print(f"error: --from {folder}: no such folder", file=sys.stderr)
            return 2
    else:
        folder = args.log or Path(tempfile.mkdtemp(prefix="suite-compiles-"))
        if folder.exists() and any(folder.glob("*.jsonl")):
            print(f"error: --log {folder} already holds records: give an empty or new folder", file=sys.stderr)
            return 2
        pytest_cmd = [sys.executable, "-m", "pytest", "-q", "-p", "experiments.diagnostics.suite_compiles",
                      "--compile-log", str(folder), *(QUICK if args.quick else ()), *args.pytest_args]
        t0 = time.perf_counter()
        rc = subprocess.run(pytest_cmd, cwd=REPO).returncode
        suite_wall = time.perf_counter() - t0
        if rc != 0:
            print(f"note: pytest exited with {rc}; the records of the tests that ran are summarised", file=sys.stderr)
    rows = read_log(folder)
    if not rows:
        print(f"error: {folder} holds no test records", file=sys.stderr)
        return 2
    summary = summarise(rows)
    lines = common.provenance_md("Where the test suite's time goes: XLA's compilations per test", __file__, argv)
    common.write_outputs(args.out, lines + markdown(summary, suite_wall, rc),
                         {"suite_wall_s": suite_wall, "exit_status": rc, **summary})
    print(f"wrote {args.out}")
    return 1 if rc else 0


if __name__ == "__main__":
    sys.exit(main())
