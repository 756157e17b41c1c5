"""Speed of jaxvo per 640x480 frame, against OpenCV / Open3D in the same process.

Sections of the report (``speed.md`` + ``speed.json``):

1. Per method (classic, huber, ransac) on static pairs (TUM freiburg2_desk) and
   dynamic pairs (Bonn crowd), by default every consecutive pair of each sequence: mean /
   median / p90 ms, FPS, compile time (the first call: trace + XLA compile + one run, measured
   separately), RANSAC hypotheses actually evaluated (with early exit; summed over the pyramid
   levels), next to the paper's Table III (25 FPS classic / Huber, 14 FPS RANSAC static, 2 FPS
   dynamic).
2. Per pyramid level: ``Config(finest_level=l)`` stops after level l, so the time
   of level l is t(finest_level=l) - t(finest_level=l+1) (level L-1, the coarsest,
   is t(finest_level=L-1); each finest_level compiles once more).
3. Peers (OpenCV rgb / depth / rgbd; Open3D color / hybrid when installed) on
   the identical pairs, and ratio columns jaxvo time / peer time (means).
4. The default odometry (``Odometry`` with ``TrackConfig()``, and its single reference) over
   whole sequences, against OpenCV rgb over the same pairs in alternating passes (mean and
   median per frame, their ratios), and a profiled pass that says where its time goes: each
   estimate by purpose (against the reference, retries, recoveries, the window's), each
   segmentation call, the window's refinement, and the host's own work.
5. Stages of one estimate per level (points, hypotheses, scoring, refinement, pyramid).
6. Batch throughput: B frame pairs stacked and processed as one ``jax.jit(jax.vmap(
   estimate_motion))`` call, pairs per second vs the one-pair-at-a-time loop, on CPU
   and, when jax sees a GPU, on the GPU.
7. Memory: peak RSS (``resource.getrusage``) of the process after each section, and
   ``jaxvo.track`` over 50 vs 500 frames of a synthetic sequence fed lazily (see
   ``--track-frames``): the RSS must not grow with the number of frames.

Example::

    python experiments/speed.py                    # full run (minutes; quiet machine please)
    python experiments/speed.py --quick --out /tmp/speed.md   # tiny, for CI
"""
from __future__ import annotations

import argparse
import functools
import time
from pathlib import Path

import common
import numpy as np  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from jaxvo.frame import Frame  # noqa: E402
from jaxvo.config import METHODS, Config
from jaxvo.estimator import estimate_motion, trace_count
from jaxvo.tracking.odometry import track  # noqa: E402
from jaxvo.estimator.solvers import jit  # noqa: E402

STATIC = "rgbd_dataset_freiburg2_desk"
DYNAMIC = "rgbd_bonn_crowd"


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--static", default=None, help=f"static sequence folder (default data_root()/tum/{STATIC})")
    ap.add_argument("--dynamic", default=None, help=f"dynamic sequence folder (default data_root()/bonn/{DYNAMIC})")
    ap.add_argument("--pairs", type=int, default=0,
                    help="frame pairs per sequence, spread over it (default 0: every consecutive pair)")
    ap.add_argument("--repeats", type=int, default=3, help="timed passes over the pairs (default 3)")
    ap.add_argument("--methods", default="classic,huber,ransac", help="jaxvo methods (default all three)")
    ap.add_argument("--peers", default="peers", help="peer names, comma list; 'peers' = all available, "
                                                      "'none' = skip")
    ap.add_argument("--level-methods", default=None,
                    help="methods for the per-level breakdown (default: all --methods; 'none' = skip)")
    ap.add_argument("--batch", default="1,4,8", help="batch sizes for the vmap throughput (default 1,4,8; "
                                                     "'none' = skip)")
    ap.add_argument("--batch-method", default="ransac", help="method for the batch throughput (default ransac)")
    ap.add_argument("--track-frames", default="50,500",
                    help="frame counts for the track memory test (default 50,500; 'none' = skip)")
    ap.add_argument("--track-method", default="ransac", help="method for the track memory test")
    ap.add_argument("--track-cycle", type=int, default=4,
                    help="distinct synthetic frames rendered and replayed ping-pong (default 4)")
    ap.add_argument("--stages", default="ransac,classic",
                    help="methods for the per-stage breakdown (default ransac,classic; 'none' = skip)")
    ap.add_argument("--stage-pairs", type=int, default=5, help="pairs per set for the stage breakdown (default 5)")
    ap.add_argument("--default-frames", type=int, default=0,
                    help="the default odometry (Odometry + TrackConfig()) over the first N frames of each "
                         "sequence (default 0: the whole sequence; -1: skip)")
    ap.add_argument("--quick", action="store_true",
                    help="tiny CI run: 2 pairs, 1 repeat, first method only, coarsest level only, "
                         "batch 2, track 3 vs 6 frames, OpenCV rgb peer only")
    ap.add_argument("--out", default=str(common.RESULTS / "speed" / "speed.md"), help="markdown output (json beside it)")
    args = ap.parse_args(argv)
    args.methods = [m for m in args.methods.split(",") if m]
    for m in args.methods:
        if m not in METHODS:
            raise SystemExit(f"unknown method {m!r}; choose from {METHODS}")
    if args.quick:
        args.pairs, args.repeats = (2 if args.pairs <= 0 else min(args.pairs, 2)), 1
        args.methods = args.methods[:1]
        if args.peers == "peers":
            args.peers = "opencv-rgb"
        if args.batch == "1,4,8":
            args.batch = "2"
        if args.track_frames == "50,500":
            args.track_frames = "3,6"
        args.track_cycle = min(args.track_cycle, 2)
        if args.batch_method == "ransac":
            args.batch_method = args.methods[0]
        if args.track_method == "ransac":
            args.track_method = args.methods[0]
        args.stage_pairs = 1
        if args.stages == "ransac,classic":
            args.stages = args.methods[0]
        args.default_frames = 4 if args.default_frames == 0 else min(args.default_frames, 4)
    args.level_methods = (args.methods if args.level_methods is None else
                          [] if args.level_methods == "none" else args.level_methods.split(","))
    args.stages = [] if args.stages == "none" else [m for m in args.stages.split(",") if m]
    args.batch = [] if args.batch == "none" else [int(b) for b in args.batch.split(",")]
    args.track_frames = [] if args.track_frames == "none" else [int(n) for n in args.track_frames.split(",")]
    args.peer_list = [] if args.peers == "none" else common.parse_methods(args.peers)
    return args


