"""The paper's synthetic-style sequences (Table II): classic vs Huber vs RANSAC with exact ground truth.

Generates (cached) jaxvo synthetic sequences ``seq0`` (hand-held, static scene), ``seq1``
(fixed camera, one person), ``seq2`` (pan-tilt head at 2 deg/s, one person), ``seq3`` (as
seq2 with two persons) and ``handheld-fast`` (fast hand-held camera, a person close and
fast), and with ``--augment`` dynamic augmentations of real TUM sequences (synthetic persons
composited into the real frames, real ground truth, exact masks), runs the three estimators on every consecutive pair and reports, per sequence and
method: translational / rotational RPE (per frame and over 1 s), ATE, the drift of the last
frame, FPS after compilation, the mean inlier ratio and the precision / recall / IoU of the
moving mask (:func:`jaxvo.pipelines.mapping.moving_mask`: outliers not hidden in the current frame,
plus the segmentation's dynamic pixels, on the reference frame's pixels) against the true
moving-pixel masks. Figures per sequence (like the paper's Fig. 5/6): trajectories (top view,
aligned to ground truth) and translational error over time for the three methods, plus
RANSAC's inlier/outlier overlay on the most dynamic frame (Fig. 4/7).

    python experiments/paper_sequences.py                    # 90 frames each at 640x480
    python experiments/paper_sequences.py --quick            # 4 frames each, a smoke run
    python experiments/paper_sequences.py --frames 300 --sequences seq1,seq2
    python experiments/paper_sequences.py --augment tum   # plus the real TUM sequences, augmented

Writes ``experiments/results/paper_sequences/paper_sequences.md`` and ``.json`` and the figures into
``experiments/results/paper_sequences/paper_sequences/``; sequences are cached in ``experiments/results/cache/``.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import numpy as np

if __package__:  # imported as experiments.paper_sequences (by a script under experiments/diagnostics/)
    from experiments import common
else:            # python experiments/paper_sequences.py
    import common

import jax  # noqa: E402

from jaxvo import geometry, viz
from jaxvo.evaluation import metrics
from jaxvo.data import trajectory  # noqa: E402
from jaxvo.camera import DEFAULT  # noqa: E402
from jaxvo.data.tum import TumSequence  # noqa: E402
from jaxvo.data.masks import load_mask_of_size as load_mask, true_masks as read_moving_masks  # noqa: E402
from jaxvo.pipelines.mapping import moving_mask  # noqa: E402
from jaxvo.config import METHODS, Config, TrackConfig
from jaxvo.tracking.odometry import track  # noqa: E402

SEQUENCES = ("seq0", "seq1", "seq2", "seq3", "handheld-fast")
SIZES = {"640x480": 0, "320x240": 1, "160x120": 2}

PAPER_NOTES = """\
What the paper reported on its own Kinect recordings of these situations (Table II, Fig. 5/6):

* **seq0** (hand-held, static scene): all three estimators work; RANSAC is as accurate as the classic one.
* **seq1** (fixed camera, one person moving): the classic estimator is dragged along by the person and
  drifts by about **20 cm and 30 degrees**, while RANSAC stays **near zero** (the camera does not move).
* **seq2** (pan-tilt head rotating at **2 deg/s**, one person): RANSAC follows the rotation; the classic
  estimator is disturbed whenever the person is in view.
