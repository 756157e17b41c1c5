"""``jaxvo map``: a coloured 3-D point-cloud map (PLY) of a sequence from a trajectory."""
from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from jaxvo.cli.options import CONVENTIONS, FORCE, SEED, compilation_cache, compile_note, sequence_with_trajectory
from jaxvo.cli.process import CtrlC, Fail, handle_errors
from jaxvo.pipelines.demo import fmt, progress_bar
from jaxvo.pipelines.mapping import map_sequence

__all__ = ["map_cmd"]


@click.command("map", help=f"""Build a coloured 3-D point-cloud map (PLY) of a sequence from a trajectory.

SEQUENCE_DIR is a TUM-layout folder; TRAJ a TUM trajectory file (T_world_cam per line, e.g.
written by 'jaxvo run', or the sequence's groundtruth.txt) whose timestamps are matched to the
frames within --max-dt seconds (frames without a pose are skipped, and so are the poses 'jaxvo
run' marked held: its estimate failed and the previous pose was kept). Every N-th matched frame
(--every), the pixels with valid depth up to --max-depth metres are back-projected and moved
into the world with the trajectory's pose. Static points keep their RGB colour; moving points
(by default the segmentation of 'jaxvo masks', decided against earlier and later frames at
the trajectory's poses, which marks people whole; with --outliers, the outliers of the
estimator on the pair (frame, next frame): residuals defined but not an inlier; with
--use-masks, the pixels of the sequence's masks/) are painted green, as the outliers of the
paper's Fig. 4/7. A voxel grid (--voxel metres; 0 = off) averages position and
colour per voxel, static and moving points apart.

OUT.ply is a binary little-endian PLY (float x y z, uchar red green blue, and uchar moving:
1 = moving, 0 = static, unless --no-labels) that Open3D, MeshLab and CloudCompare open.
--preview writes a PNG rendering of it (perspective + top view).

{CONVENTIONS}
""")
@click.argument("sequence_dir", type=click.Path(path_type=Path))
@click.argument("traj", type=click.Path(path_type=Path))
@click.argument("out_ply", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--every", type=click.IntRange(min=1), default=5, show_default=True,
              help="Use every N-th frame that has a pose.")
@click.option("--voxel", type=click.FloatRange(min=0), default=0.01, show_default=True,
              help="Voxel size in metres for downsampling (0 = keep every point).")
@click.option("--method", type=click.Choice(["classic", "huber", "ransac"]), default="ransac", show_default=True,
              help="Estimator of --outliers (and whose thresholds the segmentation uses).")
@click.option("--max-frames", type=click.IntRange(min=1), default=None, help="Use at most N frames of the sequence.")
@click.option("--max-depth", type=click.FloatRange(min=0, min_open=True), default=4.0, show_default=True,
              help="Ignore depth beyond this (metres).")
@click.option("--preview", "preview", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Also write a PNG preview of the map.")
@click.option("--use-masks", is_flag=True,
              help="Label moving points from the sequence's masks/ (masks.txt) instead of running the estimator.")
@click.option("--hindsight", is_flag=True,
              help="Label moving points with the masks of 'jaxvo masks' (each frame against earlier and later "
                   "frames at the trajectory's poses). [the default]")
@click.option("--outliers", is_flag=True,
              help="Label moving points with the outliers of one estimate (frame, next frame) instead.")
@click.option("--no-labels", is_flag=True, help="No moving/static labels: every point in its RGB colour.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the jax.random key (RANSAC sampling).")
@sequence_with_trajectory
@FORCE
@compilation_cache
@handle_errors
def map_cmd(sequence_dir, traj, out_ply, every, voxel, method, max_frames, max_depth, preview, use_masks,
            hindsight, outliers, no_labels, seed, camera_preset, depth_scale, max_dt, no_progress, force):
    if use_masks + hindsight + outliers + no_labels > 1:
        raise Fail("--use-masks, --hindsight, --outliers and --no-labels exclude each other")
    labels = None if no_labels else ("masks" if use_masks else "estimate" if outliers else "hindsight")
    pbar = []

    def on_start(seq, held):
        said = (labels or "none") if labels != "estimate" else f"{method} outliers"
        click.echo(f"jaxvo map: {seq.name}, {len(seq)} frames ({held} held poses of {traj} left out), every {every}, "
                   f"labels {said}, {seq.camera!r}", err=True)
        if labels in ("estimate", "hindsight"):   # the inputs passed their checks: now it compiles
            compile_note()
        if not no_progress:
            pbar.append(progress_bar(total=0, unit="frame", desc="map"))
    ctrl_c = CtrlC()

    def progress(done, total):
        ctrl_c.check()
        if pbar:
            pbar[0].total = total
            pbar[0].update(done - pbar[0].n)
    try:
        run = ctrl_c.run(lambda: map_sequence(sequence_dir, traj, out_ply, every=every, voxel=voxel, method=method,
                                              max_frames=max_frames, max_depth=max_depth, preview=preview,
                                              labels=labels, seed=seed, camera_preset=camera_preset,
                                              depth_scale=depth_scale, max_dt=max_dt, force=force,
                                              on_start=on_start, progress=progress))
    finally:
        if pbar:
            pbar[0].close()
    res, cloud, seq = run.map, run.map.cloud, run.sequence
    lines = [f"frames        {len(res.frames)} used (every {every} of {len(seq)}; frames with a pose within "
             f"{max_dt} s)",
             f"points        {len(cloud)} after a {voxel:g} m voxel grid ({res.raw_points} back-projected), "
             f"{int(cloud.moving.sum())} moving ({100 * float(cloud.moving.mean()):.1f} %)",
             f"map           {out_ply} (binary PLY, static points in RGB, moving points green"
             + (", property 'moving')" if labels else ")")]
    if labels == "estimate":
        lines.insert(1, f"inlier ratio  {fmt(float(np.nanmean(res.inlier_ratio)), 3)} (mean, {method})")
    if preview is not None:
        lines.append(f"preview       {preview}")
    lines.append(f"time          {res.seconds:.1f} s")
    click.echo("\n".join(lines))
