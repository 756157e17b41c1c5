"""Where along a recording the default odometry's error accumulates, and what the segmentation
trusted there.

For each seed the default odometry (``jaxvo.track``, ``TrackConfig()``; ``--config`` / ``--policy``
change fields of ``Config`` / ``TrackConfig``) runs over the sequence (default: the Bonn crowd
excerpt). Its trajectory is cut into stretches of ``--stretch`` frames; for each, the error of the
stretch's relative pose (its first frame to its last) against the ground truth interpolated at the
frames (translation mm, rotation deg, as an RPE over the stretch), beside the ground truth's own
motion over it. Per frame: the error of its own estimate (``T_cur_ref`` against its reference,
against the ground truth's), the share of the reference's valid-depth pixels the segmentation
trusted as static for it (``TrackStep.static_mask``), the estimate's inlier ratio and whether the
frame was held. Reported: each stretch (mean over the seeds) with the mean static share and inlier
ratio of its frames and its held frames, what each stretch's error costs the whole trajectory (its ATE
and RPE 1 s with that stretch's relative motions replaced by the ground truth's), and the frames whose
own estimate erred most (each seed).

A stretch with a large error and a low static share is where people cover what the reference
could have been aligned on; one with a large error and a high share points at the estimator.

Example::

    python -m experiments.diagnostics.error_stretches --seeds 0,1,2
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import List, Optional, Sequence

import numpy as np

from experiments import common
import jax  # noqa: E402

from jaxvo import geometry  # noqa: E402
from jaxvo.config import Config, TrackConfig  # noqa: E402
from jaxvo.data import data_root  # noqa: E402
from jaxvo.tracking.odometry import track  # noqa: E402

OUT = Path(__file__).resolve().parents[1] / "results" / "error_stretches" / "error_stretches.md"


def parse_args(argv: Optional[List[str]] = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sequence", nargs="?", default=None,
                    help="TUM-layout sequence folder with ground truth (default: data_root()/bonn/rgbd_bonn_crowd)")
    ap.add_argument("--seeds", default="0", help="comma-separated PRNG seeds (default %(default)s)")
    ap.add_argument("--stretch", type=int, default=10, help="frames per stretch (default %(default)s)")
    ap.add_argument("--worst", type=int, default=10, help="frames listed whose own estimate erred most (default %(default)s)")
    ap.add_argument("--config", default=None, help="JSON object of Config fields to change")
    ap.add_argument("--policy", default=None, help="JSON object of TrackConfig fields to change")
    ap.add_argument("--quick", action="store_true", help="the first 12 frames, stretches of 4, for CI")
    ap.add_argument("--out", default=str(OUT), help="markdown output (json beside it; default %(default)s)")
    args = ap.parse_args(argv)
    try:
        args.seed_list = common.int_list(args.seeds)
    except ValueError as e:
        ap.error(f"--seeds: {e}")
    if args.stretch < 1 or args.worst < 0:
        ap.error(f"--stretch must be >= 1 and --worst >= 0, got {args.stretch} and {args.worst}")
    try:
        args.config_obj = Config.from_dict(common.config_changes(args.config))
        args.policy_obj = TrackConfig.from_json(common.json_variants(args.policy, "TrackConfig field values",
                                                                     "--policy")) if args.policy else TrackConfig()
    except (TypeError, ValueError) as e:
        ap.error(f"--config / --policy: {e}")
    return args


def stretch_errors(poses: np.ndarray, G: np.ndarray, length: int) -> List[dict]:
    """Per stretch of ``length`` frames (the last one may be shorter; the next stretch starts at
    its last frame): ``first``, ``last`` (frame indices), ``err_mm`` / ``err_deg`` (the error of
    the estimated relative pose ``inv(P_first) P_last`` against the ground truth's
    ``inv(G_first) G_last``) and ``gt_mm`` / ``gt_deg`` (the ground truth's motion over it).
    poses, G: (N, 4, 4) T_world_cam of the same frames."""
    rows = []
    n = len(poses)
    for a in range(0, n - 1, length):
        b = min(a + length, n - 1)
        gt = geometry.inverse(G[a]) @ G[b]
        t, r = common.pose_error(geometry.inverse(poses[a]) @ poses[b], gt)
        rows.append({"first": a, "last": b, "err_mm": 1000 * t, "err_deg": r,
                     "gt_mm": 1000 * float(np.linalg.norm(gt[:3, 3])),
                     "gt_deg": float(np.degrees(geometry.rotation_angle(gt[:3, :3])))})
    return rows


def stretch_costs(seq, poses: np.ndarray, G: np.ndarray, stretches: List[dict]) -> List[dict]:
    """What each stretch's error costs the whole trajectory: per stretch, the trajectory's ATE (m) and
    RPE 1 s (m/s; None where the frames span under a second) as :func:`experiments.common.evaluate`
    scores it, with that stretch's consecutive relative motions replaced by the ground truth's and
    the others as estimated. The first row (``first`` None) is the trajectory as estimated.
    poses, G: (N, 4, 4) T_world_cam of ``seq``'s frames."""
    rel = geometry.consecutive_motions(poses)
    exact = geometry.consecutive_motions(G)
    rows = []
    for row in [{"first": None, "last": None}] + stretches:
        r = rel.copy()
        if row["first"] is not None:
            r[row["first"]:row["last"]] = exact[row["first"]:row["last"]]
        m = common.evaluate(seq, r)
        rows.append({"first": row["first"], "last": row["last"], "ate": m["ate"], "rpe1s": m["rpe1s_t"]})
    return rows


def frame_rows(steps, G: np.ndarray, depths) -> List[dict]:
    """Per tracked frame (``TrackStep`` of frames >= 1): its reference, the error of its own estimate
    against the ground truth's ``inv(G_frame) G_reference`` (mm, deg), the share of the reference's
    valid-depth pixels its static mask trusted, the inlier ratio, and whether it was held.
    depths: (H, W) depth of each frame (metres; 0 = invalid)."""
    rows = []
    for s in steps:
        est, r = s.estimate, s.reference
        t, deg = common.pose_error(np.asarray(est.T_cur_ref, np.float64), geometry.inverse(G[s.frame]) @ G[r])
        valid = np.asarray(depths[r]) > 0
        static = np.asarray(s.static_mask)
        rows.append({"frame": s.frame, "reference": r, "est_mm": 1000 * t, "est_deg": deg,
                     "static": float(static[valid].mean()) if valid.any() else float("nan"),
                     "inliers": float(est.inlier_ratio), "held": not s.valid})
    return rows


def main(argv: Optional[Sequence[str]] = None) -> dict:
    args = parse_args(None if argv is None else list(argv))
    folder = Path(args.sequence) if args.sequence else data_root() / "bonn" / "rgbd_bonn_crowd"
    if not folder.is_dir():
        raise SystemExit(f"{folder}: no such sequence folder ({common.missing_data_message()})")
    t0 = time.time()
    seq = common.open_sequence(folder, max_frames=12 if args.quick else None)
    ok, G = seq.groundtruth_at_frames() or (None, None)
    if G is None or not np.all(ok):
        raise SystemExit(f"{folder}: the ground truth must cover every frame")
    frames = common.load_frames(seq)
    length = 4 if args.quick else args.stretch
    per_seed, worst, costs = [], [], []
    for seed in args.seed_list:
        common.log(f"[error_stretches] {seq.name} seed {seed}")
        steps = []
        result = track(frames, seq.camera, args.config_obj, key=jax.random.key(seed), policy=args.policy_obj,
                       callback=steps.append)
        poses = np.asarray(result.poses, np.float64)
        stretches = stretch_errors(poses, G, length)
        costs.append(stretch_costs(seq, poses, G, stretches))
        fr = frame_rows(steps, G, [f.depth for f in frames])
        for row in stretches:
            inside = [f for f in fr if row["first"] < f["frame"] <= row["last"]]
            row.update(static=float(np.mean([f["static"] for f in inside])),
                       inliers=float(np.mean([f["inliers"] for f in inside])),
                       held=sum(f["held"] for f in inside),
                       references=len({f["reference"] for f in inside}))
        per_seed.append(stretches)
        worst += [dict(f, seed=seed) for f in sorted(fr, key=lambda f: -f["est_mm"])[:args.worst]]
    keys = ("err_mm", "err_deg", "static", "inliers", "held", "references")
    rows = [dict(per_seed[0][i], **{k: float(np.mean([s[i][k] for s in per_seed])) for k in keys})
            for i in range(len(per_seed[0]))]
    lines = common.provenance_md("Where the default odometry's error accumulates", "experiments/diagnostics/error_stretches.py",
                                 argv)
    lines += [f"Sequence `{seq.name}`, {len(frames)} frames; seeds {args.seeds}"
              + (f"; Config fields changed: `{args.config}`" if args.config else "")
              + (f"; TrackConfig fields changed: `{args.policy}`" if args.policy else "")
              + f". Total wall time {time.time() - t0:.0f} s.", "",
              f"## Stretches of {length} frames", "",
              "*error*: of the stretch's relative pose (first to last frame) against the ground truth's, "
              "mean over the seeds; *GT motion*: the ground truth's over the stretch; *static share*: of the "
              "references' valid-depth pixels the segmentation trusted, mean over the stretch's frames; "
              "*held* and *references*: per stretch, mean over the seeds.", ""]
    lines += common.md_table(rows, [("frames", "first", "d"), ("to", "last", "d"), ("error [mm]", "err_mm", ".1f"),
                                    ("error [deg]", "err_deg", ".2f"), ("GT motion [mm]", "gt_mm", ".1f"),
                                    ("GT motion [deg]", "gt_deg", ".2f"), ("static share", "static", ".2f"),
                                    ("inlier ratio", "inliers", ".2f"), ("held", "held", ".1f"),
                                    ("references", "references", ".1f")])
    def mean(key, i):
        values = [c[i][key] for c in costs]
        return None if any(v is None for v in values) else float(np.mean(values))

    cost_rows = [{"stretch": "none (as estimated)" if c["first"] is None else f"{c['first']}-{c['last']}",
                  "ate": mean("ate", i), "rpe1s": mean("rpe1s", i)} for i, c in enumerate(costs[0])]
    lines += ["", "## What each stretch costs the trajectory", "",
              "The whole trajectory's ATE and RPE 1 s (translation) with one stretch's consecutive relative "
              "motions replaced by the ground truth's, the rest as estimated, mean over the seeds: where the "
              "trajectory's error would go if that stretch were tracked exactly. The first row is the "
              "trajectory as estimated.", ""]
    lines += common.md_table(cost_rows, [("exact stretch", "stretch", ""), ("ATE [m]", "ate", ".4f"),
                                         ("RPE 1 s [m/s]", "rpe1s", ".4f")])
    lines += ["", f"## The {args.worst} frames per seed whose own estimate erred most", "",
              "The error of the frame's estimate against its reference (`T_cur_ref`), against the ground "
              "truth's relative pose of the two frames.", ""]
    lines += common.md_table(worst, [("seed", "seed", "d"), ("frame", "frame", "d"), ("reference", "reference", "d"),
                                     ("error [mm]", "est_mm", ".1f"), ("error [deg]", "est_deg", ".2f"),
                                     ("static share", "static", ".2f"), ("inlier ratio", "inliers", ".2f"),
                                     ("held", "held", "")])
    data = {"args": {k: v for k, v in vars(args).items() if not k.endswith("_obj")}, "stretches": rows,
            "per_seed": per_seed, "worst": worst, "costs": cost_rows, "costs_per_seed": costs}
    out = common.write_outputs(args.out, lines, data)
    common.log(f"[error_stretches] wrote {out}")
    return data


if __name__ == "__main__":
    main()