# ----------------------------------------------------------------------------- data

def load_pairs(path, n_pairs: int, name: str):
    """n_pairs consecutive pairs (k, k+1) spread evenly over the sequence; frames decoded into memory."""
    seq = common.open_sequence(path)
    N = len(seq)
    n_pairs = N - 1 if n_pairs <= 0 else min(n_pairs, N - 1)
    starts = np.unique(np.linspace(0, N - 2, num=n_pairs).round().astype(int))
    idx = sorted(set(starts.tolist()) | set((starts + 1).tolist()))
    frames_by_idx = {i: seq.frame(i) for i in idx}
    order = {i: k for k, i in enumerate(idx)}
    frames = [frames_by_idx[i] for i in idx]
    pairs = [(order[s], order[s + 1]) for s in starts]
    common.log(f"[speed] {name}: {seq.name}, {len(pairs)} pairs from {N} frames")
    return seq, frames, pairs


# ----------------------------------------------------------------------------- sections

def time_methods_and_peers(sets, methods, peer_names, repeats, key):
    """Per jaxvo method and per peer, per pair set: compile time and per-pair timings over
    ``repeats`` passes. The passes are interleaved (pass 1 of every method and peer, then pass
    2, ...), so that a load that other processes put on the machine for a minute weighs on
    jaxvo and the peers alike: timed one after the other, the ratio to OpenCV swung from 0.93
    to 1.27 between two runs 5 minutes apart. Returns (method rows, peer rows)."""
    peers = []
    for name in peer_names:
        if common.peer_available(name):
            peers.append(name)
        else:
            common.log(f"  {name}: not available, skipped")
    secs = {(n, s): [] for n in list(methods) + peers for s in sets}
    hyps = {key_: [] for key_ in secs}
    fails = {key_: 0 for key_ in secs}
    compile_s = {}
    for rep in range(repeats):
        for n in list(methods) + peers:
            for set_name, (seq, frames, pairs) in sets.items():
                if n in methods:
                    r = common.run_method(n, frames, seq.camera, Config(), key, pairs, warmup=(rep == 0))
                    hyps[n, set_name].append(r["hypotheses"])
                else:
                    r = common.run_method(n, frames, seq.camera, pairs=pairs, warmup=(rep == 0))
                    fails[n, set_name] += int(np.sum(~r["valid"]))
                if rep == 0:
                    compile_s[n, set_name] = r.get("compile_s")
                secs[n, set_name].append(r["seconds"])
    mrows, prows = [], []
    for m in methods:
        for set_name, (seq, frames, pairs) in sets.items():
            st = common.timing_stats(np.concatenate(secs[m, set_name]))
            hy = np.concatenate(hyps[m, set_name])
            comp = compile_s[m, set_name] if set_name == next(iter(sets)) else None
            paper = common.PAPER_FPS.get(m if m != "ransac" else f"ransac-{set_name}")
            mrows.append({"method": m, "set": set_name, "sequence": seq.name, "pairs": len(pairs),
                          "compile_s": comp,
                          "hypotheses_mean": float(hy.mean()) if m == "ransac" else None,
                          "hypotheses_max": int(hy.max()) if m == "ransac" else None,
                          "paper_fps": paper, **st, "peak_rss_mb": common.peak_rss_mb()})
            common.log(f"  {m:8s} {set_name:8s} median {st['median_ms']:.1f} ms  p90 {st['p90_ms']:.1f} ms  "
                       f"{st['fps']:.1f} FPS" + (f"  hyps {hy.mean():.1f}" if m == "ransac" else "")
                       + (f"  compile {comp:.1f} s" if comp else ""))
    for name in peers:
        for set_name in sets:
            st = common.timing_stats(np.concatenate(secs[name, set_name]))
            prows.append({"method": name, "set": set_name, "failures": fails[name, set_name], **st})
            common.log(f"  {name:14s} {set_name:8s} median {st['median_ms']:.1f} ms  p90 {st['p90_ms']:.1f} ms")
    return mrows, prows


def time_levels(seq, frames, pairs, methods, repeats, key, quick: bool):
    """t(finest_level=l) for each level l, and the per-level differences."""
    from jaxvo.estimator.pyramid import num_levels_for
    cam = seq.camera
    L = num_levels_for(cam.width, cam.height)
    levels = [L - 1] if quick else list(range(L - 1, -1, -1))
    rows = []
    for m in methods:
        cum = {}
        for lv in levels:
            cfg = Config(method=m, finest_level=lv)
            t0 = time.perf_counter()
            common.time_jaxvo_pair(frames[pairs[0][0]], frames[pairs[0][1]], cam, cfg, key)
            comp = time.perf_counter() - t0
            s = []
            for _ in range(repeats):
                for k, (i, j) in enumerate(pairs):
                    s.append(common.time_jaxvo_pair(frames[i], frames[j], cam, cfg, jax.random.fold_in(key, k))[1])
            cum[lv] = (float(np.median(s)) * 1000, comp)
        for lv in levels:
            coarser = cum.get(lv + 1, (0.0, None))[0]
            w, h = cam.width >> lv, cam.height >> lv
            rows.append({"method": m, "level": lv, "size": f"{w}x{h}", "cumulative_ms": cum[lv][0],
                         "level_ms": cum[lv][0] - coarser, "compile_s": cum[lv][1]})
            common.log(f"  {m:8s} level {lv} ({w}x{h}): through this level {cum[lv][0]:.1f} ms, "
                       f"this level {cum[lv][0] - coarser:.1f} ms")
    return rows


