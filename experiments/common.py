"""Shared helpers of the experiment scripts (``table1.py``, ``speed.py``, ``sweep.py``, ...).

One place for: finding and opening sequences, generating (cached) dynamic
augmentations of real sequences, running a jaxvo method or a peer over a
sequence (trajectory + per-pair wall times), evaluating a trajectory into a
row dict (RPE per frame and over 1 s, ATE), machine / command provenance, and
writing markdown tables and JSON.

Conventions as in jaxvo: ``T_cur_ref`` maps reference-camera points into the
current camera; trajectories are ``T_world_cam`` (N, 4, 4) float64; times are
seconds inside, milliseconds in tables.
"""
from __future__ import annotations

import json
import math
import os
import platform
import resource
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable, Dict, Iterable, List, Optional, Sequence, Tuple

import numpy as np

_HERE = Path(__file__).resolve().parent
_REPO = _HERE.parent

import jax

from jaxvo import data as datasets
from jaxvo.runtime import machine
from jaxvo.evaluation import peers
from jaxvo.data import trajectory  # noqa: E402
from jaxvo.config import METHODS, Config  # noqa: E402
from jaxvo.estimator.motion import estimate_motion  # noqa: E402

RESULTS = _HERE / "results"
CACHE = RESULTS / "cache"

#: The paper's Table I translational RPE (m/s, fixed 1 s delta), by TUM sequence short name.
PAPER_RPE_T = {
    "freiburg1_xyz": 0.0269,
    "freiburg2_desk": 0.0189,
    "freiburg2_xyz": 0.0121,
    "freiburg2_desk_with_person": 0.0272,
    "freiburg3_sitting_halfsphere": 0.0265,
}

#: The paper's Table III (frames per second on its machine).
PAPER_FPS = {"classic": 25.0, "huber": 25.0, "ransac-static": 14.0, "ransac-dynamic": 2.0}


# ----------------------------------------------------------------------------- provenance

def command_line(script: str, argv: Optional[Sequence[str]]) -> str:
    """The command that reproduces a run from the repository root, e.g. ``python
    experiments/speed.py --pairs 20``; a script under ``experiments/diagnostics/`` runs as a
    module (``python -m experiments.diagnostics.variants``)."""
    args = list(sys.argv[1:] if argv is None else argv)
    try:
        rel = Path(script).resolve().relative_to(_REPO)
    except ValueError:
        rel = Path(script)
    run = ["-m", ".".join(rel.with_suffix("").parts)] if rel.parent == Path("experiments", "diagnostics") else [str(rel)]
    return " ".join(["python"] + run + [shlex.quote(a) for a in args])


