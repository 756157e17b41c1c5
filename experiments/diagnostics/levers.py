"""What a change to the default odometry would buy in time and cost in accuracy, on whole sequences.

Each variant changes fields of ``Config`` (the estimator), ``TrackConfig`` (the policy) and/or
``SegmentParams`` (the segmentation) from the default, or reads the frames through a lens or with another depth scale (``--variants`` JSON:
name -> {"config": {...}, "policy": {...}, "segment": {...}, "lens": "bonn", [k1, k2, p1, p2, k3], "none" or
"folder", "depth_scale": 5155, "fr2", "recorded" or "folder"}, the lens as ``jaxvo run --lens``, the depth
scale as ``jaxvo run --depth-scale``, "folder" the published one of each sequence's name; without them
the reader's default, as ``jaxvo run`` reads the folder (a TUM fr1/fr2 or Bonn folder with its published
lens and depth correction; ``"lens": "none", "depth_scale": "recorded"``: the files as they are); the
first variant is the baseline). For each sequence (default: the Bonn crowd excerpt and TUM fr2/desk) and each seed,
every variant runs ``Odometry`` over the whole sequence (frames decoded into memory first, one
warm-up pass per variant to compile); the variants and OpenCV's RGB odometry over the same pairs
are timed in turn, pass by pass, so that other processes on the machine weigh on all alike.
Reported per variant and sequence: mean and median ms per frame, the ratio of the mean to
OpenCV's mean, estimates per frame, ATE and RPE over 1 s (mean and range over the seeds), held
frames. ``--perturb K`` runs each seed on K inputs: the frames as read and K - 1 draws of
sub-grey-level luminance noise (:func:`experiments.common.perturbed`), since a result on the Bonn
excerpt moves with such changes more than with the seed. The speed benchmark
(``experiments/speed.py``) says where the default's time goes; this script measures what a lever
found there would change.

Example::

    python -m experiments.diagnostics.levers --seeds 0,1,2
"""
from __future__ import annotations

import argparse
import json
import time
from typing import List, Optional

import numpy as np

from experiments import common
import jax  # noqa: E402

from jaxvo.camera import Lens, preset_for_sequence, lens_for_sequence  # noqa: E402
from jaxvo.config import Config, TrackConfig  # noqa: E402
from jaxvo.data.calibration import resolve_depth_scale  # noqa: E402
from jaxvo.tracking.odometry import Odometry  # noqa: E402
from jaxvo.tracking.segmentation import SegmentParams  # noqa: E402

DEFAULT_VARIANTS = json.dumps({
    "default": {},
    "single reference": {"policy": {"window": 1}},
    "no recovery": {"policy": {"recover": False}},
    "finest level 1": {"config": {"finest_level": 1}},
})


