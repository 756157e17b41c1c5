"""Config.scan_levels: the pyramid levels as one ``lax.scan`` against the default per-level code.

For each method, both variants of the estimator (``jaxvo.odometry._estimate_jit``) at 640x480:
the XLA compilation of the first call (``.lower`` then ``.compile`` timed alone, wall and CPU
seconds, lines of the lowered StableHLO), then the wall time per pair on consecutive pairs of a
static (TUM fr2/desk) and a dynamic (Bonn crowd) sequence, the two variants timed alternately
pass by pass in this one process (so that other processes on the machine affect both alike),
and the largest difference of their T_cur_ref on those pairs (same key).
"""
from __future__ import annotations

import argparse
import time
from typing import List, Optional

import numpy as np

import common  # noqa: F401  (sys.path for jaxvo)
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

from jaxvo.config import METHODS, Config  # noqa: E402
from jaxvo.odometry import _estimate_jit, estimate_motion  # noqa: E402


def parse_args(argv: Optional[List[str]] = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--methods", default="classic,huber,ransac", help="comma list (default classic,huber,ransac)")
    ap.add_argument("--pairs", type=int, default=5, help="consecutive pairs per sequence (default 5)")
    ap.add_argument("--repeats", type=int, default=3, help="timed passes per variant (default 3)")
    ap.add_argument("--out", default="experiments/results/scan_levels.md", help="markdown output (json beside it)")
    return ap.parse_args(argv)


def compile_stats(config: Config, camera) -> dict:
    img = jax.ShapeDtypeStruct((camera.height, camera.width), jnp.float32)
    args = (img, img, img, img, camera, config, jax.random.key(0), jax.ShapeDtypeStruct((4, 4), jnp.float32), img)
    lowered = _estimate_jit.trace(*args).lower()
    t0, c0 = time.perf_counter(), time.process_time()
    lowered.compile()
    return {"compile_s": time.perf_counter() - t0, "compile_cpu_s": time.process_time() - c0,
            "lines": lowered.as_text().count("\n")}


def main(argv: Optional[List[str]] = None) -> None:
    args = parse_args(argv)
    header = common.provenance_md("Config.scan_levels: one scanned level body against per-level code",
                                  __file__, argv)
    pairs = []
    for name in ("rgbd_dataset_freiburg2_desk", "rgbd_bonn_crowd"):
        seq = common.open_sequence(common.find_named(name))
        idx = np.linspace(0, len(seq) - 2, args.pairs).astype(int)
        pairs += [(seq.frame(i), seq.frame(i + 1), seq.camera) for i in idx]
    rows = []
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    bad = [m for m in methods if m not in METHODS]
    if bad:
        raise SystemExit(f"error: unknown method {bad[0]!r}: choose from {', '.join(METHODS)}")
    for method in methods:
        variants = {"per level": Config(method=method), "scan": Config(method=method, scan_levels=True)}
        row = {"method": method}
        for v, cfg in variants.items():
            st = compile_stats(cfg, pairs[0][2])
            common.log(f"{method} {v}: XLA compile {st['compile_s']:.1f} s (cpu {st['compile_cpu_s']:.1f} s), "
                       f"{st['lines']} lines")
            row.update({f"{v} {k}": x for k, x in st.items()})
            jax.block_until_ready(estimate_motion(*pairs[0], cfg, jax.random.key(0)))  # the first call
        times = {v: [] for v in variants}
        poses = {v: [] for v in variants}
        for r in range(args.repeats):
            for v in (list(variants) if r % 2 == 0 else list(variants)[::-1]):
                for a, b, cam in pairs:
                    t0 = time.perf_counter()
                    est = jax.block_until_ready(estimate_motion(a, b, cam, variants[v], jax.random.key(0)))
                    times[v].append(time.perf_counter() - t0)
                    if r == 0:
                        poses[v].append(np.asarray(est.T_cur_ref))
        for v in variants:
            row[f"{v} ms"] = 1e3 * float(np.median(times[v]))
        row["ratio"] = row["scan ms"] / row["per level ms"]
        row["max_dT"] = float(max(np.abs(x - y).max() for x, y in zip(poses["per level"], poses["scan"])))
        common.log(f"{method}: per pair {row['per level ms']:.1f} ms per level, {row['scan ms']:.1f} ms scan")
        rows.append(row)
    lines = header + [
        "XLA compile: `_estimate_jit(...).lower(...).compile()` of the estimator at 640x480 alone (wall and "
        "CPU s; lines: the lowered StableHLO). Per pair: median wall time of `estimate_motion` (blocked) over "
        f"{args.pairs} static (fr2/desk) + {args.pairs} dynamic (Bonn crowd) consecutive pairs x {args.repeats} "
        "passes, the two variants alternating pass by pass. max |dT|: largest entry of the difference of the "
        "two T_cur_ref over the pairs (same key).", ""]
    lines += common.md_table(rows, [
        ("method", "method", "s"),
        ("compile s per level", "per level compile_s", ".1f"), ("compile s scan", "scan compile_s", ".1f"),
        ("cpu s per level", "per level compile_cpu_s", ".1f"), ("cpu s scan", "scan compile_cpu_s", ".1f"),
        ("lines per level", "per level lines", "d"), ("lines scan", "scan lines", "d"),
        ("ms/pair per level", "per level ms", ".1f"), ("ms/pair scan", "scan ms", ".1f"),
        ("scan / per level", "ratio", ".2f"), ("max abs dT", "max_dT", ".1e")])
    common.write_outputs(args.out, lines, {"rows": rows, "argv": argv})
    print("\n".join(lines))


if __name__ == "__main__":
    main()
