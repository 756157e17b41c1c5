"""What the reference pairs look like at the *true* pose: overlap, exposure change, and where the
estimator goes when started there.

For each pair (reference, current) of a sequence with ground truth, at the ground-truth
T_cur_ref and at pyramid level 1 (320x240): the fraction of the reference's valid pixels whose
depth agrees with the current frame (|depth residual| < 3 cm), the median luminance residual
over those pixels (an exposure change shows as an offset: depth does not depend on exposure)
and the fraction of them under the paper's |luminance residual| < 30; then ``estimate_motion``
(default Config, optionally ``brightness="offset"``) started from the true pose, and how far its
result is from it. Used to diagnose Bonn crowd frames 105-130 (docs/results.md).

    python -m experiments.diagnostics.exposure                             # Bonn crowd, the default pairs
    python -m experiments.diagnostics.exposure SEQ --pairs 60-61,109-120
"""
from __future__ import annotations

import argparse
from pathlib import Path

from experiments import common
import numpy as np  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from jaxvo import geometry  # noqa: E402
from jaxvo.config import Config  # noqa: E402
from jaxvo.estimator.motion import estimate_motion  # noqa: E402
from jaxvo.estimator.pyramid import build_pyramid  # noqa: E402
from jaxvo.estimator.residuals import reference_points, residuals  # noqa: E402

DEFAULT_PAIRS = "60-61,95-101,105-112,109-115,109-120,109-128,130-134"


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sequence", nargs="?", default=None,
                    help="TUM-layout folder with ground truth (default: data_root()/bonn/rgbd_bonn_crowd)")
    ap.add_argument("--pairs", default=DEFAULT_PAIRS, help=f"comma list of REF-CUR frame indices ({DEFAULT_PAIRS})")
    ap.add_argument("--out", default=str(common.RESULTS / "exposure" / "exposure.md"), help="markdown output (JSON next to it)")
    a = ap.parse_args(argv)
    try:
        a.pair_list = [tuple(int(x) for x in p.split("-")) for p in a.pairs.split(",") if p.strip()]
        assert a.pair_list and all(len(p) == 2 for p in a.pair_list)
    except (ValueError, AssertionError):
        ap.error(f"--pairs: expected REF-CUR,REF-CUR,..., got {a.pairs!r}")
    return a


def at_true_pose(ref, cur, camera, T, agree=0.03, thresh_lum=30.0):
    """(depth agreement, median luminance residual over the agreeing pixels, their fraction under
    thresh_lum) at pose T (level 1)."""
    rp = build_pyramid(jnp.asarray(ref.intensity, jnp.float32), jnp.asarray(ref.depth, jnp.float32), 2)[1]
    cp = build_pyramid(jnp.asarray(cur.intensity, jnp.float32), jnp.asarray(cur.depth, jnp.float32), 2)[1]
    pts = reference_points(rp, camera.at_level(1), 1)
    res = residuals(jnp.asarray(T, jnp.float32), pts, cp, camera.at_level(1))
    ok = np.asarray(res.valid_depth & (jnp.abs(res.r_depth) < agree))
    ri = np.asarray(res.r_int)[ok]
    n_valid = max(int(np.asarray(pts.valid).sum()), 1)
    return ok.sum() / n_valid, float(np.median(ri)) if ri.size else None, float(np.mean(np.abs(ri) < thresh_lum)) \
        if ri.size else None


def main(argv=None) -> Path:
    a = parse_args(argv)
    path = Path(a.sequence) if a.sequence else common.datasets.data_root() / "bonn" / "rgbd_bonn_crowd"
    if not path.is_dir():
        raise SystemExit(common.missing_data_message())
    seq = common.open_sequence(path)
    covered, P = seq.groundtruth_at_frames()
    rows = []
    for r, c in a.pair_list:
        if not (0 <= r < len(seq) and 0 <= c < len(seq)) or not (covered[r] and covered[c]):
            raise SystemExit(f"--pairs: {r}-{c} is outside {path.name}'s {len(seq)} frames or its ground truth")
        ref, cur = seq.frame(r), seq.frame(c)
        T = geometry.inverse(P[c]) @ P[r]
        agree, offset, under = at_true_pose(ref, cur, seq.camera, T)
        row = {"pair": f"{r}->{c}", "depth_agree": agree, "lum_offset": offset, "lum_ok": under,
               "mean_I_ref": float(np.mean(ref.intensity)), "mean_I_cur": float(np.mean(cur.intensity))}
        for b in ("none", "offset"):
            est = estimate_motion(ref, cur, seq.camera, Config(brightness=b), jax.random.key(0), init=T)
            E = geometry.inverse(T) @ np.asarray(est.T_cur_ref, np.float64)
            row[f"err_mm_{b}"] = 1000 * float(np.linalg.norm(E[:3, 3]))
            row[f"valid_{b}"] = bool(est.valid)
        rows.append(row)
        common.log(f"{row['pair']}: depth agrees {agree:.2f}, luminance offset {offset}, "
                   f"from the true pose {row['err_mm_none']:.1f} / {row['err_mm_offset']:.1f} mm")
    lines = common.provenance_md("Pairs at the true pose: overlap, exposure, and the estimate started there",
                                 __file__, argv,
                                 f"Sequence {path.name}. Level 1 (half resolution); depth agrees: |depth residual| "
                                 "< 3 cm at the ground-truth pose, as a fraction of the reference's valid pixels; "
                                 "offset: median luminance residual over those pixels (0-255); under 30: their "
                                 "fraction with |luminance residual| < 30; error: translation of the estimate "
                                 "(default Config, RANSAC without the map's weights) started from the true pose.")
    lines += common.md_table(rows, [("pair", "pair", ""), ("depth agrees", "depth_agree", ".2f"),
                                    ("luminance offset", "lum_offset", ".1f"), ("under 30", "lum_ok", ".2f"),
                                    ("mean I ref", "mean_I_ref", ".0f"), ("mean I cur", "mean_I_cur", ".0f"),
                                    ("error mm", "err_mm_none", ".1f"), ("valid", "valid_none", ""),
                                    ("error mm, brightness offset", "err_mm_offset", ".1f"),
                                    ("valid, offset", "valid_offset", "")])
    out = common.write_outputs(a.out, lines, {"rows": rows, "args": {"sequence": str(path), "pairs": a.pairs}})
    common.log(f"wrote {out}")
    return out


if __name__ == "__main__":
    main()
