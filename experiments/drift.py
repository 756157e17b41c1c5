"""Drift over long dynamic sequences: the keyframe window (``TrackConfig()``) against the single
reference (``TrackConfig(window=1)``), per seed, on

* jaxvo's synthetic ``crowd`` sequence (``jaxvo.synthetic``: a hand-held camera panning slowly,
  three persons walking on their own paths, at times covering half the image, Kinect-like sensor
  noise; exact ground truth), ``--frames`` frames at ``--size``; with ``--scene crowd-close`` the
  persons come closer and stand in view for seconds before they walk out (up to three quarters of
  the image);
* dynamic augmentations of real static recordings (``--augment``: synthetic walking persons
  composited into them, ``jaxvo.synthetic.augment``), at their own size.

Drift is reported per 100 frames: the RPE over a 100-frame delta (translation m, rotation deg)
and the mean ATE of the 100-frame segments (each aligned on its own), besides the whole
sequence's ATE and RPE over 1 s. Seeds pick the scene, the persons' paths, the sensor noise and
RANSAC's key. ``--jobs`` runs seeds in parallel processes (one CPU thread each).

Writes ``drift.md`` and ``drift.json``.

Example::

    python experiments/drift.py                                   # 900 frames, seeds 0-11
    python experiments/drift.py --frames 120 --seeds 0 --out /tmp/drift.md
    python experiments/drift.py --augment ../shared/data/tum/rgbd_dataset_freiburg2_desk --frames 0
    python experiments/drift.py --policy '{"second_opinion": 0}'   # a TrackConfig field changed in both
    python experiments/drift.py --scene crowd-close --out experiments/results/drift/crowd_close.md
"""
from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import time
from pathlib import Path

import numpy as np

try:                    # run as a script (python experiments/drift.py)
    import common
except ImportError:     # imported as experiments.drift (experiments.diagnostics)
    from experiments import common

SEGMENT = 100


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--frames", type=int, default=900, help="frames of the synthetic crowd sequence (0: none)")
    ap.add_argument("--scene", choices=("crowd", "crowd-close"), default="crowd",
                    help="the synthetic sequence: crowd (persons walking at 1.2-3 m) or crowd-close (persons at "
                         "0.9-2.3 m who stand in view for seconds, then walk out)")
    ap.add_argument("--size", default="320x240", help="synthetic image size WxH (intrinsics scaled from 640x480)")
    ap.add_argument("--seeds", default=",".join(map(str, range(12))), help="comma-separated seeds")
    ap.add_argument("--augment", nargs="*", default=[], help="real static TUM sequences to augment with persons")
    ap.add_argument("--persons", type=int, default=2, help="persons composited into each augmented sequence")
    ap.add_argument("--jobs", type=int, default=1, help="parallel processes (each one CPU thread)")
    ap.add_argument("--policy", default=None,
                    help="JSON object of jaxvo.TrackConfig fields changed in both trackings (the single reference "
                         "is the same with window 1), e.g. '{\"second_opinion\": 0}'")
    common.add_poses_arg(ap, both=True)
    ap.add_argument("--out", default=str(common.RESULTS / "drift" / "drift.md"), help="markdown output (JSON beside)")
    args = ap.parse_args(argv)
    try:
        _policies(args.policy)
    except (TypeError, ValueError) as e:
        ap.error(f"--policy: {e}")
    return args


SINGLE_THREAD = "--xla_cpu_multi_thread_eigen=false"


def _single_thread():
    """One CPU thread for XLA in this process, so that --jobs processes share the cores evenly.
    XLA reads the flag when JAX starts its backend, so this is called only where that has not
    happened yet: in a spawned worker, and in the script's own process before ``main``. (A token
    without ``--`` in XLA_FLAGS silently ends the parsing, so every flag here is well formed.)"""
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + SINGLE_THREAD).strip()


