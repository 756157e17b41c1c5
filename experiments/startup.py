"""Start-up cost: the first poses of a new process, ``jaxvo run`` and a library script, with and without the caches.

Each entry point runs in its own new process, whole (interpreter start, imports, reading,
loading or compiling the programs, the poses, writing and exit), on the first frames of a
sequence, in a fresh (temporary) cache folder (``JAXVO_CACHE_DIR``), with Python's bytecode cache
on as in an installed jaxvo (:func:`_child_env`):

* ``cli``: ``jaxvo run SEQ --max-frames 3`` (the default tracking, trajectory written and
  evaluated as a user's run);
* ``estimate_motion``: ``python -c`` importing jaxvo, reading two frames and calling
  ``jaxvo.estimate_motion`` once;
* ``track``: ``python -c`` importing jaxvo and running ``jaxvo.track`` (``Odometry``) on 3 frames.

Per pass and entry point: ``cold`` (an empty folder: a new machine; everything traced and
compiled), then ``--warm-runs`` processes on the folder it filled (``warm``: a machine that ran
it once). Reported per run: the wall time of the whole process, its CPU time (user + sys of the
child, less sensitive to other processes on a shared machine than the wall time), and the time
from the process's start to its first pose (the library scripts report it themselves; for
``cli``: when its trajectory file, flushed a pose at a time, first holds frame 1's pose). The
passes (``--repeats``, each in a fresh folder, the entry points alternating) give the median
and, in brackets, the range. ``--methods`` picks the estimator (``default``: no options;
``paper``: ``Config.paper()`` / ``--paper``).

Then, unless ``--no-stages``, where the first compilation goes: the estimator alone
(``estimate_motion``'s jitted function on the sequence's image size) traced, lowered and
XLA-compiled in this process with no cache, each stage timed, and the size of the lowered
program (lines of StableHLO text) and of the compiled one (fusions: the kernels XLA generates code
for); the same program compiled with other XLA options (legacy CPU fusion emitters, LLVM's lower
optimisation levels, LLVM's expensive passes off), each one's CPU time to load its executable back,
time per pair and largest pose difference from the default's (the trade between compile time and
run time, and whether it keeps the estimates bitwise); and the default
estimator's parts (prior fit, RANSAC hypotheses and scoring, refinement) at the finest and the
coarsest level, each compiled alone. Last, where XLA's compilation of the default estimator
spends its time (``codegen_rows``): its phases (HLO optimisation passes, then code generation:
emitting each kernel and compiling it with LLVM) and the LLVM compile time of each kernel, added
up by the estimator stage it belongs to (the named scopes of ``kernel_profile.py``), read from
XLA's own timing log (``TF_CPP_VMODULE``) in a child process.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import List, Optional

import numpy as np

import common

from jaxvo.data import outputs  # noqa: E402
from jaxvo.runtime import cache  # noqa: E402

SCRIPT = Path(__file__)
ENTRIES = ("cli", "estimate_motion", "track")
METHOD_ARGS = {"default": [], "classic": ["--method", "classic"], "huber": ["--method", "huber"],
               "ransac": ["--method", "ransac"], "paper": ["--paper"]}
FRAMES = 3
# the process's start as the parent saw it (time.time()), for a library script's own first-pose time
_T0_ENV = "JAXVO_STARTUP_T0"
# a library script: argv = sequence, method, entry; prints one JSON line of its own times (seconds
# since the process started)
_LIBRARY = """
import json, os, sys, time
t0 = float(os.environ["%s"])
import jax
import jaxvo
t_import = time.time()
seq_dir, method, entry = sys.argv[1:4]
config = jaxvo.Config.paper() if method == "paper" else jaxvo.Config() if method == "default" else jaxvo.Config(method=method)
seq = jaxvo.open_sequence(seq_dir)
first = []
if entry == "estimate_motion":
    est = jaxvo.estimate_motion(seq.frame(0), seq.frame(1), seq.camera, config, jax.random.key(0))
    est.T_cur_ref.block_until_ready()
    first.append(time.time())
    T = est.T_cur_ref
else:
    T = jaxvo.track((seq.frame(i) for i in range(%d)), seq.camera, config, jax.random.key(0),
                    callback=lambda step: first.append(time.time())).poses[-1]
