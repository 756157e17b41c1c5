"""Where the estimator's time goes inside its compiled program: XLA's own per-kernel times.

``speed.py``'s stage table replays each stage of the estimator as its own jitted call, and a
stage run alone is not what it costs inside the whole program, where XLA fuses it with its
neighbours (a pyramid computed inside the estimator costs far less than one computed alone).
This script profiles the compiled estimator itself: the same program as ``estimate_motion``,
compiled with XLA's trace annotations on (``xla_cpu_enable_xprof_traceme``), runs the pairs
under ``jax.profiler.trace``; every kernel (fusion, dot, custom call) XLA executed is timed,
and attributed to a stage by the ``jax.named_scope`` the estimator traced it under (kept in
the compiled program's metadata), and to the jaxvo source line that produced it:

* pyramid: ``build_pyramid`` of both frames, every level;
* points: the reference points of each level (``select_points``, ``reference_points``, the
  padded stacks of the scanned levels);
* prior fit: the plain least-squares fit RANSAC starts from;
* RANSAC sampling / hypotheses / scoring: the sampling CDF and the patches; the hypotheses'
  fits; their scores (and the starting poses');
* refinement: the consensus refinement (Huber IRLS, jaxopt) and its inlier mask (classic
  and Huber: their fits);
* final masks and statistics: the dense residuals at the finest level and the failure flag's
  statistics;
* brightness offset: the exposure change fitted at each level and applied to the reference
  (``Config.brightness``);
* other: the rest (the loops' bookkeeping, the carried pose).

Kernel times are CPU time in kernels: XLA runs independent kernels of one program on several
threads, so their sum can exceed the wall time. The scanned levels share their kernels, so the
table is per stage, not per level.

Example::

    python experiments/kernel_profile.py                        # fr2_desk and Bonn crowd pairs
    python experiments/kernel_profile.py --quick --out /tmp/p.md # a synthetic sequence, for CI
"""
from __future__ import annotations

import argparse
import collections
import gzip
import json
import re
import shutil
import tempfile
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import common
import numpy as np  # noqa: E402

import jax  # noqa: E402
from jaxvo.config import Config  # noqa: E402
from jaxvo.estimator import estimate_args, estimate_arrays, estimate_motion  # noqa: E402
from jaxvo.frame import Frame  # noqa: E402
from jaxvo.estimator.solvers import COMPILER_OPTIONS  # noqa: E402
from speed import DYNAMIC, STATIC, load_pairs  # noqa: E402

SCRIPT = Path(__file__)

# (stage, the jax.named_scope of jaxvo.tracking.odometry / jaxvo.estimator.ransac that marks it in a kernel's op_name)
STAGES: Tuple[Tuple[str, str], ...] = (
    ("pyramid", "pyramid"),
    ("points", "points"),
    ("prior fit", "prior_fit"),
    ("RANSAC sampling", "ransac_sampling"),
    ("RANSAC hypotheses", "ransac_hypotheses"),
    ("RANSAC scoring", "ransac_scoring"),
    ("refinement", "refinement"),
    ("final masks and statistics", "final"),
    ("brightness offset", "brightness"),
)
# HLO instructions that only contain other kernels: their events would count those twice
_CONTAINERS = re.compile(r"\b(while|conditional|call)\(")


