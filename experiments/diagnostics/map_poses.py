"""What the moving masks reach with other poses for the segmentation's motion test.

Each new reference of the default odometry is tested for motion against an earlier frame
(:func:`jaxvo.tracking.segmentation.motion_regions`) at the pose between the two that the odometry
chained (``Odometry.view_pose``). Where persons the map has not found yet pull the first
estimates, that pose is centimetres off, and parallax then moves the nearest static objects in
the test as if they walked. This script runs the default odometry with that one pose taken from
elsewhere, everything else unchanged:

* ``chained``: as the library does (the default);
* ``true``: the ground-truth relative pose (what a perfect pose there would give: a bound);
* ``re-estimated``: RANSAC (``Config()``) between the two frames' motion-test images (160x120 at
  640x480), started from the chained pose, kept where its estimate is valid;
* ``re-estimated-full``: the same between the two frames themselves (full resolution; the
  odometry no longer holds the earlier frame, the script passes it in).

It reports the moving mask as ``experiments/paper_sequences.py`` scores it (pooled over the
seeds) and the ATE, per sequence and variant.

    python -m experiments.diagnostics.map_poses      # fr2_desk and fr3 long_office + persons, seeds 0-11

Writes ``experiments/results/map_poses/map_poses.md`` and ``.json``; sequences are cached in
``experiments/results/cache/`` (shared with ``paper_sequences.py``).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import List, Optional, Sequence

import numpy as np

from experiments import common

import jax  # noqa: E402

from jaxvo import geometry
from jaxvo.tracking import odometry  # noqa: E402
from jaxvo.config import Config  # noqa: E402
from jaxvo.frame import Frame  # noqa: E402

from experiments import paper_sequences

VARIANTS = ("chained", "true", "re-estimated", "re-estimated-full")


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    paper_sequences.add_job_args(ap, "", "0,1,2,3,4,5,6,7,8,9,10,11")
    ap.set_defaults(augment="tum")
    ap.add_argument("--variants", default=",".join(VARIANTS), help=f"comma list of {', '.join(VARIANTS)}")
    ap.add_argument("--out", type=Path, default=common.RESULTS / "map_poses" / "map_poses.md", help="markdown output (json next to it)")
    a = ap.parse_args(argv)
    paper_sequences.check_job_args(a, ap)
    a.variants = [v.strip() for v in a.variants.split(",") if v.strip()]
    bad = [v for v in a.variants if v not in VARIANTS]
    if bad or not a.variants:
        ap.error(f"--variants: choose from {', '.join(VARIANTS)}")
    return a


def odometry_with(variant: str, T_world_cam_true: Optional[np.ndarray] = None, frames: Optional[list] = None):
    """A subclass of :class:`Odometry` whose motion test runs at ``variant``'s pose
    (``view_pose``: T_view_new, float32).

    T_world_cam_true: (N, 4, 4) ground-truth camera-to-world poses of the frames ("true").
    frames: the sequence's frames ("re-estimated-full")."""
    if variant == "chained":
        return odometry.Odometry

    class ViewPoseOdometry(odometry.Odometry):
        def view_pose(self, view, new, T_world_new):
            if variant == "true":
                return (geometry.inverse(T_world_cam_true[view]) @ T_world_cam_true[new]).astype(np.float32)
            T0 = super().view_pose(view, new, T_world_new)
            if variant == "re-estimated-full":
                ref, other, camera = frames[new], frames[view], self.camera
            else:
                (ref_int, ref_depth), (view_int, view_depth) = self.static_map.cues[new], self.static_map.cues[view]
                ref = Frame(np.asarray(ref_int), np.asarray(ref_depth))
                other = Frame(np.asarray(view_int), np.asarray(view_depth))
                camera = self.static_map.cue_camera
            # a key of its own, apart from every frame's estimate (those fold in j - 1 < 10**6)
            est = odometry.estimate_motion(ref, other, camera, Config(), jax.random.fold_in(self.key, 10 ** 6 + new),
                                           init=T0)
            return np.asarray(est.T_cur_ref, np.float32) if bool(est.valid) else T0

    return ViewPoseOdometry


def main(argv: Optional[Sequence[str]] = None) -> dict:
    a = parse_args(argv)
    argv_list = list(sys.argv[1:] if argv is None else argv)
    t_start = time.perf_counter()
    rows = []
    jobs = paper_sequences.sequence_jobs(a.sequences, a.augment, a.seed_list, a.frames, cache=a.cache)
    for name, seed, seq, true_masks, frames in paper_sequences.opened_jobs(jobs):
        ok, G = seq.groundtruth_at_frames()
        if "true" in a.variants and not np.all(ok):
            raise SystemExit(f"{name} (seed {seed}): ground truth misses {int((~ok).sum())} frames; "
                             "the 'true' variant needs a pose for every frame")
        for variant in a.variants:
            common.log(f"{name} (seed {seed}): {variant}")
            r = paper_sequences.run_default(seq, frames, true_masks, jax.random.key(seed),
                                            odometry=odometry_with(variant, G, frames))
            m = r["mask"]
            rows.append({"sequence": name, "seed": seed, "variant": variant,
                         "ate": common.evaluate(seq, r["relative"])["ate"],
                         "counts": [m["tp"], m["fp"], m["fn"]]})
    write(a, argv_list, rows, time.perf_counter() - t_start)
    return {"rows": rows}


def _scores(tp, fp, fn) -> tuple:
    return (tp / (tp + fp) if tp + fp else None, tp / (tp + fn) if tp + fn else None)


def write(a, argv, rows: List[dict], total_s: float) -> None:
    lines = common.provenance_md("Moving masks with other poses for the motion test", __file__, argv)
    lines += ["", f"The default odometry (`jaxvo.track`, `TrackConfig()`) with the pose of each new reference's "
              f"motion test against its earlier view (`Odometry.view_pose`) from the chained estimates "
              f"(*chained*, the library's), from the ground truth (*true*), or re-estimated by RANSAC between the "
              f"two frames' motion-test images (*re-estimated*, 160x120) or the frames themselves "
              f"(*re-estimated-full*); everything else unchanged. Seeds "
              f"{', '.join(map(str, a.seed_list))}, at most {a.frames} frames per sequence, the augmentations with "
              f"2 persons covering ~30 % of the view as `experiments/paper_sequences.py` makes them. Moving mask as "
              f"that script scores it, pooled over the seeds' pixels; ATE mean (range) over the seeds. Total wall "
              f"time {total_s:.0f} s.", "",
              "| sequence | poses for the motion test | mask P | mask R | ATE m |", "| --- | --- | --- | --- | --- |"]
    for name in dict.fromkeys(r["sequence"] for r in rows):
        for variant in dict.fromkeys(r["variant"] for r in rows):
            rs = [r for r in rows if r["sequence"] == name and r["variant"] == variant]
            p, rc = _scores(*np.sum([r["counts"] for r in rs], 0).tolist())
            ate = [r["ate"] for r in rs if r["ate"] is not None]
            ate_s = f"{np.mean(ate):.4f} ({min(ate):.4f}-{max(ate):.4f})" if ate else "n/a"
            lines.append(f"| {name} | {variant} | {common.fmt(p, '.3f')} | {common.fmt(rc, '.3f')} | {ate_s} |")
    common.write_outputs(a.out, lines, {"rows": rows})


if __name__ == "__main__":
    main()