print(json.dumps({"import_s": t_import - t0, "first_pose_s": first[0] - t0, "T": jax.device_get(T).tolist()}))
""" % (_T0_ENV, FRAMES)


def parse_args(argv: Optional[List[str]] = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sequence", default=None, help="sequence folder (default: the bundled fr2/desk excerpt)")
    ap.add_argument("--methods", default="default",
                    help=f"comma list of {', '.join(METHOD_ARGS)} (default: %(default)s)")
    ap.add_argument("--entries", default=",".join(ENTRIES), help="comma list of %(default)s (default: all)")
    ap.add_argument("--repeats", type=int, default=2,
                    help="passes, each in a fresh cache folder; the table gives their median and range (default: %(default)s)")
    ap.add_argument("--warm-runs", type=int, default=3, help="warm processes per pass (default: %(default)s)")
    ap.add_argument("--no-stages", action="store_true", help="skip the trace / lower / compile breakdown")
    ap.add_argument("--quick", action="store_true",
                    help="a 160x120 synthetic sequence, classic only, one pass with one warm run (smoke test)")
    ap.add_argument("--out", type=Path, default=common.RESULTS / "startup" / "startup.md", help="markdown output")
    ap.add_argument("--codegen-child", nargs=2, metavar=("SEQ", "HLO_OUT"), help=argparse.SUPPRESS)
    return ap.parse_args(argv)


def _command(entry: str, seq: Path, method: str, out: Path) -> List[str]:
    if entry == "cli":
        # --poses tracked: frame 1's line is written as soon as it is estimated (the default, refined,
        # writes it once settled, a few frames later: the end of a 3-frame run); the programs and
        # the estimates are the same, the poses are a host-side choice
        return [sys.executable, "-m", "jaxvo", "run", str(seq), "--out", str(out), "--max-frames", str(FRAMES),
                "--no-progress", "--force", "--poses", "tracked"] + METHOD_ARGS[method]
    return [sys.executable, "-c", _LIBRARY, str(seq), method, entry]


def _has_pose(paths) -> bool:
    """Whether one of ``paths`` (a trajectory being written, or written) holds an estimated pose:
    a second pose line (the first is frame 0's start pose, written before any estimate)."""
    for p in paths:
        try:
            with open(p) as fh:
                if sum(1 for line in fh if line.strip() and not line.startswith("#")) >= 2:
                    return True
        except OSError:
            pass
    return False


def _child_env(folder: Path, t0: float) -> dict:
    """A timed process's environment: this one's, its cache folder and start time set, and Python's
    bytecode cache on (``PYTHONDONTWRITEBYTECODE`` dropped), as in an installed jaxvo, whose
    modules are compiled to bytecode once: where the variable is set, every process would compile
    jaxvo's sources again (about a tenth of a second), which no user's process does."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    return {**env, cache.ENV: str(folder), _T0_ENV: repr(t0)}


def run_once(entry: str, seq: Path, method: str, folder: Path, poll_s: float = 0.005) -> dict:
    """One new process of ``entry``: its wall time, CPU time (user + sys) and first-pose time (s),
    all from the moment the process is started. ``cli``'s first pose is when its trajectory (written
    under its ``.partial`` name and flushed a pose at a time, ``--poses tracked``) first holds frame 1's pose, watched
    every ``poll_s``; the library scripts report theirs (``track``: frame 1's callback)."""
    out = folder / "traj.txt"
    cmd = _command(entry, seq, method, out)
    watched = (outputs.partial_path(out), out)
    for p in watched:   # the previous process's
        p.unlink(missing_ok=True)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.time()
    first = float("nan")
    with tempfile.TemporaryFile("w+") as so, tempfile.TemporaryFile("w+") as se:
        proc = subprocess.Popen(cmd, stdout=so, stderr=se, text=True, cwd=common._REPO, env=_child_env(folder, t))
        while proc.poll() is None:
            if entry == "cli" and first != first and _has_pose(watched):
                first = time.time() - t
            time.sleep(poll_s)
        wall = time.time() - t
        so.seek(0), se.seek(0)
        stdout, stderr = so.read(), se.read()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"error: {' '.join(cmd[:3])} ... failed (exit status {proc.returncode}):\n{stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if entry != "cli":
        first = json.loads(stdout.splitlines()[-1])["first_pose_s"]
    elif first != first and _has_pose(watched):   # a process faster than one poll
        first = wall
    return {"process_s": wall, "cpu_s": cpu, "first_pose_s": first}


KEYS = ("first_pose_s", "process_s", "cpu_s")


def startup_rows(seq: Path, methods: List[str], entries: List[str], repeats: int = 1, warm_runs: int = 3) -> List[dict]:
    """Per method, entry point and run (cold, warm): the median and range over the passes (each in
    its own fresh cache folder, the entry points alternating) of the first-pose, process and CPU
    times; a pass's warm time is the median of its ``warm_runs`` processes."""
    times: dict = {}
    for rep in range(repeats):
        for method in methods:
            for entry in entries:
                folder = Path(tempfile.mkdtemp(prefix="jaxvo-startup-"))
                try:
                    runs = [("cold", run_once(entry, seq, method, folder))]
                    warm = [run_once(entry, seq, method, folder) for _ in range(warm_runs)]
                    runs.append(("warm", {k: float(np.median([w[k] for w in warm])) for k in KEYS}))
                finally:
                    shutil.rmtree(folder, ignore_errors=True)
                for run, r in runs:
                    times.setdefault((method, entry, run), []).append(r)
                    print(f"{method:8s} {entry:15s} {run:5s} pass {rep + 1}: first pose {r['first_pose_s']:5.1f} s  "
                          f"process {r['process_s']:5.1f} s  cpu {r['cpu_s']:5.1f} s  (load {os.getloadavg()[0]:.1f})",
                          flush=True)
    rows = []
    for (method, entry, run), rs in times.items():
        row = {"method": method, "entry": entry, "run": run}
        for k in KEYS:
            v = [r[k] for r in rs]
            row.update({k: float(np.median(v)), k + "_min": min(v), k + "_max": max(v)})
        rows.append(row)
    return rows


# XLA options that trade compile time against run time, each compiled from the same lowered
# program: XLA's defaults; its legacy CPU fusion emitters (``xla_cpu_use_fusion_emitters`` off),
# which compile each fusion faster; LLVM's optimisation level 1 and 0 (default 2); LLVM's expensive
# passes off. Only a variant whose poses equal the default's (max dT 0) could replace it
EMITTERS = (("", {}), (", legacy fusion emitters", {"xla_cpu_use_fusion_emitters": False}),
            (", LLVM -O1", {"xla_backend_optimization_level": 1}),
            (", LLVM -O0", {"xla_backend_optimization_level": 0}),
            (", LLVM expensive passes off", {"xla_llvm_disable_expensive_passes": True}))


def load_cpu_s(compiled) -> float:
    """CPU seconds to load ``compiled``'s executable back from its serialization (what a process
    with a warm cache pays for it, besides reading the file)."""
    from jax._src import xla_bridge
    from jax._src.compiler import get_compile_options

    backend = xla_bridge.get_backend()
    blob = backend.serialize_executable(compiled.runtime_executable())
    devices = xla_bridge.xla_client.DeviceList(tuple(backend.devices()[:1]))
    c = time.process_time()
    backend.deserialize_executable(blob, devices, get_compile_options(num_replicas=1, num_partitions=1))
    return time.process_time() - c


def _config(method: str):
    """The estimator's Config for a ``--methods`` entry (``paper``: ``Config.paper()``, as ``jaxvo run --paper``)."""
    from jaxvo.config import Config

    if method == "paper":
        return Config.paper()
    return Config() if method == "default" else Config(method=method)


def stage_rows(seq: Path, methods: List[str], pairs: int = 5, repeats: int = 5) -> List[dict]:
    """Trace / lower / XLA compile of the estimator alone, no cache (this process compiled nothing yet),
    with each of :data:`EMITTERS`' XLA options, the CPU time to load each executable back, each
    compiled program's median time per pair on the sequence's first ``pairs`` consecutive pairs
    (``repeats`` passes, alternating) and the largest difference of its poses from the first's."""
    import jax
    import numpy as np

    from jaxvo.estimator import estimate_args, estimate_arrays_jit
    from jaxvo.estimator.solvers import COMPILER_OPTIONS

    s = common.open_sequence(seq, max_frames=pairs + 1)
    frames = common.load_frames(s)
    rows = []
    for method in methods:
        config = _config(method)
        args = common.estimator_shapes(s.camera, config)
        t0 = time.perf_counter()
        traced = estimate_arrays_jit.trace(*args)
        t1 = time.perf_counter()
        lowered = traced.lower()
        t2 = time.perf_counter()
        lines = lowered.as_text().count("\n")
        programs = []
        for label, options in EMITTERS:
            t3, c3 = time.perf_counter(), time.process_time()
            compiled = lowered.compile({**COMPILER_OPTIONS, **options})
            t4, c4 = time.perf_counter(), time.process_time()
            programs.append(compiled)
            fusions = common.kernel_count(compiled)
            rows.append({"method": method, "part": "whole estimator" + label, "trace_s": t1 - t0, "lower_s": t2 - t1,
                         "compile_s": t4 - t3, "compile_cpu_s": c4 - c3, "lines": lines, "fusions": fusions,
                         "load_cpu_s": load_cpu_s(compiled)})
            print(f"{method:8s} {'whole estimator' + label}: trace {t1 - t0:.2f} s  lower {t2 - t1:.2f} s  "
                  f"XLA compile {t4 - t3:.2f} s (cpu {c4 - c3:.2f} s)  {lines} lines, {fusions} fusions", flush=True)
        inputs = [estimate_args(a, b, s.camera, config, jax.random.key(k), None, None)
                  for k, (a, b) in enumerate(zip(frames[:-1], frames[1:]))]
        for row, ms in zip(rows[-len(programs):], common.median_ms_per_call(programs, inputs, repeats)):
            row["pair_ms"] = ms
        poses = [[np.asarray(prog(*a)[0]) for a in inputs] for prog in programs]
        for row, p in zip(rows[-len(programs) + 1:], poses[1:]):
            row["max_dT"] = max(float(np.abs(x - y).max()) for x, y in zip(poses[0], p))
        print(f"{method:8s} ms per pair: " + ", ".join(f"{r['part']} {r['pair_ms']:.1f}" for r in rows[-len(programs):])
              + "; max |T difference| " + ", ".join(f"{r['max_dT']:.1e}" for r in rows[-len(programs) + 1:]), flush=True)
    return rows


def part_rows(seq: Path) -> List[dict]:
    """The default estimator's parts at the finest and the coarsest level, each compiled alone (the
    level's pyramid and points included), to show which code the XLA compilation spends its time on."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxvo.config import Config
    from jaxvo.estimator.pyramid import build_pyramid
    from jaxvo.estimator.levels import ransac_options
    from jaxvo.estimator.ransac import ransac_level
    from jaxvo.estimator.residuals import reference_points, select_points
    from jaxvo.estimator.solvers import irls, solve_pose_small

    s = common.open_sequence(seq)
    c = Config()
    rows = []
    for level in (0, 3):
        cam = s.camera.at_level(level)
        h, w = s.camera.height >> level, s.camera.width >> level
        img = jax.ShapeDtypeStruct((h, w), jnp.float32)
        T = jax.ShapeDtypeStruct((4, 4), jnp.float32)

        def prepared(i, d, i2, d2):
            ref, cur = build_pyramid(i, d, 1, c.max_depth)[0], build_pyramid(i2, d2, 1, c.max_depth)[0]
            return ref, cur, select_points(ref, cam, c.blocks[level])

        def prior(i, d, i2, d2, T):
            ref, cur, pts = prepared(i, d, i2, d2)
            return solve_pose_small(T, pts, cur, cam, pts.weight, c.max_iterations).T

        def hypotheses(i, d, i2, d2, T):
            ref, cur, _ = prepared(i, d, i2, d2)
            stride = max(1, int(np.ceil(np.sqrt(h * w / c.max_score_pixels))))
            return ransac_level(T, ref, cur, cam, reference_points(ref, cam, stride), jax.random.key(0),
                                **ransac_options(c)).T

        def refinement(i, d, i2, d2, T):
            ref, cur, pts = prepared(i, d, i2, d2)
            return irls(T, pts, cur, cam, pts.weight, c.huber_k, c.irls_rounds, c.irls_iterations).T

        def pyramid_and_points(i, d, i2, d2, T):
            return prepared(i, d, i2, d2)[2].points.sum() + T

        for name, fn in (("pyramid level + points", pyramid_and_points), ("prior fit", prior),
                         ("RANSAC hypotheses + scoring", hypotheses), ("refinement (Huber IRLS, jaxopt)", refinement)):
            t0 = time.perf_counter()
            lowered = jax.jit(fn).lower(img, img, img, img, T)
            t1, c1 = time.perf_counter(), time.process_time()
            compiled = lowered.compile()
            t2, c2 = time.perf_counter(), time.process_time()
            rows.append({"method": "default", "part": f"level {level} ({w}x{h}): {name}", "trace_s": float("nan"),
                         "lower_s": t1 - t0, "compile_s": t2 - t1, "compile_cpu_s": c2 - c1,
                         "lines": lowered.as_text().count("\n"),
                         "fusions": common.kernel_count(compiled)})
            print(f"level {level} {name:32s} XLA compile {t2 - t1:.2f} s (cpu {c2 - c1:.2f} s)", flush=True)
    return rows


# XLA's timing log lines (xla/service/cpu: cpu_compiler.cc, ir_compiler.cc) at TF_CPP_VMODULE level 2
_XLA_VMODULE = "cpu_compiler=1,ir_compiler=2"
_XLA_TIME = r"time: (?P<t>[0-9.]+) (?P<u>us|ms|s) "
_UNITS = {"us": 1e-6, "ms": 1e-3, "s": 1.0}


def _seconds(m) -> float:
    return float(m.group("t")) * _UNITS[m.group("u")]


def codegen_child(seq: Path, hlo_out: Path) -> None:
    """In a process started with XLA's timing log on (see :func:`codegen_rows`): compile the
    default estimator at the sequence's image size, no cache, and write its optimised HLO."""
    import jax

    from jaxvo.config import Config
    from jaxvo.estimator import estimate_arrays_jit
    from jaxvo.estimator.solvers import COMPILER_OPTIONS

    jax.config.update("jax_enable_compilation_cache", False)
    camera = common.open_sequence(seq, max_frames=2).camera
    lowered = estimate_arrays_jit.trace(*common.estimator_shapes(camera, Config())).lower()
    print("jaxvo-codegen-start", file=sys.stderr, flush=True)
    compiled = lowered.compile(COMPILER_OPTIONS)
    print("jaxvo-codegen-end", file=sys.stderr, flush=True)
    hlo_out.write_text(compiled.as_text())


def parse_codegen_log(log: str, kernels: dict) -> dict:
    """XLA's timing log of one compilation (the lines between the child's start and end marks)
    -> {"hlo_passes_s", "codegen_s" (wall: emitting and LLVM-compiling the kernels), "llvm_cpu_s"
    (LLVM time summed over the kernels, on several threads), "modules", "stages": {stage:
    [modules, llvm s]}, "top": [(llvm s, kernel, stage, innermost jaxvo source)]}. ``kernels``:
    :func:`kernel_profile.kernel_sources` of the compiled program. None if the log has no
    timing lines (another XLA version may log differently)."""
    from kernel_profile import stage_of

    body = log.split("jaxvo-codegen-start", 1)[-1].split("jaxvo-codegen-end", 1)[0]
    hlo = [_seconds(m) for m in re.finditer(r"Running HLO passes on \[[^\]]*\] for CPU " + _XLA_TIME, body)]
    gen = [_seconds(m) for m in re.finditer(r"Compiling \[[^\]]*\] for CPU using JIT " + _XLA_TIME, body)]
    mods = [(m.group(1), _seconds(m)) for m in re.finditer(r"Compiled LLVM module: (\S+) " + _XLA_TIME, body)]
    if not mods:
        return None
    stages, top = {}, []
    for module, sec in mods:
        # __compute_module_<kernel>_kernel_module (sometimes the prefix twice, or _elemental_ before the suffix)
        name = re.sub(r"^(__compute_module_)+", "", module)
        name = re.sub(r"(_elemental)?(_kernel_module)?$", "", name)
        op, src = kernels.get(name, ("", []))
        stage = stage_of(op) if name in kernels else "other"
        n, t = stages.get(stage, (0, 0.0))
        stages[stage] = (n + 1, t + sec)
        top.append((sec, name, stage, f"{src[0][0]}:{src[0][1]}:{src[0][2]}" if src else ""))
    top.sort(reverse=True)
    return {"hlo_passes_s": max(hlo, default=float("nan")), "codegen_s": max(gen, default=float("nan")),
            "llvm_cpu_s": sum(t for _, t in mods), "modules": len(mods), "stages": stages, "top": top[:10]}


def codegen_rows(seq: Path) -> Optional[dict]:
    """:func:`parse_codegen_log` of the default estimator's compilation in a child process (XLA
    reads its logging settings when it loads, so they cannot be switched on in this one)."""
    from kernel_profile import kernel_sources

    with tempfile.TemporaryDirectory(prefix="jaxvo-codegen-") as tmp:
        hlo = Path(tmp) / "estimate.hlo.txt"
        env = {**os.environ, "TF_CPP_MIN_LOG_LEVEL": "0", "TF_CPP_VMODULE": _XLA_VMODULE}
        t = time.perf_counter()
        r = subprocess.run([sys.executable, str(SCRIPT), "--codegen-child", str(seq), str(hlo)], capture_output=True,
                           text=True, env=env, cwd=common._REPO)
        if r.returncode != 0:
            raise SystemExit(f"error: the compile-time child process failed:\n{r.stderr[-2000:]}")
        out = parse_codegen_log(r.stderr, kernel_sources(hlo.read_text()))
    if out is None:
        print("XLA wrote no timing log: the compile-time breakdown is left out", flush=True)
        return None
    print(f"XLA compile of the default estimator: HLO passes {out['hlo_passes_s']:.2f} s, code generation "
          f"{out['codegen_s']:.2f} s, LLVM {out['llvm_cpu_s']:.2f} cpu s in {out['modules']} kernels "
          f"(child process {time.perf_counter() - t:.0f} s)", flush=True)
    return out


def main(argv: Optional[List[str]] = None) -> None:
    args = parse_args(argv)
    if args.codegen_child:
        codegen_child(Path(args.codegen_child[0]), Path(args.codegen_child[1]))
        return
    t_start = time.perf_counter()
    load = os.getloadavg()[0]
    tmp = None
    entries = [e.strip() for e in args.entries.split(",") if e.strip()]
    if [e for e in entries if e not in ENTRIES]:
        raise SystemExit(f"error: --entries: choose from {', '.join(ENTRIES)}")
    if args.quick:
        tmp = Path(tempfile.mkdtemp(prefix="jaxvo-startup-seq-"))
        seq = common.synthetic_sequence(tmp / "seq", FRAMES)
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
        rows = startup_rows(seq, methods, entries, 1 if args.quick else max(1, args.repeats),
                            1 if args.quick else max(1, args.warm_runs))
        load_after = os.getloadavg()[0]
        stages = [] if args.no_stages else stage_rows(seq, methods) + ([] if args.quick else part_rows(seq))
        codegen = None if args.no_stages or args.quick else codegen_rows(seq)
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    write(args, argv, seq, rows, stages, codegen, time.perf_counter() - t_start, (load, load_after))


def _spread(row: dict, key: str) -> str:
    """``median [min-max]`` of a startup row's passes (the median alone for one pass)."""
    lo, hi = row.get(key + "_min", row[key]), row.get(key + "_max", row[key])
    return f"{row[key]:.1f}" + (f" [{lo:.1f}-{hi:.1f}]" if hi > lo else "")


def write(args, argv, seq: Path, rows: List[dict], stages: List[dict], codegen: Optional[dict], total_s: float,
          loads=(float("nan"), float("nan"))) -> None:
    lines = common.provenance_md("Start-up: the first poses of a new process", str(SCRIPT), argv)
    lines += [f"Sequence: `{seq.name}`, its first {FRAMES} frames. Each entry point in its own new process, "
              "whole (interpreter start, imports, reading, the programs loaded or compiled, the poses, writing "
              "and exit), in a fresh cache folder (`JAXVO_CACHE_DIR`) per pass: `cli`: `jaxvo run SEQ "
              f"--max-frames {FRAMES} --poses tracked` (the default tracking, each line written as it is estimated; trajectory written and evaluated); `estimate_motion`: "
              "`python -c` importing jaxvo and calling `jaxvo.estimate_motion` once on frames 0 and 1; `track`: "
              f"`python -c` running `jaxvo.track` (`Odometry`) on {FRAMES} frames. `cold`: an empty folder (a new "
              f"machine); `warm`: the folder the cold run filled (per pass, the median of "
              f"{1 if args.quick else args.warm_runs} warm processes). `first pose s`: from the process's start to its first pose (`cli`: its "
              "trajectory's line for frame 1, watched every 5 ms); `process s`: the whole process's wall time; "
              "`cpu s`: its user + sys time (less sensitive to other processes than the wall time); Python's "
              "bytecode cache on, as in an installed jaxvo (`PYTHONDONTWRITEBYTECODE` dropped). Passes: "
              f"{1 if args.quick else args.repeats}, each in a fresh folder: the median, and in brackets the range. "
              f"Load average (1 min) at the start of the runs {loads[0]:.2f}, at their end {loads[1]:.2f}: other "
              "processes share this machine, so compare rows of one run, CPU times first.", "",
              "| method | entry | run | first pose s | process s | cpu s |", "| --- | --- | --- | --- | --- | --- |"]
    lines += [f"| {r['method']} | {r['entry']} | {r['run']} | {_spread(r, 'first_pose_s')} | "
              f"{_spread(r, 'process_s')} | {_spread(r, 'cpu_s')} |" for r in rows]
    if stages:
        lines += ["", "## Where the first compilation goes", "",
                  "The estimator alone (`jaxvo.estimator.estimate_arrays_jit`) at the sequence's image size, in one "
                  "process with no cache: `jit(...).trace`, `.lower` (for the parts: both), `.compile` (XLA) "
                  "timed separately; `cpu`: CPU seconds of the whole process during the XLA compilation (less "
                  "sensitive to other processes than the wall time); lines: the lowered StableHLO text. The "
                  "parts: pieces of the default estimator at one pyramid level, each compiled alone with that "
                  "level's pyramid and reference points (the estimator compiles each of them once per level). "
                  "fusions: the kernels of the compiled program (XLA generates code for each); the variants: the "
                  "same lowered program compiled with XLA's legacy fusion emitters "
                  "(`xla_cpu_use_fusion_emitters` off), LLVM's optimisation level 1 or 0 "
                  "(`xla_backend_optimization_level`, default 2), or LLVM's expensive passes off "
                  "(`xla_llvm_disable_expensive_passes`); load cpu s: CPU seconds to load the executable back "
                  "from its serialization (what a warm process pays for it); ms / pair: the compiled program's "
                  "median time per pair on the sequence's first consecutive pairs, the programs alternating (same "
                  "process); max dT: the largest difference of a variant's poses from the default's (0: bitwise "
                  "equal).",
                  "", "| method | part | trace s | lower s | XLA compile s | XLA compile cpu s | load cpu s | lines | "
                  "fusions | ms / pair | max dT |", "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        for r in stages:
            trace = "n/a" if r["trace_s"] != r["trace_s"] else f"{r['trace_s']:.2f}"  # NaN: traced with lower
            extra = [str(r["fusions"]) if "fusions" in r else "n/a",
                     f"{r['pair_ms']:.1f}" if "pair_ms" in r else "n/a",
                     f"{r['max_dT']:.1e}" if "max_dT" in r else "n/a"]
            load = f"{r['load_cpu_s']:.2f}" if "load_cpu_s" in r else "n/a"
            lines.append(f"| {r['method']} | {r['part']} | {trace} | {r['lower_s']:.2f} | {r['compile_s']:.1f} | "
                         f"{r['compile_cpu_s']:.1f} | {load} | {r['lines']} | " + " | ".join(extra) + " |")
    if codegen:
        lines += ["", "## Where XLA's compilation of the default estimator goes", "",
                  "The default estimator compiled once more, in a child process with XLA's timing log on "
                  f"(`TF_CPP_VMODULE={_XLA_VMODULE}`): HLO optimisation passes "
                  f"{codegen['hlo_passes_s']:.2f} s, then code generation {codegen['codegen_s']:.2f} s (wall: "
                  "emitting each kernel, one after the other, and compiling it with LLVM, on several threads), in "
                  f"which LLVM took {codegen['llvm_cpu_s']:.2f} CPU s over {codegen['modules']} kernels (XLA "
                  "compiles a kernel once and reuses it for identical fusions). By the estimator stage a kernel "
                  "belongs to (the named scopes of `experiments/kernel_profile.py`; `other`: loop bookkeeping "
                  "and the rest):", "",
                  "| stage | kernels | LLVM cpu s | share |", "| --- | --- | --- | --- |"]
        total = codegen["llvm_cpu_s"]
        for stage, (n, t) in sorted(codegen["stages"].items(), key=lambda kv: -kv[1][1]):
            lines.append(f"| {stage} | {n} | {t:.2f} | {t / total:.2f} |")
        lines += ["", "The kernels LLVM took longest on:", "", "| kernel | LLVM s | stage | innermost jaxvo source |",
                  "| --- | --- | --- | --- |"]
        lines += [f"| {name} | {sec:.3f} | {stage} | `{src}` |" for sec, name, stage, src in codegen["top"]]
    lines += ["", f"Total wall time {total_s:.0f} s."]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
