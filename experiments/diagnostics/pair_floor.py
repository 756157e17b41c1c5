"""How close each estimator comes to the ground truth on single frame pairs, and how close the
ground truth itself can tell: the per-pair floor under the RPE of a recording.

For each stretch of a recording (default: the Bonn crowd excerpt's empty room, frames 0-24, and
its people, frames 25-159; TUM fr2/desk, all 50 frames), every consecutive pair is estimated by
each method alone (``estimate_motion`` with ``Config(method=...)``, the key of pair k
``fold_in(key(0), k)``; the peers as ``jaxvo.evaluation.peers`` run them), and the default odometry
(``jaxvo.track`` with ``TrackConfig()``) runs over the stretch, whose consecutive relative poses are
what its RPE is made of; ``--config`` changes ``Config`` fields of both. Each pair's T_cur_ref is compared with the ground truth interpolated at the
two frames' stamps (as ``jaxvo eval``): the translational error |t| (mm) and rotational error (deg)
of ``inv(T_gt) @ T_est``, RMSE over the stretch.

The ground truth's own orientation noise: a motion-capture marker body's orientation jitters from
sample to sample where its position hardly does. Reported per recording: the RMS change of the
relative rotation between consecutive ground-truth samples (the rotation's second difference,
deg; for a smooth hand-held motion it is far below the rotation per sample), raw and with each
sample's orientation replaced by the chordal mean of the orientations of the k samples on either
side, k = ``--smooth`` seconds times the ground truth's rate (positions unchanged). The rotational
error is given against both: against the smoothed ground truth it is the estimator's own, as far
as the smoothing removes the ground truth's noise and keeps the motion.

Example::

    python -m experiments.diagnostics.pair_floor
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Dict, List, Optional

import numpy as np

from experiments import common
import jax  # noqa: E402

from jaxvo import geometry  # noqa: E402
from jaxvo.config import METHODS, Config  # noqa: E402
from jaxvo.data import data_root  # noqa: E402
from jaxvo.data.stamps import interpolate_poses  # noqa: E402
from jaxvo.evaluation.metrics import summarize  # noqa: E402
from jaxvo.tracking.odometry import track  # noqa: E402

DEFAULT_STRETCHES = json.dumps({
    "Bonn crowd, empty room": ["bonn/rgbd_bonn_crowd", 0, 25],
    "Bonn crowd, people": ["bonn/rgbd_bonn_crowd", 25, 160],
    "fr2/desk": ["tum/rgbd_dataset_freiburg2_desk", 0, 50],
})


def parse_args(argv: Optional[List[str]] = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stretches", default=DEFAULT_STRETCHES,
                    help='JSON object: name -> [sequence folder (absolute, or under the data root), first frame, '
                         'end frame (exclusive)] (default: %(default)s)')
    ap.add_argument("--methods", default="classic,huber,ransac,default,peers",
                    help="comma list: jaxvo methods, 'default' (the default odometry), peer names, 'peers' = "
                         "every available peer (default: %(default)s)")
    ap.add_argument("--config", default=None,
                    help="JSON object of jaxvo.Config fields applied to the jaxvo methods and the default odometry "
                         "(e.g. '{\"terms\": \"rgbd\"}')")
    ap.add_argument("--smooth", type=float, default=0.1,
                    help="seconds either side of a ground-truth sample whose orientations are averaged into "
                         "its own (default 0.1)")
    ap.add_argument("--quick", action="store_true", help="4 pairs per stretch (for tests)")
    ap.add_argument("--out", default=str(common.RESULTS / "pair_floor" / "pair_floor.md"), help="markdown output")
    return ap.parse_args(argv)


def parse_stretches(text: str) -> Dict[str, tuple]:
    """name -> (folder Path, first frame, end frame); a bad entry stops with its name."""
    raw = common.json_variants(text, '["folder", first, end]', "--stretches")
    out = {}
    for name, spec in raw.items():
        ok = isinstance(spec, list) and len(spec) == 3 and isinstance(spec[0], str) \
            and all(isinstance(x, int) for x in spec[1:]) and 0 <= spec[1] < spec[2] - 1
        if not ok:
            raise SystemExit(f"--stretches: {name}: expected [folder, first, end] with 0 <= first < end - 1, "
                             f"got {spec!r}")
        folder = Path(spec[0]) if Path(spec[0]).is_absolute() else data_root() / spec[0]
        if not folder.is_dir():
            raise SystemExit(f"--stretches: {name}: no folder {folder} (set JAXVO_DATA or give an absolute path)")
        out[name] = (folder, spec[1], spec[2])
    return out


def parse_method_list(text: str) -> List[str]:
    toks = [t.strip() for t in text.split(",") if t.strip()]
    rest = ",".join(t for t in toks if t != "default")
    return (["default"] if "default" in toks else []) + (common.parse_methods(rest) if rest else [])


def smoothed_orientations(t: np.ndarray, T: np.ndarray, seconds: float) -> np.ndarray:
    """Poses (N, 4, 4) at stamps t (N,) with each orientation the chordal mean (the rotation
    nearest the mean matrix) of the orientations of the k samples on either side, k =
    round(seconds x the median sample rate), fewer at the ends; positions as given. For a
    constant angular velocity the mean of a symmetric window is the sample's own orientation."""
    k = max(1, int(round(seconds / float(np.median(np.diff(t))))))
    out = np.array(T, np.float64, copy=True)
    n = len(T)
    for i in range(n):
        w = min(k, i, n - 1 - i)   # symmetric at the ends too
        out[i, :3, :3] = geometry.project_to_so3(np.mean(T[i - w:i + w + 1, :3, :3], axis=0))
    return out


