"""Moving-pixel masks in hindsight (``jaxvo masks``) against the default odometry's own masks.

On sequences with exact moving masks (the synthetic seq1-3 and handheld-fast, and the dynamic
augmentation of fr2_desk: 2 persons, 30 % coverage), for each seed:

* the default odometry (``jaxvo.track``) runs along the sequence; its moving mask is scored as
  ``experiments/paper_sequences.py`` scores it (per estimate, on its reference frame, over the
  pixels it decided: the estimate's valid pixels and the segmentation's dynamic ones);
* :func:`jaxvo.tracking.hindsight.sequence_masks` then decides every frame's mask from the odometry's
  poses (``estimated``; the frames whose estimate failed and whose pose was held get no mask and
  serve as no view, as ``jaxvo masks`` leaves out the poses ``jaxvo run`` marks held; their true
  moving pixels count as missed) and from the ground-truth poses (``true``: what the method gives when the
  poses are right). These are scored per frame over **every pixel with valid depth** (a superset
  of the pixels the online measure counts, so the comparison does not favour them).

Precision and recall treat the moving class as positive, pooled per seed; the tables give the
mean and range over the seeds, and the pooled counts of all seeds.

    python experiments/hindsight_masks.py                                   # the results file
    python experiments/hindsight_masks.py --sequences seq2 --augment '' --seeds 0 --frames 30

Writes ``experiments/results/hindsight_masks/hindsight_masks.md`` and ``.json``; sequences are cached in
``experiments/results/cache/`` (shared with ``paper_sequences.py``).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

import common

import jax  # noqa: E402

from jaxvo.data import trajectory  # noqa: E402
from jaxvo.data.tum import TumSequence  # noqa: E402
from jaxvo.tracking.hindsight import OFFSETS, HindsightParams, sequence_masks  # noqa: E402

import paper_sequences  # noqa: E402


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    paper_sequences.add_job_args(ap, "seq1,seq2,seq3,handheld-fast", "0,1,2,3,4,5,6,7,8,9,10,11")
    ap.add_argument("--synthetic-seeds", default="0,1,2",
                    help="seeds of the synthetic sequences (default 0-2: they are 90 frames each)")
    ap.add_argument("--ratio", type=float, default=HindsightParams().ratio, help="HindsightParams.ratio")
    ap.add_argument("--region-ratio", type=float, default=HindsightParams().region_ratio,
                    help="HindsightParams.region_ratio")
    ap.add_argument("--depth-slope", type=float, default=HindsightParams().depth_slope,
                    help="HindsightParams.depth_slope")
    ap.add_argument("--quick", action="store_true",
                    help="a smoke run: seq1 only, 8 frames, seed 0, no augmentation")
    ap.add_argument("--out", type=Path, default=common.RESULTS / "hindsight_masks" / "hindsight_masks.md",
                    help="markdown output (json next to it)")
    a = ap.parse_args(argv)
    if a.quick:
        a.sequences, a.augment, a.frames, a.seeds, a.synthetic_seeds = "seq1", "", 8, "0", "0"
    paper_sequences.check_job_args(a, ap)
    try:
        a.synthetic_seed_list = common.int_list(a.synthetic_seeds)
    except ValueError as e:
        ap.error(f"--synthetic-seeds: {e}")
    return a


def hindsight_counts(seq: TumSequence, poses, true_masks: list, params: HindsightParams) -> np.ndarray:
    """(tp, fp, fn, tn) of the hindsight masks from ``poses`` (N, 4, 4) T_world_cam, pooled over the
    frames, on each frame's pixels with valid depth (up to ``Config().max_depth``); a frame without
    a pose (NaN) has no mask: nothing of it counts as moving."""
    counts = np.zeros(4, np.int64)
    masks = dict(sequence_masks(seq.frame, poses, seq.camera, params=params))
    for i in range(len(seq)):
        d = np.asarray(seq.frame(i).depth)
        m = masks.get(i, np.zeros(d.shape, bool))
        valid = (d > 0) & (d <= 4.0)
        t = true_masks[i]
        counts += [(m & t & valid).sum(), (m & ~t & valid).sum(), (~m & t & valid).sum(), (~m & ~t & valid).sum()]
    return counts


def scores(c) -> tuple:
    tp, fp, fn = (int(x) for x in c[:3])
    return (tp / (tp + fp) if tp + fp else None, tp / (tp + fn) if tp + fn else None)


def _cell(values, spec=".3f") -> str:
    v = [x for x in values if x is not None]
    if not v:
        return "n/a"
    return f"{np.mean(v):{spec}} ({min(v):{spec}} - {max(v):{spec}})" if len(v) > 1 else f"{v[0]:{spec}}"


def main(argv: Optional[Sequence[str]] = None) -> dict:
    a = parse_args(argv)
    argv_list = list(sys.argv[1:] if argv is None else argv)
    params = HindsightParams(ratio=a.ratio, region_ratio=a.region_ratio, depth_slope=a.depth_slope)
    t_start = time.perf_counter()
    jobs = paper_sequences.sequence_jobs([], a.augment, a.seed_list, a.frames, cache=a.cache)
    jobs += paper_sequences.sequence_jobs(a.sequences, [], a.synthetic_seed_list, a.frames, cache=a.cache)
    rows = []
    for name, seed, seq, true, frames in paper_sequences.opened_jobs(jobs):
        common.log(f"{name} (seed {seed}): the default odometry, {len(seq)} frames")
        run = paper_sequences.run_default(seq, frames, true, jax.random.key(seed))
        m = run["mask"]
        row = {"sequence": name, "seed": seed, "frames": len(seq),
               "online": (m["tp"], m["fp"], m["fn"], m["tn"]), "ate": common.evaluate(seq, run["relative"])["ate"]}
        # a held frame's pose is a guess: no mask, no view (as jaxvo masks leaves out '# held' poses)
        held = ~np.concatenate([[True], run["valid"]])
        estimated = np.where(held[:, None, None], np.nan, trajectory.chain(run["relative"]))
        row["held"] = int(held.sum())
        for which, poses in (("estimated", estimated),
                             ("true", seq.groundtruth_at_frames()[1])):
            t0 = time.perf_counter()
            row[which] = hindsight_counts(seq, poses, true, params)
            row[f"{which}_s"] = time.perf_counter() - t0
        common.log(f"  online {scores(row['online'])}, hindsight {scores(row['estimated'])} "
                   f"(true poses {scores(row['true'])}), {row['estimated_s']:.1f} s")
        rows.append(row)

    lines = common.provenance_md("Moving-pixel masks in hindsight", __file__, argv_list)
    lines += [f"Offsets {', '.join(str(o) for o in OFFSETS)} frames; ratio {params.ratio}, region_ratio "
              f"{params.region_ratio}, depth_slope {params.depth_slope} (`jaxvo.tracking.hindsight.HindsightParams`). {a.frames} frames at most per "
              f"sequence; " + "; ".join(([f"the augmentation's seeds {a.seeds}"] if a.augment else [])
                                         + ([f"the synthetic sequences' {a.synthetic_seeds}"] if a.sequences else []))
              + ". "
              f"Total wall time {time.perf_counter() - t_start:.0f} s.", "",
              "*online*: the default odometry's moving mask as `paper_sequences.py` scores it (per estimate, "
              "on its reference, over the pixels it decided). *hindsight*: `jaxvo.tracking.hindsight.sequence_masks` "
              "from the odometry's poses (*estimated*) and from the ground truth (*true*), per frame over "
              "every pixel with valid depth. Precision / recall: mean (min - max) of the per-seed pooled "
              "scores; *pooled*: all seeds' counts together. *s per frame*: the hindsight pass from the "
              "estimated poses, its compilation included.", ""]
    table = []
    for name in dict.fromkeys(r["sequence"] for r in rows):
        rs = [r for r in rows if r["sequence"] == name]
        entry = {"sequence": name, "seeds": len(rs), "ate": _cell([r["ate"] for r in rs], ".4f"),
                 "s_per_frame": float(np.mean([r["estimated_s"] / r["frames"] for r in rs]))}
        for which in ("online", "estimated", "true"):
            per = [scores(r[which]) for r in rs]
            pooled = scores(np.sum([r[which] for r in rs], axis=0))
            entry[which] = {"precision": _cell([p for p, _ in per]), "recall": _cell([q for _, q in per]),
                            "pooled": f"{common.fmt(pooled[0], '.3f')} / {common.fmt(pooled[1], '.3f')}"}
        table.append(entry)
    lines += ["| sequence | seeds | default ATE m | online P | online R | online pooled P / R | hindsight P | "
              "hindsight R | hindsight pooled P / R | true poses: pooled P / R | s per frame |",
              "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for e in table:
        lines.append(f"| {e['sequence']} | {e['seeds']} | {e['ate']} | {e['online']['precision']} | "
                     f"{e['online']['recall']} | {e['online']['pooled']} | {e['estimated']['precision']} | "
                     f"{e['estimated']['recall']} | {e['estimated']['pooled']} | {e['true']['pooled']} | "
                     f"{e['s_per_frame']:.2f} |")
    lines += ["", "Per seed (precision / recall):", "",
              "| sequence | seed | default ATE m | online | hindsight | true poses |", "| --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        cells = [" / ".join(common.fmt(x, ".3f") for x in scores(r[w])) for w in ("online", "estimated", "true")]
        lines.append(f"| {r['sequence']} | {r['seed']} | {common.fmt(r['ate'], '.4f')} | " + " | ".join(cells) + " |")
    data = {"command": common.command_line(__file__, argv_list),
            "machine": common.machine_info(), "params": params._asdict(), "offsets": list(OFFSETS),
            "rows": rows, "table": table}
    out = common.write_outputs(a.out, lines, data)
    common.log(f"wrote {out}")
    return data


if __name__ == "__main__":
    main()
