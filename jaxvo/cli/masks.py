"""``jaxvo masks``: moving-pixel masks of a tracked sequence, decided in hindsight."""
from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from jaxvo.cli.options import CONVENTIONS, FORCE, POSITIVE, compilation_cache, compile_note, sequence_with_trajectory
from jaxvo.cli.process import CtrlC, Fail, handle_errors
from jaxvo.pipelines.demo import progress_bar
from jaxvo.pipelines.masks import write_hindsight_masks
from jaxvo.tracking.hindsight import OFFSETS as HINDSIGHT_OFFSETS, HindsightParams

__all__ = ["masks_cmd"]


@click.command("masks", help=f"""Moving-pixel masks of a tracked sequence, decided in hindsight.

SEQUENCE_DIR is a sequence folder; TRAJ a TUM trajectory file (T_world_cam per line, e.g.
written by 'jaxvo run') whose timestamps are matched to the frames within --max-dt seconds.
Frames without a pose, and those whose pose 'jaxvo run' marked held (its estimate failed and
the previous pose was kept: a guess), get no mask and serve as no other frame's view.
Each frame with a pose is compared with the frames --offsets away, before and after it, at
the trajectory's relative poses (jaxvo.tracking.hindsight): a pixel is moving when, in at least
--ratio of the frames that see it (not hidden behind something nearer), its depth or its
luminance changed (beyond the inlier thresholds, the depth's growing with z^2, the pair's
exposure offset and the image gradient); a 3-D region at least --region-ratio of whose pixels move is flagged
whole. Unlike the masks of 'jaxvo run --save-masks', these use later frames too, so a
person is flagged before it has moved off its pixels; they are only as good as the poses.

OUT_DIR gets one 8-bit PNG per frame (255 = moving), named by the frame's timestamp
(e.g. 1311868164.363181.png), the format 'jaxvo eval --masks-dir' scores. The masks are
written as they are decided, into OUT_DIR.partial, which becomes OUT_DIR at the end.

{CONVENTIONS}
""")
@click.argument("sequence_dir", type=click.Path(path_type=Path))
@click.argument("traj", type=click.Path(path_type=Path))
@click.argument("out_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--offsets", default=",".join(str(o) for o in HINDSIGHT_OFFSETS), show_default=True,
              help="Comma list of the frame offsets each frame is compared with (negative: earlier).")
@click.option("--ratio", type=click.FloatRange(0, 1, min_open=True), default=HindsightParams().ratio,
              show_default=True, help="Share of the seeing frames in which a pixel must have changed.")
@click.option("--region-ratio", type=click.FloatRange(0, 1, min_open=True),
              default=HindsightParams().region_ratio, show_default=True,
              help="Share of a 3-D region's pixels that must move for the whole region to be flagged.")
@click.option("--depth-slope", type=click.FloatRange(min=0), default=HindsightParams().depth_slope,
              show_default=True, help="The depth tolerance grows with depth: thresh-depth + depth-slope * z^2 (m).")
@click.option("--thresh-lum", type=POSITIVE, default=None,
              help="Luminance threshold (0-255). [default: Config's, 30]")
@click.option("--thresh-depth", type=POSITIVE, default=None,
              help="Depth threshold in metres. [default: Config's, 0.05]")
@click.option("--max-frames", type=click.IntRange(min=1), default=None, help="Use at most N frames of the sequence.")
@sequence_with_trajectory
@FORCE
@compilation_cache
@handle_errors
def masks_cmd(sequence_dir, traj, out_dir, offsets, ratio, region_ratio, depth_slope, thresh_lum, thresh_depth,
              max_frames, camera_preset, depth_scale, max_dt, no_progress, force):
    from jaxvo.config import Config

    try:
        offset_list = [int(o) for o in offsets.split(",") if o.strip()]
    except ValueError:
        raise Fail(f"--offsets must be a comma list of integers, got {offsets!r}") from None
    if not any(offset_list):
        raise Fail("--offsets must hold at least one nonzero frame offset")
    config = Config().replace(**{k: v for k, v in (("thresh_lum", thresh_lum), ("thresh_depth", thresh_depth))
                                 if v is not None})
    params = HindsightParams(ratio=ratio, region_ratio=region_ratio, depth_slope=depth_slope)
    pbar = []

    def on_start(seq, posed, held):
        click.echo(f"jaxvo masks: {seq.name}, {posed} of {len(seq)} frames with a pose ({held} held poses of "
                   f"{traj} left out), offsets "
                   f"{','.join(str(o) for o in offset_list)}, {seq.camera!r}", err=True)
        compile_note()          # the inputs passed their checks: now it compiles
        if not no_progress:
            pbar.append(progress_bar(total=posed, unit="frame", desc="masks"))
    ctrl_c = CtrlC()

    def on_mask(i):
        ctrl_c.check()
        if pbar:
            pbar[0].update(1)
    try:
        run = ctrl_c.run(lambda: write_hindsight_masks(
            sequence_dir, traj, out_dir, offsets=offset_list, params=params, config=config, max_frames=max_frames,
            camera_preset=camera_preset, depth_scale=depth_scale, max_dt=max_dt, force=force, on_start=on_start,
            on_mask=on_mask))
    finally:
        if pbar:
            pbar[0].close()
    moving = run.moving
    click.echo(f"wrote {len(moving)} masks to {out_dir} (moving pixels per frame: {100 * np.mean(moving):.1f} % "
               f"mean, {100 * np.max(moving):.1f} % max; {run.seconds:.1f} s)")
