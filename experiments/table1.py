"""The paper's Table I protocol on every available sequence, jaxvo methods and peers side by side.

For each sequence (default: every folder under ``data_root()/tum`` and
``data_root()/bonn``, or the folders given as arguments) and for the dynamic
augmentations of the real TUM sequences (``jaxvo.synthetic.augment``, generated
into a cache folder), every method runs on the identical decoded frames with the
same intrinsics and the same 4 m depth cut-off, and is evaluated the same way:

* translational RPE (m/s, RMSE, fixed 1 s delta) where ground truth covers >= 1 s;
* per-frame RPE (delta = 1 frame, m/frame and deg/frame, RMSE) always;
* rotational RPE (deg/s over 1 s, deg/frame) and ATE (m, RMSE after rigid alignment);

with the paper's published translational RPE in an adjacent column where the
sequence is one of the paper's. Writes ``table1.md`` and ``table1.json``.

Example::

    python experiments/table1.py                       # everything found, all methods and peers
    python experiments/table1.py --quick               # 3 frames, classic + OpenCV rgb (CI)
    python experiments/table1.py path/to/rgbd_dataset_freiburg1_xyz --max-frames 300
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import common
import numpy as np  # noqa: E402

import jax  # noqa: E402
from jaxvo.camera import LENSES, Lens, preset_for_sequence  # noqa: E402
from jaxvo.config import Config  # noqa: E402
from jaxvo.data.calibration import parse_depth_scale  # noqa: E402

DEFAULT_METHODS = "classic,huber,ransac,opencv-rgb,opencv-rgbd,open3d-color,open3d-hybrid"


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("sequences", nargs="*", help="TUM-layout sequence folders (default: data_root()/tum/* "
                                                 "and data_root()/bonn/*)")
    ap.add_argument("--methods", default=DEFAULT_METHODS,
                    help="comma list of jaxvo methods and peers; 'peers' = all available peers, 'all' = "
                         f"everything (default {DEFAULT_METHODS}; unavailable peers are skipped)")
    ap.add_argument("--max-frames", type=int, default=None, help="use at most N frames per sequence")
    ap.add_argument("--depth-scale", default=None,
                    help="read the real sequences' depth at this scale (as jaxvo run --depth-scale: a number, "
                         "fr1 / fr2 for TUM's published depth correction, 'recorded' for the layout's as it is), or "
                         "'folder': each sequence's published correction (jaxvo.camera.DEPTH_CORRECTIONS); default "
                         "the reader's (the folder's sensor's)")
    ap.add_argument("--lens", default=None,
                    help="read the real sequences through this lens (as jaxvo run --lens: 5 numbers, fr1 / fr2 / "
                         "bonn, or 'none' for the images as they are); default the reader's (the folder's sensor's)")
    ap.add_argument("--no-augment", action="store_true", help="skip the dynamic augmentations")
    ap.add_argument("--persons", type=int, default=2, help="augmentation: moving occluders (default 2)")
    ap.add_argument("--coverage", type=float, default=0.3, help="augmentation: image coverage (default 0.3)")
    ap.add_argument("--seed", type=int, default=0, help="augmentation seed and PRNG key (default 0)")
    ap.add_argument("--cache", default=None, help=f"folder for generated augmentations (default {common.CACHE})")
    ap.add_argument("--quick", action="store_true",
                    help="tiny run for CI: 3 frames, first sequence only, methods classic,opencv-rgb "
                         "unless --methods is given")
    ap.add_argument("--out", default=str(common.RESULTS / "table1" / "table1.md"), help="markdown output (json beside it)")
    args = ap.parse_args(argv)
    if args.quick:
        args.max_frames = args.max_frames or 3
        if args.methods == DEFAULT_METHODS:
            args.methods = "classic,opencv-rgb"
    return args


def run_sequence(path: Path, methods, args, kind: str):
    scale = lens = None
    if kind == "real" and args.depth_scale is not None:
        scale = preset_for_sequence(path.name) if args.depth_scale == "folder" else parse_depth_scale(args.depth_scale)
    if kind == "real" and args.lens is not None:
        lens = Lens.parse(args.lens)
    seq = common.open_sequence(path, max_frames=args.max_frames, depth_scale=scale, lens=lens)
    common.log(f"[table1] {seq.name}: {len(seq)} frames, {kind}")
    frames = common.load_frames(seq)
    span = float(seq.timestamps[-1] - seq.timestamps[0])
    rows = []
    for m in methods:
        t0 = time.perf_counter()
        res = common.run_method(m, frames, seq.camera, Config(), jax.random.key(args.seed))
        ev = common.evaluate(seq, res["relative"])
        pe = common.relative_errors(seq, res["relative"])
        st = common.timing_stats(res["seconds"])
        row = {"sequence": seq.name, "kind": kind, "frames": len(seq), "span_s": span, "method": m,
               "depth_scale": seq.depth_scale, "lens": "none" if seq.lens.is_pinhole else seq.sensor if seq.lens == LENSES.get(seq.sensor) else "given",
               "paper_rpe1s_t": common.paper_rpe(path) if m == "ransac" else None,
               "median_ms": st["median_ms"], "pair_t_median_mm": _nanmed(pe["trans"]) * 1000.0,
               "pair_r_median_deg": _nanmed(pe["rot"]), "failures": int(np.sum(~res["valid"])),
               "mean_inlier_ratio": float(np.nanmean(res["inlier_ratio"])) if not common.is_peer(m) else None,
               "wall_s": time.perf_counter() - t0, **ev}
        rows.append(row)
        common.log(f"  {m:14s} rpe_f {common.fmt(ev['rpef_t'], '.5f')} m/frame  rpe_1s "
                   f"{common.fmt(ev['rpe1s_t'], '.4f')} m/s  ate {common.fmt(ev['ate'], '.4f')} m  "
                   f"{st['median_ms']:.1f} ms/pair")
    return rows


def _nanmed(x) -> float:
    x = np.asarray(x, float)
    return float(np.nanmedian(x)) if np.isfinite(x).any() else float("nan")


COLUMNS = [
    ("sequence", "sequence", ""), ("frames", "frames", "d"), ("depth scale", "depth_scale", "g"), ("lens", "lens", ""),
    ("method", "method", ""),
    ("RPE-t 1 s (m/s)", "rpe1s_t", ".4f"), ("paper RANSAC RPE-t 1 s (m/s)", "paper_rpe1s_t", ".4f"),
    ("RPE-r 1 s (deg/s)", "rpe1s_r", ".3f"),
    ("RPE-t per frame (mm)", lambda r: None if r["rpef_t"] is None else 1000 * r["rpef_t"], ".2f"),
    ("RPE-r per frame (deg)", "rpef_r", ".3f"), ("ATE (m)", "ate", ".4f"),
    ("failed pairs", "failures", "d"), ("ms/pair", "median_ms", ".1f"),
]


def main(argv=None) -> Path:
    args = parse_args(argv)
    methods = common.parse_methods(args.methods)
    skipped = [m for m in methods if common.is_peer(m) and not common.peer_available(m)]
    methods = [m for m in methods if m not in skipped]
    seqs = [Path(s) for s in args.sequences] or common.default_sequences()
    if not seqs:
        raise SystemExit(common.missing_data_message())
    if args.quick and not args.sequences:
        seqs = seqs[:1]
    rows = []
    for p in seqs:
        rows += run_sequence(p, methods, args, "real")
    augmented, not_augmented = [], []
    if not args.no_augment:
        for p in seqs:
            if common.datasets.is_bonn_sequence(p) or "_aug_" in p.name or not (p / "groundtruth.txt").is_file():
                continue  # Bonn is dynamic already; augment needs TUM ground truth
            common.log(f"[table1] augmenting {p.name} ({args.persons} persons, coverage {args.coverage})")
            try:
                aug = common.augmented_sequence(p, args.persons, args.coverage, args.seed, args.max_frames,
                                                args.cache)
            except common.datasets.DatasetError as e:   # e.g. ground truth that starts after the first frame
                common.log(f"[table1] {p.name}: skipped, cannot augment: {e}")
                not_augmented.append(f"{p.name} (cannot augment: {e})")
                continue
            augmented.append(aug)
            rows += run_sequence(aug, methods, args, "augmented")

    lines = common.provenance_md("Table I: accuracy on real and dynamically augmented sequences", __file__, argv)
    lines += [
        "Protocol (as the paper's Table I): each method runs on the identical decoded frames, intrinsics "
        "(the dataset's published preset) and 4 m depth cut-off; consecutive frame pairs; the chained "
        "trajectory is evaluated against the ground truth interpolated at the frame timestamps. "
        "RPE-t 1 s: translational relative pose error, RMSE over all pairs 1 s apart (m/s), only where "
        "the ground-truth-covered span is >= 1 s (n/a otherwise). Per-frame RPE: delta = 1 frame, RMSE. "
        "ATE: RMSE after rigid (no scale) alignment. The paper's column is its published translational "
        "RPE (m/s) for its RANSAC method on the full sequence; ours may use an excerpt "
        "(frames column), so the comparison is only indicative where the excerpt is short.",
        "",
        f"Methods: {', '.join(methods)}." + (f" Not available here (skipped): {', '.join(skipped)}." if skipped else ""),
        f"Augmentations: `jaxvo.synthetic.augment` with {args.persons} persons, coverage {args.coverage}, "
        f"seed {args.seed}, cached in `{args.cache or common.CACHE}`." if augmented else "Augmentations: none.",
    ]
    if not_augmented:
        lines += [f"Not augmented: {'; '.join(not_augmented)}."]
    lines += [
        "",
    ]
    for kind, title in (("real", "Real sequences"), ("augmented", "Dynamic augmentations of the real sequences")):
        sub = [r for r in rows if r["kind"] == kind]
        if not sub:
            continue
        lines += [f"## {title}", ""] + common.md_table(sub, COLUMNS) + [""]
    lines += _verdict(rows, methods)
    out = common.write_outputs(args.out, lines, {"command": common.command_line(__file__, argv),
                                                 "machine": common.machine_info(), "rows": rows,
                                                 "methods": methods, "skipped": skipped,
                                                 "not_augmented": not_augmented})
    common.log(f"[table1] wrote {out} and {out.with_suffix('.json')}")
    return out


def _verdict(rows, methods):
    """Plain comparison: ransac against the best peer per sequence (per-frame RPE-t)."""
    if "ransac" not in methods:
        return []
    out = ["## RANSAC against the peers (per-frame translational RPE, lower is better)", ""]
    for seqname in dict.fromkeys(r["sequence"] for r in rows):
        sr = {r["method"]: r for r in rows if r["sequence"] == seqname}
        ours = sr.get("ransac", {}).get("rpef_t")
        cmp = [(m, r["rpef_t"]) for m, r in sr.items() if common.is_peer(m) and r["rpef_t"] is not None]
        if ours is None or not cmp:
            continue
        parts = [f"{m} {1000 * v:.2f} mm ({ours / v:.2f}x)" for m, v in cmp]
        out.append(f"- {seqname}: ransac {1000 * ours:.2f} mm/frame; ratio ransac/peer: " + "; ".join(parts))
    return out + [""]


if __name__ == "__main__":
    main()