def rotation_jerk(T: np.ndarray) -> float:
    """RMS angle (deg) between consecutive relative rotations R_i^T R_{i+1} of poses (N, 4, 4)."""
    R = T[:, :3, :3]
    rel = np.einsum("nji,njk->nik", R[:-1], R[1:])
    step = np.einsum("nji,njk->nik", rel[:-1], rel[1:])
    ang = [np.degrees(geometry.rotation_angle(S)) for S in step]
    return float(np.sqrt(np.mean(np.square(ang)))) if ang else float("nan")


def pair_errors(relative: np.ndarray, G: np.ndarray) -> Dict[str, np.ndarray]:
    """Per consecutive pair k: translational (m) and rotational (deg) error of relative[k]
    (T_cur_ref of frames k, k + 1) against the ground truth poses G (N, 4, 4), and the
    ground truth's own motion (|t| m, angle deg)."""
    out = {k: np.zeros(len(relative)) for k in ("trans", "rot", "gt_trans", "gt_rot")}
    for k, T in enumerate(relative):
        gt = geometry.inverse(G[k + 1]) @ G[k]
        out["trans"][k], out["rot"][k] = common.pose_error(T, gt)
        out["gt_trans"][k] = np.linalg.norm(gt[:3, 3])
        out["gt_rot"][k] = np.degrees(geometry.rotation_angle(gt[:3, :3]))
    return out