# ----------------------------------------------------------------------------- stages

def _timed(fn, *args, repeats: int = 3) -> float:
    """Median seconds of ``fn(*args)`` blocked until ready, after one call that compiles it."""
    jax.block_until_ready(fn(*args))
    ts = []
    for _ in range(max(repeats, 1)):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def time_stages(sets, config: Config, n_pairs: int, repeats: int, key):
    """Cost of each stage of one ``estimate_motion(config)`` call, per pyramid level.

    The level loop of :func:`jaxvo.estimator.motion.estimate_motion` is replayed with each stage as
    its own jitted call on the same inputs (the pose carried from level to level as in the
    estimator, so the iteration counts are the real ones): ``points`` (the reference points
    and the scoring subgrid), ``prior`` (the plain LM fit that makes the first candidate),
    ``hypotheses`` (one vmapped trip of ``batch_size`` x ``batches_per_trip`` patch fits x the
    trips the real estimate ran at that level), ``scoring`` (likewise), ``ransac other`` (the whole
    ``ransac_level`` call minus the two: sampling and loop), ``refinement`` (the consensus
    refinement), ``solve`` (classic / huber's level solve). ``pyramid``: both frames' pyramids;
    ``host transfer``: the two frames to the device and the result back; ``rest``: the
    end-to-end time minus the sum (the final masks and statistics, dispatch and fusion
    effects of running the stages as separate programs).
    """
    from jaxvo.estimator.inputs import num_levels
    from jaxvo.estimator.levels import level_block, ransac_options
    from jaxvo.estimator.pyramid import build_pyramid
    from jaxvo.estimator.ransac import fit_hypothesis, inliers, ransac_level, sample_patches, score_pose, score_weights
    from jaxvo.estimator.residuals import reference_points, residuals, select_points
    from jaxvo.estimator.solvers import irls, solve_pose, solve_pose_small

    cfg = config
    dw = cfg.depth_weight if cfg.terms == "rgbd" else None
    hdw = ransac_options(cfg)["depth_weight"]   # the hypotheses' depth term, as the estimator fits them

    def stage_functions(stride, blk):
        """The jitted stages of one level (the camera ``lc`` an argument), built once per level so each
        compiles once for both sets."""
        def points(rl, lc):
            sp = (select_points(rl, lc, stride) if cfg.score_selection == "gradient"
                  else reference_points(rl, lc, stride))
            return select_points(rl, lc, blk), sp

        def solve(T, pts, cl, lc):
            if cfg.method == "classic":
                return solve_pose(T, pts, cl, lc, pts.weight, cfg.max_iterations, depth_weight=dw).T
            return irls(T, pts, cl, lc, pts.weight, cfg.huber_k, cfg.irls_rounds, cfg.irls_iterations,
                        depth_weight=dw).T

        def prior(T, pts, cl, lc):
            return solve_pose_small(T, pts, cl, lc, pts.weight, cfg.max_iterations, depth_weight=dw).T

        def ransac(T, rl, cl, sp, kk, lc):
            return ransac_level(T, rl, cl, lc, sp, kk, **ransac_options(cfg)).T

        def sample(rl, kk, lc):  # lc unused: every stage takes the camera
            return sample_patches(kk, rl, cfg.n_points, cfg.batch_size * cfg.batches_per_trip, cfg.patch_radius)

        def fit(T, rl, cl, pu, pv, lc):
            return jax.vmap(lambda a, b: fit_hypothesis(T, rl, cl, lc, a, b, cfg.hypothesis_iterations, hdw))(pu, pv)

        def score(Ts, sp, cl, lc):
            sw = score_weights(sp, cfg.score_depth_power)
            return jax.vmap(lambda X: score_pose(X, sp, cl, lc, cfg.thresh_lum, cfg.thresh_depth, cfg.scoring,
                                                 sw))(Ts)

        def refine(T, pts, cl, lc):
            for _ in range(cfg.refine_rounds):
                mask = inliers(residuals(T, pts, cl, lc), cfg.thresh_lum, cfg.thresh_depth)
                consensus = jnp.where(mask, pts.weight, 0.0)
                if cfg.consensus_weights == "huber":
                    T = irls(T, pts, cl, lc, consensus, cfg.huber_k, cfg.irls_rounds, cfg.irls_iterations,
                             depth_weight=dw).T
                else:
                    T = solve_pose(T, pts, cl, lc, consensus, cfg.max_iterations, depth_weight=dw).T
            return T
        return {name: jit(f) for name, f in (("points", points), ("solve", solve), ("prior", prior),
                                                 ("ransac", ransac), ("sample", sample), ("fit", fit),
                                                 ("score", score), ("refine", refine))}

    rows = []
    fns: dict = {}
    for set_name, (seq, frames, pairs) in sets.items():
        cam = seq.camera
        L = num_levels(cfg, cam.width, cam.height)
        if ("pyramid", L) not in fns:
            fns["pyramid", L] = jit(lambda i, d: build_pyramid(i, d, L, cfg.max_depth, jnp.ones_like(i)))
        pyr = fns["pyramid", L]
        acc: dict = {}

        def add(level, stage, seconds):
            acc.setdefault((level, stage), []).append(seconds)

        for k, (i, j) in enumerate(pairs[:n_pairs]):
            ref, cur = frames[i], frames[j]
            pk = jax.random.fold_in(key, k)
            arrays = [ref.intensity, ref.depth, cur.intensity, cur.depth]
            add(-1, "host transfer in", _timed(lambda: [jax.device_put(a) for a in arrays], repeats=repeats))
            ri, rd, ci, cd = [jax.device_put(a) for a in arrays]
            add(-1, "pyramid", _timed(pyr, ri, rd, repeats=repeats) + _timed(pyr, ci, cd, repeats=repeats))
            est = estimate_motion(ref, cur, cam, cfg, pk)
            total = _timed(lambda: estimate_motion(ref, cur, cam, cfg, pk), repeats=repeats)
            get = _timed(lambda: jax.device_get((est.T_cur_ref, est.inlier_ratio, est.valid)), repeats=repeats)
            add(-1, "host transfer out", get)
            add(-1, "end to end", total + get)
            rp, cp = pyr(ri, rd), pyr(ci, cd)
            T = jnp.eye(4, dtype=jnp.float32)
            hyps = np.asarray(est.hypotheses)
            for lv in range(L - 1, cfg.finest_level - 1, -1):
                lc = cam.at_level(lv)
                rl, cl = rp[lv], cp[lv]
                hh, ww = rl.depth.shape
                if (lv, hh, ww) not in fns:
                    stride = max(1, int(np.ceil(np.sqrt(hh * ww / cfg.max_score_pixels))))
                    fns[lv, hh, ww] = stage_functions(stride, level_block(cfg, lv))
                f = {name: functools.partial(fn, lc=lc) for name, fn in fns[lv, hh, ww].items()}
                add(lv, "points", _timed(f["points"], rl, repeats=repeats))
                pts, sp = f["points"](rl)
                if cfg.method != "ransac":
                    add(lv, "solve", _timed(f["solve"], T, pts, cl, repeats=repeats))
                    T = f["solve"](T, pts, cl)
                    continue
                if lv >= cfg.ransac_finest:
                    if cfg.prior_candidate == "refined":
                        add(lv, "prior", _timed(f["prior"], T, pts, cl, repeats=repeats))
                        T = f["prior"](T, pts, cl)
                    lkey = jax.random.fold_in(pk, lv)
                    t_rs = _timed(f["ransac"], T, rl, cl, sp, lkey, repeats=repeats)
                    pu, pv = f["sample"](rl, lkey)
                    t_fit = _timed(f["fit"], T, rl, cl, pu, pv, repeats=repeats)
                    t_score = _timed(f["score"], f["fit"](T, rl, cl, pu, pv), sp, cl, repeats=repeats)
                    # a trip fits every slot of its batches, the ones after the stop too
                    trips = int(np.ceil(hyps[lv] / (cfg.batch_size * cfg.batches_per_trip)))
                    add(lv, "hypotheses", trips * t_fit)
                    add(lv, "scoring", trips * t_score)
                    add(lv, "ransac other", max(t_rs - trips * (t_fit + t_score), 0.0))
                    T = f["ransac"](T, rl, cl, sp, lkey)
                add(lv, "refinement", _timed(f["refine"], T, pts, cl, repeats=repeats))
                T = f["refine"](T, pts, cl)
            dev = float(np.max(np.abs(np.asarray(T) - np.asarray(est.T_cur_ref))))
            add(-1, "max |T - estimate|", dev)
        med = {kk: float(np.median(v)) for kk, v in acc.items()}
        e2e = med[(-1, "end to end")]
        parts = sum(v for (lv, st), v in med.items() if st not in ("end to end", "max |T - estimate|"))
        med[(-1, "rest")] = e2e - parts
        for (lv, st), v in sorted(med.items(), key=lambda kv: (-kv[0][0] if kv[0][0] >= 0 else -99, kv[0][1])):
            is_dev = st.startswith("max")
            rows.append({"method": cfg.method, "set": set_name, "level": "all" if lv < 0 else lv,
                         "size": "" if lv < 0 else f"{cam.width >> lv}x{cam.height >> lv}", "stage": st,
                         "ms": None if is_dev else v * 1000, "share": None if is_dev else v / e2e,
                         "value": v if is_dev else None})
        common.log(f"  stages {cfg.method} {set_name}: end to end {e2e * 1000:.1f} ms; "
                   + ", ".join(f"L{lv} {st} {v * 1000:.1f}" for (lv, st), v in med.items()
                               if lv >= 0 and v * 1000 > 0.05 * e2e * 1000))
    return rows


