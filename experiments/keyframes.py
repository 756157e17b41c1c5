"""Frame-to-frame chaining vs keyframes (``jaxvo.TrackConfig``) on real sequences.

For each sequence and method it runs ``jaxvo.track`` twice, with the paper's
frame-to-frame chaining and with references up to ``--gap`` frames back, and
scores the trajectories against ground truth: RPE with a 1 s delta (m/s,
deg/s), RPE per frame, ATE, and how many frames failed (held their previous
pose). A "standing still" row (every relative motion the identity) shows what a
tracker that does nothing scores, which matters on a nearly still camera.

Writes ``keyframes.md`` and ``keyframes.json``.

Example::

    python experiments/keyframes.py                      # Bonn crowd and TUM fr2_desk
    python experiments/keyframes.py --max-frames 20 --out /tmp/kf.md
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common  # noqa: E402
import numpy as np  # noqa: E402

import jax  # noqa: E402
from jaxvo.odometry import Config, TrackConfig, track  # noqa: E402

DEFAULT_SEQUENCES = ("bonn/rgbd_bonn_crowd", "tum/rgbd_dataset_freiburg2_desk")


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("sequences", nargs="*", help="TUM-layout sequence folders (default: "
                    + ", ".join(f"data_root()/{s}" for s in DEFAULT_SEQUENCES) + ")")
    ap.add_argument("--methods", default="classic,huber,ransac", help="comma-separated jaxvo methods")
    ap.add_argument("--gap", type=int, default=8, help="keyframe max_gap (default 8; lag = gap // 2)")
    ap.add_argument("--max-frames", type=int, default=None, help="use at most N frames per sequence")
    ap.add_argument("--seed", type=int, default=0, help="PRNG key seed (default 0)")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results" / "keyframes.md"),
                    help="markdown output (JSON next to it)")
    return ap.parse_args(argv)


def _row(seq, name, policy_name, relative, valid=None, seconds=None):
    ev = common.evaluate(seq, relative)
    return {"sequence": seq.name, "method": name, "chaining": policy_name, **ev,
            "failures": None if valid is None else int(np.sum(~np.asarray(valid))),
            "ms_per_frame": seconds}


def main(argv=None) -> Path:
    args = parse_args(argv)
    paths = [Path(p) for p in args.sequences] or [common.datasets.data_root() / s for s in DEFAULT_SEQUENCES]
    paths = [p for p in paths if p.is_dir()]
    if not paths:
        raise SystemExit(common.missing_data_message())
    methods = common.parse_methods(args.methods)
    policies = {"frame to frame": TrackConfig.frame_to_frame(),
                f"keyframes {args.gap}": TrackConfig.keyframes(args.gap)}
    rows = []
    for path in paths:
        seq = common.open_sequence(path, args.max_frames)
        frames = common.load_frames(seq)
        rows.append(_row(seq, "standing still", "-", [np.eye(4)] * (len(frames) - 1)))
        for method in methods:
            if common.is_peer(method):
                continue
            for pname, policy in policies.items():
                t0 = time.perf_counter()
                tr = track(frames, seq.camera, Config(method=method), jax.random.key(args.seed), policy=policy)
                ms = 1000 * (time.perf_counter() - t0) / max(len(frames) - 1, 1)
                rows.append(_row(seq, method, pname, tr.relative, tr.valid, ms))
                r = rows[-1]
                common.log(f"{seq.name} {method} {pname}: RPE 1 s {common.fmt(r['rpe1s_t'])} m/s "
                           f"{common.fmt(r['rpe1s_r'], '.2f')} deg/s, ATE {common.fmt(r['ate'])} m, "
                           f"failures {r['failures']}")
    for r in rows:
        r["rpef_t_mm"] = None if r.get("rpef_t") is None else 1000 * r["rpef_t"]
    lines = common.provenance_md(
        "Frame to frame vs keyframes", "experiments/keyframes.py", argv,
        "RPE 1 s: translational (m/s) and rotational (deg/s) RMSE with a fixed 1 s delta; RPE 1 f: "
        "per frame (mm); ATE: RMSE after SE(3) alignment (m); failures: frames whose estimate failed "
        "and held the previous pose; ms/frame includes compilation on each method's first call.")
    lines += common.md_table(rows, [("sequence", "sequence", ""), ("method", "method", ""),
                                    ("chaining", "chaining", ""), ("RPE 1 s [m/s]", "rpe1s_t", ".4f"),
                                    ("RPE 1 s [deg/s]", "rpe1s_r", ".2f"), ("RPE 1 f [mm]", "rpef_t_mm", ".2f"),
                                    ("ATE [m]", "ate", ".4f"), ("failures", "failures", ""),
                                    ("ms/frame", "ms_per_frame", ".0f")])
    out = common.write_outputs(args.out, lines, {"rows": rows, "args": vars(args)})
    common.log(f"wrote {out}")
    return out


if __name__ == "__main__":
    main()