* **seq3** (as seq2, two persons): as seq2, with more of the image moving.
* **fast hand-held, person close**: the hard case (the moving person covers most of the image)."""


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sequences", default=",".join(SEQUENCES),
                    help=f"comma list of {', '.join(SEQUENCES)} (default: all)")
    ap.add_argument("--frames", type=int, default=90, help="frames per sequence (30 Hz; default 90)")
    ap.add_argument("--quick", action="store_true", help="4 frames per sequence (a smoke run)")
    ap.add_argument("--size", choices=list(SIZES), default="640x480", help="image size (default 640x480)")
    ap.add_argument("--methods", default=",".join(METHODS + ("default",)),
                    help="comma list of classic, huber, ransac (every consecutive pair, the paper's protocol) "
                         "and default (jaxvo's default odometry: ransac with segmented keyframes, jaxvo.track)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the scenes and of RANSAC")
    ap.add_argument("--seeds", default=None,
                    help="comma list of seeds, each a full run (scenes, augmentations and RANSAC), with a table "
                         "of the mean and range over them; figures and notes are of the first (default: --seed)")
    ap.add_argument("--sensor", dest="sensor", action="store_true", default=True,
                    help="Kinect-like sensor effects (default)")
    ap.add_argument("--no-sensor", dest="sensor", action="store_false", help="exact renders")
    ap.add_argument("--augment", default=None,
                    help="comma list of real TUM sequence folders to run too, each as its dynamic augmentation "
                         "(jaxvo.synthetic.augment: 2 persons, 30 %% coverage, the seed; real frames, real ground "
                         "truth, exact masks); 'tum' = every sequence under data_root()/tum")
    ap.add_argument("--augment-depth-time", action="store_true",
                    help="the augmentations' persons in each depth image rendered at its own timestamp and pose "
                         "(as a sensor that takes depth and colour apart sees them), not at the colour image's")
    ap.add_argument("--policy", default=None,
                    help="JSON object of jaxvo.TrackConfig fields changed in the default's policy "
                         "(e.g. '{\"restart\": 9}')")
    ap.add_argument("--config", default=None,
                    help="JSON object of jaxvo.Config fields applied to every method, the default included "
                         "(e.g. '{\"ransac_finest\": 2}')")
    ap.add_argument("--cache", type=Path, default=None, help=f"folder of generated sequences (default {common.CACHE})")
    common.add_poses_arg(ap)
    ap.add_argument("--out", type=Path, default=common.RESULTS / "paper_sequences" / "paper_sequences.md",
                    help="markdown output (json next to it, figures in <stem>/)")
    a = ap.parse_args(argv)
    if a.quick:
        a.frames = 4
    if a.frames < 3:
        ap.error("--frames must be >= 3")
    a.sequences = [s.strip() for s in a.sequences.split(",") if s.strip()]
    bad = [s for s in a.sequences if s not in SEQUENCES]
    if bad:
        ap.error(f"unknown sequence(s) {', '.join(bad)}; choose from {', '.join(SEQUENCES)}")
    a.augment = augment_list(a.augment, ap)
    try:
        a.policy_obj = TrackConfig.from_json(a.policy) if a.policy else TrackConfig()
        a.policy_obj.validate()
    except (ValueError, TypeError) as e:
        ap.error(f"--policy: {e}")
    try:
        a.config = common.config_changes(a.config)
    except (ValueError, TypeError) as e:
        ap.error(f"--config: {e}")
    try:
        a.seed_list = common.int_list(a.seeds) if a.seeds else [a.seed]
    except ValueError as e:
        ap.error(f"--seeds: {e}")
    a.seed = a.seed_list[0]
    a.methods = [m.strip() for m in a.methods.split(",") if m.strip()]
    bad = [m for m in a.methods if m not in METHODS + ("default",)]
    if bad:
        ap.error(f"unknown method(s) {', '.join(bad)}; choose from {', '.join(METHODS)}")
    return a


def augment_list(text: Optional[str], ap) -> List[Path]:
    if not text:
        return []
    if text.strip() == "tum":
        found = common.datasets.find_sequences(common.datasets.data_root() / "tum")
        if not found:
            ap.error(f"--augment tum: {common.missing_data_message()}")
        return found
    paths = [Path(t.strip()) for t in text.split(",") if t.strip()]
    missing = [str(p) for p in paths if not (p / "groundtruth.txt").is_file()]
    if missing:
        ap.error(f"--augment: no TUM sequence with ground truth at {', '.join(missing)}")
    return paths


def add_job_args(ap, sequences: str, seeds: str) -> None:
    """The options of the scripts that run on synthetic sequences and on the augmentation of a real
    one (mask_limits.py, hindsight_masks.py): --sequences, --augment, --frames, --seeds, --cache;
    :func:`check_job_args` checks them."""
    ap.add_argument("--sequences", default=sequences,
                    help=f"comma list of synthetic sequences ({', '.join(SEQUENCES)}); '' for none")
    ap.add_argument("--augment", default=None,
                    help="comma list of real TUM sequence folders, each as its dynamic augmentation (2 persons, "
                         "30 %% coverage, the seed), as in paper_sequences.py; default: freiburg2_desk under the "
                         "data root; '' for none")
    ap.add_argument("--frames", type=int, default=90, help="frames per sequence (default 90, as paper_sequences.py)")
    ap.add_argument("--seeds", default=seeds, help="comma list of seeds (scenes, augmentations, RANSAC)")
    ap.add_argument("--cache", type=Path, default=None, help=f"folder of generated sequences (default {common.CACHE})")


def check_job_args(a, ap) -> None:
    """Parse what :func:`add_job_args` added, in place: ``a.sequences`` a list of known names,
    ``a.augment`` a list of folders (default fr2_desk under the data root), ``a.seed_list``."""
    a.sequences = [s.strip() for s in a.sequences.split(",") if s.strip()]
    bad = [s for s in a.sequences if s not in SEQUENCES]
    if bad:
        ap.error(f"unknown sequence(s) {', '.join(bad)}; choose from {', '.join(SEQUENCES)}")
    if a.augment is None:
        desk = common.find_named("rgbd_dataset_freiburg2_desk")
        if desk is None:
            ap.error(f"--augment: {common.missing_data_message()}")
        a.augment = [desk]
    else:
        a.augment = augment_list(a.augment, ap)
    try:
        a.seed_list = common.int_list(a.seeds)
    except ValueError as e:
        ap.error(f"--seeds: {e}")
    if a.frames < 3:
        ap.error("--frames must be >= 3")


def synthetic_sequence(name: str, frames: int, size: str, seed: int, sensor: bool, cache=None) -> Path:
    """Generate (once) a jaxvo synthetic sequence into the cache and return its folder."""
    import json

    from jaxvo.synthetic import SensorModel, generate
    cache = Path(cache) if cache is not None else common.CACHE
    cache.mkdir(parents=True, exist_ok=True)
    gi = cache / ".gitignore"
    if cache == common.CACHE and not gi.exists():
        gi.write_text("# generated data, not committed\n*\n")
    out = cache / f"synth_{name}_{size}_n{frames}_s{seed}{'_sensor' if sensor else ''}"
    try:
        ok = json.loads((out / "info.json").read_text()).get("frames") == frames and (out / "masks.txt").is_file()
    except (OSError, ValueError):
        ok = False
    if not ok:
        common.log(f"generating {name} ({frames} frames, {size}) -> {out}")
        generate(name, out, frames=frames, seed=seed, camera=DEFAULT.at_level(SIZES[size]),
                 sensor=SensorModel() if sensor else None)
    return out


def end_drift(seq: TumSequence, poses) -> Dict[str, Optional[float]]:
    """Error of the last pose relative to the first: translation (m) and rotation (deg) of
    ``inv(gt_rel) @ est_rel`` with ``rel = inv(T_first) @ T_last``; plus the ground-truth and
    estimated rotation angle first -> last (deg)."""
    g = seq.groundtruth_at_frames()
    if g is None or not (g[0][0] and g[0][-1]):
        return {"drift_t": None, "drift_r": None, "gt_angle": None, "est_angle": None}
    T = g[1]
    gt_rel = geometry.inverse(T[0]) @ T[-1]
    est_rel = geometry.inverse(poses[0]) @ poses[-1]
    E = geometry.inverse(gt_rel) @ est_rel
    return {"drift_t": float(np.linalg.norm(E[:3, 3])),
            "drift_r": float(np.degrees(geometry.rotation_angle(E[:3, :3]))),
            "gt_angle": float(np.degrees(geometry.rotation_angle(gt_rel[:3, :3]))),
            "est_angle": float(np.degrees(geometry.rotation_angle(est_rel[:3, :3])))}


def sequence_jobs(sequences: Sequence[str], augment: Sequence[Path], seeds: Sequence[int], frames: int,
                  size: str = "640x480", sensor: bool = True, cache=None, depth_time: bool = False) -> list:
    """(name, seed, make, camera) per seed and sequence: the synthetic ``sequences`` and the dynamic
    augmentations (2 persons, 30 % coverage; ``depth_time``: the depth images' persons at their own
    timestamps, ``jaxvo.synthetic.augment``) of the real ``augment`` folders; ``make()`` generates
    the sequence (cached) and returns its folder; camera: the intrinsics to read it with (None:
    the real sequence's preset)."""
    jobs = []
    for seed in seeds:
        jobs += [(name, seed, lambda name=name, seed=seed: synthetic_sequence(name, frames, size, seed, sensor, cache),
                  DEFAULT.at_level(SIZES[size])) for name in sequences]
        jobs += [(f"{common.short_name(p)}+persons", seed, lambda p=p, seed=seed: common.augmented_sequence(
            p, persons=2, coverage=0.3, seed=seed, max_frames=frames, cache_dir=cache, depth_time=depth_time), None)
                 for p in augment]
    return jobs


def opened_jobs(jobs):
    """Yield ``(name, seed, seq, true masks, frames)`` for each job of :func:`sequence_jobs`, the
    sequence generated (cached) and read; a job whose sequence cannot be made is logged and skipped."""
    for name, seed, make, camera in jobs:
        try:
            d = make()
        except common.datasets.DatasetError as e:
            common.log(f"{name}: skipped: {e}")
            continue
        seq = TumSequence(d, camera=camera)
        yield name, seed, seq, true_masks(d, seq), common.load_frames(seq)


def true_masks(folder, seq: TumSequence) -> list:
    """The exact moving-pixel mask of each frame of ``seq`` ((H, W) bool), from ``folder``'s masks
    (the one nearest in time)."""
    mt, mp = read_moving_masks(folder)
    H, W = seq.camera.height, seq.camera.width
    return [load_mask(mp[int(np.argmin(np.abs(mt - t)))], (H, W)) for t in seq.timestamps]


def run_default(seq: TumSequence, frames: list, true_masks: list, key, policy: Optional[TrackConfig] = None,
                config: Optional[dict] = None, odometry=None, poses: str = "refined") -> dict:
    """jaxvo's default odometry (``jaxvo.track``, ``TrackConfig()``) along the sequence, in the same
    form as :func:`run_one`. Its moving mask (on the reference of each estimate) is the estimate's
    outliers not hidden in the current frame plus what the segmentation marked dynamic; seconds per frame include the map updates.
    Also ``mask_steps``: (pairs, 6) int64, per estimate (frame, reference, tp, fp, fn, tn) of that mask,
    and ``valid``: (pairs,) bool, False where the estimate of frame i+1 failed and its pose was held.
    ``odometry``: a subclass of :class:`jaxvo.Odometry` to run instead (``jaxvo.track``'s loop).
    ``poses``: the relative motions of the poses as tracked or refined in hindsight (``common.POSES``)."""
    cam = seq.camera
    per_step = []
    cover = np.array([m.mean() for m in true_masks])
    shown, secs, ratio, last = [None], [], [], [time.perf_counter()]

    def on_step(step):
        est = step.estimate
        pred, val = moving_mask(est, cam.width, cam.height, step.static_mask, valid_too=True)
        s = metrics.mask_scores(pred, true_masks[step.reference], val)
        per_step.append((step.frame, step.reference, s.tp, s.fp, s.fn, s.tn))
        if shown[0] is None or cover[step.reference] > cover[shown[0][2]]:  # the most covered reference
            shown[0] = (~pred, val, step.reference)
        ratio.append(float(est.inlier_ratio))
        now = time.perf_counter()
        secs.append(now - last[0])
        last[0] = now

    t0 = time.perf_counter()
    if odometry is None:
        tr = track(frames, cam, Config.from_json(config or {}), key, policy=TrackConfig() if policy is None else policy,
                   callback=on_step)
    else:
        odo = odometry(cam, Config.from_json(config or {}), key, TrackConfig() if policy is None else policy)
        for frame in frames:
            step = odo.add(frame)
            if step.frame > 0:
                on_step(step)
        tr = odo.result()
    steps = np.asarray(per_step, np.int64).reshape(-1, 6)
    tp, fp, fn, tn = (int(c) for c in steps[:, 2:].sum(0))
    return {"relative": common.track_relative(tr, poses), "valid": tr.valid, "seconds": np.asarray(secs[1:] or secs), "compile_s": secs[0] if secs else
            time.perf_counter() - t0, "inlier_ratio": np.asarray(ratio),
            "mask": {"precision": tp / (tp + fp) if tp + fp else None, "recall": tp / (tp + fn) if tp + fn else None,
                     "iou": tp / (tp + fp + fn) if tp + fp + fn else None, "tp": tp, "fp": fp, "fn": fn, "tn": tn},
            "shown": shown[0], "mask_steps": steps}


def run_one(seq: TumSequence, frames: list, true_masks: list, method: str, key,
            policy: Optional[TrackConfig] = None, config: Optional[dict] = None, poses: str = "refined") -> dict:
    """Every consecutive pair with one method: relative motions, timings, inlier ratios, pooled mask counts.
    config: Config fields changed from their defaults (every method). poses: the default's, as
    tracked or refined in hindsight (:func:`run_default`)."""
    if method == "default":
        return run_default(seq, frames, true_masks, key, policy, config, poses=poses)
    cam = seq.camera
    cfg = Config.from_json({**(config or {}), "method": method})
    P = len(frames) - 1
    rel = np.zeros((P, 4, 4))
    secs = np.zeros(P)
    ratio = np.zeros(P)
    counts = np.zeros(4, np.int64)
    _, compile_s = common.time_jaxvo_pair(frames[0], frames[1], cam, cfg, jax.random.fold_in(key, 0))
    cover = np.array([m.mean() for m in true_masks[:-1]])
    show = int(np.argmax(cover)) if cover.size else 0
    shown = None
    for k in range(P):
        est, secs[k] = common.time_jaxvo_pair(frames[k], frames[k + 1], cam, cfg, jax.random.fold_in(key, k))
        rel[k] = np.asarray(est.T_cur_ref, np.float64)
        ratio[k] = float(est.inlier_ratio)
        pred, val = moving_mask(est, cam.width, cam.height, valid_too=True)
        s = metrics.mask_scores(pred, true_masks[k], val)
        counts += (s.tp, s.fp, s.fn, s.tn)
        if k == show:
            shown = (np.asarray(est.inlier_mask, bool), np.asarray(est.valid_mask, bool), k)
    tp, fp, fn, tn = (int(c) for c in counts)
    return {"relative": rel, "seconds": secs, "compile_s": compile_s, "inlier_ratio": ratio,
            "mask": {"precision": tp / (tp + fp) if tp + fp else None, "recall": tp / (tp + fn) if tp + fn else None,
                     "iou": tp / (tp + fp + fn) if tp + fp + fn else None, "tp": tp, "fp": fp, "fn": fn, "tn": tn},
            "shown": shown}


def figures(name: str, seq: TumSequence, runs: Dict[str, dict], fig_dir: Path, frames: list, true_masks) -> Dict[str, str]:
    fig_dir.mkdir(parents=True, exist_ok=True)
    out: Dict[str, str] = {}
    gs, gT, _ = common.groundtruth_at(seq)
    t0 = seq.timestamps[0]
    trajs = {"groundtruth": gT[:, :3, 3]}
    for m, r in runs.items():
        poses = trajectory.chain(r["relative"])
        trajs[m] = metrics.ate(gs, gT, seq.timestamps, poses).aligned[:, :3, 3]
    out["trajectories"] = str(viz.save_figure(
        viz.plot_trajectories(trajs, title=f"{name}: trajectories, top view (aligned to ground truth)"),
        fig_dir / f"{name}_trajectories.png"))
    times = {m: seq.timestamps[1:len(r["relative"]) + 1] - t0 for m, r in runs.items()}
    errs = {m: 1000.0 * common.relative_errors(seq, r["relative"])["trans"] for m, r in runs.items()}
    out["translational_error"] = str(viz.save_figure(
        viz.plot_errors_over_time(times, errs, ylabel="translational error [mm/frame]",
                                  title=f"{name}: translational error per frame"),
        fig_dir / f"{name}_translational_error.png"))
    m = "default" if "default" in runs else "ransac" if "ransac" in runs else next(iter(runs))
    if runs[m]["shown"] is not None:
        inl, val, k = runs[m]["shown"]
        out["overlay"] = str(viz.save_figure(
            viz.plot_overlay(frames[k].intensity, inl, val, true_masks[k],
                             title=f"{name} frame {k}, {m}: inliers blue, outliers green, true moving outlined red"),
            fig_dir / f"{name}_overlay_{m}.png"))
    return out


def _seeds_text(seeds: List[int]) -> str:
    return str(seeds[0]) if len(seeds) == 1 else f"each of {', '.join(map(str, seeds))}"


SUMMARY_COLUMNS = ("sequence", "method", "seeds", "RPE 1 s m/s", "RPE 1 s deg/s", "ATE m", "mask P", "mask R")


def seed_summary(rows: List[dict]) -> List[dict]:
    """Per (sequence, method): mean (min - max) over the seeds of the rows' main measures."""
    out = []
    for key in dict.fromkeys((r["sequence"], r["method"]) for r in rows):
        group = [r for r in rows if (r["sequence"], r["method"]) == key]

        def cell(field, fmt):
            v = [r[field] for r in group if r.get(field) is not None]
            return "n/a" if not v else f"{np.mean(v):{fmt}} ({min(v):{fmt}} - {max(v):{fmt}})"

        out.append({"sequence": key[0], "method": key[1], "seeds": str(len(group)),
                    "RPE 1 s m/s": cell("rpe1s_t", ".4f"), "RPE 1 s deg/s": cell("rpe1s_r", ".2f"),
                    "ATE m": cell("ate", ".4f"), "mask P": cell("mask_precision", ".3f"),
                    "mask R": cell("mask_recall", ".3f")})
    return out


def main(argv: Optional[Sequence[str]] = None) -> dict:
    a = parse_args(argv)
    argv_list = list(sys.argv[1:] if argv is None else argv)
    t_start = time.perf_counter()
    fig_dir = a.out.parent / a.out.stem
    rows: List[dict] = []
    figs: Dict[str, Dict[str, str]] = {}
    notes: List[str] = []
    jobs = sequence_jobs(a.sequences, a.augment, a.seed_list, a.frames, a.size, a.sensor, a.cache, a.augment_depth_time)
    for name, seed, make, camera in jobs:
        key = jax.random.key(seed)
        first = seed == a.seed_list[0]
        try:
            d = make()
        except common.datasets.DatasetError as e:   # e.g. ground truth that starts after the first frame
            common.log(f"{name}: skipped, cannot augment: {e}")
            if first:
                notes.append(f"* **{name}**: skipped, cannot augment: {e}")
            continue
        seq = TumSequence(d, camera=camera)   # an augmentation: the real sequence's preset
        frames = common.load_frames(seq)
        true = true_masks(d, seq)
        cover = float(np.mean([m.mean() for m in true]))
        runs = {}
        for method in a.methods:
            common.log(f"{name} (seed {seed}): {method} on {len(frames) - 1} pairs")
            r = run_one(seq, frames, true, method, key, a.policy_obj, a.config, a.poses)
            runs[method] = r
            ev = common.evaluate(seq, r["relative"])
            dr = end_drift(seq, trajectory.chain(r["relative"]))
            ts = common.timing_stats(r["seconds"])
            rows.append({"sequence": name, "seed": seed, "frames": len(frames), "method": method,
                         "moving_pct": 100 * cover,
                         **ev, "rpef_t_mm": None if ev["rpef_t"] is None else 1000 * ev["rpef_t"],
                         **dr, "drift_t_cm": None if dr["drift_t"] is None else 100 * dr["drift_t"],
                         "fps": ts["fps"], "median_ms": ts["median_ms"], "compile_s": r["compile_s"],
                         "inlier_ratio": float(np.mean(r["inlier_ratio"])),
                         "mask_precision": r["mask"]["precision"], "mask_recall": r["mask"]["recall"],
                         "mask_iou": r["mask"]["iou"], "mask_counts": {k: r["mask"][k] for k in "tp fp fn tn".split()},
                         "per_pair_trans_m": common.relative_errors(seq, r["relative"])["trans"]})
        if not first:
            continue
        figs[name] = figures(name, seq, runs, fig_dir, frames, true)
        dur = float(seq.timestamps[-1] - seq.timestamps[0])
        by = {r["method"]: r for r in rows if r["sequence"] == name and r["seed"] == seed}
        if name == "seq1" and by:
            notes.append("* **seq1** (camera fixed): drift of the last frame " + "; ".join(
                f"{m} {by[m]['drift_t_cm']:.1f} cm / {by[m]['drift_r']:.2f} deg" for m in by
                if by[m]["drift_t_cm"] is not None) + f" after {dur:.1f} s.")
        if name in ("seq2", "seq3") and by:
            gt = next(iter(by.values()))["gt_angle"]
            notes.append(f"* **{name}**: ground-truth rotation {gt:.2f} deg over {dur:.1f} s "
                         f"({gt / dur if dur > 0 else float('nan'):.2f} deg/s); estimated " + "; ".join(
                             f"{m} {by[m]['est_angle']:.2f} deg ({by[m]['est_angle'] / dur:.2f} deg/s, "
                             f"end error {by[m]['drift_r']:.2f} deg)" for m in by if by[m]["est_angle"] is not None)
                         + ".")

    # markdown
    lines = common.provenance_md(
        "Paper sequences (synthetic, exact ground truth): classic vs Huber vs RANSAC",
        __file__, argv_list,
        extra=(f"Synthetic sequences ({', '.join(a.sequences)}): {a.frames} frames each at {a.size}, 30 Hz, "
               f"seed {_seeds_text(a.seed_list)}, {'Kinect-like sensor effects' if a.sensor else 'exact renders'}, from "
               f"`jaxvo.synthetic.generate`. " if a.sequences else "")
              + (f"Dynamic augmentations ({', '.join(common.short_name(p) for p in a.augment)}): the real frames "
                 f"(at most {a.frames}) with 2 synthetic persons covering ~30 % of the image composited in "
                 f"(`jaxvo.synthetic.augment`, seed {_seeds_text(a.seed_list)}), the real ground truth and exact masks. "
                 if a.augment else "") + "Total wall time {WALL} s.")
    lines += ["RPE per frame: RMSE translational (mm/frame) and rotational (deg/frame) error of consecutive "
              "pairs; RPE 1 s: drift in m/s and deg/s (n/a when the run is shorter than 1 s); ATE: RMSE (m) "
              "after rigid alignment; drift: error of the last pose relative to the first (cm, deg); FPS "
              "after compilation (1000 / median ms per pair, this machine); mask P/R/IoU: moving mask "
              "(outliers not hidden by something in front in the current frame, plus the segmentation's "
              "dynamic pixels; jaxvo.pipelines.mapping.moving_mask) against the true moving-pixel mask, pooled over "
              "all pairs, over the pixels where the residuals are defined.", ""]
    cols = [("sequence", "sequence", "s")] + ([("seed", "seed", "d")] if len(a.seed_list) > 1 else []) + [
            ("frames", "frames", "d"), ("moving %", "moving_pct", ".1f"), ("method", "method", "s"),
            ("RPE mm/frame", "rpef_t_mm", ".2f"), ("RPE deg/frame", "rpef_r", ".3f"),
            ("RPE 1 s m/s", "rpe1s_t", ".4f"), ("RPE 1 s deg/s", "rpe1s_r", ".3f"), ("ATE m", "ate", ".4f"),
            ("drift cm", "drift_t_cm", ".2f"), ("drift deg", "drift_r", ".2f"), ("FPS", "fps", ".1f"),
            ("inlier ratio", "inlier_ratio", ".3f"), ("mask P", "mask_precision", ".3f"),
            ("mask R", "mask_recall", ".3f"), ("mask IoU", "mask_iou", ".3f")]
    lines += common.md_table(rows, cols) + [""]
    if len(a.seed_list) > 1:
        lines += [f"## Mean and range over the {len(a.seed_list)} seeds", "",
                  "Each cell: mean (min - max) over the seeds above; mask P / R pooled per seed.", ""]
        lines += common.md_table(seed_summary(rows), [(c, c, "s") for c in SUMMARY_COLUMNS]) + [""]
    lines += ["## What the paper reported", "", PAPER_NOTES, "", "## What jaxvo gets here", ""]
    lines += (notes or ["* (seq1 / seq2 not in this run)"]) + [""]
    if a.frames < 30:
        lines += [f"Only {a.frames} frames per sequence: a smoke run, too short to compare with the paper "
                  f"(the person barely moves and drift has no time to build up).", ""]
    lines += ["## Figures", ""]
    for name, f in figs.items():
        rel = {k: Path(v).relative_to(a.out.parent).as_posix() if Path(v).is_relative_to(a.out.parent) else v
               for k, v in f.items()}
        lines += [f"### {name}", ""] + [f"![{name} {k}]({v})" for k, v in rel.items()] + [""]
    wall = time.perf_counter() - t_start
    lines = [ln.replace("{WALL}", f"{wall:.0f}") for ln in lines]
    data = {"command": common.command_line(__file__, argv_list), "machine": common.machine_info(),
            "frames": a.frames, "size": a.size, "seed": a.seed, "seeds": a.seed_list, "sensor": a.sensor, "wall_s": wall,
            "rows": rows, "figures": figs, "paper": PAPER_NOTES}
    common.write_outputs(a.out, lines, data)
    common.log(f"wrote {a.out} ({wall:.0f} s)")
    return data


if __name__ == "__main__":
    main()