class _TimedStaticMap:
    """A :class:`jaxvo.tracking.static_map.StaticMap` whose public calls are blocked on and timed
    (seconds appended to ``timings["map: <call>"]``): the same programs and results, the time of
    each segmentation step apart from the estimates'."""

    @staticmethod
    def make(camera, max_depth, params, timings):
        from jaxvo.tracking import static_map

        def timed(name, method, result):
            def call(self, *a, **k):
                start = time.perf_counter()
                out = method(self, *a, **k)
                jax.block_until_ready(result(self, out))
                timings.setdefault(f"map: {name}", []).append(time.perf_counter() - start)
                return out
            return call

        base = static_map.StaticMap
        state = lambda self, out: (self.L, self.flags)      # noqa: E731
        cls = type("TimedStaticMap", (base,), {
            "add": timed("frame inputs", base.add, lambda self, out: (self.depths, self.cues)),
            "trust": timed("static weights", base.trust, lambda self, out: out),
            "read": timed("read an estimate", base.read, lambda self, out: out),
            "update": timed("vote", base.update, state),
            "new_reference": timed("new reference", base.new_reference, state),
        })
        return cls(camera, max_depth, params)


#: the default odometry and its single-reference variant, timed over whole sequences
DEFAULT_POLICIES = (("default (TrackConfig())", {}), ("single reference (window=1)", {"window": 1}))