def parse_args(argv: Optional[List[str]] = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sequences", nargs="*", help="TUM-layout sequence folders (default: data_root()/bonn/"
                                                 "rgbd_bonn_crowd and data_root()/tum/rgbd_dataset_freiburg2_desk)")
    ap.add_argument("--variants", default=DEFAULT_VARIANTS,
                    help='JSON object: name -> {"config": {Config fields}, "policy": {TrackConfig fields}, '
                         '"segment": {SegmentParams fields, e.g. {"motion_gain": Infinity}}, "lens": '
                         '"folder", a preset or 5 numbers, "depth_scale": a number, a sensor or "folder"}; the '
                         "first is the baseline (default: %(default)s)")
    ap.add_argument("--seeds", default="0,1,2", help="comma-separated PRNG seeds (default 0,1,2)")
    ap.add_argument("--max-frames", type=int, default=None, help="at most N frames per sequence")
    ap.add_argument("--perturb", type=int, default=1,
                    help="inputs per seed: the frames as read, then K - 1 draws of +-0.25 grey-level luminance "
                         "noise (default 1: as read)")
    common.add_poses_arg(ap, both=True)
    ap.add_argument("--out", default=str(common.RESULTS / "levers" / "levers.md"), help="markdown output")
    return ap.parse_args(argv)


def parse_variants(text: str) -> dict:
    """name -> (Config, TrackConfig, Lens or "folder", depth scale: None, a number, a sensor or
    "folder", SegmentParams); a misspelt field or a bad value stops with the variant's name."""
    raw = common.json_variants(text, '{"config": ..., "policy": ..., "segment": ..., "lens": ..., "depth_scale": ...}')
    out = {}
    for name, spec in raw.items():
        if not isinstance(spec, dict) or set(spec) - {"config", "policy", "segment", "lens", "depth_scale"}:
            raise SystemExit(f"--variants: {name}: expected keys 'config', 'policy', 'segment', 'lens' and/or "
                             f"'depth_scale'")
        try:
            config = Config.from_dict(common.config_changes(json.dumps(spec.get("config", {}))))
            policy = TrackConfig(**spec.get("policy", {}))
            policy.validate()
            segment = SegmentParams(**spec.get("segment", {}))
            bad = [f for f, v in segment._asdict().items() if isinstance(v, bool) or not isinstance(v, (int, float))]
            if bad:
                raise ValueError(f"SegmentParams.{bad[0]} must be a number, got {getattr(segment, bad[0])!r}")
            lens = spec.get("lens")
            lens = lens if lens in (None, "folder") else Lens.parse(lens)
            scale = spec.get("depth_scale")
            if scale != "folder":
                resolve_depth_scale(scale, 1.0)
                if scale is not None and not (isinstance(scale, str) or float(scale) > 0):
                    raise ValueError(f"depth_scale must be a number > 0, a sensor or 'folder', got {scale!r}")
        except (TypeError, ValueError) as e:
            raise SystemExit(f"--variants: {name}: {e}")
        out[name] = (config, policy, lens, scale, segment)
    return out


def run_pass(seq, frames, config: Config, policy: TrackConfig, key, segment: Optional[SegmentParams] = None):
    """One pass of the odometry: (per-frame seconds of frames 1.., its Track, estimates, held)."""
    odo = Odometry(seq.camera, config, key, policy, segment_params=segment)
    # counts the estimates by purpose; each is blocked on, as the odometry reads each at once anyway
    odo.timings = {}
    secs = []
    for f in frames:
        t = time.perf_counter()
        odo.add(f)
        secs.append(time.perf_counter() - t)
    tr = odo.result()
    n_est = sum(len(v) for k, v in odo.timings.items() if k.startswith("estimate"))
    return np.asarray(secs[1:]), tr, n_est, int(np.sum(~tr.valid))


def main(argv=None):
    args = parse_args(argv)
    if args.perturb < 1:
        raise SystemExit(f"--perturb: expected an integer >= 1 (inputs per seed), got {args.perturb}")
    variants = parse_variants(args.variants)
    seeds = common.int_list(args.seeds)
    paths = args.sequences or common.default_sequences()
    rows = []
    for path in paths:
        seq = common.open_sequence(path, max_frames=args.max_frames)
        frames = common.load_frames(seq)
        common.log(f"[levers] {seq.name}: {len(frames)} frames")
        kinds = common.pose_kinds(args.poses)
        labels = {(name, kind): common.pose_label(name, kind, args.poses) for name in variants for kind in kinds}
        times = {label: [] for label in labels.values()}
        cv = [common.run_method("opencv-rgb", frames, seq.camera)["seconds"]]
        results = {label: [] for label in labels.values()}
        def reading(name):
            """(lens, depth scale) the variant reads the sequence with, "folder" resolved (None: the
            reader's default, the folder's sensor's)."""
            lens, scale = variants[name][2:4]
            return (lens_for_sequence(seq.name) if lens == "folder" else lens,
                    preset_for_sequence(seq.name) if scale == "folder" else scale)

        def frames_read(lens, scale):
            return frames if lens is None and scale is None else common.load_frames(
                common.open_sequence(path, max_frames=args.max_frames, depth_scale=scale, lens=lens))
        # each reading's frames as the reader gives them (undistorted after decoding, before any noise)
        seen = {(lens, scale): frames_read(lens, scale) for lens, scale in {reading(n) for n in variants}}
        for name, (config, policy, _, _, segment) in variants.items():   # warm-up: compile each variant
            run_pass(seq, seen[reading(name)][:3], config, policy, jax.random.key(seeds[0]), segment)
        for run, (seed, draw) in enumerate((s, d) for d in range(args.perturb) for s in seeds):
            inputs = {how: common.perturbed(fr, draw) for how, fr in seen.items()}
            order = list(variants) if run % 2 == 0 else list(variants)[::-1]
            for name in order:
                config, policy, _, _, segment = variants[name]
                secs, tr, n_est, held = run_pass(seq, inputs[reading(name)], config, policy, jax.random.key(seed),
                                                 segment)
                for kind in kinds:
                    label = labels[(name, kind)]
                    times[label].append(secs)
                    results[label].append({**common.evaluate(seq, common.track_relative(tr, kind)),
                                           "estimates": n_est / len(secs), "held": held})
                    common.log(f"  seed {seed} input {draw} {label}: {secs.mean() * 1000:.1f} ms/frame, "
                                f"ATE {results[label][-1]['ate']:.4f}")
            cv.append(common.run_method("opencv-rgb", frames, seq.camera, warmup=False)["seconds"])
        cv_mean = float(np.mean(np.concatenate(cv))) * 1000
        for name in results:
            st = common.timing_stats(np.concatenate(times[name]))
            res = results[name]

            def stat(k):
                v = [r[k] for r in res if r[k] is not None]
                return (float(np.mean(v)), float(np.min(v)), float(np.max(v))) if v else (None, None, None)
            ate, rpe = stat("ate"), stat("rpe1s_t")
            rows.append({"sequence": seq.name, "variant": name, "frames": len(frames), **st,
                         "ratio_opencv": st["mean_ms"] / cv_mean, "opencv_mean_ms": cv_mean,
                         "estimates": float(np.mean([r["estimates"] for r in res])),
                         "ate": ate[0], "ate_range": _range(ate), "rpe1s": rpe[0], "rpe1s_range": _range(rpe),
                         "held": float(np.mean([r["held"] for r in res]))})
    lines = common.provenance_md("Levers on the default odometry: time and accuracy, whole sequences", __file__, argv)
    lines += [f"Variants (fields changed from `Config()` / `TrackConfig()`): `{args.variants}`. Seeds "
              f"{args.seeds}, each on {args.perturb} input(s) (the frames as read"
              f"{', then draws of +-0.25 grey-level luminance noise' if args.perturb > 1 else ''}). "
              "Time: mean / median wall time of `Odometry.add` per frame over all seeds' passes, "
              "after a warm-up; `/ OpenCV`: the mean against OpenCV rgb's mean over the same pairs, timed "
              "between the passes. `estimates`: `estimate_motion` calls per frame. ATE, RPE 1 s: mean over the "
              "runs (seeds x inputs) [range], of the poses "
              f"{'refined in hindsight (Track.refined) and, in the rows named tracked, as tracked (Track.tracked)' if args.poses == 'both' else args.poses}"
              ".", ""]
    lines += common.md_table(rows, [("sequence", "sequence", ""), ("variant", "variant", ""),
                                    ("mean ms", "mean_ms", ".1f"), ("median ms", "median_ms", ".1f"),
                                    ("/ OpenCV", "ratio_opencv", ".2f"), ("estimates", "estimates", ".2f"),
                                    ("ATE m", "ate", ".4f"), ("ATE range", "ate_range", ""),
                                    ("RPE 1 s m/s", "rpe1s", ".4f"), ("RPE range", "rpe1s_range", ""),
                                    ("held", "held", ".1f")]) + [""]
    out = common.write_outputs(args.out, lines, {"command": common.command_line(__file__, argv),
                                                 "machine": common.machine_info(), "rows": rows})
    common.log(f"[levers] wrote {out}")
    return out


def _range(s) -> str:
    return "n/a" if s[0] is None else f"{s[1]:.4f}-{s[2]:.4f}"


if __name__ == "__main__":
    main()
