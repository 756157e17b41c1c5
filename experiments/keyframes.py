"""Frame-to-frame chaining vs keyframes (``jaxvo.TrackConfig``) on real sequences, per keyframe gap.

For each sequence, method and keyframe gap (``max_gap``; ``lag = gap // 2``; gap 1 is
the paper's frame-to-frame chaining) it runs ``jaxvo.track`` and scores the
trajectory against ground truth: RPE with a 1 s delta (m/s, deg/s), RPE per frame,
ATE, and how many frames failed (held their previous pose). ``ransac`` runs once per
seed; ``classic`` and ``huber`` draw no random numbers and run once. A "standing
still" row (every relative motion the identity) shows what a tracker that does nothing
scores, which matters on a nearly still camera.

A second table compares the methods under the *same* policy: for every gap, ransac
(mean and range over the seeds) against classic, and their ratio.

Writes ``keyframes.md`` and ``keyframes.json``.

Example::

    python experiments/keyframes.py                      # Bonn crowd and TUM fr2_desk
    python experiments/keyframes.py --gaps 1,6,default --seeds 0,1,2 --methods classic,ransac
    python experiments/keyframes.py --max-frames 20 --out /tmp/kf.md
    python experiments/keyframes.py --gaps default --methods ransac --policy '{"fuse": false}'
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import common
import numpy as np  # noqa: E402

import jax  # noqa: E402
from jaxvo.config import Config, TrackConfig
from jaxvo.tracking.odometry import track  # noqa: E402

DEFAULT_SEQUENCES = ("bonn/rgbd_bonn_crowd", "tum/rgbd_dataset_freiburg2_desk")


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("sequences", nargs="*", help="TUM-layout sequence folders (default: "
                    + ", ".join(f"data_root()/{s}" for s in DEFAULT_SEQUENCES) + ")")
    ap.add_argument("--methods", default="classic,huber,ransac", help="comma-separated jaxvo methods")
    ap.add_argument("--gaps", default="1,6,default",
                    help="comma-separated keyframe max_gap values (lag = gap // 2; 1 = frame to frame) "
                         "and/or 'default' (jaxvo's default: segmented keyframes)")
    ap.add_argument("--max-frames", type=int, default=None, help="use at most N frames per sequence")
    ap.add_argument("--config", default=None,
                    help="JSON object of jaxvo.Config fields applied to every method (e.g. '{\"ransac_finest\": 1}')")
    ap.add_argument("--policy", default=None,
                    help="JSON object of jaxvo.TrackConfig fields changed in the 'default' policy "
                         "(e.g. '{\"fuse\": false, \"smooth\": false}')")
    ap.add_argument("--seeds", default="0", help="comma-separated PRNG key seeds for ransac (default 0)")
    ap.add_argument("--out", default=str(common.RESULTS / "keyframes" / "keyframes.md"),
                    help="markdown output (JSON next to it)")
    return ap.parse_args(argv)


def _policies(text: str, changes=None):
    """(gap, name, TrackConfig) per comma-separated token: a keyframe gap (1 = frame to frame,
    the paper's chaining; keyframes without segmentation) or "default" (jaxvo's default
    policy: keyframes with the persistent static/dynamic segmentation; ``changes``, a dict of
    TrackConfig fields, applied to it)."""
    out = []
    for token in [t.strip() for t in text.split(",") if t.strip()]:
        if token == "default":
            try:
                p = TrackConfig.from_json(json.dumps(changes)) if changes else TrackConfig()
                p.validate()
            except (ValueError, TypeError) as e:
                raise SystemExit(f"--policy: {e}") from None
            name = "default (segmented keyframes)" + (f" {json.dumps(changes)}" if changes else "")
            out.append((p.max_gap, name, p))
            continue
        try:
            gap = int(token)
        except ValueError:
            raise SystemExit(f"--gaps: expected integers or 'default', got {token!r}") from None
        if gap < 1:
            raise SystemExit(f"--gaps: a keyframe gap must be >= 1, got {gap}")
        # keyframes(1) is max_gap 1, lag 0: the paper's frame-to-frame chaining
        out.append((gap, "frame to frame" if gap == 1 else f"keyframes {gap}", TrackConfig.keyframes(gap)))
    if not out:
        raise SystemExit("--gaps: empty list")
    return out


def _row(seq, name, policy_name, relative, valid=None, seconds=None, gap=None, seed=None):
    ev = common.evaluate(seq, relative)
    return {"sequence": seq.name, "method": name, "chaining": policy_name, "gap": gap, "seed": seed, **ev,
            "failures": None if valid is None else int(np.sum(~np.asarray(valid))),
            "ms_per_frame": seconds}


def main(argv=None) -> Path:
    args = parse_args(argv)
    paths = [Path(p) for p in args.sequences] or [common.datasets.data_root() / s for s in DEFAULT_SEQUENCES]
    paths = [p for p in paths if p.is_dir()]
    if not paths:
        raise SystemExit(common.missing_data_message())
    methods = [m for m in common.parse_methods(args.methods) if not common.is_peer(m)]
    try:
        seeds = common.int_list(args.seeds)
    except ValueError as e:
        raise SystemExit(f"--seeds: {e}") from None
    try:
        changes = json.loads(args.policy) if args.policy else None
    except ValueError as e:
        raise SystemExit(f"--policy: {e}") from None
    policies = _policies(args.gaps, changes)
    try:
        base = common.config_changes(args.config)
    except ValueError as e:
        raise SystemExit(f"--config: {e}")
    rows = []
    for path in paths:
        seq = common.open_sequence(path, args.max_frames)
        frames = common.load_frames(seq)
        rows.append(_row(seq, "standing still", "-", [np.eye(4)] * (len(frames) - 1)))
        for method in methods:
            for gap, pname, policy in policies:
                for seed in (seeds if method == "ransac" else seeds[:1]):
                    t0 = time.perf_counter()
                    cfg = Config.from_json({**base, "method": method})
                    tr = track(frames, seq.camera, cfg, jax.random.key(seed), policy=policy)
                    ms = 1000 * (time.perf_counter() - t0) / max(len(frames) - 1, 1)
                    rows.append(_row(seq, method, pname, tr.relative, tr.valid, ms, gap,
                                     seed if method == "ransac" else None))
                    r = rows[-1]
                    common.log(f"{seq.name} {method} {pname} seed {r['seed']}: RPE 1 s {common.fmt(r['rpe1s_t'])} "
                               f"m/s {common.fmt(r['rpe1s_r'], '.2f')} deg/s, ATE {common.fmt(r['ate'])} m, "
                               f"failures {r['failures']}")
    for r in rows:
        r["rpef_t_mm"] = None if r.get("rpef_t") is None else 1000 * r["rpef_t"]
    lines = common.provenance_md(
        "Frame to frame vs keyframes", __file__, argv,
        "RPE 1 s: translational (m/s) and rotational (deg/s) RMSE with a fixed 1 s delta; RPE 1 f: "
        "per frame (mm); ATE: RMSE after SE(3) alignment (m); failures: frames whose estimate failed "
        "and held the previous pose; ms/frame includes compilation on each method's first call.")
    lines += common.md_table(rows, [("sequence", "sequence", ""), ("method", "method", ""),
                                    ("chaining", "chaining", ""), ("RPE 1 s [m/s]", "rpe1s_t", ".4f"),
                                    ("RPE 1 s [deg/s]", "rpe1s_r", ".2f"), ("RPE 1 f [mm]", "rpef_t_mm", ".2f"),
                                    ("ATE [m]", "ate", ".4f"), ("failures", "failures", ""),
                                    ("seed", "seed", ""), ("ms/frame", "ms_per_frame", ".0f")])
    compare = same_policy_comparison(rows)
    if compare:
        lines += ["", "## ransac against classic under the same policy", "",
                  "ransac: mean over the seeds [min, max]; ratio: ransac mean / classic (below 1: ransac better).", ""]
        lines += common.md_table(compare, [
            ("sequence", "sequence", ""), ("chaining", "chaining", ""),
            ("classic RPE 1 s [m/s]", "classic_rpe1s_t", ".4f"), ("ransac RPE 1 s [m/s]", "ransac_rpe1s_t", ""),
            ("ratio", "ratio_rpe1s_t", ".2f"), ("classic [deg/s]", "classic_rpe1s_r", ".2f"),
            ("ransac [deg/s]", "ransac_rpe1s_r", ""), ("classic ATE [m]", "classic_ate", ".4f"),
            ("ransac ATE [m]", "ransac_ate", ""), ("ratio ATE", "ratio_ate", ".2f"),
            ("failures classic / ransac", "failures", "")])
    out = common.write_outputs(args.out, lines, {"rows": rows, "same_policy": compare, "args": vars(args)})
    common.log(f"wrote {out}")
    return out


def same_policy_comparison(rows):
    """Per (sequence, chaining) with both methods: classic's scores, ransac's mean [min, max] over
    seeds, and the ratio of the means."""
    out = []
    keys = dict.fromkeys((r["sequence"], r["chaining"]) for r in rows if r["method"] == "ransac")
    for seq, chaining in keys:
        rs = [r for r in rows if r["sequence"] == seq and r["chaining"] == chaining and r["method"] == "ransac"]
        cs = [r for r in rows if r["sequence"] == seq and r["chaining"] == chaining and r["method"] == "classic"]
        if not cs:
            continue
        c = cs[0]
        row = {"sequence": seq, "chaining": chaining, "seeds": [r["seed"] for r in rs]}
        for m, spec in (("rpe1s_t", ".4f"), ("rpe1s_r", ".2f"), ("ate", ".4f")):
            vals = [r[m] for r in rs if r[m] is not None]
            row[f"classic_{m}"] = c[m]
            if not vals:
                row[f"ransac_{m}"] = None
                continue
            mean = float(np.mean(vals))
            row[f"ransac_{m}_mean"] = mean
            row[f"ransac_{m}"] = (f"{mean:{spec}}" if len(vals) == 1 else
                                  f"{mean:{spec}} [{min(vals):{spec}}, {max(vals):{spec}}]")
            if m != "rpe1s_r" and c[m]:
                row[f"ratio_{m}"] = mean / c[m]
        row["failures"] = f"{c['failures']} / {', '.join(str(r['failures']) for r in rs)}"
        out.append(row)
    return out


if __name__ == "__main__":
    main()