def time_default(sets, repeats: int, key):
    """The default odometry over whole sequences against OpenCV's RGB odometry over the same
    consecutive pairs, in interleaved passes, and where its time goes.

    sets: name -> (sequence, frames decoded into memory). Per set and policy: one warm-up pass
    (``compile_s``: its wall time minus the timed passes' mean, i.e. what compiling cost), then
    ``repeats`` passes of ``Odometry.add`` over every frame alternating with passes of OpenCV over
    every consecutive pair; per-frame mean and median over all timed passes, and their ratios.
    Then one profiled pass (``Odometry.timings`` and a timed segmentation, blocked on each call):
    ms per frame by part, the host's own work (policy, bookkeeping, transfers) the rest."""
    from jaxvo.config import TrackConfig
    from jaxvo.tracking.odometry import Odometry

    rows, parts = [], []
    for set_name, (seq, frames) in sets.items():
        c0 = time.process_time()
        opencv = common.run_method("opencv-rgb", frames, seq.camera)   # warm-up included
        cv_secs, cv_cpu = [opencv["seconds"]], [time.process_time() - c0]
        for label, changes in DEFAULT_POLICIES:
            policy = TrackConfig(**changes)

            def one_pass(profile=False):
                odo = Odometry(seq.camera, Config(), key, policy)
                if profile:
                    odo.timings = {}
                    odo.static_map = _TimedStaticMap.make(seq.camera, odo.config.max_depth, odo.params, odo.timings)
                secs = []
                c = time.process_time()
                for f in frames:
                    t = time.perf_counter()
                    odo.add(f)
                    secs.append(time.perf_counter() - t)
                # frame 0: no estimate, its map inputs; CPU: every thread of the process (XLA's and the host's)
                return odo, np.asarray(secs), time.process_time() - c

            t0 = time.perf_counter()
            odo, _, _ = one_pass()
            warm = time.perf_counter() - t0
            secs, cpu = [], []
            for _ in range(repeats):
                _, s_t, c_t = one_pass()
                secs.append(s_t[1:])
                cpu.append(c_t / len(s_t))
                c0 = time.process_time()
                cv_secs.append(common.run_method("opencv-rgb", frames, seq.camera, warmup=False)["seconds"])
                cv_cpu.append(time.process_time() - c0)
            st = common.timing_stats(np.concatenate(secs))
            cv = common.timing_stats(np.concatenate(cv_secs))
            cv_pairs = len(frames) - 1
            held = int(np.sum(~np.asarray(odo.valid)))
            rows.append({"method": label, "set": set_name, "sequence": seq.name, "frames": len(frames), **st,
                         "opencv_mean_ms": cv["mean_ms"], "opencv_median_ms": cv["median_ms"],
                         "ratio_mean": st["mean_ms"] / cv["mean_ms"], "ratio_median": st["median_ms"] / cv["median_ms"],
                         "cpu_ms": 1000 * float(np.mean(cpu)),
                         "opencv_cpu_ms": 1000 * float(np.mean(cv_cpu[1:])) / cv_pairs,
                         "compile_s": max(0.0, warm - float(np.mean([s.sum() for s in secs]))), "held": held,
                         "switches": len(set(odo.references))})
            common.log(f"  {label} {set_name}: mean {st['mean_ms']:.1f} ms/frame (median {st['median_ms']:.1f}); "
                       f"OpenCV mean {cv['mean_ms']:.1f} ({cv['median_ms']:.1f}): {rows[-1]['ratio_mean']:.2f}x mean, "
                       f"{rows[-1]['ratio_median']:.2f}x median")
            odo, psecs, _ = one_pass(profile=True)
            total = float(psecs.sum())     # frame 0 included: its map inputs are timed too
            n = len(psecs) - 1
            timed = 0.0
            for part, ts in sorted(odo.timings.items(), key=lambda kv: -sum(kv[1])):
                timed += sum(ts)
                parts.append({"method": label, "set": set_name, "part": part, "calls": len(ts),
                              "calls_per_frame": len(ts) / n, "ms_per_call": 1000 * float(np.mean(ts)),
                              "ms_per_frame": 1000 * sum(ts) / n, "share": sum(ts) / total})
            parts.append({"method": label, "set": set_name, "part": "host (policy, bookkeeping, transfers)",
                          "calls": None, "calls_per_frame": None, "ms_per_call": None,
                          "ms_per_frame": 1000 * (total - timed) / n, "share": (total - timed) / total})
            parts.append({"method": label, "set": set_name, "part": "profiled pass, all", "calls": n,
                          "calls_per_frame": 1.0, "ms_per_call": 1000 * total / n,
                          "ms_per_frame": 1000 * total / n, "share": 1.0})
    return rows, parts


def _default_targets(rows):
    """The issue's target for the default odometry: <= 0.5x OpenCV rgb, mean over the whole sequence."""
    out = ["Target: the default <= 0.5x OpenCV rgb per frame, mean over the whole sequence.", ""]
    for r in rows:
        if r["method"] == DEFAULT_POLICIES[0][0]:
            verdict = "met" if r["ratio_mean"] <= 0.5 else f"NOT met ({r['ratio_mean'] / 0.5:.2f}x the limit)"
            out.append(f"- {r['set']} ({r['sequence']}, {r['frames']} frames): {r['ratio_mean']:.2f}x mean -> {verdict}")
    return out + [""]


def _one_pair(ri, rd, ci, cd, key, camera, config):
    return estimate_motion(Frame(ri, rd), Frame(ci, cd), camera, config, key).T_cur_ref


#: jit(vmap(estimate_motion)) over stacked pairs; frames, keys, camera and config are arguments.
BATCHED = jit(jax.vmap(_one_pair, in_axes=(0, 0, 0, 0, 0, None, None)))


