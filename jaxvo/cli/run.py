"""``jaxvo run``: track one sequence, or several as batches, and write their trajectories."""
from __future__ import annotations

import sys
from pathlib import Path

import click
import numpy as np

from jaxvo.camera import DEPTH_CORRECTIONS, LENSES, PRESETS
from jaxvo.cli.options import (CONVENTIONS, DEPTH_SCALE_HELP, FORCE, POSITIVE, SEED, compilation_cache, compile_note,
                               depth_scale_option, device, lens_option, scale_text)
from jaxvo.cli.process import CtrlC, exit_now, handle_errors
from jaxvo.data.outputs import partial_path
from jaxvo.data import DatasetError
from jaxvo.pipelines.demo import fmt, progress_bar
from jaxvo.pipelines.run import count_poses, execute_run, expand_sequences, plan_run
from jaxvo.pipelines.settings import setup_run

__all__ = ["run_cmd"]


@click.command("run", help=f"""Track a sequence and write its trajectory.

SEQUENCE_DIR is an RGB-D sequence folder: the TUM RGB-D layout (rgb.txt, depth.txt, rgb/,
depth/ with 16-bit depth PNGs = metres x 5000, optional groundtruth.txt; TUM, Bonn RGB-D
Dynamic, ETH3D SLAM with its calibration.txt, jaxvo synthetic), ICL-NUIM (associations.txt)
or Redwood / Open3D (color/ and depth/ folders, depth in millimetres). Colour and depth are
associated by nearest timestamp (at most --max-dt seconds apart). Image size comes from the
images; intrinsics from --camera / --fx ..., else the folder's calibration file, else the
preset for the folder name (scaled to the image size: a guess, printed as such). Depth whose
median is outside 0.2-10 m (or under 0.7 m with the layout's default scale: millimetres read
as 1/5000 m) stops the run with the --depth-scale to pass.

The trajectory file starts with '#' lines naming jaxvo's version, the method, seed,
full config and keyframe policy (JSON), the machine (CPU, usable cores, jax/jaxlib) and the
reader's settings (jaxvo run SEQ --config TRAJ reruns it bitwise on the same machine, and
says what differs on another); it is written and flushed one line per frame to OUT.partial while
the run goes on (the first frame at the identity; each line once its refined pose is final, a few
frames later, or at once with --poses tracked) and renamed to OUT when complete, so a run
that fails, is interrupted (Ctrl-C) or killed keeps every finished frame in OUT.partial and
never leaves a half trajectory under OUT; Ctrl-C prints the summary of what was done and
exits with code 130. Outputs that would replace or land inside an input are refused
(--force to allow).

At the end a summary: frames, failures (pairs whose estimate was flagged invalid: too few
inliers, too little depth or texture agreement, or ill-conditioned; and frames whose depth image
has no valid pixel, a covered sensor, held without an estimate), mean inlier ratio, compile time (the first pair's wall time,
which includes JAX compilation) and frames/s after it (the progress bar's fps). A run in which
more than half of the pairs failed produced nothing usable (a wrong --depth-scale, masks that
hide every pixel): after the summary one error line names the likely cause, the trajectory is
kept, and the exit code is 2. With groundtruth.txt it also prints
RPE with a delta of 1 frame (m/frame, deg/frame) and of 1 s when the run is long enough
(m/s, deg/s), and ATE (m, after alignment) with the scale of the similarity alignment (1 for a
metric trajectory; a few per cent off where the depth reads too far or too near: --depth-scale).

Pairs i -> i+1 use the random key jax.random.fold_in(jax.random.key(SEED), i), exactly as
jaxvo.tracking.odometry.track does, so the CLI and the library give identical trajectories.

Several SEQUENCE_DIRs (or a folder holding sequence folders) are tracked together: sequences
of the same image size run as one batch (their estimates jax.vmap'd in lockstep, spread over
the available devices with jax.sharding; each keeps its own keyframes and segmentation and the
key of SEED), so the batch compiles once. Each sequence's trajectory goes to
OUT_DIR/<sequence name>.txt (--out-dir, default the current folder) and gets one summary line;
a frame that does not read stops only its own sequence (its trajectory keeps its .partial name
and its error line), and a sequence done is renamed at once.
A batched pose equals the sequence's pose alone up to float rounding of the batched program
(robust steps can turn that into ~1 mm, see jaxvo.tracking.batch).

{CONVENTIONS}
""")
@click.argument("sequence_dirs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--method", type=click.Choice(["classic", "huber", "ransac"]), default=None,
              help="Estimator: classic least squares, Huber IRLS, or the paper's RANSAC. [default: ransac, "
                   "or the config file's]")