def _policies(changes=None):
    """{"window": TrackConfig() with ``changes`` (a JSON object of its fields, or None), "single": the
    same with window 1}; ValueError naming a bad field or value."""
    from jaxvo.config import TrackConfig
    window = TrackConfig.from_json(changes) if changes else TrackConfig()
    window.validate()
    return {"window": window, "single": window._replace(window=1)}


def drift_stats(stamps, gt, est):
    """Drift of the (N, 4, 4) T_world_cam ``est`` against ``gt`` (stamps (N,) s): a dict of the
    whole ATE (m), RPE 1 s (m/s, deg/s), RPE over 100 frames (m, deg) and the mean ATE of the
    100-frame segments (m). A sequence shorter than 1 s has no RPE 1 s, one of at most 100 frames no
    100-frame figures (their keys are left out, and the summary shows n/a)."""
    from jaxvo.evaluation import metrics
    n = len(stamps)
    out = {"ate": metrics.ate(stamps, gt, stamps, est).stats.rmse}
    if stamps[-1] - stamps[0] >= 1.0:
        r1 = metrics.rpe(stamps, gt, stamps, est, delta=1.0)
        out["rpe1s_t"], out["rpe1s_r"] = r1.trans_stats.rmse, r1.rot_stats.rmse
    if n > SEGMENT:
        r = metrics.rpe(stamps, gt, stamps, est, delta=SEGMENT, delta_unit="f")
        out["rpe100_t"], out["rpe100_r"] = r.trans_stats.rmse, r.rot_stats.rmse
        segs = [metrics.ate(stamps[a:a + SEGMENT], gt[a:a + SEGMENT], stamps[a:a + SEGMENT], est[a:a + SEGMENT])
                .stats.rmse for a in range(0, n - SEGMENT + 1, SEGMENT)]
        out["ate100"] = float(np.mean(segs))
    return out


def _track_all(frames, camera, seed, changes=None, poses: str = "refined"):
    """{policy: (poses (N, 4, 4), held frames, s per frame after the first 10)} for both policies
    (:func:`_policies` of ``changes``); ``poses``: refined in hindsight or as tracked (``common.POSES``),
    or both (each policy's tracked poses then under "<policy>, tracked")."""
    import jax
    from jaxvo.tracking.odometry import Odometry
    out = {}
    for name, policy in _policies(changes).items():
        odo = Odometry(camera, key=jax.random.PRNGKey(seed), policy=policy)
        t0 = None
        for i, f in enumerate(frames):
            if i == 10:
                t0 = time.perf_counter()
            odo.add(f)
        dt = (time.perf_counter() - t0) / max(1, len(frames) - 10) if t0 else float("nan")
        tr = odo.result()
        for kind in common.pose_kinds(poses):
            out[common.pose_label(name, kind, poses)] = (common.track_poses(tr, kind), int(np.sum(~tr.valid)), dt)
    return out


def run_crowd(job):
    """One seed of a synthetic crowd (``scene``: crowd or crowd-close): rows for both policies."""
    seed, frames, size, changes, poses, scene = job
    from jaxvo.camera import DEFAULT, camera_for_size
    from jaxvo.frame import make_frame
    from jaxvo.synthetic import SensorModel, make_sequence
    w, h = map(int, size.split("x"))
    camera = camera_for_size(DEFAULT, w, h)
    seq = make_sequence(scene, frames=frames, seed=seed, camera=camera)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xD21F7]))
    imgs, covered = [], []
    for k in range(frames):
        r = seq.render(k, sensor=SensorModel(), rng=rng)
        imgs.append(make_frame(r.rgb, r.depth))
        covered.append(float(r.moving_mask.mean()))
    rows = []
    for name, (P, held, dt) in _track_all(imgs, camera, seed, changes, poses).items():
        rows.append({"data": f"synthetic {scene} {frames} frames {size}", "seed": seed, "policy": name, "held": held,
                     "ms_per_frame": 1000 * dt, "moving_max": max(covered), "moving_mean": float(np.mean(covered)),
                     **drift_stats(seq.timestamps, seq.poses, P)})
    return rows


