"""Hyperparameter sweep of RANSAC as ONE vmap'd computation over a grid of Config values.

The grid is (thresh_lum x thresh_depth) at the default w, plus a line over w at
the default thresholds. Config's numeric fields are pytree leaves, so
``jax.vmap`` over (thresh_lum, thresh_depth, w) arrays of length G (both grids
concatenated) turns ``estimate_motion`` into one compiled function that solves
every grid cell of a frame pair in a single call. It runs on every consecutive
pair of a real static sequence (TUM freiburg2_desk) and of its dynamic
augmentation (``jaxvo.synthetic.augment``); each cell's motions are chained and
scored by translational RPE (per frame; and over 1 s where the sequence is long
enough). The same grid is then run as G separate ``estimate_motion`` calls per
pair (compiled once, values passed as traced leaves) for the wall-time
comparison and the agreement check.

Writes ``sweep.md``, ``sweep.json`` and ``sweep.png`` (heat maps).

Example::

    python experiments/sweep.py                     # default grid, all frames
    python experiments/sweep.py --quick --out /tmp/sweep.md
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import common
import numpy as np  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from jaxvo.frame import Frame  # noqa: E402
from jaxvo.config import METHODS, Config  # noqa: E402
from jaxvo.estimator.motion import estimate_motion  # noqa: E402
from jaxvo.estimator.solvers import jit  # noqa: E402

STATIC = "rgbd_dataset_freiburg2_desk"


def _floats(s):
    return [float(x) for x in s.split(",") if x]


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("sequence", nargs="?", default=None,
                    help=f"real TUM sequence folder (default data_root()/tum/{STATIC})")
    ap.add_argument("--lum", default="10,20,30,45,60", help="thresh_lum values (0-255 units)")
    ap.add_argument("--depth", default="0.02,0.05,0.1,0.2", help="thresh_depth values (m)")
    ap.add_argument("--w", default="0.1,0.2,0.3,0.5,0.7", help="w values (assumed outlier fraction)")
    ap.add_argument("--max-frames", type=int, default=None, help="frames per sequence (default all)")
    ap.add_argument("--method", default="ransac", choices=METHODS,
                    help="estimator (default ransac; the thresholds and w only change ransac's poses)")
    ap.add_argument("--persons", type=int, default=2, help="augmentation: moving occluders (default 2)")
    ap.add_argument("--coverage", type=float, default=0.3, help="augmentation: image coverage (default 0.3)")
    ap.add_argument("--no-augment", action="store_true", help="skip the dynamic augmentation")
    ap.add_argument("--no-separate", action="store_true", help="skip the separate-calls timing")
    ap.add_argument("--cache", default=None, help=f"augmentation cache folder (default {common.CACHE})")
    ap.add_argument("--quick", action="store_true", help="tiny CI run: 3 frames, 2x2 grid, 2 values of w")
    ap.add_argument("--out", default=str(common.RESULTS / "sweep" / "sweep.md"), help="markdown output (json, png beside it)")
    args = ap.parse_args(argv)
    if args.quick:
        args.max_frames = args.max_frames or 3
        args.lum, args.depth, args.w = "20,40", "0.03,0.1", "0.2,0.5"
    args.lum, args.depth, args.w = _floats(args.lum), _floats(args.depth), _floats(args.w)
    return args


def make_grid(lum, depth, w, base: Config):
    """Flattened grid: (thresh_lum, thresh_depth, w) arrays of length len(lum)*len(depth) + len(w)."""
    tl, td = np.meshgrid(np.asarray(lum, np.float32), np.asarray(depth, np.float32), indexing="ij")
    n2 = tl.size
    TL = np.concatenate([tl.ravel(), np.full(len(w), base.thresh_lum, np.float32)])
    TD = np.concatenate([td.ravel(), np.full(len(w), base.thresh_depth, np.float32)])
    W = np.concatenate([np.full(n2, base.w, np.float32), np.asarray(w, np.float32)])
    return TL, TD, W, n2


def _one_cell(ri, rd, ci, cd, camera, base, key, tl, td, w):
    cfg = base.replace(thresh_lum=tl, thresh_depth=td, w=w)
    return estimate_motion(Frame(ri, rd), Frame(ci, cd), camera, cfg, key).T_cur_ref


#: jit(vmap over the grid) of estimate_motion. Frames, camera, base config and key are
#: arguments shared by all cells (not baked-in constants), so one compilation serves every
#: pair and every sequence with the same image size and static config.
SWEEP = jit(jax.vmap(_one_cell, in_axes=(None,) * 7 + (0, 0, 0)))


def run_sequence(path, args, base: Config, key, label: str):
    seq = common.open_sequence(path, max_frames=args.max_frames)
    frames = common.load_frames(seq)
    P = len(frames) - 1
    TL, TD, W, n2 = make_grid(args.lum, args.depth, args.w, base)
    G = TL.size
    common.log(f"[sweep] {label}: {seq.name}, {P} pairs, grid {len(args.lum)}x{len(args.depth)} + {len(args.w)} "
               f"= {G} cells")
    grid = (jnp.asarray(TL), jnp.asarray(TD), jnp.asarray(W))

    def call(k):
        a, b = frames[k], frames[k + 1]
        return SWEEP(a.intensity, a.depth, b.intensity, b.depth, seq.camera, base, jax.random.fold_in(key, k), *grid)

    t0 = time.perf_counter()
    jax.block_until_ready(call(0))
    vm_compile = time.perf_counter() - t0
    rel = np.zeros((G, P, 4, 4))
    t0 = time.perf_counter()
    for k in range(P):
        rel[:, k] = np.asarray(jax.block_until_ready(call(k)), np.float64)
    vm_wall = time.perf_counter() - t0

    sep_wall = sep_compile = None
    max_dev = None
    if not args.no_separate:
        t0 = time.perf_counter()
        common.time_jaxvo_pair(frames[0], frames[1], seq.camera,
                               base.replace(thresh_lum=float(TL[0]), thresh_depth=float(TD[0]), w=float(W[0])),
                               jax.random.fold_in(key, 0))
        sep_compile = time.perf_counter() - t0
        dev = 0.0
        t0 = time.perf_counter()
        for g in range(G):
            cfg = base.replace(thresh_lum=float(TL[g]), thresh_depth=float(TD[g]), w=float(W[g]))
            for k in range(P):
                est = estimate_motion(frames[k], frames[k + 1], seq.camera, cfg, jax.random.fold_in(key, k))
                T = np.asarray(jax.block_until_ready(est.T_cur_ref), np.float64)
                dev = max(dev, float(np.max(np.abs(T - rel[g, k]))))
        sep_wall = time.perf_counter() - t0
        max_dev = dev

    scores = []
    for g in range(G):
        ev = common.evaluate(seq, rel[g])
        scores.append({"thresh_lum": float(TL[g]), "thresh_depth": float(TD[g]), "w": float(W[g]),
                       "grid": "lum x depth" if g < n2 else "w", **ev})
    common.log(f"  vmapped: {vm_wall:.2f} s ({G * P} estimates; compile {vm_compile:.1f} s); separate: "
               + (f"{sep_wall:.2f} s (compile {sep_compile:.1f} s), max |dT| {max_dev:.2e}" if sep_wall else "skipped"))
    return {"label": label, "sequence": seq.name, "pairs": P, "cells": G, "vmap_wall_s": vm_wall,
            "vmap_compile_s": vm_compile, "separate_wall_s": sep_wall, "separate_compile_s": sep_compile,
            "max_abs_diff": max_dev, "scores": scores, "n2": n2}


def metric_of(s):
    """The heat-map metric: 1 s translational RPE (m/s) where available, else per-frame (m/frame)."""
    return (s["rpe1s_t"], "RPE-t 1 s (m/s)") if s["rpe1s_t"] is not None else (s["rpef_t"], "RPE-t per frame (m)")


def plot(results, args, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    n = len(results)
    fig, axes = plt.subplots(2, n, figsize=(5.2 * n, 8), squeeze=False,
                             gridspec_kw={"height_ratios": [3, 1.4]})
    for c, res in enumerate(results):
        n2 = res["n2"]
        vals = np.array([np.nan if metric_of(s)[0] is None else metric_of(s)[0] for s in res["scores"]])
        unit = metric_of(res["scores"][0])[1]
        grid = vals[:n2].reshape(len(args.lum), len(args.depth))
        ax = axes[0, c]
        im = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis")
        ax.set_xticks(range(len(args.depth)), [f"{d:g}" for d in args.depth])
        ax.set_yticks(range(len(args.lum)), [f"{x:g}" for x in args.lum])
        ax.set_xlabel("thresh_depth (m)")
        ax.set_ylabel("thresh_lum (0-255)")
        ax.set_title(f"{res['label']}: {res['sequence']}\n{unit}", fontsize=9)
        for i in range(grid.shape[0]):
            for j in range(grid.shape[1]):
                if np.isfinite(grid[i, j]):
                    ax.text(j, i, f"{grid[i, j]:.4f}", ha="center", va="center", fontsize=7, color="w")
        fig.colorbar(im, ax=ax)
        ax = axes[1, c]
        ax.plot(args.w, vals[n2:], "o-")
        ax.set_xlabel("w (assumed outlier fraction)")
        ax.set_ylabel(unit, fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> Path:
    args = parse_args(argv)
    base = Config(method=args.method)
    key = jax.random.key(0)
    real = Path(args.sequence) if args.sequence else common.datasets.data_root() / "tum" / STATIC
    if not real.is_dir():
        raise SystemExit(f"missing sequence {real} (pass a folder or set JAXVO_DATA)")
    results = [run_sequence(real, args, base, key, "real")]
    if not args.no_augment:
        aug = common.augmented_sequence(real, args.persons, args.coverage, 0, args.max_frames, args.cache)
        results.append(run_sequence(aug, args, base, key, "augmented"))
    out = Path(args.out)
    png = out.with_suffix(".png")
    out.parent.mkdir(parents=True, exist_ok=True)
    plot(results, args, png)

    lines = common.provenance_md(f"Hyperparameter sweep ({args.method}) as one vmap'd computation", __file__, argv)
    lines += [f"Grid: thresh_lum {args.lum} x thresh_depth {args.depth} at w = {base.w}, plus w {args.w} at "
              f"thresh_lum = {base.thresh_lum}, thresh_depth = {base.thresh_depth}; all cells in one "
              "`jax.jit(jax.vmap(estimate_motion))` call per frame pair (Config's numeric fields vmapped). "
              f"Heat maps: `{png.name}`.", ""]
    lines += ["## Wall time", ""]
    lines += common.md_table(results, [
        ("sequence", "sequence", ""), ("pairs", "pairs", "d"), ("cells", "cells", "d"),
        ("vmapped s", "vmap_wall_s", ".2f"), ("separate calls s", "separate_wall_s", ".2f"),
        ("speedup", lambda r: None if not r["separate_wall_s"] else r["separate_wall_s"] / r["vmap_wall_s"], ".2f"),
        ("vmap compile s", "vmap_compile_s", ".1f"), ("single compile s", "separate_compile_s", ".1f"),
        ("max abs diff T", "max_abs_diff", ".1e")]) + [""]
    lines += ["Times exclude compilation (reported separately). `max abs diff T`: largest element-wise difference "
              "between the vmapped and the separate estimates (same keys).", ""]
    for res in results:
        lines += [f"## {res['label']}: {res['sequence']} (translational RPE per cell)", ""]
        lines += common.md_table(res["scores"], [
            ("grid", "grid", ""), ("thresh_lum", "thresh_lum", "g"), ("thresh_depth", "thresh_depth", "g"),
            ("w", "w", "g"), ("RPE-t 1 s (m/s)", "rpe1s_t", ".4f"),
            ("RPE-t per frame (mm)", lambda s: None if s["rpef_t"] is None else 1000 * s["rpef_t"], ".2f"),
            ("ATE (m)", "ate", ".4f")]) + [""]
        best = min((s for s in res["scores"] if metric_of(s)[0] is not None), key=lambda s: metric_of(s)[0],
                   default=None)
        if best:
            lines += [f"Best cell: thresh_lum {best['thresh_lum']:g}, thresh_depth {best['thresh_depth']:g}, "
                      f"w {best['w']:g} -> {metric_of(best)[1]} {metric_of(best)[0]:.4f}.", ""]
    data = {"command": common.command_line(__file__, argv), "machine": common.machine_info(),
            "lum": args.lum, "depth": args.depth, "w": args.w, "method": args.method, "results": results}
    common.write_outputs(out, lines, data)
    common.log(f"[sweep] wrote {out}, {out.with_suffix('.json')}, {png}")
    return out


if __name__ == "__main__":
    main()