@click.option("--out", "out", type=click.Path(dir_okay=False, path_type=Path), default=Path("traj.txt"),
              show_default=True, help="Trajectory file to write (TUM format, T_world_cam).")
@click.option("--out-dir", type=click.Path(file_okay=False, path_type=Path), default=Path("."),
              show_default=True, help="With several sequences: the folder for their trajectories "
                                      "(<sequence name>.txt each).")
@click.option("--max-frames", type=click.IntRange(min=2), default=None, help="Use at most N frames.")
@click.option("--start", type=click.IntRange(min=0), default=0, show_default=True,
              help="Index of the first (associated) frame to use.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the jax.random key (RANSAC sampling).")
@click.option("--config", "config_file", type=click.Path(path_type=Path), default=None,
              help="JSON object of jaxvo.Config fields (e.g. {\"p\": 0.99, \"w\": 0.3, \"thresh_lum\": 30, "
                   "\"blocks\": [4, 2, 1, 1]}), or a trajectory file written by jaxvo run: its '#' header gives "
                   "the config, seed, keyframe policy, frames, depth scale and intrinsics, so the run is "
                   "reproduced bitwise on the same machine (with the same usable cores; a note names what "
                   "differs on another). Options given on the command line override it.")
@click.option("--thresh-lum", type=POSITIVE, default=None,
              help="Inlier threshold on |luminance residual|, 0-255 units. [default: 30]")
@click.option("--thresh-depth", type=POSITIVE, default=None,
              help="Inlier threshold on |depth residual|, metres. [default: 0.05]")
@click.option("--finest-level", type=click.IntRange(min=0), default=None,
              help="Stop the coarse-to-fine estimate at this pyramid level (0 = full resolution, 1 = half, ...); "
                   "faster, less accurate. [default: 0]")
@click.option("--save-masks", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Write each pair's outlier mask (8-bit PNG, 255 = outlier: residuals defined but not an "
                   "inlier, or dynamic for the segmentation) at full image size into this new folder, named "
                   "by the reference and the current frame's timestamps (the mask lives on the reference "
                   "image's pixels), e.g. 1311868164.363181-1311868164.395219.png, listed in masks.txt "
                   "(reference timestamp, file, current timestamp), which jaxvo eval --masks-dir reads.")
@click.option("--camera", "camera_preset", type=click.Choice(sorted(PRESETS)), default=None,
              help="Intrinsics preset (640x480). [default: the folder's calibration.txt (ETH3D), "
                   "camera_intrinsic.json (Open3D) or info.json (jaxvo), else from the folder name: "
                   "freiburg1/2/3 -> fr1/fr2/fr3, rgbd_bonn_* -> bonn, otherwise default (525, 525, 319.5, 239.5), "
                   "scaled to the image size]")
@click.option("--depth-scale", default=None, callback=depth_scale_option, metavar="SCALE", help=DEPTH_SCALE_HELP)
@click.option("--mask-dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Folder of user masks, one 8-bit PNG per colour frame named like the colour image (or "
                   "<timestamp>.png): nonzero = the pixel may be used, 0 = ignore it (e.g. a person detector's "
                   "people). A frame's mask applies where it is the reference; frames without one use every "
                   "pixel. jaxvo's own outlier decision still runs on the pixels left.")
@click.option("--fx", type=float, default=None, help="Override the focal length fx (pixels).")
@click.option("--fy", type=float, default=None, help="Override the focal length fy (pixels).")
@click.option("--cx", type=float, default=None, help="Override the principal point cx (pixels, column).")
@click.option("--cy", type=float, default=None, help="Override the principal point cy (pixels, row).")
@click.option("--lens", default=None, callback=lens_option, metavar="LENS",
              help="Undistort the images as they are read, for this lens: k1,k2,p1,p2,k3 (OpenCV's order), "
                   "a published one: fr1, fr2 (TUM), bonn, or 'none' (the images as they are). [default: the "
                   "published lens of the sensor the folder name identifies (freiburg1/2, rgbd_bonn_*) where "
                   "the intrinsics are its preset, else none]")
