"""jaxvo on one accelerator: per-pair time, batched throughput, memory, and agreement with the CPU.

Writes ``gpu.md`` and ``gpu.json`` to ``--out`` (rewritten after every measurement, so a run
that is killed keeps what finished) and prints its progress. Sections, in the order they run:

1. ``device``: jax.devices(), the device kind, jax / jaxlib / plugin versions, nvidia-smi.
2. ``pairs``: ``jaxvo.estimate_motion`` per consecutive 640x480 pair of the Bonn crowd excerpt
   and fr2_desk, for classic / huber / ransac: the first call of each set (trace + XLA compile +
   one run) apart, then ``--repeats`` passes, each estimate blocked until ready
   (``jax.block_until_ready``) and its pose pulled to the host (``jax.device_get``).
3. ``cpu``: the same pairs, same keys, on ``jax.devices("cpu")[0]`` in this process
   (``jax.default_device``): the largest translation (m) and rotation (deg) difference of
   ``T_cur_ref`` per method between the default device and the CPU, and the CPU's times.
4. ``track``: the default tracking (``jaxvo.Odometry(camera, Config(), key, TrackConfig())``,
   ``add`` per frame), one pass to compile, then one timed pass over the same frames.
5. ``batch``: ``jax.jit(jax.vmap(estimate_motion))`` over B RANSAC pairs (the pairs of both sets
   cycled, each with its own camera and the key it had in ``pairs``), lowered and compiled
   apart (compile time, XLA's memory analysis), then timed with the inputs already on the device
   (``compute``) and with their transfer from the host (``with transfer``); throughput in
   pairs/s, device memory (``memory_stats()``: bytes in use before, peak after; the peak
   cannot be reset, so it is the peak so far and batch sizes run in increasing order), and the
   largest pose difference of the batched estimates from the one-pair estimates.
6. ``multi``: several sequences tracked at once (``jaxvo.tracking.batch.track_batch``, frames in
   memory; the default tracking per sequence, estimates vmapped in lockstep): a first run
   compiles, a second is timed. Then ``jaxvo.pipelines.run.run_sequences`` (what
   ``jaxvo run`` does for several sequences: frames read from disk) on the same sequences.
7. ``track_cpu``: the default tracking of section 4 on the CPU, its poses against the default
   device's (largest translation / rotation difference over the trajectory).

A section or batch size that would start after ``--time-limit`` seconds is skipped and
reported as skipped.

Example (data in TUM layout under $JAXVO_DATA/bonn/rgbd_bonn_crowd and
$JAXVO_DATA/tum/rgbd_dataset_freiburg2_desk)::

    python experiments/gpu.py --out /tmp/gpu_out             # full (an H100: ~5 minutes)
    python experiments/gpu.py --out /tmp/gpu_out --quick     # tiny, runs on a CPU too
"""
from __future__ import annotations

import argparse
import contextlib
import gc
import importlib.metadata
import json
import math
import os
import platform
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Dict, List, NamedTuple, Optional

import numpy as np

import jax
import jax.numpy as jnp
from jax.sharding import Mesh, NamedSharding, PartitionSpec

import jaxvo
from jaxvo.config import Config, TrackConfig
from jaxvo.data import TumSequence, data_root
from jaxvo.frame import Frame
from jaxvo.pipelines.run import run_sequences
from jaxvo.tracking import batch as _batch
from jaxvo.tracking.batch import track_batch

# the library's batched estimate (what track_batch runs): vmapped over (frames, camera, key,
# initial pose, weights), the config shared; timing it directly shares its compilation with track_batch
_BATCHED = getattr(_batch, "_BATCHED", None)

METHODS = ("classic", "huber", "ransac")
SECTIONS = ("pairs", "cpu", "track", "batch", "multi", "track_cpu")
_T0 = time.perf_counter()