def time_batches(seq, frames, pairs, batch_sizes, method, repeats, key):
    """Throughput of B pairs per jit(vmap) call vs one pair per call, per jax device kind."""
    cfg = Config(method=method)
    cam = seq.camera
    devices = {"cpu": jax.devices("cpu")[0]}
    try:
        gpus = jax.devices("gpu")
        if gpus:
            devices["gpu"] = gpus[0]
    except RuntimeError:
        pass
    rows = []
    for dev_name, dev in devices.items():
        with jax.default_device(dev):
            # one pair per call, the ordinary estimate_motion
            est0, _ = common.time_jaxvo_pair(frames[pairs[0][0]], frames[pairs[0][1]], cam, cfg, key)
            s = []
            for _ in range(repeats):
                for k, (i, j) in enumerate(pairs):
                    s.append(common.time_jaxvo_pair(frames[i], frames[j], cam, cfg, jax.random.fold_in(key, k))[1])
            single = float(np.median(s))
            rows.append({"device": dev_name, "method": method, "batch": "1 (loop)", "call_ms": single * 1000,
                         "pairs_per_s": 1.0 / single, "speedup": 1.0, "compile_s": None,
                         "max_dev_vs_loop": 0.0})
            for B in batch_sizes:
                sel = [pairs[k % len(pairs)] for k in range(B)]
                keys = jnp.stack([jax.random.fold_in(key, k % len(pairs)) for k in range(B)])
                stack = [np.stack([getattr(frames[p[a]], f) for p in sel])
                         for a, f in ((0, "intensity"), (0, "depth"), (1, "intensity"), (1, "depth"))]
                keys = jax.device_put(keys, dev)
                args = [jax.device_put(x, dev) for x in stack] + [keys]
                t0 = time.perf_counter()
                out = jax.block_until_ready(BATCHED(*args, cam, cfg))
                comp = time.perf_counter() - t0
                ts = []
                traces0 = trace_count()
                for _ in range(max(repeats, 1)):
                    # the transfer of the stacked frames counts, as in the per-pair loop
                    t0 = time.perf_counter()
                    out = jax.block_until_ready(BATCHED(*[jax.device_put(x, dev) for x in stack], keys, cam, cfg))
                    ts.append(time.perf_counter() - t0)
                call = float(np.median(ts))
                if trace_count() != traces0:
                    common.log("  WARNING: the batched function was retraced inside the timed loop")
                # agreement with the unbatched estimate of the first pair
                dev_err = float(np.max(np.abs(np.asarray(out[0]) - np.asarray(est0.T_cur_ref))))
                rows.append({"device": dev_name, "method": method, "batch": B, "call_ms": call * 1000,
                             "pairs_per_s": B / call, "speedup": (B / call) * single, "compile_s": comp,
                             "max_dev_vs_loop": dev_err})
                common.log(f"  {dev_name} batch {B}: {call * 1000:.1f} ms/call, {B / call:.1f} pairs/s "
                           f"({(B / call) * single:.2f}x the loop), compile {comp:.1f} s")
    return rows