@click.option("--max-dt", type=POSITIVE, default=0.02, show_default=True,
              help="Maximum colour/depth (and estimate/ground-truth) timestamp difference, seconds.")
@click.option("--keyframe-gap", type=click.IntRange(min=1), default=None,
              help="Each frame is estimated against a reference (keyframe) up to this many frames back "
                   "(earlier when the estimate says the reference no longer serves) [default: 6, and "
                   "frame to frame while the segmentation sees nothing move; a gap given here is kept "
                   "throughout]; 1 = frame to frame (see jaxvo.TrackConfig).")
@click.option("--keyframe-lag", type=click.IntRange(min=0), default=None,
              help="After the reference moves it is this many frames behind the current one "
                   "[default: half of --keyframe-gap].")
@click.option("--segment/--no-segment", default=None,
              help="Keep a static/dynamic segmentation across frames (free-space votes of earlier and "
                   "later frames, carried from reference to reference) and trust only static pixels "
                   "[default: on, off with --frame-to-frame].")
@click.option("--window", type=click.IntRange(min=1), default=None,
              help="Keyframes in the window: each new keyframe is estimated against the others and their "
                   "poses are refined together; a frame that fails against its reference is tried against "
                   "them [default: 3; 1 = the single reference; 1 with --frame-to-frame].")
@click.option("--poses", type=click.Choice(["tracked", "refined"]), default=None,
              help="The trajectory's poses: as tracked, a line per frame as it goes; or refined in hindsight, "
                   "each frame on the latest pose of its keyframe, a line once it is final (a few frames "
                   "later; the rest at the end or at Ctrl-C) [default: refined; tracked with --frame-to-frame].")
@click.option("--frame-to-frame", is_flag=True,
              help="The paper's chaining: every frame against the previous one, no segmentation. With "
                   "--config '{\"prior_candidate\": \"raw\", ...}' or --paper, the published algorithm.")
@click.option("--paper", is_flag=True,
              help="The seed paper's algorithm as published: jaxvo.Config.paper(method) and "
                   "--frame-to-frame.")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
