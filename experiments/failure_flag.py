"""The failure flag ``MotionEstimate.valid`` as a classifier, on pairs with known truth.

Each pair is estimated with ``estimate_motion`` (default Config, RANSAC) from the identity.
The truth "should be invalid" is

* by construction for pairs that carry no usable motion: a frame against its mirror image
  (left-right or up-down; no rigid motion maps one onto the other), frames of two different
  scenes, a frame against sensor noise, textureless pairs (constant intensity);
* otherwise by the estimate's error against the ground-truth motion: wrong when the
  translation error exceeds ``--max-trans`` m or the rotation error ``--max-rot`` degrees.

Pairs: real TUM / Bonn frames at gaps from 1 frame to the whole excerpt (Bonn frames 0 and 159
are 5 s apart), synthetic renders of the default room (jaxvo.synthetic) with the camera moved
by known small and large steps (overlapping, barely overlapping, turned away).

Reports precision and recall of "invalid" (positive class: should be invalid), per category
counts, and the statistics the flag is decided on (:class:`jaxvo.estimator.TrustStats`).

    python experiments/failure_flag.py            # writes experiments/results/failure_flag/failure_flag.{md,json}
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import common

import jax  # noqa: E402

from jaxvo import geometry  # noqa: E402
from jaxvo.camera import DEFAULT  # noqa: E402
from jaxvo.frame import Frame  # noqa: E402
from jaxvo.config import Config  # noqa: E402
from jaxvo.estimator import estimate_motion, explain_validity  # noqa: E402

NO_MOTION = ("mirrored", "unrelated", "noise", "textureless")
# the rule before the agreement statistics: an inlier ratio of at least 0.2 (the default then)
OLD_MIN_INLIER_RATIO = 0.2


def _rot(axis: int, deg: float) -> np.ndarray:
    w = np.zeros(3)
    w[axis] = np.radians(deg)
    T = np.eye(4)
    T[:3, :3] = geometry.exp_so3(w)
    return T


def _trans(x=0.0, y=0.0, z=0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def real_pairs(max_pairs_per_seq: int, split: str = "tune"):
    """(category, name, ref, cur, camera, T_cur_ref true or None) from the bundled real sequences.
    ``split`` "tune" (the pairs the thresholds were chosen on) or "held-out" (other frames)."""
    at = (0.0, 0.5, 1.0) if split == "tune" else (0.2, 0.7, 0.9)
    out = []
    loaded = {}
    for name in ("rgbd_dataset_freiburg2_desk", "rgbd_dataset_freiburg3_long_office_household", "rgbd_bonn_crowd"):
        path = common.find_named(name)
        if path is None:
            common.log(f"[failure_flag] {name} not found, skipped")
            continue
        seq = common.open_sequence(path)
        mask, gt = seq.groundtruth_at_frames()
        n = len(seq)
        cache = {}

        def fr(i, seq=seq, cache=cache):
            if i not in cache:
                cache[i] = seq.frame(i)
            return cache[i]
        short = common.short_name(path)
        gaps = [g for g in (1, 2, 4, 8, 15, 30, 60, 100, 159) if g < n]
        pairs = []
        for g in gaps:
            starts = np.unique((np.asarray(at) * (n - 1 - g)).astype(int))
            pairs += [(int(i), int(i) + g) for i in starts]
        if n > 1 and split == "tune":
            pairs.append((0, n - 1))
        pairs = sorted(set(pairs))[:max_pairs_per_seq]
        for i, j in pairs:
            if not (mask[i] and mask[j]):
                continue
            T_true = np.linalg.inv(gt[j]) @ gt[i]
            cat = "overlapping" if j - i <= 8 else "far apart"
            out.append((cat, f"{short} {i}->{j}", fr(i), fr(j), seq.camera, T_true))
        # no rigid motion: mirror images, and constant intensity (no texture)
        for i in ((0, n // 2) if split == "tune" else (n // 4, (3 * n) // 4)):
            f = fr(i)
            out.append(("mirrored", f"{short} {i} vs left-right mirror", f,
                        Frame(np.ascontiguousarray(f.intensity[:, ::-1]), np.ascontiguousarray(f.depth[:, ::-1])),
                        seq.camera, None))
            out.append(("mirrored", f"{short} {i} vs up-down mirror", f,
                        Frame(np.ascontiguousarray(f.intensity[::-1]), np.ascontiguousarray(f.depth[::-1])),
                        seq.camera, None))
            j = min(i + 1, n - 1)
            flat = lambda fr_: Frame(np.full_like(fr_.intensity, 128.0), fr_.depth)  # noqa: E731
            out.append(("textureless", f"{short} {i}->{j} constant intensity", flat(f), flat(fr(j)), seq.camera, None))
        loaded[short] = (seq, fr)
    # frames of two different scenes, and a frame against noise
    names = list(loaded)
    rng = np.random.default_rng(0 if split == "tune" else 1)
    for a in names:
        seq_a, fr_a = loaded[a]
        for b in names:
            if b != a:
                seq_b, fr_b = loaded[b]
                i = 0 if split == "tune" else len(seq_a) // 3
                j = 0 if split == "tune" else len(seq_b) // 2
                out.append(("unrelated", f"{a} {i} vs {b} {j}", fr_a(i), fr_b(j), seq_a.camera, None))
        f = fr_a(0 if split == "tune" else len(seq_a) - 1)
        noise = Frame(rng.uniform(0, 255, f.intensity.shape).astype(np.float32),
                      rng.uniform(0.5, 4.0, f.depth.shape).astype(np.float32))
        out.append(("noise", f"{a} vs noise", f, noise, seq_a.camera, None))
    return out


def synthetic_pairs(split: str = "tune"):
    """Renders of the default room (320x240) with known camera steps from two base poses per split."""
    from jaxvo.synthetic import SensorModel, make_room, render

    cam = DEFAULT.at_level(1)
    scene = make_room(0)
    out = []
    base = [np.eye(4), _rot(1, 30.0) @ _trans(0.1, 0.0, -0.2)] if split == "tune" else \
        [_rot(1, -25.0) @ _trans(-0.2, 0.0, 0.1), _rot(0, 10.0) @ _trans(0.0, -0.1, 0.0)]
    steps = {"overlapping": [_trans(0.02), _trans(z=0.05), _rot(1, 2.0), _rot(0, 3.0) @ _trans(0.03),
                             _rot(1, 5.0) @ _trans(z=0.05), _rot(2, 8.0), _trans(0.10, 0.0, 0.10)],
             "far apart": [_rot(1, 20.0), _rot(1, 35.0), _rot(0, 30.0), _trans(0.4, 0.0, 0.3),
                           _rot(1, 60.0), _rot(1, 90.0), _rot(1, 180.0)]}
    sensor = SensorModel()
    for b, T0 in enumerate(base):
        b += 0 if split == "tune" else 2
        ref = render(scene, cam, T0, sensor=sensor, rng=10 * b).frame()
        for cat, lst in steps.items():
            for k, D in enumerate(lst):
                T1 = T0 @ D                                   # T_world_cur
                cur = render(scene, cam, T1, sensor=sensor, rng=10 * b + k + 1).frame()
                T_true = np.linalg.inv(T1) @ T0               # T_cur_ref
                ang = np.degrees(geometry.rotation_angle(D[:3, :3]))
                out.append((cat, f"synthetic base {b}: step {np.linalg.norm(D[:3, 3]):.2f} m {ang:.0f} deg",
                            ref, cur, cam, T_true))
        out.append(("mirrored", f"synthetic base {b} vs left-right mirror", ref,
                    Frame(np.ascontiguousarray(ref.intensity[:, ::-1]), np.ascontiguousarray(ref.depth[:, ::-1])),
                    cam, None))
        flat = Frame(np.full_like(ref.intensity, 100.0), ref.depth)
        cur = render(scene, cam, T0 @ _trans(0.02), sensor=sensor, rng=10 * b + 99).frame()
        out.append(("textureless", f"synthetic base {b} constant intensity", flat,
                    Frame(np.full_like(cur.intensity, 100.0), cur.depth), cam, None))
    return out


def motion_error(T_est, T_true):
    E = np.linalg.inv(T_true) @ np.asarray(T_est, np.float64)
    return float(np.linalg.norm(E[:3, 3])), float(np.degrees(geometry.rotation_angle(E[:3, :3])))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--max-trans", type=float, default=0.10, help="translation error (m) above which an estimate is wrong")
    ap.add_argument("--max-rot", type=float, default=5.0, help="rotation error (deg) above which an estimate is wrong")
    ap.add_argument("--max-pairs-per-seq", type=int, default=40)
    ap.add_argument("--no-synthetic", action="store_true")
    ap.add_argument("--quick", action="store_true", help="a tiny run: 2 real pairs per sequence, 'tune' split only")
    ap.add_argument("--out", type=Path, default=common.RESULTS / "failure_flag" / "failure_flag.md")
    args = ap.parse_args(argv)

    t0 = time.perf_counter()
    pairs = []
    if args.quick:
        args.max_pairs_per_seq, args.no_synthetic = 2, True
    for split in ("tune",) if args.quick else ("tune", "held-out"):
        got = real_pairs(args.max_pairs_per_seq, split) + ([] if args.no_synthetic else synthetic_pairs(split))
        pairs += [(split,) + p for p in got]
    common.log(f"[failure_flag] {len(pairs)} pairs")
    config = Config()
    rows = []
    for k, (split, cat, name, ref, cur, cam, T_true) in enumerate(pairs):
        est = estimate_motion(ref, cur, cam, config, jax.random.key(k))
        stats, valid = jax.device_get(explain_validity(ref, cur, cam, est, config))
        assert bool(valid) == bool(est.valid)
        if T_true is None:
            et, er, should = float("nan"), float("nan"), True
        else:
            et, er = motion_error(est.T_cur_ref, T_true)
            should = not (et <= args.max_trans and er <= args.max_rot)
        true_step = (float(np.linalg.norm(T_true[:3, 3])), float(np.degrees(geometry.rotation_angle(T_true[:3, :3])))) \
            if T_true is not None else (float("nan"), float("nan"))
        rows.append({"split": split, "category": cat, "pair": name, "should_be_invalid": bool(should), "flag_invalid": not bool(valid),
                     "err_trans_m": et, "err_rot_deg": er, "step_m": true_step[0], "step_deg": true_step[1],
                     **{f: float(getattr(stats, f)) for f in stats._fields}})
        common.log(f"  {k + 1}/{len(pairs)} {cat:<12} {name:<48} should {int(should)} flag {int(not valid)} "
                   f"err {et:.3f} m {er:.2f} deg  " + " ".join(f"{f[:6]} {float(getattr(stats, f)):.3g}"
                                                            for f in stats._fields))
    def scores(sel, key="flag_invalid"):
        p = np.array([r["should_be_invalid"] for r in sel], bool)
        f = np.array([r[key] for r in sel], bool)
        tp, fp, fn = int(np.sum(p & f)), int(np.sum(~p & f)), int(np.sum(p & ~f))
        return {"pairs": len(sel), "should be invalid": int(p.sum()), "flagged invalid": int(f.sum()),
                "caught": tp, "false alarms": fp, "missed": fn,
                "precision": tp / (tp + fp) if tp + fp else float("nan"),
                "recall": tp / (tp + fn) if tp + fn else float("nan")}

    for r in rows:   # the rule before this experiment: finite, conditioned, inlier ratio >= 0.2
        r["old_flag_invalid"] = not (r["finite"] and r["conditioning"] > 1e-9
                                     and r["inlier_ratio"] >= OLD_MIN_INLIER_RATIO)
    cols = [("split", "split", "s"), ("category", "category", "s")] + \
        [(k, k, ".3f" if k in ("precision", "recall") else "d") for k in scores(rows)]
    summary = [{"split": sp, "category": "all", **scores([r for r in rows if r["split"] == sp])}
               for sp in ("tune", "held-out")]
    summary.append({"split": "both", "category": "all", **scores(rows)})
    old = [{"split": sp, "category": "all (old rule)", **scores([r for r in rows if sp in ("both", r["split"])],
                                                               "old_flag_invalid")}
           for sp in ("tune", "held-out", "both")]
    cats = sorted({r["category"] for r in rows}, key=lambda c: (c in NO_MOTION, c))
    per_cat = [{"split": "both", "category": c, **scores([r for r in rows if r["category"] == c])} for c in cats]
    allsc = summary[-1]
    lines = common.provenance_md("The failure flag as a classifier", __file__, argv,
                                 f"Positive class: the estimate should be flagged invalid (no rigid motion "
                                 f"relates the frames, or error > {args.max_trans:g} m / {args.max_rot:g} deg "
                                 f"against the ground truth). Default Config (RANSAC), identity start. The "
                                 f"photometric threshold (min_photometric_agreement "
                                 f"{config.min_photometric_agreement:g}) was chosen on the 'tune' pairs, "
                                 f"min_inlier_ratio {config.min_inlier_ratio:g} and min_depth_agreement "
                                 f"{config.min_depth_agreement:g} on Bonn crowd tracking (jaxvo.Config); "
                                 f"the 'held-out' pairs are other frames and poses. The old rule: finite, "
                                 f"conditioned, inlier ratio >= {OLD_MIN_INLIER_RATIO:g}.")
    lines += ["", f"**precision {allsc['precision']:.3f}, recall {allsc['recall']:.3f}** of \"invalid\" over "
                  f"{len(rows)} pairs ({allsc['should be invalid']} should be invalid; {allsc['caught']} caught, "
                  f"{allsc['false alarms']} false alarms, {allsc['missed']} missed)", ""]
    lines += common.md_table(summary + old + per_cat, cols)
    wrong = [r for r in rows if r["should_be_invalid"] != r["flag_invalid"]]
    if wrong:
        lines += ["", "Misclassified pairs:", ""]
        lines += common.md_table(wrong, [("split", "split", "s"), ("pair", "pair", "s"),
                                         ("should be invalid", "should_be_invalid", "s"),
                                         ("error m", "err_trans_m", ".3f"), ("error deg", "err_rot_deg", ".2f"),
                                         ("inlier ratio", "inlier_ratio", ".3f"),
                                         ("depth agreement", "depth_agreement", ".3f"),
                                         ("photometric agreement", "photometric_agreement", ".3f")])
    lines += ["", f"{len(rows)} pairs in {time.perf_counter() - t0:.0f} s."]
    common.write_outputs(args.out, lines, {"summary": summary, "old_rule": old, "per_category": per_cat, "rows": rows,
                                           "max_trans": args.max_trans, "max_rot": args.max_rot})
    print("\n".join(lines))


if __name__ == "__main__":
    main()