def log(msg: str) -> None:
    print(f"[gpu {time.perf_counter() - _T0:6.1f} s] {msg}", flush=True)


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--out", required=True, help="folder for gpu.md and gpu.json (created)")
    ap.add_argument("--bonn", default=None, help="Bonn crowd folder (default data_root()/bonn/rgbd_bonn_crowd)")
    ap.add_argument("--fr2", default=None,
                    help="fr2_desk folder (default data_root()/tum/rgbd_dataset_freiburg2_desk)")
    ap.add_argument("--bonn-pairs", type=int, default=30, help="consecutive Bonn pairs from the start (default 30)")
    ap.add_argument("--fr2-pairs", type=int, default=20, help="consecutive fr2_desk pairs (default 20)")
    ap.add_argument("--repeats", type=int, default=2, help="timed passes per measurement (default 2)")
    ap.add_argument("--batches", default="1,8,64,256", help="vmapped RANSAC batch sizes (default 1,8,64,256)")
    ap.add_argument("--seqs", type=int, default=8, help="sequences tracked at once (default 8)")
    ap.add_argument("--seq-frames", type=int, default=11, help="frames per sequence tracked at once (default 11)")
    ap.add_argument("--sections", default=",".join(SECTIONS), help=f"comma list of {', '.join(SECTIONS)}")
    ap.add_argument("--methods", default=",".join(METHODS), help="per-pair methods (default classic,huber,ransac)")
    ap.add_argument("--time-limit", type=float, default=300.0,
                    help="seconds after start past which no new measurement starts (default 300)")
    ap.add_argument("--reserve", type=float, default=100.0,
                    help="seconds before --time-limit at which the timings start even if some compilations "
                         "have not finished (default 100)")
    ap.add_argument("--compile-workers", type=int, default=max(2, min(6, (os.cpu_count() or 2) // 2)),
                    help="compilations at once (default half the host CPUs, 2 to 6)")
    ap.add_argument("--quick", action="store_true",
                    help="tiny run for a CPU: 2 pairs per set, 1 repeat, batches 1,2, 2 sequences of 3 frames")
    a = ap.parse_args(argv)
    if a.quick:
        a.bonn_pairs, a.fr2_pairs, a.repeats, a.batches, a.seqs, a.seq_frames = 2, 2, 1, "1,2", 2, 3
        a.time_limit = max(a.time_limit, 3600.0)
    a.batches = [int(b) for b in a.batches.split(",") if b.strip()]
    a.sections = [s.strip() for s in a.sections.split(",") if s.strip()]
    a.methods = [m.strip() for m in a.methods.split(",") if m.strip()]
    if set(a.methods) - set(METHODS):
        ap.error(f"unknown methods {sorted(set(a.methods) - set(METHODS))}")
    unknown = set(a.sections) - set(SECTIONS)
    if unknown:
        ap.error(f"unknown sections {sorted(unknown)}")
    root = data_root()
    a.bonn = Path(a.bonn) if a.bonn else root / "bonn" / "rgbd_bonn_crowd"
    a.fr2 = Path(a.fr2) if a.fr2 else root / "tum" / "rgbd_dataset_freiburg2_desk"
    return a


# ----------------------------------------------------------------------------- results


class Report:
    """The results so far (a JSON-able dict), written to ``out`` as gpu.json and gpu.md on each :meth:`save`."""

    def __init__(self, out: Path, args):
        self.out = out
        out.mkdir(parents=True, exist_ok=True)
        self.data: Dict = {"command": " ".join([Path(sys.argv[0]).name] + sys.argv[1:]),
                           "quick": bool(args.quick), "repeats": args.repeats, "time_limit_s": args.time_limit,
                           "skipped": []}

    def save(self) -> None:
        self.data["elapsed_s"] = time.perf_counter() - _T0
        try:
            md = markdown(self.data)
        except Exception as e:  # noqa: BLE001 - the json keeps everything; the table must not stop the run
            md = f"# jaxvo on one accelerator\n\nThe table could not be written ({type(e).__name__}: {e}); see gpu.json.\n"
        for name, text in (("gpu.json", json.dumps(self.data, indent=1, default=_jsonable)), ("gpu.md", md)):
            tmp = self.out / (name + ".tmp")
            tmp.write_text(text)
            os.replace(tmp, self.out / name)


def _jsonable(x):
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    return str(x)


def stats_ms(seconds: List[float]) -> Dict:
    """median / mean / p90 / min / max (ms) and count of per-call wall times (s)."""
    s = np.asarray(seconds, np.float64) * 1000
    if s.size == 0:
        return {"n": 0}
    return {"n": int(s.size), "median_ms": float(np.median(s)), "mean_ms": float(np.mean(s)),
            "p90_ms": float(np.percentile(s, 90)), "min_ms": float(np.min(s)), "max_ms": float(np.max(s))}


class PoseDiff(NamedTuple):
    """Differences between two lists of 4x4 poses: the largest translation difference (m,
    Euclidean norm), the largest rotation difference (deg, angle of R_a^T R_b), the median
    translation difference, and how many poses were not finite in either list (left out)."""
    max_translation_m: float
    max_rotation_deg: float
    median_translation_m: float
    nonfinite: int


def pose_diff(Ta, Tb) -> PoseDiff:
    Ta, Tb = np.asarray(Ta, np.float64).reshape(-1, 4, 4), np.asarray(Tb, np.float64).reshape(-1, 4, 4)
    ok = np.all(np.isfinite(Ta), axis=(1, 2)) & np.all(np.isfinite(Tb), axis=(1, 2))
    if not ok.any():
        return PoseDiff(float("nan"), float("nan"), float("nan"), int((~ok).sum()))
    Ta, Tb = Ta[ok], Tb[ok]
    dt = np.linalg.norm(Ta[:, :3, 3] - Tb[:, :3, 3], axis=1)
    # the angle of R_a^T R_b from |R_a - R_b|_F = 2 sqrt 2 sin(angle / 2): exact for small angles
    # (acos((tr - 1) / 2) is not), and 0 for equal matrices even where float32 rounding left
    # them a little off orthonormal
    fro = np.linalg.norm(Ta[:, :3, :3] - Tb[:, :3, :3], axis=(1, 2))
    ang = np.degrees(2 * np.arcsin(np.clip(fro / math.sqrt(8), 0, 1)))
    return PoseDiff(float(dt.max()), float(ang.max()), float(np.median(dt)), int((~ok).sum()))


# ----------------------------------------------------------------------------- data


class PairSet(NamedTuple):
    """Consecutive frames of one sequence, decoded into memory: pairs are (k, k + 1)."""
    name: str
    camera: jaxvo.Camera
    frames: List[Frame]
    keys: list   # one jax.random key per pair: fold_in(key(0), k)

    @property
    def pairs(self) -> int:
        return len(self.frames) - 1


#: how the real sequences are read here: the files as they are (no lens, the layout's depth scale),
#: not with a dataset's published calibration as ``jaxvo run`` reads them. This script measures time
#: and the agreement of the accelerator with the CPU on the same inputs, which the reading does not
#: change; reading the files as they are keeps its stored results those of this command.
AS_RECORDED = {"lens": "none", "depth_scale": "recorded"}


def load_set(name: str, path: Path, n_pairs: int) -> PairSet:
    seq = TumSequence(path, max_frames=n_pairs + 1, **AS_RECORDED)
    frames = [seq.frame(i) for i in range(len(seq))]
    log(f"{name}: {len(frames)} frames {seq.camera.width}x{seq.camera.height} from {path}")
    return PairSet(name, seq.camera, frames, pair_keys(len(frames) - 1))


def pair_keys(n: int) -> list:
    """The key of pair k: fold_in(key(0), k), on the default device."""
    return [jax.random.fold_in(jax.random.key(0), k) for k in range(n)]


# ----------------------------------------------------------------------------- sections


def device_info() -> Dict:
    devs = jax.devices()
    info = {"devices": [str(d) for d in devs], "platform": devs[0].platform,
            "device_kind": devs[0].device_kind, "device_count": len(devs),
            "jax": jax.__version__, "jaxlib": importlib.metadata.version("jaxlib"),
            "python": platform.python_version(), "host_cpus": os.cpu_count(), "jaxvo": str(Path(jaxvo.__file__).parent)}
    try:
        info["platform_version"] = devs[0].client.platform_version
    except Exception as e:  # noqa: BLE001 - backend-specific attribute
        info["platform_version"] = f"n/a ({type(e).__name__})"
    info["packages"] = sorted({f"{d.metadata['Name']}=={d.version}" for d in importlib.metadata.distributions()
                               if d.metadata["Name"] and "jax" in d.metadata["Name"].lower()})
    try:
        smi = subprocess.run(["nvidia-smi", "--query-gpu=name,driver_version,memory.total", "--format=csv,noheader"],
                             capture_output=True, text=True, timeout=20)
        info["nvidia_smi"] = smi.stdout.strip() or smi.stderr.strip()
    except (OSError, subprocess.SubprocessError) as e:
        info["nvidia_smi"] = f"n/a ({type(e).__name__})"
    info["compilation_cache_dir"] = jax.config.jax_compilation_cache_dir
    info["env"] = {k: v for k, v in os.environ.items() if k.startswith(("XLA_", "JAX_", "CUDA_VISIBLE"))}
    ms = memory_stats()
    info["memory_limit_bytes"] = None if ms is None else ms.get("bytes_limit")
    return info


def memory_stats() -> Optional[Dict]:
    try:
        return jax.devices()[0].memory_stats()
    except Exception:  # noqa: BLE001 - not every backend has them
        return None


class Warm:
    """The work that compiles (first calls, warm-up passes, batched programs), run before any timing
    on up to ``workers`` threads at once (XLA compiles one program per thread; the host has cores
    to spare), each task once the tasks it depends on are done. A task's wall time counts the
    compilations running beside it."""

    class Task:
        def __init__(self, name, fn, deps):
            self.name, self.fn, self.deps = name, fn, deps
            self.state, self.result, self.error, self.wall_s = "pending", None, None, None

    def __init__(self, workers: int):
        self.workers = workers
        self.tasks: Dict[str, "Warm.Task"] = {}
        self.cv = threading.Condition()
        self.threads: List[threading.Thread] = []

    def add(self, name: str, fn, deps=()) -> None:
        self.tasks[name] = Warm.Task(name, fn, [d for d in deps if d in self.tasks])

    def start(self) -> None:
        for i in range(self.workers):
            t = threading.Thread(target=self._work, name=f"warm-{i}", daemon=True)
            t.start()
            self.threads.append(t)

    def _next(self) -> Optional["Warm.Task"]:
        """The first pending task whose dependencies are done (None when nothing is pending);
        waits while pending tasks wait on running ones. Call with the lock held."""
        while True:
            pending = [t for t in self.tasks.values() if t.state == "pending"]
            if not pending:
                return None
            for t in pending:
                if any(self.tasks[d].state in ("failed", "skipped") for d in t.deps):
                    t.state, t.error = "skipped", "a task it needs failed"
                    self.cv.notify_all()
                elif all(self.tasks[d].state == "done" for d in t.deps):
                    t.state = "running"
                    return t
            self.cv.wait(1.0)

    def _work(self) -> None:
        while True:
            with self.cv:
                task = self._next()
            if task is None:
                return
            log(f"  compiling: {task.name}")
            t0 = time.perf_counter()
            try:
                result, state, error = task.fn(), "done", None
            except Exception as e:  # noqa: BLE001 - recorded; the timings of the other tasks still run
                result, state, error = None, "failed", f"{type(e).__name__}: {str(e).splitlines()[0][:300] if str(e) else ''}"
            with self.cv:
                task.result, task.state, task.error = result, state, error
                task.wall_s = time.perf_counter() - t0
                self.cv.notify_all()
            log(f"  compiled: {task.name} ({state}, {task.wall_s:.1f} s)" + (f": {error}" if error else ""))

    def wait(self, deadline: float) -> None:
        """Until every task has ended or ``time.perf_counter() - _T0`` passes ``deadline``."""
        with self.cv:
            while any(t.state in ("pending", "running") for t in self.tasks.values()):
                left = deadline - (time.perf_counter() - _T0)
                if left <= 0:
                    return
                self.cv.wait(min(left, 5.0))

    def get(self, name: str):
        """(result, None) of a finished task, else (None, why not)."""
        t = self.tasks.get(name)
        if t is None:
            return None, "not run"
        if t.state == "done":
            return t.result, None
        if t.state in ("pending", "running"):
            return None, "still compiling at the deadline"
        return None, t.error

    def summary(self) -> List[Dict]:
        return [{"task": t.name, "state": t.state, "wall_s": t.wall_s, "error": t.error} for t in self.tasks.values()]


def _estimate(s: PairSet, k: int, config: Config, key):
    """One estimate of pair k, blocked until ready; returns (seconds, T_cur_ref (4, 4) host, estimate)."""
    t0 = time.perf_counter()
    est = jaxvo.estimate_motion(s.frames[k], s.frames[k + 1], s.camera, config, key)
    jax.block_until_ready(est)
    T = np.asarray(jax.device_get(est.T_cur_ref))
    return time.perf_counter() - t0, T, est


def _on(device):
    """``jax.default_device(device)`` (thread-local), or nothing for None."""
    return contextlib.nullcontext() if device is None else jax.default_device(device)


def first_calls(sets: List[PairSet], method: str, device=None) -> Dict[str, float]:
    """Wall time (s) of the first estimate of each set (on ``device``, None = the default one)."""
    out = {}
    with _on(device):
        for s in sets:
            keys = pair_keys(1) if device is not None else s.keys
            out[s.name] = _estimate(s, 0, Config(method=method), keys[0])[0]
    return out


def time_pairs(sets: List[PairSet], method: str, repeats: int, first: Dict[str, float]):
    """Per-pair times of one method on every set over ``repeats`` passes; the poses of the first pass."""
    cfg = Config(method=method)
    row = {"method": method, "sets": {}}
    poses = {}
    for s in sets:
        secs, Ts, hyps = [], [], []
        for r in range(repeats):
            for k in range(s.pairs):
                dt, T, est = _estimate(s, k, cfg, s.keys[k])
                secs.append(dt)
                if r == 0:
                    Ts.append(T)
                    hyps.append(int(np.sum(jax.device_get(est.hypotheses))))
        st = stats_ms(secs)
        row["sets"][s.name] = {"pairs": s.pairs, "first_call_s": first[s.name], **st,
                               "compile_s": first[s.name] - st["median_ms"] / 1000, "fps": 1000 / st["median_ms"],
                               "hypotheses_mean": float(np.mean(hyps))}
        poses[s.name] = np.stack(Ts)
        log(f"  {method} {s.name}: median {st['median_ms']:.1f} ms, mean {st['mean_ms']:.1f} ms over {st['n']} calls")
    return row, poses


def cpu_agreement(sets: List[PairSet], method: str, ref_poses: Dict[str, np.ndarray], first: Dict[str, float],
                  cpu) -> Dict:
    """One pass over the pairs on the CPU (``cpu``: its device, or None when it is the default
    device); its times and its poses against ``ref_poses``."""
    cfg = Config(method=method)
    row = {"method": method, "device": str(cpu or jax.devices()[0]), "same_device": cpu is None, "sets": {}}
    with _on(cpu):
        for s in sets:
            keys = pair_keys(s.pairs)
            secs, Ts, placed = [], [], set()
            for k in range(s.pairs):
                dt, T, est = _estimate(s, k, cfg, keys[k])
                secs.append(dt)
                Ts.append(T)
                placed |= {str(d) for d in est.T_cur_ref.devices()}
            d = pose_diff(ref_poses[s.name], np.stack(Ts))
            row["sets"][s.name] = {"first_call_s": first[s.name], **stats_ms(secs), "result_on": sorted(placed),
                                   **d._asdict()}
            log(f"  {method} {s.name} on {sorted(placed)}: median {np.median(secs) * 1000:.1f} ms; max diff "
                f"{d.max_translation_m:.2e} m, {d.max_rotation_deg:.2e} deg")
    return row


def track_pass(s: PairSet, device=None):
    """The default tracking over the set's frames (``Odometry.add`` per frame) on ``device``:
    (per-frame seconds, Track)."""
    with _on(device):
        odo = jaxvo.Odometry(s.camera, Config(), jax.random.key(0), TrackConfig())
        secs = []
        for f in s.frames:
            t0 = time.perf_counter()
            odo.add(f)
            secs.append(time.perf_counter() - t0)
    return secs, odo.result()


def warm_tracking(sets: List[PairSet], device=None) -> Dict[str, Dict]:
    out = {}
    for s in sets:
        t0 = time.perf_counter()
        secs, _ = track_pass(s, device)
        out[s.name] = {"warmup_pass_s": time.perf_counter() - t0, "warmup_first_two_s": sum(secs[:2])}
    return out


def time_tracking(s: PairSet, warm: Dict, device=None):
    """The timed pass of the default tracking (the first frame only records itself: not counted)."""
    secs, res = track_pass(s, device)
    st = stats_ms(secs[1:])
    row = {"set": s.name, "frames": len(s.frames), **warm, **st, "fps": 1000 / st["median_ms"],
           "failed": int(np.sum(~res.valid)), "references": sorted(set(int(r) for r in res.reference))}
    return row, res.poses


class BatchPrep(NamedTuple):
    """A compiled batch of B pairs: the host inputs, the slots' (set, pair), the program and what compiling it took."""
    B: int
    host: list          # [ri, rd, ci, cd] (B, H, W) float32, cameras (stacked leaves), T0 (B, 4, 4), weights (B, H, W)
    keys: jnp.ndarray   # (B,) keys
    slots: list
    compiled: object
    lower_s: float
    compile_s: float
    xla_memory: object


def _sharding():
    """As jaxvo.tracking.batch places a batch: its leading axis split over jax.devices()."""
    return NamedSharding(Mesh(np.asarray(jax.devices()), ("seq",)), PartitionSpec("seq"))


def batch_inputs(sets: List[PairSet], B: int):
    """B pairs (both sets' pairs cycled) as the library's batched estimate takes them, on the host:
    [ri, rd, ci, cd] (B, H, W) float32, the stacked cameras, initial poses (identity) and
    weights (ones), the stacked keys (the key each pair had in ``pairs``), the (set, pair) of each slot."""
    pool = [(s, k) for k in range(max(x.pairs for x in sets)) for s in sets if k < s.pairs]
    sel = [pool[i % len(pool)] for i in range(B)]
    imgs = [np.stack([np.asarray(getattr(s.frames[k + a], f), np.float32) for s, k in sel])
            for a, f in ((0, "intensity"), (0, "depth"), (1, "intensity"), (1, "depth"))]
    cams = jax.tree.map(lambda *x: np.asarray(x, np.float32), *[s.camera for s, _ in sel])
    h, w = imgs[0].shape[1:]
    T0 = np.broadcast_to(np.eye(4, dtype=np.float32), (B, 4, 4)).copy()
    wt = np.ones((B, h, w), np.float32)
    keys = jnp.stack([s.keys[k] for s, k in sel])
    return imgs + [cams, T0, wt], keys, [(s.name, k) for s, k in sel]


def _placed(host, keys):
    """The batch's arguments on the devices: (ri, rd, ci, cd, cameras, config, keys, T0, weights)."""
    sh = _sharding()
    ri, rd, ci, cd, cams, T0, wt = jax.device_put(host, sh)
    return (ri, rd, ci, cd, cams, Config(method="ransac"), jax.device_put(keys, sh), T0, wt)


def compile_batch(sets: List[PairSet], B: int) -> BatchPrep:
    if _BATCHED is None:
        raise RuntimeError("jaxvo.tracking.batch has no _BATCHED (the batched estimate): nothing to compile")
    host, keys, slots = batch_inputs(sets, B)
    args = _placed(host, keys)
    t0 = time.perf_counter()
    lowered = _BATCHED.lower(*args)
    lower_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    compiled = lowered.compile()
    compile_s = time.perf_counter() - t0
    try:
        ma = compiled.memory_analysis()
        xm = {k: int(getattr(ma, k)) for k in ("argument_size_in_bytes", "output_size_in_bytes", "alias_size_in_bytes",
                                                "temp_size_in_bytes", "generated_code_size_in_bytes") if hasattr(ma, k)}
    except Exception as e:  # noqa: BLE001 - not every backend reports it
        xm = f"n/a ({type(e).__name__})"
    del args
    return BatchPrep(B, host, keys, slots, compiled, lower_s, compile_s, xm)


def time_batch(prep: BatchPrep, repeats: int, ref_poses: Dict[str, np.ndarray]) -> Dict:
    """Calls of a compiled batch: with its inputs on the device (compute) and sent from the host
    each call (with transfer); device memory around them; the poses against the one-pair ones."""
    B = prep.B
    gc.collect()
    before = memory_stats()
    row = {"batch": B, "input_bytes": int(sum(x.nbytes for x in prep.host[:4])) + int(prep.host[6].nbytes),
           "lower_s": prep.lower_s, "compile_s": prep.compile_s, "xla_memory": prep.xla_memory,
           "bytes_in_use_before": None if before is None else before.get("bytes_in_use"),
           "peak_bytes_before": None if before is None else before.get("peak_bytes_in_use")}

    def call(args):
        out = prep.compiled(*args)
        jax.block_until_ready(out)
        return out, np.asarray(jax.device_get(out.T_cur_ref))

    args = _placed(prep.host, prep.keys)
    placed = memory_stats()
    t0 = time.perf_counter()
    out, T = call(args)
    row["first_run_s"] = time.perf_counter() - t0
    compute, transfer = [], []
    for _ in range(repeats):
        del out
        t0 = time.perf_counter()
        out, T = call(args)
        compute.append(time.perf_counter() - t0)
        del out
        t0 = time.perf_counter()
        out, T = call(_placed(prep.host, prep.keys))
        transfer.append(time.perf_counter() - t0)
    after = memory_stats()
    row["compute"] = {**stats_ms(compute), "pairs_per_s": B / float(np.median(compute))}
    row["with_transfer"] = {**stats_ms(transfer), "pairs_per_s": B / float(np.median(transfer))}
    row["bytes_in_use_inputs_placed"] = None if placed is None else placed.get("bytes_in_use")
    row["peak_bytes_after"] = None if after is None else after.get("peak_bytes_in_use")
    row["hypotheses_mean"] = float(np.mean(np.sum(np.asarray(jax.device_get(out.hypotheses)), axis=1)))
    row["valid"] = int(np.sum(np.asarray(jax.device_get(out.valid))))
    if ref_poses:
        ref = np.stack([ref_poses[name][k] for name, k in prep.slots])
        row["vs_one_pair"] = pose_diff(ref, T)._asdict()
    del out, args
    return row


def sequences_at_once(sets: List[PairSet], n: int, frames: int):
    """n (set, start) slices of ``frames`` frames: the sets alternate, starts 3 frames apart
    (wrapping within each set)."""
    out = []
    for i in range(n):
        s = sets[i % len(sets)]
        span = len(s.frames) - frames + 1
        if span < 1:
            raise ValueError(f"{s.name}: {len(s.frames)} frames, fewer than --seq-frames {frames}")
        out.append((s, (3 * (i // len(sets))) % span))
    return out


def run_multi(sets: List[PairSet], n: int, frames: int):
    """track_batch of n sequences (frames in memory, the default tracking each): (seconds, tracks)."""
    chosen = sequences_at_once(sets, n, frames)
    t0 = time.perf_counter()
    tracks = track_batch([s.frames[a:a + frames] for s, a in chosen], [s.camera for s, _ in chosen], Config(),
                         [jax.random.key(0)] * n, TrackConfig())
    return time.perf_counter() - t0, tracks


def time_multi(sets: List[PairSet], paths: Dict[str, Path], n: int, frames: int, first: float) -> Dict:
    """The timed track_batch run; then run_sequences (frames read from disk) of the same slices."""
    chosen = sequences_at_once(sets, n, frames)
    wall, tracks = run_multi(sets, n, frames)
    pairs = n * (frames - 1)
    row = {"sequences": n, "frames_each": frames, "slices": [f"{s.name}[{a}:{a + frames}]" for s, a in chosen],
           "first_run_s": first, "wall_s": wall, "pairs_per_s": pairs / wall, "ms_per_step": 1000 * wall / (frames - 1),
           "failed": int(sum(np.sum(~t.valid) for t in tracks))}
    log(f"  track_batch {n} x {frames} frames: {wall:.2f} s = {row['pairs_per_s']:.1f} pairs/s")
    seqs = [TumSequence(paths[s.name], start=a, max_frames=frames, **AS_RECORDED) for s, a in chosen]
    t0 = time.perf_counter()
    results = run_sequences(seqs, Config(), seed=0)
    wall = time.perf_counter() - t0
    row["run_sequences"] = {"wall_s": wall, "pairs_per_s": pairs / wall,
                            "vs_track_batch": pose_diff(np.concatenate([t.poses for t in tracks]),
                                                        np.concatenate([r.poses for r in results]))._asdict()}
    log(f"  run_sequences: {wall:.2f} s = {pairs / wall:.1f} pairs/s (reading from disk)")
    return row


# ----------------------------------------------------------------------------- markdown


def _f(x, fmt="{:.1f}"):
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    return fmt.format(x)


def _mib(x):
    return "-" if x is None else f"{x / 2 ** 20:.0f}"


def _lines(rows) -> List[str]:
    """Markdown table lines of ``rows`` (each an iterable of cells), then a blank line."""
    return ["| " + " | ".join(str(c) for c in cells) + " |" for cells in rows] + [""]


def _set_lines(rows: List[Dict], cells) -> List[str]:
    """Table lines, one per method and set of ``rows`` (each {"method", "sets": {name: dict}}):
    method, set name, then ``cells(set dict)``."""
    return _lines([r["method"], name] + cells(s) for r in rows for name, s in r["sets"].items())


def markdown(d: Dict) -> str:
    L = ["# jaxvo on one accelerator", ""]
    dev = d.get("device")
    if dev:
        L += [f"Device: **{dev['device_kind']}** ({dev['platform']}, {dev['device_count']} device(s): "
              f"{', '.join(dev['devices'])}); nvidia-smi: {dev.get('nvidia_smi')}", "",
              f"jax {dev['jax']}, jaxlib {dev['jaxlib']}, platform version {dev.get('platform_version')}; "
              f"packages: {', '.join(dev['packages'])}; Python {dev['python']}, {dev['host_cpus']} host CPUs; "
              f"jaxvo from `{dev['jaxvo']}`; device memory limit {_mib(dev.get('memory_limit_bytes'))} MiB; "
              f"environment {dev.get('env') or '{}'}; persistent compilation cache {dev.get('compilation_cache_dir')}.", ""]
    L += [f"Command: `{d['command']}`; {d['repeats']} timed pass(es) per measurement; "
          f"elapsed {d.get('elapsed_s', 0):.0f} s" + (" (quick mode)" if d["quick"] else "") + ".", ""]
    c = d.get("compilation")
    if c:
        L += ["## Compilation", "",
              f"First calls, warm-up passes and batched programs ran before any timing, {c['workers']} at once "
              f"(so each one's wall time counts the others beside it); all done after {c['wall_s']:.0f} s.", "",
              "| task | state | wall s | error |", "|---|---|---:|---|"]
        L += _lines((t["task"], t["state"], _f(t["wall_s"]), t["error"] or "") for t in c["tasks"])
    if d.get("pairs"):
        L += ["## Per pair: `jaxvo.estimate_motion`, 640x480", "",
              "Each call blocked until ready and its pose pulled to the host. First call: trace + "
              "compile + one run (while other compilations ran, see Compilation); compile = first call - median. "
              "Hypotheses: RANSAC hypotheses evaluated per pair, summed over the levels.", "",
              "| method | set | pairs | median ms | mean ms | p90 ms | FPS | first call s | compile s | hypotheses |",
              "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
        L += _set_lines(d["pairs"], lambda s: [s["pairs"], _f(s["median_ms"]), _f(s["mean_ms"]), _f(s["p90_ms"]),
                                               _f(s["fps"]), _f(s["first_call_s"]), _f(s["compile_s"]),
                                               _f(s["hypotheses_mean"])])
    if d.get("cpu"):
        same = any(r.get("same_device") for r in d["cpu"])
        L += ["## Default device against the CPU (same pairs, same keys, one process)", "",
              f"CPU: `{d['cpu'][0]['device']}`" + (" (the default device itself: CPU against CPU)" if same else "")
              + ". Translation: Euclidean norm of the difference of T_cur_ref's translations; rotation: "
              "angle of R_a^T R_b.", "",
              "| method | set | CPU median ms | CPU first call s | max translation diff m | max rotation diff deg "
              "| median translation diff m | non-finite |", "|---|---|---:|---:|---:|---:|---:|---:|"]
        L += _set_lines(d["cpu"], lambda s: [_f(s["median_ms"]), _f(s["first_call_s"]), f"{s['max_translation_m']:.2e}",
                                             f"{s['max_rotation_deg']:.2e}", f"{s['median_translation_m']:.2e}",
                                             s["nonfinite"]])
    if d.get("track"):
        L += ["## Default tracking: `Odometry(camera, Config(), key, TrackConfig()).add` per frame", "",
              "| set | frames | median ms | mean ms | p90 ms | FPS | compile pass s | first two frames s | failed |",
              "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
        L += _lines((r["set"], r["frames"], _f(r["median_ms"]), _f(r["mean_ms"]), _f(r["p90_ms"]), _f(r["fps"]),
                     _f(r["warmup_pass_s"]), _f(r["warmup_first_two_s"]), r["failed"]) for r in d["track"])
    if d.get("batch"):
        L += ["## RANSAC batches: `jit(vmap(estimate_motion))` over B pairs, 640x480", "",
              "compute: inputs already on the device; with transfer: the B pairs' images sent from the host "
              "each call. Peak memory: `peak_bytes_in_use` after the size (the peak so far). XLA temp: "
              "the compiled program's scratch memory (`memory_analysis`).", "",
              "| B | compute ms/call | compute pairs/s | with transfer ms/call | with transfer pairs/s | compile s "
              "| in use before MiB | peak after MiB | XLA temp MiB | XLA args+out MiB | hypotheses | max diff vs one pair m / deg |",
              "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
        for r in d["batch"]:
            if "error" in r:
                L.append(f"| {r['batch']} | {r['error']} |" + " |" * 10)
                continue
            xm = r.get("xla_memory") if isinstance(r.get("xla_memory"), dict) else {}
            io = (xm["argument_size_in_bytes"] + xm["output_size_in_bytes"]) if "argument_size_in_bytes" in xm else None
            v = r.get("vs_one_pair")
            L.append(f"| {r['batch']} | {_f(r['compute']['median_ms'])} | {_f(r['compute']['pairs_per_s'])} | "
                     f"{_f(r['with_transfer']['median_ms'])} | {_f(r['with_transfer']['pairs_per_s'])} | "
                     f"{_f(r['lower_s'] + r['compile_s'])} | {_mib(r['bytes_in_use_before'])} | "
                     f"{_mib(r['peak_bytes_after'])} | {_mib(xm.get('temp_size_in_bytes'))} | {_mib(io)} | "
                     f"{_f(r['hypotheses_mean'])} | "
                     + ("-" if not v else f"{v['max_translation_m']:.1e} / {v['max_rotation_deg']:.1e}") + " |")
        L.append("")
    if d.get("multi"):
        m = d["multi"]
        rs = m["run_sequences"]
        L += ["## Several sequences at once (default tracking, estimates vmapped in lockstep)", "",
              f"{m['sequences']} sequences x {m['frames_each']} frames ({', '.join(m['slices'])}).", "",
              "| how | wall s | pairs/s | ms per lockstep frame | first run s |", "|---|---:|---:|---:|---:|",
              f"| track_batch, frames in memory | {_f(m['wall_s'], '{:.2f}')} | {_f(m['pairs_per_s'])} | "
              f"{_f(m['ms_per_step'])} | {_f(m['first_run_s'])} |",
              f"| run_sequences, frames from disk | {_f(rs['wall_s'], '{:.2f}')} | {_f(rs['pairs_per_s'])} | - | - |", "",
              f"Poses of run_sequences against track_batch: max {rs['vs_track_batch']['max_translation_m']:.1e} m, "
              f"{rs['vs_track_batch']['max_rotation_deg']:.1e} deg.", ""]
    if d.get("track_cpu"):
        same = d["track_cpu"][0].get("same_device")
        L += ["## Default tracking, default device against the CPU (trajectory poses T_world_cam)", "",
              f"CPU: `{d['track_cpu'][0]['device']}`" + (" (the default device itself)" if same else "") + ".", "",
              "| set | CPU median ms | max translation diff m | max rotation diff deg | non-finite |",
              "|---|---:|---:|---:|---:|"]
        L += _lines((r["set"], _f(r["median_ms"]), f"{r['max_translation_m']:.2e}", f"{r['max_rotation_deg']:.2e}",
                     r["nonfinite"]) for r in d["track_cpu"])
    if d.get("skipped"):
        L += ["## Skipped", ""] + [f"- {s}" for s in d["skipped"]] + [""]
    if d.get("errors"):
        L += ["## Errors", ""] + [f"- {s}" for s in d["errors"]] + [""]
    return "\n".join(L)


# ----------------------------------------------------------------------------- main


def main(argv=None) -> Path:
    args = parse_args(argv)
    rep = Report(Path(args.out), args)
    d = rep.data

    def time_left(what: str) -> bool:
        if time.perf_counter() - _T0 < args.time_limit:
            return True
        d["skipped"].append(f"{what}: past --time-limit {args.time_limit:.0f} s")
        log(f"skipped {what} (time limit)")
        rep.save()
        return False

    def guarded(what: str, fn, *a):
        """fn(*a), or None with the error recorded (the other measurements still run)."""
        try:
            return fn(*a)
        except Exception as e:  # noqa: BLE001 - a failed measurement must not lose the others
            msg = f"{what}: {type(e).__name__}: {str(e).splitlines()[0][:300] if str(e) else ''}"
            d.setdefault("errors", []).append(msg)
            log("ERROR " + msg)
            rep.save()
            return None

    def ready(name: str):
        """The warm task's result, or None with the reason recorded as skipped."""
        result, why = warm.get(name)
        if why is not None:
            d["skipped"].append(f"{name}: {why}")
            log(f"skipped {name}: {why}")
            rep.save()
        return result

    d["device"] = device_info()
    log(f"device {d['device']['device_kind']} ({d['device']['platform']}), jax {d['device']['jax']}, "
        f"devices {d['device']['devices']}; nvidia-smi: {d['device']['nvidia_smi']}; jaxvo {d['device']['jaxvo']}")
    rep.save()
    sets = [load_set("bonn_crowd", args.bonn, args.bonn_pairs), load_set("fr2_desk", args.fr2, args.fr2_pairs)]
    paths = {"bonn_crowd": args.bonn, "fr2_desk": args.fr2}
    cpu_dev = jax.devices("cpu")[0]
    cpu = None if jax.devices()[0] == cpu_dev else cpu_dev   # None: the CPU is the default device
    sec = set(args.sections)

    # ---- compile everything first, several programs at once
    warm = Warm(args.compile_workers)   # tasks in the order of preference
    if sec & {"pairs", "cpu", "track", "multi", "track_cpu"}:
        for m in (["ransac"] if "ransac" in args.methods else []) + [m for m in args.methods if m != "ransac"]:
            warm.add(f"pairs {m}", lambda m=m: first_calls(sets, m))
    if "batch" in sec:
        for B in sorted(args.batches):
            warm.add(f"batch {B}", lambda B=B: compile_batch(sets, B))
    if "track" in sec or "track_cpu" in sec:
        warm.add("track", lambda: warm_tracking(sets), ["pairs ransac"])
    if "cpu" in sec and cpu is not None:
        for m in args.methods:
            warm.add(f"cpu {m}", lambda m=m: first_calls(sets, m, cpu))
    if "multi" in sec:
        # after the batch of the same size: track_batch then finds that program compiled
        warm.add("multi", lambda: run_multi(sets, args.seqs, args.seq_frames)[0], ["track", f"batch {args.seqs}"])
    if "track_cpu" in sec and cpu is not None:
        warm.add("track_cpu", lambda: warm_tracking(sets, cpu), ["cpu ransac", "track"])
    log(f"compiling {len(warm.tasks)} tasks on {args.compile_workers} thread(s)")
    warm.start()
    warm.wait(args.time_limit - args.reserve)
    d["compilation"] = {"workers": args.compile_workers, "wall_s": time.perf_counter() - _T0, "tasks": warm.summary()}
    rep.save()
    log("timings")

    poses: Dict[str, Dict[str, np.ndarray]] = {}
    if "pairs" in sec:
        log("per pair")
        d["pairs"] = []
        for m in args.methods:
            first = ready(f"pairs {m}")
            if first is None or not time_left(f"pairs {m}"):
                continue
            got = guarded(f"pairs {m}", time_pairs, sets, m, args.repeats, first)
            if got:
                d["pairs"].append(got[0])
                poses[m] = got[1]
            rep.save()

    if "cpu" in sec:
        log("against the CPU")
        d["cpu"] = []
        for m in poses:
            first = warm.get(f"pairs {m}")[0] if cpu is None else ready(f"cpu {m}")
            if first is None or not time_left(f"cpu {m}"):
                continue
            row = guarded(f"cpu {m}", cpu_agreement, sets, m, poses[m], first, cpu)
            if row:
                d["cpu"].append(row)
            rep.save()

    track_poses = {}
    if "track" in sec or "track_cpu" in sec:
        log("default tracking")
        d["track"] = []
        tw = ready("track")
        for s in sets if tw else []:
            if not time_left(f"track {s.name}"):
                break
            got = guarded(f"track {s.name}", time_tracking, s, tw[s.name])
            if got:
                d["track"].append(got[0])
                track_poses[s.name] = got[1]
                log(f"  {s.name}: median {got[0]['median_ms']:.1f} ms/frame, mean {got[0]['mean_ms']:.1f}")
            rep.save()

    if "batch" in sec:
        log("RANSAC batches")
        d["batch"] = []
        for B in sorted(args.batches):
            prep = ready(f"batch {B}")
            if prep is None:
                d["batch"].append({"batch": B, "error": warm.get(f"batch {B}")[1]})
                rep.save()
                continue
            if not time_left(f"batch {B}"):
                break
            row = guarded(f"batch {B}", time_batch, prep, args.repeats, poses.get("ransac", {}))
            if row is None:
                d["batch"].append({"batch": B, "error": d["errors"][-1].split(": ", 1)[1][:160]})
            else:
                d["batch"].append(row)
                log(f"  batch {B}: {row['compute']['median_ms']:.1f} ms = {row['compute']['pairs_per_s']:.1f} pairs/s "
                    f"({row['with_transfer']['pairs_per_s']:.1f} with transfer), peak {_mib(row['peak_bytes_after'])} MiB")
            rep.save()
        gc.collect()

    if "multi" in sec:
        log("several sequences at once")
        first = ready("multi")
        if first is not None and time_left("multi"):
            d["multi"] = guarded("multi", time_multi, sets, paths, args.seqs, args.seq_frames, first)
            rep.save()

    if "track_cpu" in sec and track_poses:
        log("default tracking on the CPU")
        d["track_cpu"] = []
        tw = ready("track") if cpu is None else ready("track_cpu")
        for s in sets if tw else []:
            if s.name not in track_poses or not time_left(f"track_cpu {s.name}"):
                continue
            got = guarded(f"track_cpu {s.name}", time_tracking, s, tw[s.name], cpu)
            if got:
                diff = pose_diff(track_poses[s.name], got[1])
                d["track_cpu"].append({"set": s.name, "device": str(cpu or jax.devices()[0]), "same_device": cpu is None,
                                       "median_ms": got[0]["median_ms"], "warmup_pass_s": got[0]["warmup_pass_s"],
                                       **diff._asdict()})
                log(f"  {s.name}: max diff {diff.max_translation_m:.2e} m, {diff.max_rotation_deg:.2e} deg")
            rep.save()

    d["compilation"]["tasks"] = warm.summary()
    rep.save()
    log(f"done: {rep.out / 'gpu.md'}")
    if any(t.is_alive() for t in warm.threads):
        # a compilation still running past the deadline: leave without waiting for it
        sys.stdout.flush()
        os._exit(0)
    return rep.out


if __name__ == "__main__":
    main()