def machine_info() -> Dict[str, object]:
    """CPU count, platform, Python / jax / OpenCV / Open3D versions, jax devices."""
    import cv2
    info = {
        "cpu_count": os.cpu_count(),
        "cpu_affinity": machine.usable_cores(),
        "cpu_model": machine.cpu_model(),
        "isa": machine.instruction_set(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "jax_backend": jax.default_backend(),
        "devices": [str(d) for d in jax.devices()],
        "opencv": cv2.__version__,
        "open3d": None,
        "load_avg_1min": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
    }
    if peers.open3d_available():
        info["open3d"] = peers._open3d_import()[0].__version__
    return info


def isa_summary(isa: str) -> str:
    """The processor's generation and widest vector unit from :func:`jaxvo.runtime.machine.instruction_set`,
    e.g. ``x86_64 family 25 model 17, AVX-512``: what tells apart machines of one model name, whose
    times (and floats) differ."""
    head, _, flags = isa.partition(":")
    flags = flags.split()
    widest = next((name for flag, name in (("avx512f", "AVX-512"), ("avx2", "AVX2"), ("avx", "AVX"), ("sve", "SVE"),
                                           ("asimd", "ASIMD")) if flag in flags), None)
    return f"{head}, {widest}" if widest else head


def provenance_md(title: str, script: str, argv, extra: str = "") -> List[str]:
    """Markdown header lines: title, the exact command, date and machine."""
    m = machine_info()
    lines = [f"# {title}", "",
             f"Produced by `{command_line(script, argv)}` (from the repository root) on "
             f"{time.strftime('%Y-%m-%d %H:%M %Z')}.", "",
             f"Machine: {m['cpu_count']} CPUs ({m['cpu_model']}, {isa_summary(m['isa'])}; {m['cpu_affinity']} usable), "
             f"load average at start {m['load_avg_1min']:.2f}, {m['platform']}; Python {m['python']}, "
             f"jax {m['jax']} (backend {m['jax_backend']}, devices {', '.join(m['devices'])}), "
             f"OpenCV {m['opencv']}, Open3D {m['open3d'] or 'not installed'}.", ""]
    if extra:
        lines += [extra, ""]
    return lines


def peak_rss_mb() -> float:
    """Peak resident set size of this process so far (MiB), from ``resource.getrusage``."""
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return r / 1024.0 if sys.platform != "darwin" else r / 2 ** 20


def current_rss_mb() -> float:
    """Current resident set size (MiB) from /proc/self/statm (NaN where unavailable)."""
    try:
        pages = int(Path("/proc/self/statm").read_text().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE") / 2 ** 20
    except (OSError, ValueError, IndexError):
        return float("nan")


# ----------------------------------------------------------------------------- sequences

def default_sequences() -> List[Path]:
    """Every sequence folder under ``data_root()/tum`` and ``data_root()/bonn``."""
    root = datasets.data_root()
    out = []
    for sub in ("tum", "bonn"):
        out += datasets.find_sequences(root / sub)
    return out


def missing_data_message() -> str:
    return (f"no sequence found under {datasets.data_root()} (tum/*, bonn/*); set JAXVO_DATA "
            f"or pass sequence folders on the command line")


def find_named(name: str) -> Optional[Path]:
    """A bundled sequence folder by (folder) name, or None."""
    try:
        return datasets.find_sequence(name)
    except ValueError:
        return None


def open_sequence(path, max_frames: Optional[int] = None, start: int = 0, depth_scale=None,
                  lens=None) -> datasets.TumSequence:
    """The reader of every experiment: ``depth_scale`` and ``lens`` None read the folder as ``jaxvo run``
    does (a TUM fr1/fr2 or Bonn folder with its published lens and depth correction)."""
    return datasets.TumSequence(path, max_frames=max_frames, start=start, depth_scale=depth_scale, lens=lens)


def load_frames(seq: datasets.TumSequence, indices: Optional[Iterable[int]] = None) -> list:
    """Decode frames into memory (so timings measure the estimator, not PNG decoding)."""
    idx = range(len(seq)) if indices is None else indices
    return [seq.frame(i) for i in idx]


def perturbed(frames: list, draw: int, amplitude: float = 0.25) -> list:
    """``frames`` with uniform noise in [-amplitude, amplitude] grey levels added to every pixel's
    luminance, the noise of ``draw`` (its own NumPy generator; draw 0: the frames themselves).
    Under half a grey level, below the 8-bit colour's own rounding: it samples how much a result
    owes to the exact input, which the PRNG seeds do not (docs/decisions/lens.md)."""
    if draw == 0:
        return frames
    rng = np.random.default_rng([draw, 0x6A78])
    return [f._replace(intensity=(np.asarray(f.intensity, np.float32)
                                  + rng.uniform(-amplitude, amplitude, np.shape(f.intensity))).astype(np.float32))
            for f in frames]


def resolve_sequence(arg, name: str, sub: str) -> Path:
    """A sequence folder: ``arg`` if given, else ``<data root>/<sub>/<name>``; SystemExit naming
    what is missing."""
    if arg:
        return Path(arg)
    p = datasets.data_root() / sub / name
    if not p.is_dir():
        raise SystemExit(f"missing sequence {p} (pass --static/--dynamic or set JAXVO_DATA)")
    return p


def synthetic_sequence(folder, frames: int, size: str = "160x120") -> Path:
    """A small synthetic sequence (``jaxvo synth seq1``) written to ``folder`` for the scripts'
    ``--quick`` smoke runs; returns ``folder``."""
    subprocess.run([sys.executable, "-m", "jaxvo", "synth", "seq1", str(folder), "--frames", str(frames), "--size",
                    size, "--no-progress"], check=True, capture_output=True, cwd=_REPO)
    return Path(folder)


def median_ms_per_call(functions: Sequence[Callable], inputs: Sequence[tuple], repeats: int) -> List[float]:
    """Median wall time (ms) of each of ``functions`` called on each argument tuple of ``inputs``
    and blocked on: a warm-up pass first (compilation), then ``repeats`` passes that alternate
    between the functions, so that a passing load weighs on all of them."""
    times: List[List[float]] = [[] for _ in functions]
    for rep in range(repeats + 1):
        for fn, ts in zip(functions, times):
            for a in inputs:
                t = time.perf_counter()
                jax.block_until_ready(fn(*a))
                if rep:
                    ts.append(time.perf_counter() - t)
    return [1000 * float(np.median(ts)) for ts in times]


def estimator_shapes(camera, config: Config) -> tuple:
    """Abstract arguments of ``jaxvo.estimator.estimate_arrays_jit`` for ``camera``'s image size (float32
    images, key 0, a (4, 4) initial pose and full-resolution weights), to trace and compile it
    without frames: ``estimate_arrays_jit.trace(*estimator_shapes(camera, config)).lower()``."""
    import jax.numpy as jnp

    img = jax.ShapeDtypeStruct((camera.height, camera.width), jnp.float32)
    return (img, img, img, img, camera, config, jax.random.key(0), jax.ShapeDtypeStruct((4, 4), jnp.float32), img)


def kernel_count(compiled) -> int:
    """The fused kernels of a compiled JAX program (``jit(f).lower(...).compile()``): XLA
    generates code for each, which is most of its compile time."""
    return len(re.findall(r"\bkind=k\w+", compiled.as_text()))


def augmented_sequence(real_dir, persons: int = 1, coverage: float = 0.3, seed: int = 0,
                       max_frames: Optional[int] = None, cache_dir=None, depth_time: bool = False) -> Path:
    """Dynamic augmentation of a real TUM sequence (``jaxvo.synthetic.augment``), cached.

    The folder is ``<cache>/<real name>_aug_p<persons>_c<coverage>_s<seed>_n<frames>`` (``_dt``
    after it with ``depth_time``: the depth images' persons at their own timestamps);
    keeping the real name as a prefix keeps the camera preset (freiburg1/2/3).
    It is regenerated only when missing (or incomplete).
    """
    from jaxvo.synthetic import augment
    real_dir = Path(real_dir)
    cache = Path(cache_dir) if cache_dir is not None else CACHE
    cache.mkdir(parents=True, exist_ok=True)
    gi = cache / ".gitignore"
    if cache == CACHE and not gi.exists():
        gi.write_text("# generated data, not committed\n*\n")
    n = "all" if max_frames is None else str(int(max_frames))
    out = cache / f"{real_dir.name}_aug_p{persons}_c{int(round(coverage * 100))}_s{seed}_n{n}{'_dt' if depth_time else ''}"
    if not (out / "info.json").is_file():
        augment(real_dir, out, persons=persons, coverage=coverage, seed=seed, max_frames=max_frames,
                depth_time=depth_time)
    return out


def short_name(path) -> str:
    """``rgbd_dataset_freiburg2_desk`` -> ``freiburg2_desk``; other names unchanged."""
    n = Path(path).name
    return n[len("rgbd_dataset_"):] if n.startswith("rgbd_dataset_") else n


def paper_rpe(path) -> Optional[float]:
    """The paper's Table I translational RPE (m/s) for this sequence, or None."""
    return PAPER_RPE_T.get(short_name(path))


# ----------------------------------------------------------------------------- running

def int_list(text: str) -> List[int]:
    """``"0,1,2"`` -> ``[0, 1, 2]``; ValueError on a non-integer or an empty list."""
    try:
        values = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ValueError(f"expected a comma list of integers, got {text!r}") from None
    if not values:
        raise ValueError("empty list")
    return values


def json_variants(text: str, expected: str, option: str = "--variants") -> dict:
    """``option`` (default ``--variants``): a non-empty JSON object of name -> entry, else
    SystemExit naming the option and saying that ``expected`` (what each entry is) was expected."""
    try:
        variants = json.loads(text)
    except json.JSONDecodeError as e:
        raise SystemExit(f"{option}: not JSON: {e}")
    if not isinstance(variants, dict) or not variants:
        raise SystemExit(f"{option}: expected a JSON object of name -> {expected}")
    return variants


def config_changes(text: Optional[str]) -> dict:
    """A ``--config`` option: a JSON object of ``jaxvo.Config`` fields to change (``{}`` for
    None), checked against Config's rules; ValueError naming the problem otherwise."""
    changes = json.loads(text) if text else {}
    if not isinstance(changes, dict):
        raise ValueError("expected a JSON object")
    Config.from_json({**changes, "method": "ransac"})   # validates every field
    return changes


def parse_methods(text: str) -> List[str]:
    """Comma list of jaxvo methods and peer names; "peers" = every available peer, "all" = both."""
    out: List[str] = []
    for tok in [t.strip() for t in text.split(",") if t.strip()]:
        if tok == "all":
            out += list(METHODS) + peers.available_peers()
        elif tok == "peers":
            out += peers.available_peers()
        elif tok in METHODS or tok in peers.PEER_NAMES:
            out.append(tok)
        else:
            raise SystemExit(f"unknown method {tok!r}: choose from {', '.join(METHODS + peers.PEER_NAMES)}, "
                             f"'peers' or 'all'")
    seen = set()
    return [m for m in out if not (m in seen or seen.add(m))]


def is_peer(name: str) -> bool:
    return name in peers.PEER_NAMES


def peer_available(name: str) -> bool:
    return name in peers.available_peers()


def time_jaxvo_pair(ref, cur, camera, config: Config, key):
    """One estimate, blocked until ready; returns (MotionEstimate, seconds)."""
    t0 = time.perf_counter()
    est = estimate_motion(ref, cur, camera, config, key)
    jax.block_until_ready(est)
    return est, time.perf_counter() - t0


def run_method(name: str, frames: Sequence, camera, config: Optional[Config] = None, key=None,
               pairs: Optional[Sequence[tuple]] = None, warmup: bool = True) -> Dict[str, object]:
    """Run a jaxvo method or a peer on frame pairs.

    Args:
      name: "classic" | "huber" | "ransac" or a peer name ("opencv-rgb", ...).
      frames: list of Frames. pairs: (i, j) index pairs, default consecutive (k, k+1).
      config: base Config for jaxvo methods (its ``method`` is replaced by ``name``).
      key: PRNG key; pair k uses ``fold_in(key, k)`` (as ``jaxvo.track``).
      warmup: run the first pair once before timing (jaxvo: compile; peers: allocation).

    Returns dict: ``relative`` (P, 4, 4) float64 T_cur_ref, ``seconds`` (P,) wall time per
    pair (after warm-up), ``compile_s`` (first call, jaxvo only, else the peer's first call),
    ``inlier_ratio`` (P,) (NaN for peers), ``hypotheses`` (P,) RANSAC hypotheses summed over
    levels (0 otherwise), ``valid`` (P,) bool (the peer's success flag for peers).
    """
    pairs = [(k, k + 1) for k in range(len(frames) - 1)] if pairs is None else list(pairs)
    P = len(pairs)
    rel = np.zeros((P, 4, 4))
    secs = np.zeros(P)
    ratio = np.full(P, np.nan)
    hyps = np.zeros(P, np.int64)
    valid = np.zeros(P, bool)
    compile_s = float("nan")
    if is_peer(name):
        peer = peers.make_peer(name, camera)
        if warmup and P:
            compile_s = peer(frames[pairs[0][0]], frames[pairs[0][1]]).seconds
        for k, (i, j) in enumerate(pairs):
            r = peer(frames[i], frames[j])
            rel[k], secs[k], valid[k] = r.T_cur_ref, r.seconds, r.success
    else:
        cfg = (config or Config()).replace(method=name)
        key = jax.random.key(0) if key is None else key
        if warmup and P:
            _, compile_s = time_jaxvo_pair(frames[pairs[0][0]], frames[pairs[0][1]], camera, cfg,
                                           jax.random.fold_in(key, 0))
        for k, (i, j) in enumerate(pairs):
            est, secs[k] = time_jaxvo_pair(frames[i], frames[j], camera, cfg, jax.random.fold_in(key, k))
            rel[k] = np.asarray(est.T_cur_ref, np.float64)
            ratio[k] = float(est.inlier_ratio)
            hyps[k] = int(np.sum(np.asarray(est.hypotheses)))
            valid[k] = bool(est.valid)
    return {"name": name, "relative": rel, "seconds": secs, "compile_s": compile_s,
            "inlier_ratio": ratio, "hypotheses": hyps, "valid": valid}


def timing_stats(seconds) -> Dict[str, float]:
    """median / p90 / mean ms and FPS (1000 / median ms) of per-pair wall times."""
    s = np.asarray(seconds, np.float64) * 1000.0
    if s.size == 0:
        return {"median_ms": float("nan"), "p90_ms": float("nan"), "mean_ms": float("nan"),
                "fps": float("nan"), "n": 0}
    med = float(np.median(s))
    return {"median_ms": med, "p90_ms": float(np.percentile(s, 90)), "mean_ms": float(np.mean(s)),
            "fps": 1000.0 / med if med > 0 else float("inf"), "n": int(s.size)}


# ----------------------------------------------------------------------------- evaluation

def groundtruth_at(seq: datasets.TumSequence):
    """(stamps (M,), T_world_cam (M, 4, 4), frame mask (N,)) at the frames that have ground truth."""
    g = seq.groundtruth_at_frames()
    if g is None:
        return None
    mask, T = g
    return seq.timestamps[mask], T[mask], mask


def pose_error(T_est, T_gt) -> Tuple[float, float]:
    """(metres, degrees): the translation and rotation angle of ``inv(T_gt) @ T_est``, the error
    of an estimated relative pose against the ground truth's (both (4, 4), same convention)."""
    from jaxvo import geometry
    E = geometry.inverse(np.asarray(T_gt, np.float64)) @ np.asarray(T_est, np.float64)
    return float(np.linalg.norm(E[:3, 3])), float(np.degrees(geometry.rotation_angle(E[:3, :3])))


def relative_errors(seq: datasets.TumSequence, relative) -> Dict[str, np.ndarray]:
    """Per consecutive pair: translational (m) and rotational (deg) error of ``T_cur_ref``
    against ground truth ``inv(T_world_cur) @ T_world_ref`` (NaN where a frame lacks ground truth)."""
    from jaxvo import geometry
    g = seq.groundtruth_at_frames()
    P = len(relative)
    t_err, r_err = np.full(P, np.nan), np.full(P, np.nan)
    if g is None:
        return {"trans": t_err, "rot": r_err}
    mask, T = g
    for k in range(P):
        if mask[k] and mask[k + 1]:
            t_err[k], r_err[k] = pose_error(relative[k], geometry.inverse(T[k + 1]) @ T[k])
    return {"trans": t_err, "rot": r_err}


#: The poses a tracking script evaluates (``--poses``): ``refined``, refined in hindsight
#: (``Track.refined``, :meth:`jaxvo.Odometry.refined_poses`; the default ``TrackConfig.poses``, the
#: trajectory ``jaxvo run`` writes), or ``tracked``, as returned frame by frame (``Track.tracked``).
POSES = ("tracked", "refined")


def add_poses_arg(ap, both: bool = False) -> None:
    """The ``--poses`` option of the scripts that evaluate the default tracking; with ``both``,
    also "both": each run evaluated both ways (:func:`pose_kinds`, :func:`pose_label`)."""
    ap.add_argument("--poses", choices=POSES + (("both",) if both else ()), default="refined",
                    help="evaluate the poses refined in hindsight (default: Track.refined, each frame on its "
                         "reference's latest anchor, as jaxvo run writes them) or as tracked (Track.tracked)"
                         + (", or both: a second row per run's name, '<name>, tracked', from the same runs"
                            if both else ""))


def pose_kinds(choice: str) -> tuple:
    """The kinds of :data:`POSES` that ``--poses`` ``choice`` evaluates (refined first)."""
    return ("refined", "tracked") if choice == "both" else (choice,)


def pose_label(name: str, kind: str, choice: str) -> str:
    """The row name of run ``name``'s ``kind`` of poses: ``name``, or ``name, tracked`` for the
    tracked rows when ``--poses both``."""
    return f"{name}, tracked" if choice == "both" and kind == "tracked" else name


def track_poses(tr, kind: str = "refined") -> np.ndarray:
    """A :class:`jaxvo.tracking.odometry.Track`'s (N, 4, 4) poses of ``kind`` (:data:`POSES`):
    ``Track.refined`` or ``Track.tracked``, whatever the policy's ``TrackConfig.poses``."""
    return tr.refined if kind == "refined" else tr.tracked


def track_relative(tr, kind: str = "refined") -> np.ndarray:
    """A :class:`jaxvo.tracking.odometry.Track`'s relative motions of :func:`track_poses`."""
    from jaxvo import geometry

    return geometry.consecutive_motions(track_poses(tr, kind))


def evaluate(seq: datasets.TumSequence, relative) -> Dict[str, object]:
    """Trajectory metrics of chained ``relative`` motions on ``seq``'s frames, against the ground
    truth interpolated at the frame stamps (:func:`jaxvo.evaluation.scoring.evaluate`,
    ``protocol="interpolated"``).

    Keys: ``rpe1s_t`` (m/s, RMSE, fixed 1 s delta; None when the ground-truth-covered span
    is under 1 s), ``rpe1s_r`` (deg/s), ``rpef_t`` (m/frame, RMSE, delta = 1 frame),
    ``rpef_r`` (deg/frame), ``rpef_t_per_s`` (rpef_t / mean frame interval, m/s: a per-frame
    drift rate, not the paper's 1 s RPE), ``ate`` (m, RMSE), ``pairs_1s`` / ``pairs_f``.
    """
    from jaxvo.evaluation.scoring import evaluate as score

    row: Dict[str, object] = {"rpe1s_t": None, "rpe1s_r": None, "rpef_t": None, "rpef_r": None,
                              "rpef_t_per_s": None, "ate": None, "pairs_1s": 0, "pairs_f": 0}
    if seq.groundtruth is None:
        row["note"] = "no ground truth"
        return row
    est = (seq.timestamps, trajectory.chain(relative))
    kw = dict(protocol="interpolated", max_dt=seq.max_dt, slack=None)
    try:
        f = score(seq, est, delta=1, delta_unit="f", **kw)
    except datasets.DatasetError:
        row["note"] = "ground truth covers < 2 frames"
        return row
    row.update(rpef_t=f.rpe.trans_stats.rmse, rpef_r=f.rpe.rot_stats.rmse, pairs_f=f.rpe.n)
    row["rpef_t_per_s"] = f.rpe.trans_stats.rmse / float(np.mean(f.rpe.dt))
    gs = f.gt[0]
    if gs[-1] - gs[0] >= 1.0 - 1e-3:
        try:
            s = score(seq, est, delta=1.0, delta_unit="s", **kw).rpe
            row.update(rpe1s_t=s.trans_drift.rmse, rpe1s_r=s.rot_drift.rmse, pairs_1s=s.n)
        except ValueError:
            pass
    row["ate"] = f.ate.stats.rmse
    return row


# ----------------------------------------------------------------------------- output

def fmt(x, spec: str = ".4f", none: str = "n/a") -> str:
    if x is None:
        return none
    if isinstance(x, (float, np.floating)):
        if not math.isfinite(float(x)):
            return none
        return format(float(x), spec)
    return str(x)


def md_table(rows: Sequence[dict], columns: Sequence[tuple]) -> List[str]:
    """Markdown table lines. ``columns``: (header, key or callable(row), format spec)."""
    head = "| " + " | ".join(c[0] for c in columns) + " |"
    sep = "| " + " | ".join("---" for _ in columns) + " |"
    lines = [head, sep]
    for r in rows:
        cells = []
        for c in columns:
            k = c[1]
            spec = c[2] if len(c) > 2 else ".4f"
            v = k(r) if callable(k) else r.get(k)
            cells.append(fmt(v, spec))
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(float(x)) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.bool_,)):
        return bool(x)
    if isinstance(x, Path):
        return str(x)
    return x


def write_outputs(md_path, lines: Sequence[str], data: Optional[dict] = None) -> Path:
    """Write the markdown (and ``<same stem>.json`` next to it when ``data`` is given)."""
    md_path = Path(md_path)
    md_path.parent.mkdir(parents=True, exist_ok=True)
    md_path.write_text("\n".join(lines).rstrip() + "\n")
    if data is not None:
        md_path.with_suffix(".json").write_text(json.dumps(_jsonable(data), indent=1) + "\n")
    return md_path


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)