def run_augmented(job):
    """One seed of a dynamic augmentation of a real recording: rows for both policies."""
    real, seed, persons, changes, poses = job
    aug = common.augmented_sequence(real, persons=persons, seed=seed)
    seq = common.open_sequence(aug)
    frames = common.load_frames(seq)
    stamps, G, mask = common.groundtruth_at(seq)
    rows = []
    for name, (P, held, dt) in _track_all(frames, seq.camera, seed, changes, poses).items():
        rows.append({"data": f"{common.short_name(real)} + {persons} persons", "seed": seed, "policy": name,
                     "held": held, "ms_per_frame": 1000 * dt, **drift_stats(stamps, G, P[mask])})
    return rows


COLUMNS = (("ate", "ATE [m]", ".4f"), ("ate100", "ATE per 100 frames [m]", ".4f"),
           ("rpe100_t", "RPE 100 frames [m]", ".4f"), ("rpe100_r", "RPE 100 frames [deg]", ".2f"),
           ("rpe1s_t", "RPE 1 s [m/s]", ".4f"), ("held", "held frames", ".1f"))


def summary_md(rows):
    """Markdown: per data and policy, mean [min - max] over seeds of each column; then the
    window / single ratio of the ATE per seed."""
    lines = ["| data | tracking | seeds | " + " | ".join(c[1] for c in COLUMNS) + " |",
             "| --- | --- | --- | " + " | ".join("---" for _ in COLUMNS) + " |"]
    for data in dict.fromkeys(r["data"] for r in rows):
        for policy in dict.fromkeys(r["policy"] for r in rows if r["data"] == data):
            sel = [r for r in rows if r["data"] == data and r["policy"] == policy]
            cells = []
            for key, _, spec in COLUMNS:
                v = [r[key] for r in sel if key in r]
                cells.append(f"{np.mean(v):{spec}} [{min(v):{spec}} - {max(v):{spec}}]" if v else "n/a")
            lines.append(f"| {data} | {policy} | {len(sel)} | " + " | ".join(cells) + " |")
    lines += ["", "Per seed, ATE window / single (below 1: the window drifts less):", ""]
    for data in dict.fromkeys(r["data"] for r in rows):
        by = {(r["seed"], r["policy"]): r["ate"] for r in rows if r["data"] == data}
        ratios = [by[(s, "window")] / by[(s, "single")] for s in sorted({s for s, _ in by}) if (s, "single") in by]
        lines.append(f"- {data}: " + ", ".join(f"{x:.2f}" for x in ratios)
                     + f" (window better on {sum(x < 1 for x in ratios)} of {len(ratios)})")
    return lines


def main(argv=None):
    args = parse_args(argv)
    seeds = common.int_list(args.seeds)
    jobs = [(run_crowd, (s, args.frames, args.size, args.policy, args.poses, args.scene)) for s in seeds
            if args.frames > 0]
    jobs += [(run_augmented, (str(Path(r)), s, args.persons, args.policy, args.poses)) for r in args.augment
             for s in seeds]
    t0 = time.time()
    if args.jobs > 1:
        with multiprocessing.get_context("spawn").Pool(args.jobs, initializer=_single_thread) as pool:
            results = [pool.apply_async(f, (a,)) for f, a in jobs]
            rows = [row for res in results for row in res.get()]
    else:
        rows = [row for f, a in jobs for row in f(a)]
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    md = common.provenance_md("Drift: keyframe window vs single reference", "experiments/drift.py", argv)
    md += ["", f"Wall time {time.time() - t0:.0f} s with {args.jobs} process(es). ms per frame: tracking only, "
           "after the first 10 frames, one CPU thread per process.", ""]
    md += summary_md(rows)
    out.write_text("\n".join(md) + "\n")
    out.with_suffix(".json").write_text(json.dumps({"rows": rows, "machine": common.machine_info()}, indent=1))
    print("\n".join(md))


if __name__ == "__main__":
    _single_thread()
    main()
