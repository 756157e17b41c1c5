"""``jaxvo augment``: composite synthetic moving persons into a real static sequence."""
from __future__ import annotations

import json
from pathlib import Path

import click

from jaxvo.camera import PRESETS
from jaxvo.cli.options import CONVENTIONS, FORCE, SEED, progress_cb
from jaxvo.cli.process import handle_errors
from jaxvo.data.outputs import check_output, check_output_folder, finish, partial_path, write_errors
from jaxvo.data import DatasetError
from jaxvo.pipelines.demo import progress_bar

__all__ = ["augment_cmd"]


@click.command("augment", help=f"""Composite synthetic moving persons into a real static sequence.

REAL_SEQ is a TUM folder with ground truth (e.g. rgbd_dataset_freiburg2_desk). K person-like
occluders walk in the real world frame in front of the camera; each is composited into colour
and depth with a per-pixel z-test, so the background keeps its real sensor noise and the
camera keeps its real ground truth (groundtruth.txt is copied). OUT_DIR gets the TUM layout
plus masks/ (255 = composited pixel), masks.txt and info.json (the real intrinsics, used by
jaxvo run). --coverage is the target fraction of the image the persons cover (calibrated on
the first frame). Frames outside the ground truth's time span (TUM recordings often start a
few frames before the motion capture) have no pose to place a person at: they are left out.

{CONVENTIONS}
""")
@click.argument("real_seq", type=click.Path(path_type=Path))
@click.argument("out_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--persons", type=click.IntRange(min=1), default=1, show_default=True, help="Number of occluders K.")
@click.option("--coverage", type=click.FloatRange(0, 1, min_open=True, max_open=True), default=0.3,
              show_default=True, help="Target fraction of the image covered by the occluders together.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of shapes, textures and paths.")
@click.option("--max-frames", type=click.IntRange(min=1), default=None, help="Write only the first N frames (that the ground truth covers).")
@click.option("--camera", "camera_preset", type=click.Choice(sorted(PRESETS)), default=None,
              help="Intrinsics of the real sequence. [default: from the folder name]")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
@FORCE
@handle_errors
def augment_cmd(real_seq, out_dir, persons, coverage, seed, max_frames, camera_preset, no_progress, force):
    from jaxvo.synthetic import augment

    real_seq = Path(real_seq)
    if not real_seq.is_dir():
        raise DatasetError(f"{real_seq}: sequence folder does not exist")
    check_output_folder(out_dir, [real_seq], force)
    tmp = partial_path(out_dir, fresh=True)
    check_output(tmp, [real_seq], force)
    pbar = None if no_progress else progress_bar(total=max_frames or 0, unit="frame", desc="augment")
    try:
        with write_errors(tmp):
            augment(real_seq, tmp, persons=persons, coverage=coverage, seed=seed, max_frames=max_frames,
                    camera=PRESETS[camera_preset] if camera_preset else None,
                    progress=progress_cb(pbar) if pbar is not None else None)
    finally:
        if pbar is not None:
            pbar.close()
    out = finish(tmp, out_dir)
    info = {}
    try:
        info = json.loads((Path(out) / "info.json").read_text())
    except (OSError, ValueError):
        pass
    cov = info.get("coverage_mean")
    click.echo(f"wrote {info.get('frames', '?')} augmented frames of {real_seq.name} to {out}"
               + (f" (mean coverage {cov:.2f})" if isinstance(cov, float) else ""))
    if info.get("frames_outside_groundtruth"):
        click.echo(f"note: left out {info['frames_outside_groundtruth']} frames outside the ground truth's "
                   f"time span (no pose to place the persons at)")
