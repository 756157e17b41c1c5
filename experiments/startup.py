"""Start-up cost of ``jaxvo run``: the first pair in a fresh process, with and without the caches.

For each method, in a fresh (temporary) cache folder: ``jaxvo run SEQ --max-frames 2`` in a new
process three times:

1. ``first``: empty cache folder: trace, export, XLA compilation, one pair;
2. ``second``: the same folder: the exported program and JAX's compiled executable are loaded
   (no tracing, no compilation);
3. ``no export``: the same folder with the exported programs deleted: JAX's compilation cache
   alone (the estimator is traced and lowered, then its executable loaded), as before
   ``jaxvo.aot``.

Reported per run: ``first pair s`` (jaxvo's summary line ``compile``: from the start of tracking
to the first pair's pose, reading, tracing, compiling and running it) and ``process s`` (the
wall time of the whole process, interpreter start and imports included, for one pair).
``default`` is ``jaxvo run`` without options (ransac and the keyframe/segmentation policy).

Then, unless ``--no-stages``, where the first compilation goes: the estimator alone
(``estimate_motion``'s jitted function on the sequence's image size) traced, lowered and
XLA-compiled in this process with no cache, each stage timed, and the size of the lowered
program (lines of StableHLO text).
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import List, Optional

import common  # noqa: F401  (sys.path for jaxvo)

from jaxvo import cache  # noqa: E402

SCRIPT = Path(__file__)
RUNS = ("first", "second", "no export")
METHOD_ARGS = {"default": [], "classic": ["--method", "classic"], "huber": ["--method", "huber"],
               "ransac": ["--method", "ransac"]}


def parse_args(argv: Optional[List[str]] = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sequence", default=None, help="sequence folder (default: the bundled fr2/desk excerpt)")
    ap.add_argument("--methods", default="default,classic,huber",
                    help=f"comma list of {', '.join(METHOD_ARGS)} (default: %(default)s)")
    ap.add_argument("--no-stages", action="store_true", help="skip the trace / lower / compile breakdown")
    ap.add_argument("--quick", action="store_true", help="a 160x120 synthetic sequence, classic only (smoke test)")
    ap.add_argument("--out", type=Path, default=common.RESULTS / "startup.md", help="markdown output")
    return ap.parse_args(argv)


def run_once(seq: Path, method: str, folder: Path, out: Path) -> dict:
    """One ``jaxvo run`` process for one pair; its first-pair time and process wall time."""
    cmd = [sys.executable, "-m", "jaxvo", "run", str(seq), "--out", str(out), "--max-frames", "2",
           "--no-progress", "--force"] + METHOD_ARGS[method]
    env = {**os.environ, cache.ENV: str(folder)}
    t = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=common._REPO)
    wall = time.perf_counter() - t
    if r.returncode != 0:
        raise SystemExit(f"error: {' '.join(cmd)} failed:\n{r.stderr[-2000:]}")
    m = re.search(r"^compile\s+([0-9.]+) s", r.stdout + r.stderr, re.M)
    return {"first_pair_s": float(m.group(1)) if m else float("nan"), "process_s": wall}


def startup_rows(seq: Path, methods: List[str]) -> List[dict]:
    rows = []
    for method in methods:
        folder = Path(tempfile.mkdtemp(prefix="jaxvo-startup-"))
        try:
            for run in RUNS:
                if run == "no export":
                    shutil.rmtree(folder / "exported", ignore_errors=True)
                r = run_once(seq, method, folder, folder / "traj.txt")
                rows.append({"method": method, "run": run, **r})
                print(f"{method:8s} {run:10s} first pair {r['first_pair_s']:6.1f} s  process {r['process_s']:6.1f} s",
                      flush=True)
        finally:
            shutil.rmtree(folder, ignore_errors=True)
    return rows


def stage_rows(seq: Path, methods: List[str]) -> List[dict]:
    """Trace / lower / XLA compile of the estimator alone, no cache (this process compiled nothing yet)."""
    import jax
    import jax.numpy as jnp

    from jaxvo.config import Config
    from jaxvo.odometry import _estimate_jit

    s = common.open_sequence(seq)
    h, w = s.camera.height, s.camera.width
    img = jax.ShapeDtypeStruct((h, w), jnp.float32)
    rows = []
    for method in methods:
        config = Config() if method == "default" else Config(method=method)
        args = (img, img, img, img, s.camera, config, jax.random.key(0), jax.ShapeDtypeStruct((4, 4), jnp.float32),
                img)
        t0 = time.perf_counter()
        traced = _estimate_jit.trace(*args)
        t1 = time.perf_counter()
        lowered = traced.lower()
        t2 = time.perf_counter()
        lines = lowered.as_text().count("\n")
        t3 = time.perf_counter()
        lowered.compile()
        t4 = time.perf_counter()
        rows.append({"method": method, "trace_s": t1 - t0, "lower_s": t2 - t1, "compile_s": t4 - t3, "lines": lines})
        print(f"{method:8s} trace {t1 - t0:.2f} s  lower {t2 - t1:.2f} s  XLA compile {t4 - t3:.2f} s  "
              f"{lines} lines", flush=True)
    return rows


def main(argv: Optional[List[str]] = None) -> None:
    args = parse_args(argv)
    t_start = time.perf_counter()
    tmp = None
    if args.quick:
        tmp = Path(tempfile.mkdtemp(prefix="jaxvo-startup-seq-"))
        seq = tmp / "seq"
        subprocess.run([sys.executable, "-m", "jaxvo", "synth", "seq1", str(seq), "--frames", "3", "--size",
                        "160x120", "--no-progress"], check=True, capture_output=True, cwd=common._REPO)
        methods = ["classic"]
    else:
        seq = Path(args.sequence) if args.sequence else common.find_named("rgbd_dataset_freiburg2_desk")
        if seq is None:
            raise SystemExit(common.missing_data_message())
        methods = [m.strip() for m in args.methods.split(",") if m.strip()]
        bad = [m for m in methods if m not in METHOD_ARGS]
        if bad:
            raise SystemExit(f"error: --methods: unknown {', '.join(bad)} (choose from {', '.join(METHOD_ARGS)})")
    try:
        rows = startup_rows(seq, methods)
        stages = [] if args.no_stages else stage_rows(seq, methods)
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    write(args, argv, seq, rows, stages, time.perf_counter() - t_start)


def write(args, argv, seq: Path, rows: List[dict], stages: List[dict], total_s: float) -> None:
    lines = common.provenance_md("Start-up: the first pair of `jaxvo run` in a new process", str(SCRIPT), argv)
    lines += [f"Sequence: `{seq.name}`, `jaxvo run SEQ --max-frames 2` (one pair) per process, each method in "
              "its own fresh cache folder (`JAXVO_CACHE_DIR`). `first`: empty folder; `second`: the folder the "
              "first run filled (exported program + JAX's compiled executables); `no export`: the same folder "
              "without `exported/`, i.e. JAX's persistent compilation cache alone (tracing and lowering "
              "still happen). `first pair s`: jaxvo's summary line `compile` (from the start of tracking to "
              "the first pair's pose); `process s`: the whole process, interpreter start and imports included. "
              "`default`: `jaxvo run` without options (ransac with the keyframe/segmentation policy). "
              "Other processes may share this machine: compare rows of one run.", "",
              "| method | run | first pair s | process s |", "| --- | --- | --- | --- |"]
    lines += [f"| {r['method']} | {r['run']} | {r['first_pair_s']:.1f} | {r['process_s']:.1f} |" for r in rows]
    if stages:
        lines += ["", "## Where the first compilation goes", "",
                  "The estimator alone (`jaxvo.odometry._estimate_jit`) at the sequence's image size, in one "
                  "process with no cache: `jit(...).trace`, `.lower`, `.compile` (XLA) timed separately; lines: "
                  "the lowered StableHLO text.", "",
                  "| method | trace s | lower s | XLA compile s | lines |", "| --- | --- | --- | --- | --- |"]
        lines += [f"| {r['method']} | {r['trace_s']:.2f} | {r['lower_s']:.2f} | {r['compile_s']:.1f} | {r['lines']} |"
                  for r in stages]
    lines += ["", f"Total wall time {total_s:.0f} s."]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