def run_stretch(name: str, folder, first: int, end: int, methods: List[str], smooth: float, quick: bool,
                config: Config) -> dict:
    n = 5 if quick else end - first
    seq = common.open_sequence(folder, max_frames=n, start=first)
    gt = seq.groundtruth
    if gt is None:
        raise SystemExit(f"{folder}: no ground truth")
    t, T = gt
    tol = seq.max_dt
    G = interpolate_poses(t, T, seq.timestamps, tol=tol)
    G_smooth = interpolate_poses(t, smoothed_orientations(t, T, smooth), seq.timestamps, tol=tol)
    frames = common.load_frames(seq)
    common.log(f"[pair_floor] {name}: {seq.name} frames {first}..{first + len(frames) - 1}")
    rows = []
    for m in methods:
        if m == "default":
            relative = track(frames, seq.camera, config, key=jax.random.key(0)).relative
        elif m in METHODS or common.peer_available(m):
            relative = common.run_method(m, frames, seq.camera, config, key=jax.random.key(0), warmup=False)["relative"]
        else:
            common.log(f"[pair_floor] {m}: not installed here, left out")
            continue
        e, s = pair_errors(relative, G), pair_errors(relative, G_smooth)
        rows.append({"stretch": name, "method": "default odometry" if m == "default" else m, "pairs": len(relative),
                     "trans_mm": 1000 * summarize(e["trans"]).rmse, "rot_deg": summarize(e["rot"]).rmse,
                     "rot_smooth_deg": summarize(s["rot"]).rmse,
                     "gt_trans_mm": 1000 * float(np.mean(e["gt_trans"])), "gt_rot_deg": float(np.mean(e["gt_rot"])),
                     "gt_rot_smooth_deg": float(np.mean(s["gt_rot"]))})
    span = (t >= seq.timestamps[0] - 1.0) & (t <= seq.timestamps[-1] + 1.0)   # the samples around the stretch
    gt_row = {"stretch": name, "samples": int(span.sum()), "rate_hz": float(1.0 / np.median(np.diff(t))),
              "jerk_deg": rotation_jerk(T[span]), "jerk_smooth_deg": rotation_jerk(smoothed_orientations(t, T, smooth)[span])}
    return {"rows": rows, "gt": gt_row}


def main(argv=None) -> None:
    args = parse_args(argv)
    stretches = parse_stretches(args.stretches)
    methods = parse_method_list(args.methods)
    if not args.smooth > 0:
        raise SystemExit(f"--smooth: expected seconds > 0, got {args.smooth}")
    try:
        config = Config.from_dict(common.config_changes(args.config))
    except ValueError as e:
        raise SystemExit(f"--config: {e}")
    t0 = time.time()
    results = [run_stretch(name, *spec, methods, args.smooth, args.quick, config) for name, spec in stretches.items()]
    rows = [r for res in results for r in res["rows"]]
    gts = [res["gt"] for res in results]
    lines = common.provenance_md("Per-pair accuracy and the ground truth's orientation noise",
                                 "experiments/diagnostics/pair_floor.py", argv)
    if args.config:
        lines += [f"Config fields changed from the default: `{args.config}`.", ""]
    lines += ["Each consecutive pair of a stretch, estimated alone (the default odometry: its track over the "
              "stretch); RMSE over the pairs of the error against the ground truth interpolated at the frames, "
              f"and the rotational error against the ground truth with each orientation averaged over "
              f"{args.smooth:g} s either side. *GT motion*: mean per pair. Total wall time "
              f"{time.time() - t0:.0f} s.", ""]
    lines += common.md_table(rows, [("stretch", "stretch", ""), ("method", "method", ""), ("pairs", "pairs", "d"),
                                    ("GT motion [mm]", "gt_trans_mm", ".1f"), ("GT motion [deg]", "gt_rot_deg", ".3f"),
                                    ("GT motion, smoothed [deg]", "gt_rot_smooth_deg", ".3f"),
                                    ("error [mm]", "trans_mm", ".1f"), ("error [deg]", "rot_deg", ".3f"),
                                    ("error vs smoothed GT [deg]", "rot_smooth_deg", ".3f")])
    lines += ["", "The ground truth's orientation from sample to sample: RMS change of the relative rotation "
                  "between consecutive samples (the samples within 1 s of the stretch).", ""]
    lines += common.md_table(gts, [("stretch", "stretch", ""), ("GT rate [Hz]", "rate_hz", ".0f"),
                                   ("samples", "samples", "d"), ("raw [deg]", "jerk_deg", ".3f"),
                                   ("smoothed [deg]", "jerk_smooth_deg", ".3f")])
    out = common.write_outputs(args.out, lines, {"args": vars(args), "rows": rows, "ground_truth": gts})
    common.log(f"[pair_floor] wrote {out}")


if __name__ == "__main__":
    main()