@FORCE
@compilation_cache
@handle_errors
def run_cmd(sequence_dirs, method, out, out_dir, max_frames, start, seed, config_file, thresh_lum, thresh_depth,
            finest_level, save_masks, camera_preset, depth_scale, mask_dir, fx, fy, cx, cy, lens, max_dt, keyframe_gap,
            keyframe_lag, segment, window, poses, frame_to_frame, paper, no_progress, force):
    dirs = expand_sequences(sequence_dirs)
    ctx = click.get_current_context()

    def given(name, value):  # None where not given on the command line: a trajectory header may set it
        return None if ctx.get_parameter_source(name) == click.core.ParameterSource.DEFAULT else value

    if len(dirs) > 1:
        for name, value in (("--out", given("out", out) is not None), ("--save-masks", save_masks is not None),
                            ("--mask-dir", mask_dir is not None)):
            if value:
                raise DatasetError(f"{name} is for one sequence; with {len(dirs)} sequences use --out-dir"
                                   if name == "--out" else f"{name} is for one sequence, got {len(dirs)} sequences")
    setup = setup_run(config_file, method=method, thresh_lum=thresh_lum, thresh_depth=thresh_depth,
                      finest_level=finest_level, seed=given("seed", seed), keyframe_gap=keyframe_gap,
                      keyframe_lag=keyframe_lag, segment=segment, window=window, poses=poses,
                      frame_to_frame=frame_to_frame,
                      paper=paper,
                      camera_preset=camera_preset, fx=fx, fy=fy, cx=cx, cy=cy, depth_scale=depth_scale,
                      max_dt=given("max_dt", max_dt), start=given("start", start), max_frames=max_frames,
                      mask_dir=mask_dir, lens=lens, from_header=len(dirs) == 1)
    if setup.machine_differences:
        click.echo(f"note: {config_file} was written on another machine ({'; '.join(setup.machine_differences)}); "
                   "the rerun may differ at float rounding, which the robust steps through a crowd can grow "
                   "(README: Reproducible runs)", err=True)
    plan = plan_run(dirs, setup, out=out, out_dir=out_dir, save_masks=save_masks, config_file=config_file,
                    force=force)
    _print_provenance(config_file, setup, plan)
    if len(dirs) > 1:
        _run_many(plan, no_progress)
        return
    seq, config = plan.sequences[0], setup.config
    click.echo(f"jaxvo run: {seq.name}, {len(seq)} frames, method {config.method}, {seq.camera!r} "
               f"(from {seq.camera_source}){_lens_note(seq)}, depth scale {seq.depth_scale:g}{_depth_note(seq)}, "
               f"device {device()}",
               err=True)
    compile_note()
    pbar = None if no_progress else progress_bar(total=len(seq) - 1, unit="frame", desc=config.method)
    # the trajectory grows, flushed line by line, under a .partial name; it gets its name when complete
    partial = partial_path(plan.outputs[0])
    done = []
    ctrl_c = CtrlC()

    def on_pair(k, step):
        done.append(bool(step.valid))
        ctrl_c.check()

    def abandoned():
        if pbar is not None:
            pbar.close()
        when = "while the first pair was compiling" if not done else f"after {len(done)} pairs"
        click.echo(f"interrupted (Ctrl-C) {when}\nframes        {count_poses(partial)} ({len(done)} pairs), "
                   f"failures {done.count(False)}\ntrajectory    {partial} ({count_poses(partial)} poses)")
    try:
        report = ctrl_c.run(lambda: execute_run(plan, pbar=pbar, on_pair=on_pair), abandoned)
    finally:
        if pbar is not None:
            pbar.close()
    _print_run_summary(report.runs[0])
    _leave(report, ctrl_c)


def _leave(report, ctrl_c):
    """Exit 130 after Ctrl-C (also one pressed after the last pair); else one ``error:`` line per
    sequence that is not a success (a frame that did not read, nothing usable) and exit 2."""
    if report.interrupted or ctrl_c.interrupted:
        exit_now(130)
    for problem in report.problems:
        click.echo(f"error: {problem}", err=True)
    if report.problems:
        sys.exit(2)


def _print_provenance(config_file, setup, plan):
    """With --config: where each setting came from (one line), the settings the file lacked
    (one note), and a note when its header was written for another sequence."""
    if not setup.sources:
        return
    click.echo(f"settings      {'; '.join(setup.sources)}", err=True)
    if setup.missing:
        click.echo(f"note: {config_file} lacks {', '.join(setup.missing)} (written by an older jaxvo?): filled "
                   f"with today's defaults, so the rerun may differ from the recorded one", err=True)
    recorded = setup.header_sequence
    if recorded is not None and len(plan.sequences) == 1 and Path(str(recorded)).name != plan.sequences[0].name:
        click.echo(f"note: {config_file} was written for {recorded}; its settings (intrinsics, depth scale, "
                   f"frames) are applied to {plan.sequences[0].path} (override them with options)", err=True)


