"""Config variants of the estimator against each other: compile time, time per pair, pose difference.

Each variant is a set of ``Config`` fields changed from the default (``--variants`` JSON: name ->
fields; the first is the baseline). For each method in ``--methods`` (a variant that sets
``method`` itself runs once) and each variant, the estimator (``jaxvo.estimator.estimate_arrays_jit``)
at 640x480: the XLA compilation of the first call (``.lower`` then ``.compile`` timed alone,
wall and CPU seconds, lines of the lowered StableHLO), then the wall time per pair on pairs
spread over a static (TUM fr2/desk) and a dynamic (Bonn crowd) sequence, the variants timed in
turn pass by pass in this one process (the order reversed every other pass, so that other
processes on the machine weigh on all alike), the mean number of RANSAC hypotheses, and the
largest difference of each variant's T_cur_ref from the baseline's on those pairs (same key).

The default variants are ``Config.scan_levels`` on (the default: one scanned level body per group of
levels) and off (one copy of the code per level).
"""
from __future__ import annotations

import argparse
import json
import time
from typing import List, Optional

import numpy as np

from experiments import common
import jax  # noqa: E402

from jaxvo.config import METHODS, Config  # noqa: E402
from jaxvo.estimator import estimate_arrays_jit, estimate_motion  # noqa: E402

DEFAULT_VARIANTS = '{"scan": {}, "per level": {"scan_levels": false}}'
SETS = (("static", "rgbd_dataset_freiburg2_desk"), ("dynamic", "rgbd_bonn_crowd"))


def parse_args(argv: Optional[List[str]] = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variants", default=DEFAULT_VARIANTS,
                    help="JSON object: variant name -> Config fields changed from the default; the first is the "
                         "baseline (default: %(default)s)")
    ap.add_argument("--methods", default="classic,huber,ransac", help="comma list (default classic,huber,ransac)")
    ap.add_argument("--pairs", type=int, default=5, help="consecutive pairs per sequence (default 5)")
    ap.add_argument("--repeats", type=int, default=3, help="timed passes per variant (default 3)")
    ap.add_argument("--quick", action="store_true", help="2 pairs per sequence, 1 pass (smoke test)")
    ap.add_argument("--out", default=str(common.RESULTS / "variants" / "variants.md"), help="markdown output (json beside it)")
    return ap.parse_args(argv)


def parse_variants(text: str) -> dict:
    """name -> dict of Config fields, each checked as a ``--config`` (a misspelt field or a bad
    value stops with the variant's name and the problem)."""
    variants = common.json_variants(text, "object of Config fields")
    for name, fields in variants.items():
        try:
            common.config_changes(json.dumps(fields))
        except ValueError as e:
            raise SystemExit(f"--variants: {name}: {e}")
    return variants


def compile_stats(config: Config, camera) -> dict:
    lowered = estimate_arrays_jit.trace(*common.estimator_shapes(camera, config)).lower()
    t0, c0 = time.perf_counter(), time.process_time()
    lowered.compile()
    return {"compile_s": time.perf_counter() - t0, "compile_cpu_s": time.process_time() - c0,
            "lines": lowered.as_text().count("\n")}


def configs(variants: dict, methods: List[str]) -> dict:
    """(method, variant) -> Config; a variant that names its own method runs once, under it."""
    out = {}
    for method in methods:
        for name, fields in variants.items():
            m = fields.get("method", method)
            if m == method:
                out[(m, name)] = Config.from_dict({**fields, "method": m})
    return out


def main(argv: Optional[List[str]] = None) -> None:
    args = parse_args(argv)
    if args.quick:
        args.pairs, args.repeats = 2, 1
    variants = parse_variants(args.variants)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    bad = [m for m in methods if m not in METHODS]
    if bad:
        raise SystemExit(f"unknown method {bad[0]!r}: choose from {', '.join(METHODS)}")
    header = common.provenance_md("Config variants: compile time, time per pair, pose difference", __file__, argv)
    pairs = {}
    for label, name in SETS:
        seq = common.open_sequence(common.find_named(name))
        idx = np.linspace(0, len(seq) - 2, args.pairs).astype(int)
        pairs[label] = [(seq.frame(i), seq.frame(i + 1), seq.camera) for i in idx]
    cfgs = configs(variants, methods)
    base = list(variants)[0]
    rows = []
    for method in methods:
        names = [v for (m, v) in cfgs if m == method]
        stats = {}
        for v in names:
            stats[v] = compile_stats(cfgs[(method, v)], pairs["static"][0][2])
            common.log(f"{method} {v}: XLA compile {stats[v]['compile_s']:.1f} s "
                       f"(cpu {stats[v]['compile_cpu_s']:.1f} s), {stats[v]['lines']} lines")
            jax.block_until_ready(estimate_motion(*pairs["static"][0], cfgs[(method, v)], jax.random.key(0)))
        times = {(v, s): [] for v in names for s in pairs}
        poses = {(v, s): [] for v in names for s in pairs}
        hyps = {(v, s): [] for v in names for s in pairs}
        for r in range(args.repeats):
            for v in (names if r % 2 == 0 else names[::-1]):
                for s, ps in pairs.items():
                    for a, b, cam in ps:
                        t0 = time.perf_counter()
                        est = jax.block_until_ready(estimate_motion(a, b, cam, cfgs[(method, v)], jax.random.key(0)))
                        times[(v, s)].append(time.perf_counter() - t0)
                        if r == 0:
                            poses[(v, s)].append(np.asarray(est.T_cur_ref))
                            hyps[(v, s)].append(int(np.sum(est.hypotheses)))
        for v in names:
            for s in pairs:
                ms = 1e3 * float(np.median(times[(v, s)]))
                row = {"method": method, "variant": v, "pairs": s, "ms": ms, "hyps": float(np.mean(hyps[(v, s)])),
                       **stats[v]}
                if base in names:
                    row["ratio"] = ms / (1e3 * float(np.median(times[(base, s)])))
                    row["max_dT"] = float(max(np.abs(x - y).max() for x, y in zip(poses[(base, s)], poses[(v, s)])))
                rows.append(row)
            common.log(f"{method} {v}: " + ", ".join(f"{s} {1e3 * np.median(times[(v, s)]):.1f} ms" for s in pairs))
    lines = header + [
        "Variants (Config fields changed from the default; the first is the baseline of `ratio` and "
        f"`max abs dT`): `{json.dumps(variants)}`.", "",
        "XLA compile: `estimate_arrays_jit(...).lower(...).compile()` of the estimator at 640x480 alone (wall and "
        "CPU s; lines: the lowered StableHLO). Per pair: median wall time of `estimate_motion` (blocked) over "
        f"{args.pairs} static (fr2/desk) or {args.pairs} dynamic (Bonn crowd) consecutive pairs spread over the "
        f"sequence x {args.repeats} passes, the variants in turn pass by pass. hyps: mean RANSAC hypotheses per "
        "pair. max |dT|: largest entry of the difference of T_cur_ref from the baseline's on the same pairs "
        "(same key).", ""]
    lines += common.md_table(rows, [
        ("method", "method", "s"), ("variant", "variant", "s"), ("pairs", "pairs", "s"),
        ("compile s", "compile_s", ".1f"), ("compile cpu s", "compile_cpu_s", ".1f"), ("lines", "lines", "d"),
        ("ms/pair", "ms", ".1f"), ("/ baseline", "ratio", ".2f"), ("hyps", "hyps", ".1f"),
        ("max abs dT", "max_dT", ".1e")])
    common.write_outputs(args.out, lines, {"rows": rows, "argv": argv})
    print("\n".join(lines))


if __name__ == "__main__":
    main()
