"""``jaxvo demo``: a synthetic dynamic scene, classic vs Huber vs RANSAC, one table and figures."""
from __future__ import annotations

from pathlib import Path

import click

from jaxvo.cli.options import CONVENTIONS, FORCE, SEED, compilation_cache, compile_note, size_option
from jaxvo.cli.process import CtrlC, exit_now, handle_errors, ignore_ctrl_c
from jaxvo.pipelines.demo import run_demo

__all__ = ["demo_cmd"]


@click.command("demo", help=f"""Synthetic dynamic scene -> classic vs Huber vs RANSAC, one table and figures.

Generates a short synthetic sequence with exact ground truth and moving-pixel masks (default
seq2, the paper's pan-tilt case: the camera pans at 2 deg/s while a person walks through the
view; Kinect-like sensor noise; handheld-fast is the hard case, a person fast and close
covering up to two thirds of the image), runs the three
estimators on it and prints one table:
RPE per frame (translation mm/frame, rotation deg/frame, RMSE over all consecutive pairs),
ATE (mm, after rigid alignment), frames/s after compilation, mean inlier ratio, and the
precision / recall of each estimator's outlier mask against the true moving pixels (on the
reference frame's pixels where the residuals are defined).

Writes into --out: sequence/ (the generated sequence, reused when it matches; a sequence/
folder jaxvo did not write is refused unless --force), traj_<method>.txt,
results.json, results.md, trajectories.png (top view), translational_error.png (error per
frame over time), inliers_outliers.png (one dynamic frame: inliers blue, outliers green, the
true moving pixels outlined red; like the paper's Fig. 4).

Images default to 320x240 so that the whole demo, JAX compilation of three estimators
included, takes about a minute or two on two CPU cores; --size 640x480 is the paper's size.

{CONVENTIONS}
""")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=Path("jaxvo-demo"),
              show_default=True, help="Output folder.")
@click.option("--frames", type=click.IntRange(min=3), default=100, show_default=True,
              help="Number of frames (30 Hz).")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the scene and of RANSAC.")
@click.option("--sequence", "seq_name", type=click.Choice(["seq0", "seq1", "seq2", "seq3", "handheld-fast"]),
              default="seq2", show_default=True,
              help="Which synthetic motion (see jaxvo synth --help); seq2 is the paper's pan-tilt scene.")
@click.option("--size", callback=size_option, default="320x240", show_default=True,
              help="Image size WIDTHxHEIGHT.")
@click.option("--sensor/--no-sensor", default=True, show_default=True, help="Kinect-like sensor effects.")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
@FORCE
@compilation_cache
@handle_errors
def demo_cmd(out_dir, frames, seed, seq_name, size, sensor, no_progress, force):
    ctrl_c = CtrlC()
    result = ctrl_c.run(lambda: run_demo(out_dir, frames=frames, seed=seed, seq_name=seq_name, size=size,
                                         sensor=sensor, progress=not no_progress, force=force, check=ctrl_c.check,
                                         on_start=compile_note),
                        lambda: click.echo("\ninterrupted (Ctrl-C)", err=True))
    if ctrl_c.interrupted:   # pressed after the last step: the files are complete, the exit code says so
        ignore_ctrl_c()
        click.echo("interrupted (Ctrl-C); the finished files are complete", err=True)
        exit_now(130)
    click.echo(result.table)
    click.echo(f"\nfigures and results in {out_dir}/ ({result.wall_s:.0f} s)")