def _run_many(plan, no_progress):
    """Several sequences: one batch per image size, a trajectory per sequence and one summary line each."""
    import jax

    seqs, config = plan.sequences, plan.setup.config
    click.echo(f"jaxvo run: {len(seqs)} sequences in {len(plan.batches)} batch(es) by image size, method "
               f"{config.method}, {len(jax.devices())} device(s) ({device()}, ...)", err=True)
    compile_note()
    pbar = None if no_progress else progress_bar(total=sum(len(s) - 1 for s in seqs), unit="frame",
                                                 desc=config.method)
    ctrl_c = CtrlC()

    def abandoned():
        if pbar is not None:
            pbar.close()
        click.echo("interrupted (Ctrl-C); finished poses are kept in the .partial trajectories")
    try:
        report = ctrl_c.run(lambda: execute_run(plan, pbar=pbar, on_pair=lambda k, step: ctrl_c.check()), abandoned)
    finally:
        if pbar is not None:
            pbar.close()
    lines = []
    for run in report.runs:
        r = run.result
        if r is None:
            why = "its batch failed, see its error line" if run.problem else "interrupted before its batch"
            kept = run.trajectory if run.trajectory.exists() else "-"
            lines.append(f"{run.sequence.name}: not tracked ({why}), trajectory {kept}")
            continue
        line = (f"{run.sequence.name}: {len(r.stamps)} frames, failures {r.failures}, inlier ratio "
                f"{fmt(float(np.mean(r.inlier_ratio)) if r.pairs else float('nan'), 3)}, compile "
                f"{fmt(r.compile_s, 1)} s, {fmt(r.fps, 2)} frames/s (batch), trajectory {run.trajectory}")
        errs = run.errors
        if errs is not None:
            if errs.rpe_1s is not None:
                line += f", RPE 1 s {errs.rpe_1s.trans_drift.rmse:.4f} m/s"
            if errs.ate is not None:
                line += f", ATE {errs.ate.rmse:.4f} m"
        if r.error is not None:
            line += " (stopped early: see its error line)"
        elif r.interrupted:
            line += " (interrupted)"
        lines.append(line)
    click.echo("\n".join(lines))
    _leave(report, ctrl_c)


def _print_run_summary(run):
    res, lines = run.result, []
    if res.interrupted:
        lines.append("interrupted (Ctrl-C): summary of the frames done so far (the trajectory keeps its "
                     ".partial name)")
    n = res.without_depth
    blank = f" ({n} frame{'' if n == 1 else 's'} without depth, held)" if n else ""
    lines.append(f"frames        {len(res.stamps)} ({res.pairs} pairs), failures {res.failures}{blank}")
    lines.append(f"inlier ratio  {fmt(float(np.mean(res.inlier_ratio)) if res.pairs else float('nan'), 3)} (mean)")
    lines.append(f"compile       {fmt(res.compile_s, 1)} s (first pair, compilation included)")
    lines.append(f"speed         {fmt(res.fps, 2)} frames/s after compilation")
    lines.append(f"trajectory    {run.trajectory} ({len(res.stamps)} poses)")
    errs = run.errors
    if errs is not None:
        for key, label in (("rpe_1f", "RPE 1 frame"), ("rpe_1s", "RPE 1 s")):
            r = getattr(errs, key)
            if r is not None:
                u = "frame" if key == "rpe_1f" else "s"
                lines.append(f"{label:<13} trans rmse {r.trans_drift.rmse:.4f} m/{u}, rot rmse "
                             f"{r.rot_drift.rmse:.3f} deg/{u} ({r.n} pairs)")
        a = errs.ate
        if a is not None:
            lines.append(f"ATE           rmse {a.rmse:.4f} m ({a.stats.n} frames), {scale_text(a.scale, 3)}")
    click.echo("\n".join(lines))


def _depth_note(seq) -> str:
    """Where the depth scale came from, when a sensor's published correction is in play:
    ``" (fr2's published correction; --depth-scale recorded: 5000)"`` where the reader applied it,
    ``" (as recorded; fr2 publishes a correction: --depth-scale fr2)"`` where a recording that has one
    is read at the layout's scale; else ""."""
    layout = type(seq).DEPTH_SCALE
    name = getattr(seq, "sensor", "default")
    corrected = layout * DEPTH_CORRECTIONS.get(name, 1.0)
    if corrected == layout:
        return ""
    if seq.depth_scale == corrected:
        return f" ({name}'s published correction; --depth-scale recorded: {layout:g})"
    if seq.depth_scale == layout:
        return f" (as recorded; {name} publishes a correction: --depth-scale {name})"
    return ""


def _lens_note(seq) -> str:
    """``", undistorted (fr2's published lens k1=..., ...; --lens none: as they are)"`` where the reader
    undistorts the images, else ""."""
    lens = getattr(seq, "lens", None)
    if lens is None or lens.is_pinhole:
        return ""
    name = getattr(seq, "sensor", "default")
    whose = f"{name}'s published lens " if LENSES.get(name) == lens else "lens "
    return (f", undistorted ({whose}{', '.join(f'{k}={v:g}' for k, v in lens._asdict().items())}; "
            f"--lens none: as they are)")