def parse_args(argv: Optional[List[str]] = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--static", default=None, help=f"static sequence folder (default: {STATIC} under the data root)")
    ap.add_argument("--dynamic", default=None, help=f"dynamic sequence folder (default: {DYNAMIC})")
    ap.add_argument("--pairs", type=int, default=10, help="consecutive pairs per sequence (default %(default)s)")
    ap.add_argument("--repeats", type=int, default=3, help="profiled passes over the pairs (default %(default)s)")
    ap.add_argument("--config", default=None, help="JSON object of Config fields changed from the default")
    ap.add_argument("--top", type=int, default=15, help="kernels listed per set (default %(default)s)")
    ap.add_argument("--quick", action="store_true", help="a 160x120 synthetic sequence, 3 pairs (smoke test)")
    ap.add_argument("--out", type=Path, default=common.RESULTS / "kernel_profile" / "kernel_profile.md", help="markdown output")
    return ap.parse_args(argv)


def kernel_sources(hlo_text: str) -> Dict[str, Tuple[str, List[Tuple[str, str, int]]]]:
    """Kernel instruction name -> (its op_name, its source stack innermost first as (file,
    function, line) of the jaxvo frames), read from the compiled module's metadata and its
    FileNames / FunctionNames / FileLocations / StackFrames tables; container instructions
    (loops, conditionals, calls) left out."""
    lines = hlo_text.splitlines()

    def table(name):
        out = {}
        if name not in lines:
            return out
        for line in lines[lines.index(name) + 1:]:
            m = re.match(r"(\d+) (.*)", line)
            if not m:
                break
            out[int(m.group(1))] = m.group(2)
        return out

    files = {k: v.strip('"') for k, v in table("FileNames").items()}
    funcs = {k: v.strip('"') for k, v in table("FunctionNames").items()}
    locs = {}
    for k, v in table("FileLocations").items():
        m = re.search(r"file_name_id=(\d+) function_name_id=(\d+) line=(\d+)", v)
        if m:
            locs[k] = (files.get(int(m.group(1)), "?"), funcs.get(int(m.group(2)), "?"), int(m.group(3)))
    frames = {}
    for k, v in table("StackFrames").items():
        m = re.search(r"file_location_id=(\d+) parent_frame_id=(\d+)", v)
        if m:
            frames[k] = (int(m.group(1)), int(m.group(2)))

    def stack(fid):
        out, seen = [], set()
        while fid in frames and fid not in seen:
            seen.add(fid)
            loc, parent = frames[fid]
            if loc in locs and "/jaxvo/" in locs[loc][0]:
                f, fn, ln = locs[loc]
                out.append((Path(f).name, fn, ln))
            fid = parent
        return out

    kernels = {}
    for line in lines:
        m = re.match(r"\s*(?:ROOT )?%(\S+) = (.*)", line)
        if not m or _CONTAINERS.search(m.group(2).split("metadata=")[0]):
            continue
        op = re.search(r'op_name="([^"]*)"', line)
        frame = re.search(r"stack_frame_id=(\d+)", line)
        kernels[m.group(1)] = (op.group(1) if op else "", stack(int(frame.group(1))) if frame else [])
    return kernels


def stage_of(op_name: str) -> str:
    """The stage of a kernel from its op_name: the innermost of the estimator's named scopes in it."""
    scopes = op_name.split("/")
    for scope in reversed(scopes):
        for stage, mark in STAGES:
            if scope == mark:
                return stage
    return "other"


def kernel_times(trace_dir: Path, names) -> Tuple[Dict[str, float], Dict[str, int]]:
    """Total microseconds and count per kernel name found in the profiler's perfetto trace."""
    found = sorted(trace_dir.rglob("*.json.gz"))
    if not found:
        raise SystemExit(f"error: jax.profiler wrote no perfetto trace under {trace_dir}")
    data = json.load(gzip.open(found[0]))
    events = data["traceEvents"] if isinstance(data, dict) else data
    us, n = collections.Counter(), collections.Counter()
    for e in events:
        if e.get("ph") == "X" and e.get("name") in names:
            us[e["name"]] += float(e.get("dur", 0.0))
            n[e["name"]] += 1
    return us, n


def profile_set(name: str, seq, frames, pairs, config: Config, repeats: int, top: int) -> dict:
    options = {**COMPILER_OPTIONS, "xla_cpu_enable_xprof_traceme": True}
    fn = jax.jit(estimate_arrays, compiler_options=options)

    def plain(ref_i, ref_z, cur_i, cur_z, camera, cfg, key, T0, weights):
        # the library's call, as users run it (the frame pyramids' program, then the estimate's):
        # the program the annotated one is compared with, read from the compilation cache where
        # a process compiled it before
        return estimate_motion(Frame(ref_i, ref_z), Frame(cur_i, cur_z), camera, cfg, key, init=T0, weights=weights)

    inputs = [estimate_args(frames[a], frames[b], seq.camera, config, jax.random.key(k), None, None)
              for k, (a, b) in enumerate(pairs)]
    sources = kernel_sources(fn.lower(*inputs[0]).compile().as_text())
    wall = dict(zip(("plain", "annotated"), common.median_ms_per_call((plain, fn), inputs, repeats)))
    # one trace per pass over the pairs: the spread of a stage's time from pass to pass shows how
    # far to trust it (kernels on XLA's threads and the profiler share the machine's cores)
    us, count = collections.Counter(), collections.Counter()
    per_pass = []
    for _ in range(repeats):
        tmp = Path(tempfile.mkdtemp(prefix="jaxvo-kernel-profile-"))
        try:
            with jax.profiler.trace(str(tmp), create_perfetto_trace=True):
                for a in inputs:
                    jax.block_until_ready(fn(*a))
            u, c = kernel_times(tmp, set(sources))
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        us.update(u)
        count.update(c)
        stage_ms = collections.Counter()
        for k, t in u.items():
            stage_ms[stage_of(sources[k][0])] += t / 1000 / len(inputs)
        per_pass.append(stage_ms)
    runs = repeats * len(inputs)
    total = sum(us.values()) / 1000 / runs
    kernels_in = collections.Counter(stage_of(sources[k][0]) for k in us)
    stages = []
    for s in [st for st, _ in STAGES] + ["other"]:
        if s not in kernels_in:
            continue
        ms = [p[s] for p in per_pass]
        stages.append({"stage": s, "ms": float(np.mean(ms)), "min_ms": min(ms), "max_ms": max(ms),
                       "share": float(np.mean(ms)) / total if total else 0.0, "kernels": kernels_in[s]})
    kernels = []
    for k, t in us.most_common(top):
        op, st = sources[k]
        where = f"{st[0][0]}:{st[0][1]}:{st[0][2]}" if st else "?"
        kernels.append({"kernel": k, "ms": t / 1000 / runs, "calls": count[k] / runs, "stage": stage_of(op),
                        "source": where})
    common.log(f"[profile] {name}: {seq.name}, {len(inputs)} pairs: wall {wall['plain']:.1f} ms/pair "
               f"({wall['annotated']:.1f} annotated), kernels {total:.1f} ms/pair")
    return {"set": name, "sequence": seq.name, "pairs": len(inputs), "wall_ms": wall["plain"],
            "annotated_wall_ms": wall["annotated"], "kernel_ms": total, "stages": stages, "kernels": kernels,
            "profiled_kernels": len(us)}


def main(argv: Optional[List[str]] = None) -> Path:
    args = parse_args(argv)
    config = Config.from_dict(common.config_changes(args.config)) if args.config else Config()
    tmp = None
    try:
        if args.quick:
            tmp = Path(tempfile.mkdtemp(prefix="jaxvo-kernel-profile-seq-"))
            paths = {"synthetic": common.synthetic_sequence(tmp / "seq", 4)}
            args.pairs, args.repeats = 3, 1
        else:
            paths = {"static": common.resolve_sequence(args.static, STATIC, "tum"),
                     "dynamic": common.resolve_sequence(args.dynamic, DYNAMIC, "bonn")}
        results = []
        for label, path in paths.items():
            seq, frames, pairs = load_pairs(path, args.pairs, label)
            results.append(profile_set(label, seq, frames, pairs, config, args.repeats, args.top))
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    return write(args, argv, config, results)


def write(args, argv, config: Config, results: List[dict]) -> Path:
    lines = common.provenance_md("Where the estimator's time goes: XLA's per-kernel times", str(SCRIPT), argv)
    lines += [f"Config: {'defaults' if args.config is None else args.config} (method {config.method}). Each set: "
              "consecutive pairs spread over the sequence, decoded into memory; the estimator compiled with XLA's "
              "trace annotations on, warmed up, then run under `jax.profiler.trace`. `wall`: median wall time "
              "per pair of the library's call (`estimate_motion`, and of the annotated program); `kernel ms`: CPU time in XLA's kernels "
              "per pair (the mean over the passes, each pass profiled on its own, and the range of the passes), "
              "attributed to a stage by the estimator's named scopes in the compiled program (see the script's "
              "docstring). XLA runs kernels on several threads at once and the profiler adds to each, so kernel "
              "time exceeds wall time: compare shares within a run, and mind the ranges.", ""]
    for r in results:
        lines += [f"## {r['set']}: {r['sequence']}, {r['pairs']} pairs", "",
                  f"wall {r['wall_ms']:.1f} ms per pair ({r['annotated_wall_ms']:.1f} annotated); "
                  f"{r['kernel_ms']:.1f} ms in {r['profiled_kernels']} kernels.", "",
                  "| stage | kernel ms / pair | passes: min - max | share | kernels |",
                  "| --- | --- | --- | --- | --- |"]
        lines += [f"| {s['stage']} | {s['ms']:.2f} | {s['min_ms']:.2f} - {s['max_ms']:.2f} | {s['share']:.2f} | "
                  f"{s['kernels']} |" for s in r["stages"]]
        lines += ["", f"The {len(r['kernels'])} kernels with the most time:", "",
                  "| kernel | ms / pair | runs / pair | stage | innermost jaxvo source |",
                  "| --- | --- | --- | --- | --- |"]
        lines += [f"| {k['kernel']} | {k['ms']:.3f} | {k['calls']:.1f} | {k['stage']} | `{k['source']}` |"
                  for k in r["kernels"]]
        lines.append("")
    out = common.write_outputs(args.out, lines, {"args": {k: str(v) for k, v in vars(args).items()},
                                                "results": results})
    print(f"wrote {out}")
    return out


if __name__ == "__main__":
    main()
