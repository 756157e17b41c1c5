"""``jaxvo synth``: write a synthetic dynamic RGB-D sequence with exact ground truth."""
from __future__ import annotations

from pathlib import Path

import click

from jaxvo.camera import DEFAULT, camera_for_size
from jaxvo.cli.options import CONVENTIONS, FORCE, SEED, progress_cb, size_option
from jaxvo.cli.process import handle_errors
from jaxvo.data.outputs import check_output_folder, finish, partial_path, write_errors
from jaxvo.pipelines.demo import progress_bar
from jaxvo.synthetic import SEQUENCES

__all__ = ["synth_cmd"]


@click.command("synth", help=f"""Write a synthetic dynamic RGB-D sequence with exact ground truth.

NAME picks the camera / person motion (the paper's Table II): seq0 hand-held camera, static
scene; seq1 fixed camera, one person walking; seq2 camera panning at 2 deg/s on a pan-tilt
head, one person; seq3 as seq2 with two persons; handheld-fast hand-held camera with a
person moving fast and close; crowd (for long runs) hand-held camera panning slowly, three persons
walking on their own paths, at times covering half the image; crowd-close as crowd, with persons
close to the camera who walk into the view, stand there for seconds and walk out (up to three
quarters of the image). Frames at 30 Hz, deterministic from --seed.

OUT_DIR gets the TUM layout (rgb/, depth/ 16-bit metres x 5000, rgb.txt, depth.txt,
groundtruth.txt as T_world_cam) plus masks/ (8-bit, 255 = pixel on a moving object),
masks.txt and info.json (intrinsics, used by jaxvo run), so jaxvo run and jaxvo eval
work on it unchanged.

{CONVENTIONS}
""")
@click.argument("name", type=click.Choice(list(SEQUENCES)))
@click.argument("out_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--frames", type=click.IntRange(min=2), default=300, show_default=True, help="Number of frames (30 Hz).")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the scene, textures and motions.")
@click.option("--size", callback=size_option, default="640x480", show_default=True,
              help="Image size WIDTHxHEIGHT (e.g. 640x480, 320x240, 424x240, 848x480); intrinsics are the "
                   "default 525/319.5/239.5 camera scaled to it (jaxvo.camera.camera_for_size).")
@click.option("--sensor/--no-sensor", default=False, show_default=True,
              help="Kinect-like sensor effects (depth noise ~Z^2, quantisation, missing depth at edges and "
                   "beyond 4 m, intensity noise, exposure changes).")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
@FORCE
@handle_errors
def synth_cmd(name, out_dir, frames, seed, size, sensor, no_progress, force):
    from jaxvo.synthetic import SensorModel, generate

    check_output_folder(out_dir, [], force)
    cam = camera_for_size(DEFAULT, *size)
    tmp = partial_path(out_dir, fresh=True)
    pbar = None if no_progress else progress_bar(total=frames, unit="frame", desc=f"render {name}")
    try:
        with write_errors(tmp):
            generate(name, tmp, frames=frames, seed=seed, camera=cam, sensor=SensorModel() if sensor else None,
                     progress=progress_cb(pbar) if pbar is not None else None)
    finally:
        if pbar is not None:
            pbar.close()
    out = finish(tmp, out_dir)
    click.echo(f"wrote {frames} frames of {name} ({size[0]}x{size[1]}, seed {seed}) to {out}")