def track_memory(frame_counts, method, cycle: int, key):
    """RSS of ``track`` over N lazily produced frames of the synthetic 'seq0' sequence.

    ``cycle`` frames are rendered once; the generator replays them ping-pong
    (0, 1, ..., c-1, c-2, ..., 0, 1, ...) so consecutive frames stay a plausible small motion,
    and yields a fresh copy each time (a new frame allocation per step, like a reader).
    """
    from jaxvo.synthetic import make_sequence
    syn = make_sequence("seq0", frames=max(cycle, 2), seed=0)
    rendered = [syn.render(k).frame() for k in range(max(cycle, 2))]
    period = 2 * len(rendered) - 2
    cfg = Config(method=method)

    def frames(n):
        for k in range(n):
            p = k % period
            f = rendered[p if p < len(rendered) else period - p]
            yield Frame(f.intensity.copy(), f.depth.copy())

    rows = []
    # warm up (compile) so the first measured run does not count compilation memory
    track(frames(2), syn.camera, cfg, key)
    for n in frame_counts:
        samples = []

        def cb(step):
            if step.frame % max(1, n // 20) == 0:
                samples.append(common.current_rss_mb())
        rss0 = common.current_rss_mb()
        t0 = time.perf_counter()
        tr = track(frames(n), syn.camera, cfg, key, callback=cb)
        wall = time.perf_counter() - t0
        rss1 = common.current_rss_mb()
        rows.append({"method": method, "frames": n, "rss_before_mb": rss0, "rss_after_mb": rss1,
                     "rss_max_sampled_mb": max(samples) if samples else rss1,
                     "rss_growth_mb": (max(samples) if samples else rss1) - rss0,
                     "peak_rss_mb": common.peak_rss_mb(), "ms_per_pair": 1000 * wall / max(n - 1, 1),
                     "valid_pairs": int(tr.valid.sum())})
        common.log(f"  track {n} frames: RSS {rss0:.0f} -> {rss1:.0f} MiB (max sampled "
                   f"{rows[-1]['rss_max_sampled_mb']:.0f}), peak {common.peak_rss_mb():.0f} MiB")
    return rows


# ----------------------------------------------------------------------------- report

def main(argv=None) -> Path:
    args = parse_args(argv)
    key = jax.random.key(0)
    t_start = time.perf_counter()
    static = load_pairs(common.resolve_sequence(args.static, STATIC, "tum"), args.pairs, "static")
    dynamic = load_pairs(common.resolve_sequence(args.dynamic, DYNAMIC, "bonn"), args.pairs, "dynamic")
    sets = {"static": static, "dynamic": dynamic}
    rss_start = common.peak_rss_mb()

    common.log("[speed] methods and peers (interleaved passes)")
    mrows, prows = time_methods_and_peers(sets, args.methods, args.peer_list, args.repeats, key)
    common.log("[speed] per level (static pairs)")
    lrows = time_levels(*static, args.level_methods, args.repeats, key, args.quick) if args.level_methods else []
    common.log("[speed] stages")
    srows = []
    for m in args.stages:
        srows += time_stages(sets, Config(method=m), args.stage_pairs, args.repeats, key)
    common.log("[speed] default odometry (Odometry + TrackConfig()) over whole sequences")
    drows, dparts = [], []
    if args.default_frames >= 0:
        whole = {}
        for name, (seq, _, _) in sets.items():
            seq = common.open_sequence(seq.path, max_frames=args.default_frames or None)
            whole[name] = (seq, common.load_frames(seq))
        drows, dparts = time_default(whole, args.repeats, key)
    common.log("[speed] batch (vmap over pairs)")
    brows = (time_batches(*static, args.batch, args.batch_method, args.repeats, key) if args.batch else [])
    common.log("[speed] track memory")
    trows = track_memory(args.track_frames, args.track_method, args.track_cycle, key) if args.track_frames else []

    # ratio table: jaxvo median / peer median on the same set
    ratio_rows = []
    for mr in mrows:
        r = {"method": mr["method"], "set": mr["set"], "mean_ms": mr["mean_ms"]}
        for pr in prows:
            if pr["set"] == mr["set"]:
                r[pr["method"]] = mr["mean_ms"] / pr["mean_ms"]
        ratio_rows.append(r)
    peer_cols = list(dict.fromkeys(p["method"] for p in prows))

    lines = common.provenance_md("Speed per 640x480 frame pair", __file__, argv)
    load = common.machine_info()["load_avg_1min"]
    if load > 0.5:
        lines += [f"Other processes ran beside this one (load average {load:.2f} at the start on "
                  f"{common.machine_info()['cpu_affinity']} usable CPUs), so absolute times vary from run to run: "
                  "compare the ratios to the peers measured in the same run.", ""]
    lines += [
        f"Pairs: {len(static[2])} static ({static[0].name}) and {len(dynamic[2])} dynamic ({dynamic[0].name}) "
        f"consecutive pairs spread over each sequence, decoded into memory first; each timed {args.repeats}x, "
        "in passes that alternate between the jaxvo methods and the peers (so a passing load weighs on both). "
        "A time is the wall time of one `estimate_motion` call including the host-to-device copy of both "
        "frames, blocked until the result is ready (`jax.block_until_ready`), after compilation; peers "
        "likewise include their input conversion and frame preparation. Compile: the first call (trace + "
        "XLA compile + one run). Hypotheses: RANSAC hypotheses evaluated per pair, summed over the "
        "pyramid levels (early exit included).", "",
        "## Per method", "",
    ]
    lines += common.md_table(mrows, [
        ("method", "method", ""), ("pairs", "set", ""), ("mean ms", "mean_ms", ".1f"),
        ("median ms", "median_ms", ".1f"), ("p90 ms", "p90_ms", ".1f"), ("FPS", "fps", ".1f"), ("paper FPS (Table III)", "paper_fps", ".0f"),
        ("compile s", "compile_s", ".1f"), ("RANSAC hyps mean", "hypotheses_mean", ".1f"),
        ("RANSAC hyps max", "hypotheses_max", "d")]) + [""]
    if lrows:
        lines += ["## Per pyramid level (static pairs)", "",
                  "`through` = median time of `Config(finest_level=l)` (levels L-1 .. l); `level` = its "
                  "difference to the next coarser run, i.e. the cost of level l.", ""]
        lines += common.md_table(lrows, [("method", "method", ""), ("level", "level", "d"), ("size", "size", ""),
                                         ("through ms", "cumulative_ms", ".1f"), ("level ms", "level_ms", ".1f"),
                                         ("compile s", "compile_s", ".1f")]) + [""]
    if prows:
        lines += ["## Peers on the same pairs", ""]
        lines += common.md_table(prows, [("peer", "method", ""), ("pairs", "set", ""),
                                         ("mean ms", "mean_ms", ".1f"), ("median ms", "median_ms", ".1f"),
                                         ("p90 ms", "p90_ms", ".1f"), ("FPS", "fps", ".1f"),
                                         ("failed", "failures", "d")]) + [""]
        lines += ["## Ratio jaxvo / peer (mean time; < 1 = jaxvo faster)", ""]
        lines += common.md_table(ratio_rows, [("method", "method", ""), ("pairs", "set", ""),
                                              ("jaxvo mean ms", "mean_ms", ".1f")]
                                 + [(p, p, ".2f") for p in peer_cols]) + [""]
        lines += _targets(mrows, prows)
    if drows:
        lines += ["## The default odometry over whole sequences, against OpenCV", "",
                  "Every frame of each sequence (frames decoded into memory first): per-frame wall time of "
                  "`Odometry.add` (every estimate the frame takes, the segmentation's updates, the window, the "
                  "host's policy and bookkeeping), after a warm-up pass over the same frames compiled "
                  f"everything; {args.repeats} timed passes, each followed by a pass of OpenCV's RGB odometry "
                  "over the same consecutive pairs (conversion and frame preparation included), so that a "
                  "passing load weighs on both. `compile s`: the warm-up pass minus a timed pass (in this "
                  "process, after the sections above compiled the estimator). `cpu ms`: the process's CPU "
                  "time (every thread: XLA runs a program's kernels on all cores) per frame over the timed "
                  "passes, beside OpenCV's per pair (one core); their ratio says how much of the wall-time "
                  "ratio is work and how much is parallelism. `held`: frames whose estimate "
                  "failed; `references`: distinct reference frames.", ""]
        lines += common.md_table(drows, [("odometry", "method", ""), ("set", "set", ""), ("frames", "frames", "d"),
                                         ("mean ms/frame", "mean_ms", ".1f"), ("median ms", "median_ms", ".1f"),
                                         ("p90 ms", "p90_ms", ".1f"), ("OpenCV mean ms", "opencv_mean_ms", ".1f"),
                                         ("OpenCV median ms", "opencv_median_ms", ".1f"),
                                         ("ratio mean", "ratio_mean", ".2f"), ("ratio median", "ratio_median", ".2f"),
                                         ("cpu ms/frame", "cpu_ms", ".1f"), ("OpenCV cpu ms", "opencv_cpu_ms", ".1f"),
                                         ("compile s", "compile_s", ".1f"), ("held", "held", "d"),
                                         ("references", "switches", "d")]) + [""]
        lines += _default_targets(drows)
        lines += ["### Where the default's time goes", "",
                  "One more pass with every estimate and every segmentation call blocked on and timed "
                  "(`Odometry.timings`; the segmentation's public calls wrapped): ms per frame by part "
                  "(`estimate: track` against the reference, `retry`, `recover` against an older keyframe, "
                  "`window` a new keyframe against the window's others, `fuse` a new reference against the old "
                  "one; `map: ...` the segmentation: each frame's inputs, the reference's static weights, "
                  "reading an estimate's statistics, a valid estimate's vote, a new reference's map; the "
                  "window's pose-graph refinement). `host`: the rest of `Odometry.add` (policy, poses, keys, "
                  "transfers). Share: of the profiled pass.", ""]
        lines += common.md_table(dparts, [("odometry", "method", ""), ("set", "set", ""), ("part", "part", ""),
                                          ("calls / frame", "calls_per_frame", ".2f"),
                                          ("ms / call", "ms_per_call", ".2f"), ("ms / frame", "ms_per_frame", ".2f"),
                                          ("share", "share", ".2f")]) + [""]
    if srows:
        lines += ["## Where the time goes: per level and per stage", "",
                  "Each stage of `estimate_motion(Config(method=m))` run as its own jitted call on the same "
                  f"inputs ({args.stage_pairs} pairs per set, median), the pose carried from level to level "
                  "as in the estimator (`max |T - estimate|` checks that the replay reaches the estimator's "
                  "pose). `hypotheses` / `scoring`: one vmapped batch x the batches the estimate ran at that "
                  "level; `ransac other`: the rest of `ransac_level` (sampling, loop); `rest`: end to end "
                  "minus all stages (final masks and statistics, dispatch). Share: of end to end.", ""]
        lines += common.md_table(srows, [("method", "method", ""), ("pairs", "set", ""), ("level", "level", ""),
                                         ("size", "size", ""), ("stage", "stage", ""), ("ms", "ms", ".2f"),
                                         ("share", "share", ".2f"), ("value", "value", ".1e")]) + [""]
    if brows:
        lines += ["## Batch throughput: `jax.jit(jax.vmap(estimate_motion))` over B stacked pairs", "",
                  "`speedup` = pairs/s of the batch against the one-pair-per-call loop on the same device; "
                  "`max dev` = max |T| difference of the batch's first pair from the unbatched estimate.", ""]
        lines += common.md_table(brows, [("device", "device", ""), ("method", "method", ""), ("B", "batch", ""),
                                         ("ms/call", "call_ms", ".1f"), ("pairs/s", "pairs_per_s", ".1f"),
                                         ("speedup", "speedup", ".2f"), ("compile s", "compile_s", ".1f"),
                                         ("max dev", "max_dev_vs_loop", ".1e")]) + [""]
        if not any(r["device"] == "gpu" for r in brows):
            lines += ["No GPU visible to jax on this machine: GPU rows absent.", ""]
    if trows:
        lines += ["## Memory of `track` vs sequence length", "",
                  f"Synthetic `seq0` (640x480): {max(args.track_cycle, 2)} frames rendered once and replayed "
                  "ping-pong by a generator that yields a fresh copy per step (lazy frames, as a reader "
                  "would). RSS sampled in the track callback; growth = max sampled - RSS before the call.", ""]
        lines += common.md_table(trows, [("method", "method", ""), ("frames", "frames", "d"),
                                         ("RSS before MiB", "rss_before_mb", ".0f"),
                                         ("RSS max MiB", "rss_max_sampled_mb", ".0f"),
                                         ("growth MiB", "rss_growth_mb", ".1f"),
                                         ("process peak MiB", "peak_rss_mb", ".0f"),
                                         ("ms/pair", "ms_per_pair", ".1f")]) + [""]
    lines += [f"Peak RSS of the whole process: {common.peak_rss_mb():.0f} MiB (after loading the pairs: "
              f"{rss_start:.0f} MiB). Total wall time {time.perf_counter() - t_start:.0f} s.", ""]
    data = {"command": common.command_line(__file__, argv), "machine": common.machine_info(),
            "methods": mrows, "levels": lrows, "peers": prows, "ratios": ratio_rows, "stages": srows,
            "default": drows, "default_parts": dparts, "batch": brows,
            "track_memory": trows, "peak_rss_mb": common.peak_rss_mb()}
    out = common.write_outputs(args.out, lines, data)
    common.log(f"[speed] wrote {out}")
    return out


def _targets(mrows, prows):
    """The targets per pair: ransac <= 0.5x OpenCV rgb, classic and huber <= 0.3x, mean over the
    same pairs (the median beside it), on this machine."""
    ref = {p["set"]: p for p in prows if p["method"] == "opencv-rgb"}
    if not ref:
        return []
    out = ["Targets (per-pair mean vs OpenCV rgb on the same pairs): ransac <= 0.5x, classic and huber <= 0.3x.", ""]
    for m in mrows:
        if m["set"] not in ref:
            continue
        lim = 0.5 if m["method"] == "ransac" else 0.3
        ratio = m["mean_ms"] / ref[m["set"]]["mean_ms"]
        verdict = "met" if ratio <= lim else f"NOT met ({ratio / lim:.2f}x the limit)"
        out.append(f"- {m['method']} ({m['set']}): {ratio:.2f}x OpenCV rgb mean "
                   f"({m['median_ms'] / ref[m['set']]['median_ms']:.2f}x median) -> {verdict}")
    return out + [""]


if __name__ == "__main__":
    main()
