"""The ``jaxvo`` command line: ``run``, ``eval``, ``gt``, ``synth``, ``augment``, ``demo``, ``map``.

Argument parsing and printing only: the work is done by the library (:mod:`jaxvo.pipelines.run`,
:mod:`jaxvo.evaluation.report`, :mod:`jaxvo.pipelines.demo`, :mod:`jaxvo.synthetic`, :mod:`jaxvo.pipelines.mapping`).

Every command reports bad input (missing or malformed files, undecodable images, a
depth image that is not 16-bit, no colour/depth association, ground truth that does
not cover the sequence, ...) as one line ``error: <file>: <problem>`` on stderr and
exit code 2, never a traceback.
"""
from __future__ import annotations

import functools
import json
import os
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Callable, Optional

import click
import numpy as np

from jaxvo.runtime import cache
from jaxvo.camera import DEFAULT, PRESETS, camera_for_size
from jaxvo.data.errors import DatasetError
from jaxvo.pipelines.demo import fmt, parse_size, progress_bar, run_demo
from jaxvo.evaluation.report import evaluate, trajectory_errors
from jaxvo.tracking.hindsight import OFFSETS as HINDSIGHT_OFFSETS, HindsightParams
from jaxvo.data.outputs import check_output, check_output_folder, finish, partial_path
from jaxvo.pipelines.run import (RunResult, load_config, load_sequence, read_run_settings, resolve_camera, run_sequence,
                          run_sequences)

# run_sequence, evaluate, ... live in jaxvo.pipelines.run / jaxvo.evaluation.report; the names stay importable from here
__all__ = ["main", "RunResult", "run_sequence", "load_config", "resolve_camera", "evaluate", "run_demo"]

CONVENTIONS = """\b
Conventions:
  * trajectories are TUM files, one line per frame:
      timestamp tx ty tz qx qy qz qw
    timestamp in seconds, translation in metres, unit quaternion (scalar last);
    each pose is T_world_cam (camera-to-world); the first frame is at the identity.
  * the estimator returns T_cur_ref, which maps 3-D points of the reference
    (earlier) camera into the current camera; poses chain as
    T_world_cur = T_world_ref @ inv(T_cur_ref). Twists are ordered (w, v).
  * intensity is luminance 0-255, depth is metres (16-bit PNG / 5000, 0 = invalid).
  * RPE: translational error in m, rotational in deg, per delta (m/s and deg/s for
    a 1-second delta, as in TUM evaluate_rpe.py); ATE: RMSE in m after a rigid
    least-squares (Horn/Umeyama) alignment of the estimate to the ground truth.
  * bad input gives one line 'error: ...' on stderr and exit code 2; Ctrl-C exit code 130.
  * outputs are written under a .partial name and renamed when complete; an output that
    would replace or land inside an input is refused unless --force."""

#: seeds: jax.random.key takes at most a 64-bit signed integer
SEED = click.IntRange(0, 2 ** 63 - 1)
POSITIVE = click.FloatRange(min=0, min_open=True)
FORCE = click.option("--force", is_flag=True,
                     help="Write even where an output would replace or land inside an input, or replace a "
                          "non-empty output folder.")

# ----------------------------------------------------------------------------- errors

class _Fail(Exception):
    """Raised to end a command with ``error: message`` and exit code 2."""


def _one_line_text(msg: str) -> str:
    return " ".join(ln.strip() for ln in str(msg).splitlines() if ln.strip())


def _one_line(e: BaseException) -> str:
    if isinstance(e, OSError) and not isinstance(e, DatasetError) and e.filename and e.strerror:
        msg = f"{e.filename}: {e.strerror}"
    else:
        msg = str(e) or type(e).__name__
    return _one_line_text(msg) or type(e).__name__


def _handle_errors(f):
    """Turn DatasetError / ValueError / OSError (bad input) into ``error: ...`` and exit code 2."""
    @functools.wraps(f)
    def wrapper(*args, **kwargs):
        try:
            return f(*args, **kwargs)
        except (_Fail, DatasetError, ValueError, OSError) as e:
            click.echo(f"error: {_one_line(e)}", err=True)
            sys.exit(2)
    return wrapper


def _compilation_cache(f):
    """Options --cache-dir / --no-cache of a command that compiles the estimator; switches on JAX's
    persistent compilation cache (:mod:`jaxvo.runtime.cache`) before the command runs."""
    @click.option("--cache-dir", type=click.Path(file_okay=False, path_type=Path), default=None,
                  help="Folder of JAX's persistent compilation cache: a later run skips compilation. "
                       f"[default: ${cache.ENV}, else $XDG_CACHE_HOME/jaxvo or ~/.cache/jaxvo; "
                       f"{cache.ENV}=off turns it off]")
    @click.option("--no-cache", is_flag=True, help="Do not use the persistent compilation cache.")
    @functools.wraps(f)
    def wrapper(*args, cache_dir=None, no_cache=False, **kwargs):
        want = cache.cache_dir(cache_dir, no_cache)
        if want is not None and cache.enable(want) is None:
            click.echo(f"warning: {want}: cannot create the compilation cache folder; compiling without it",
                       err=True)
        return f(*args, **kwargs)
    return wrapper


def _device() -> str:
    """The device the estimator runs on (the first of jax.devices()), e.g. 'cpu:0' or 'gpu:0 (NVIDIA H100 ...)'."""
    import jax

    d = jax.devices()[0]
    kind = f" ({d.device_kind})" if d.device_kind != d.platform else ""
    return f"{d.platform}:{d.id}{kind}"


def _exit_now(code: int) -> None:
    """Flush and leave at once, skipping interpreter teardown (which can crash while XLA is busy)."""
    for f in (sys.stdout, sys.stderr):
        try:
            f.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


def entry(prog_name: str = "jaxvo") -> None:
    """The process entry point (``jaxvo``, ``python -m jaxvo``): the command, then, once the
    threads Python would wait for are done (the segmentation's programs compiled ahead), a flush
    and an immediate exit with the command's status. The interpreter's own teardown destroys
    XLA's runtime while its native threads may still be busy, and then aborts ("terminate called
    after throwing an instance of ''") after every output was written: 3 of 6 ``jaxvo run
    --method classic`` processes on a warm cache (``experiments/startup.py``'s ``second`` run,
    2026-11-26)."""
    code = 0
    try:
        main.main(prog_name=prog_name)
    except SystemExit as e:
        if isinstance(e.code, str):
            click.echo(e.code, err=True)
            code = 1
        else:
            code = 0 if e.code is None else int(e.code)
    for t in threading.enumerate():
        if t is not threading.main_thread() and not t.daemon:
            t.join()
    _exit_now(code)


class _Group(click.Group):
    """The ``jaxvo`` group: click's usage errors as one ``error:`` line (exit 2), Ctrl-C as exit 130."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        _quiet_native_stderr()
        try:
            rv = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except click.UsageError as e:
            hint = f" (see '{e.ctx.command_path} --help')" if e.ctx is not None else ""
            click.echo(f"error: {_one_line_text(e.format_message())}{hint}", err=True)
            sys.exit(2)
        except click.ClickException as e:
            click.echo(f"error: {_one_line_text(e.format_message())}", err=True)
            sys.exit(2)
        except (click.Abort, KeyboardInterrupt):
            _ignore_ctrl_c()
            click.echo("interrupted (Ctrl-C); unfinished outputs keep their .partial names", err=True)
            _exit_now(130)
        if not standalone_mode:
            return rv
        sys.exit(rv if isinstance(rv, int) else 0)


def _ignore_ctrl_c() -> None:
    """While we report an interrupt and leave, a second Ctrl-C must not end in a traceback."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def _quiet_native_stderr() -> None:
    """Send what C libraries write straight to file descriptor 2 (libpng's and OpenCV's warnings
    about a damaged PNG, XLA's log lines) to /dev/null, keeping Python's ``sys.stderr`` (our
    messages, the progress bar) on the real stderr, so a bad file gives one ``error:`` line and
    nothing before it. Only for a real terminal/pipe stderr; ``JAXVO_NATIVE_STDERR=1`` keeps it."""
    os.environ.setdefault("OPENCV_LOG_LEVEL", "SILENT")
    if os.environ.get("JAXVO_NATIVE_STDERR") or sys.stderr is not sys.__stderr__:
        return
    try:
        if sys.stderr.fileno() != 2:
            return
        sys.stderr.flush()
        keep = os.dup(2)
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 2)
        os.close(devnull)
    except (AttributeError, ValueError, OSError):
        return
    sys.stderr = os.fdopen(keep, "w", buffering=1, encoding=sys.__stderr__.encoding or "utf-8",
                           errors="backslashreplace")


class _CtrlC:
    """Ctrl-C for a long job that runs JAX: the job runs in a worker thread and SIGINT only sets a
    flag, so the main thread notices at once even while XLA compiles (which no Python signal
    handler can interrupt). The job checks :meth:`check` between steps and ends cleanly; a job
    that does not get there within ``grace`` seconds (still compiling) is abandoned:
    ``on_abandon()`` reports, and the process exits 130 without tearing XLA down."""

    def __init__(self, grace: float = 3.0):
        self.flag = threading.Event()
        self.grace = grace

    def check(self, *_) -> None:
        if self.flag.is_set():
            raise KeyboardInterrupt

    def run(self, fn: Callable, on_abandon: Callable[[], None] = lambda: None):
        if threading.current_thread() is not threading.main_thread():
            return fn()
        box = {}

        def target():
            try:
                box["value"] = fn()
            except BaseException as e:  # re-raised in the main thread
                box["error"] = e
        worker = threading.Thread(target=target, name="jaxvo-job", daemon=True)
        old = signal.signal(signal.SIGINT, lambda signum, frame: self.flag.set())
        try:
            worker.start()
            while worker.is_alive() and not self.flag.is_set():
                worker.join(0.1)
            if worker.is_alive():
                worker.join(self.grace)
                if worker.is_alive():
                    _ignore_ctrl_c()
                    on_abandon()
                    _exit_now(130)
        finally:
            signal.signal(signal.SIGINT, signal.SIG_IGN if self.flag.is_set() else old)
        if "error" in box:
            raise box["error"]
        return box["value"]


def _pose_count(path) -> int:
    try:
        return sum(1 for ln in Path(path).read_text().splitlines() if ln.strip() and not ln.startswith("#"))
    except OSError:
        return 0


# ----------------------------------------------------------------------------- helpers

def track_policy(gap: Optional[int] = None, lag: Optional[int] = None, base=None, frame_to_frame: bool = False,
                 segment: Optional[bool] = None):
    """:class:`jaxvo.estimator.motion.TrackConfig` from the CLI's options on top of ``base`` (default
    ``TrackConfig()``, jaxvo's segmented keyframes): ``--frame-to-frame`` (the paper's chaining),
    ``--keyframe-gap`` / ``--keyframe-lag`` (lag defaults to gap // 2; None keeps base's; a gap
    turns off the calm frame-to-frame mode),
    ``--segment/--no-segment``. A bad combination raises ValueError naming the options."""
    from jaxvo.config import TrackConfig

    base = TrackConfig() if base is None else base
    if frame_to_frame or (gap == 1 and not lag):
        base, gap = TrackConfig.frame_to_frame(), None
    if gap is None:
        policy = base if lag is None else base._replace(lag=int(lag))
    elif int(gap) == 1:
        policy = TrackConfig.frame_to_frame(lag=0 if lag is None else int(lag))
    else:
        # an explicit gap is kept on static stretches too (no frame to frame while calm)
        policy = base._replace(max_gap=int(gap), lag=int(gap) // 2 if lag is None else int(lag), calm_fraction=0.0)
    if segment is not None:
        policy = policy._replace(segment=bool(segment))
    try:
        policy.validate()
    except ValueError:
        raise ValueError(f"--keyframe-lag {policy.lag} must be smaller than --keyframe-gap {policy.max_gap}") \
            from None
    return policy


def _size_option(ctx, param, value):
    try:
        return parse_size(value)
    except ValueError as e:
        raise click.BadParameter(str(e).split(": ", 1)[-1]) from None


# ----------------------------------------------------------------------------- the group

@click.group(cls=_Group, help=f"""jaxvo: robust dense RGB-D visual odometry (classic, Huber and RANSAC) in JAX.

\b
  jaxvo demo                          # synthetic dynamic scene, all three methods, figures
  jaxvo run SEQ --out traj.txt        # track a TUM-layout sequence folder
  jaxvo eval SEQ traj.txt             # RPE / ATE against the sequence's ground truth
  jaxvo synth seq2 OUT                # write a synthetic sequence (TUM layout + masks/)
  jaxvo augment REAL_SEQ OUT          # add synthetic moving persons to a real sequence
  jaxvo map SEQ traj.txt map.ply      # coloured 3-D point cloud (moving points green)
  jaxvo masks SEQ traj.txt OUT        # moving-pixel masks in hindsight (earlier and later frames)
  jaxvo gt SEQ -o gt.txt              # ground truth as camera poses (for evo)

{CONVENTIONS}
""")
@click.version_option(package_name="jaxvo", prog_name="jaxvo")
def main():
    pass


# ----------------------------------------------------------------------------- run

def _note_other_machine(config_file, settings) -> None:
    """Say so when ``--config TRAJ`` reruns a trajectory that another machine wrote (its
    ``# machine:`` header, :mod:`jaxvo.runtime.machine`): the rerun may then differ at float rounding."""
    from jaxvo.runtime import machine

    recorded = settings.get("machine")
    if recorded is None:
        return
    if not isinstance(recorded, dict):
        raise DatasetError(f"{config_file}: '# machine:' header: expected a JSON object, got {recorded!r}")
    diffs = machine.differences(recorded, machine.record())
    if diffs:
        click.echo(f"note: {config_file} was written on another machine ({'; '.join(diffs)}); the rerun "
                   "may differ at float rounding, which the robust steps through a crowd can grow "
                   "(README: Reproducible runs)", err=True)


@main.command("run", help=f"""Track a sequence and write its trajectory.

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
the run goes on (the first frame at the identity) and renamed to OUT when complete, so a run
that fails, is interrupted (Ctrl-C) or killed keeps every finished frame in OUT.partial and
never leaves a half trajectory under OUT; Ctrl-C prints the summary of what was done and
exits with code 130. Outputs that would replace or land inside an input are refused
(--force to allow).

At the end a summary: frames, failures (pairs whose estimate was flagged invalid: too few
inliers, too little depth or texture agreement, or ill-conditioned), mean inlier ratio, compile time (the first pair's wall time,
which includes JAX compilation) and frames/s after it. With groundtruth.txt it also prints
RPE with a delta of 1 frame (m/frame, deg/frame) and of 1 s when the run is long enough
(m/s, deg/s), and ATE (m, after alignment).

Pairs i -> i+1 use the random key jax.random.fold_in(jax.random.key(SEED), i), exactly as
jaxvo.tracking.odometry.track does, so the CLI and the library give identical trajectories.

Several SEQUENCE_DIRs (or a folder holding sequence folders) are tracked together: sequences
of the same image size run as one batch (their estimates jax.vmap'd in lockstep, spread over
the available devices with jax.sharding; each keeps its own keyframes and segmentation and the
key of SEED), so the batch compiles once. Each sequence's trajectory goes to
OUT_DIR/<sequence name>.txt (--out-dir, default the current folder) and gets one summary line.
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
                   "inlier) at full image size into this folder, named by the REFERENCE frame's timestamp "
                   "(the mask lives on the reference image's pixels), e.g. 1311868164.363181.png.")
@click.option("--camera", "camera_preset", type=click.Choice(sorted(PRESETS)), default=None,
              help="Intrinsics preset (640x480). [default: the folder's calibration.txt (ETH3D), "
                   "camera_intrinsic.json (Open3D) or info.json (jaxvo), else from the folder name: "
                   "freiburg1/2/3 -> fr1/fr2/fr3, rgbd_bonn_* -> bonn, otherwise default (525, 525, 319.5, 239.5), "
                   "scaled to the image size]")
@click.option("--depth-scale", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Depth PNG value / depth-scale = metres: 5000 for TUM, Bonn, ETH3D, ICL-NUIM; 1000 for "
                   "millimetres (Open3D, RealSense, Redwood). [default: the layout's]")
@click.option("--mask-dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Folder of user masks, one 8-bit PNG per colour frame named like the colour image (or "
                   "<timestamp>.png): nonzero = the pixel may be used, 0 = ignore it (e.g. a person detector's "
                   "people). A frame's mask applies where it is the reference; frames without one use every "
                   "pixel. jaxvo's own outlier decision still runs on the pixels left.")
@click.option("--fx", type=float, default=None, help="Override the focal length fx (pixels).")
@click.option("--fy", type=float, default=None, help="Override the focal length fy (pixels).")
@click.option("--cx", type=float, default=None, help="Override the principal point cx (pixels, column).")
@click.option("--cy", type=float, default=None, help="Override the principal point cy (pixels, row).")
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
@click.option("--frame-to-frame", is_flag=True,
              help="The paper's chaining: every frame against the previous one, no segmentation. With "
                   "--config '{\"prior_candidate\": \"raw\", ...}' or --paper, the published algorithm.")
@click.option("--paper", is_flag=True,
              help="The seed paper's algorithm as published: jaxvo.Config.paper(method) and "
                   "--frame-to-frame.")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
@FORCE
@_compilation_cache
@_handle_errors
def run_cmd(sequence_dirs, method, out, out_dir, max_frames, start, seed, config_file, thresh_lum, thresh_depth,
            finest_level, save_masks, camera_preset, depth_scale, mask_dir, fx, fy, cx, cy, max_dt, keyframe_gap,
            keyframe_lag, segment, frame_to_frame, paper, no_progress, force):
    from jaxvo.config import TrackConfig

    dirs = _expand_sequences(sequence_dirs)
    sequence_dir = dirs[0]

    settings = read_run_settings(config_file) if config_file is not None else {}
    _note_other_machine(config_file, settings)
    ctx = click.get_current_context()

    def default(name):  # not given on the command line: a trajectory header's value may take its place
        return ctx.get_parameter_source(name) == click.core.ParameterSource.DEFAULT

    config = load_config(config_file, method=method, thresh_lum=thresh_lum, thresh_depth=thresh_depth,
                         finest_level=finest_level)
    if "seed" in settings and default("seed"):
        seed = int(settings["seed"])
    try:
        base = TrackConfig.from_json(settings["track"]) if "track" in settings else None
    except (ValueError, TypeError) as e:
        raise DatasetError(f"{config_file}: '# track:' header: {e}") from None
    if paper:
        from jaxvo.config import Config
        config = Config.paper(config.method, thresh_lum=config.thresh_lum, thresh_depth=config.thresh_depth,
                              finest_level=config.finest_level)
    policy = track_policy(keyframe_gap, keyframe_lag, base, frame_to_frame or paper, segment)
    if len(dirs) > 1:
        for name, value in (("--out", not default("out")), ("--save-masks", save_masks is not None),
                            ("--mask-dir", mask_dir is not None)):
            if value:
                raise DatasetError(f"{name} is for one sequence; with {len(dirs)} sequences use --out-dir"
                                   if name == "--out" else f"{name} is for one sequence, got {len(dirs)} sequences")
        seqs = [load_sequence(d, camera_preset, fx, fy, cx, cy, depth_scale=depth_scale, max_dt=max_dt,
                              start=start, max_frames=max_frames) for d in dirs]
        _run_many(seqs, config, seed, policy, out_dir, [config_file], force, no_progress)
        return
    sq = settings.get("sequence") or {}
    if sq:
        start = sq.get("start", start) if default("start") else start
        max_frames = sq.get("frames", max_frames) if default("max_frames") else max_frames
        max_dt = sq.get("max_dt", max_dt) if default("max_dt") else max_dt
        depth_scale = sq.get("depth_scale") if depth_scale is None else depth_scale
        mask_dir = sq.get("mask_dir") if mask_dir is None else mask_dir
        c = sq.get("camera")
        if camera_preset is None and (fx, fy, cx, cy) == (None,) * 4 and isinstance(c, dict):
            fx, fy, cx, cy = c.get("fx"), c.get("fy"), c.get("cx"), c.get("cy")
    check_output(out, [sequence_dir, config_file, mask_dir], force, "--out")
    if save_masks is not None:
        check_output(save_masks, [sequence_dir, config_file, mask_dir], force, "--save-masks")
    seq = load_sequence(sequence_dir, camera_preset, fx, fy, cx, cy, depth_scale=depth_scale, max_dt=max_dt,
                        start=start, max_frames=max_frames, mask_dir=mask_dir)
    if len(seq) < 2:
        raise DatasetError(f"{sequence_dir}: only {len(seq)} frame(s) to use, need at least 2")
    seq.check(1)                 # a bad first image is reported before compiling
    gt = seq.groundtruth         # and so is ground truth that does not cover the frames
    click.echo(f"jaxvo run: {seq.name}, {len(seq)} frames, method {config.method}, {seq.camera!r} "
               f"(from {seq.camera_source}), depth scale {seq.depth_scale:g}, device {_device()}", err=True)
    pbar = None if no_progress else progress_bar(total=len(seq) - 1, unit="frame", desc=config.method)
    # the trajectory grows, flushed line by line, under a .partial name; it gets its name when complete
    partial = partial_path(out)
    done = []
    ctrl_c = _CtrlC()

    def on_pair(step):
        done.append(bool(step.valid))
        ctrl_c.check()

    def abandoned():
        if pbar is not None:
            pbar.close()
        when = "while the first pair was compiling" if not done else f"after {len(done)} pairs"
        click.echo(f"interrupted (Ctrl-C) {when}\nframes        {_pose_count(partial)} ({len(done)} pairs), "
                   f"failures {done.count(False)}\ntrajectory    {partial} ({_pose_count(partial)} poses)")
    try:
        res = ctrl_c.run(lambda: run_sequence(seq, config, seed, out=partial, save_masks=save_masks, pbar=pbar,
                                              policy=policy, on_pair=on_pair), abandoned)
    except (DatasetError, ValueError, OSError) as e:
        n = _pose_count(partial)
        raise DatasetError(_one_line(e) + (f" ({n} finished poses kept in {partial})" if n else "")) from None
    finally:
        if pbar is not None:
            pbar.close()
    if res.interrupted:
        _print_run_summary(res, partial, gt, max_dt)
        _exit_now(130)
    finish(partial, out)
    _print_run_summary(res, out, gt, max_dt)


def _expand_sequences(paths) -> list:
    """The sequence folders named on the command line: each path as it is, except a folder that is
    not a sequence itself but holds sequence folders (rgb.txt + depth.txt), which stands for them."""
    from jaxvo.data.layouts import find_sequences, is_sequence_dir as _is_sequence_dir, open_sequence

    dirs = []
    for p in paths:
        inner = find_sequences(p) if p.is_dir() and not _is_sequence_dir(p) else []
        if inner:
            try:
                open_sequence(p, max_frames=1)
                inner = []          # a sequence of another layout (ICL-NUIM, Redwood): itself
            except (DatasetError, ValueError):
                pass
        dirs += inner or [p]
    return dirs


def _run_many(seqs, config, seed, policy, out_dir, inputs, force, no_progress):
    """Several sequences: one batch per image size (:func:`jaxvo.pipelines.run.run_sequences`), a
    trajectory per sequence in ``out_dir`` and one summary line each."""
    names = [seq.name for seq in seqs]
    outs = [out_dir / (f"{n}.txt" if names.count(n) == 1 else f"{n}-{k}.txt") for k, n in enumerate(names)]
    for seq, o in zip(seqs, outs):
        if len(seq) < 2:
            raise DatasetError(f"{seq.path}: only {len(seq)} frame(s) to use, need at least 2")
        check_output(o, [s.path for s in seqs] + list(inputs), force, "--out-dir")
        seq.check(1)
    groups: dict = {}
    for k, seq in enumerate(seqs):
        groups.setdefault((seq.camera.width, seq.camera.height), []).append(k)
    import jax
    click.echo(f"jaxvo run: {len(seqs)} sequences in {len(groups)} batch(es) by image size, method "
               f"{config.method}, {len(jax.devices())} device(s) ({_device()}, ...)", err=True)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise DatasetError(f"--out-dir {out_dir}: cannot create it ({e.strerror or e})") from None
    pbar = None if no_progress else progress_bar(total=sum(len(s) - 1 for s in seqs), unit="frame",
                                                 desc=config.method)
    ctrl_c = _CtrlC()
    results: dict = {}

    def abandoned():
        if pbar is not None:
            pbar.close()
        click.echo("interrupted (Ctrl-C); finished poses are kept in the .partial trajectories")
    try:
        for (w, h), ks in groups.items():
            res = ctrl_c.run(lambda ks=ks: run_sequences([seqs[k] for k in ks], config, seed,
                                                         [partial_path(outs[k]) for k in ks], pbar=pbar,
                                                         policy=policy, on_pair=lambda s, step: ctrl_c.check()),
                             abandoned)
            results.update(zip(ks, res))
            if any(r.interrupted for r in res):
                break
    except (DatasetError, ValueError, OSError) as e:
        raise DatasetError(_one_line(e) + " (finished poses kept in the .partial trajectories)") from None
    finally:
        if pbar is not None:
            pbar.close()
    interrupted = any(r.interrupted for r in results.values()) or len(results) < len(seqs)
    lines = []
    for k, seq in enumerate(seqs):
        if k not in results:
            continue
        r = results[k]
        path = partial_path(outs[k]) if interrupted else outs[k]
        if not interrupted:
            finish(partial_path(outs[k]), outs[k])
        line = (f"{seq.name}: {len(r.stamps)} frames, failures {r.failures}, inlier ratio "
                f"{fmt(float(np.mean(r.inlier_ratio)) if r.pairs else float('nan'), 3)}, compile "
                f"{fmt(r.compile_s, 1)} s, {fmt(r.fps, 2)} frames/s (batch), trajectory {path}")
        gt = seq.groundtruth
        if gt is not None:
            errs = trajectory_errors(gt, r.stamps, r.poses, seq.max_dt)
            if errs.get("rpe_1s") is not None:
                line += f", RPE 1 s {errs['rpe_1s'].trans_drift.rmse:.4f} m/s"
            if errs.get("ate") is not None:
                line += f", ATE {errs['ate'].rmse:.4f} m"
        lines.append(line)
    click.echo("\n".join(lines))
    if interrupted:
        _exit_now(130)


def _print_run_summary(res: RunResult, out, gt, max_dt):
    lines = []
    if res.interrupted:
        lines.append("interrupted (Ctrl-C): summary of the frames done so far (the trajectory keeps its "
                     ".partial name)")
    lines.append(f"frames        {len(res.stamps)} ({res.pairs} pairs), failures {res.failures}")
    lines.append(f"inlier ratio  {fmt(float(np.mean(res.inlier_ratio)) if res.pairs else float('nan'), 3)} (mean)")
    lines.append(f"compile       {fmt(res.compile_s, 1)} s (first pair, compilation included)")
    lines.append(f"speed         {fmt(res.fps, 2)} frames/s after compilation")
    if out is not None:
        lines.append(f"trajectory    {out} ({len(res.stamps)} poses)")
    if gt is not None:
        errs = trajectory_errors(gt, res.stamps, res.poses, max_dt)
        for key, label in (("rpe_1f", "RPE 1 frame"), ("rpe_1s", "RPE 1 s")):
            r = errs.get(key)
            if r is not None:
                u = "frame" if key == "rpe_1f" else "s"
                lines.append(f"{label:<13} trans rmse {r.trans_drift.rmse:.4f} m/{u}, rot rmse "
                             f"{r.rot_drift.rmse:.3f} deg/{u} ({r.n} pairs)")
        a = errs.get("ate")
        if a is not None:
            lines.append(f"ATE           rmse {a.rmse:.4f} m ({a.stats.n} frames)")
    click.echo("\n".join(lines))


# ----------------------------------------------------------------------------- eval


@main.command("eval", help=f"""Compare a trajectory with ground truth: RPE, ATE, mask scores.

GROUNDTRUTH is a TUM ground-truth file or a sequence folder (its groundtruth.txt is used;
for Bonn RGB-D Dynamic folders, rgbd_bonn_*, the motion-capture marker poses are converted
to camera poses). EST is a TUM trajectory file (e.g. from jaxvo run).

Prints a table of the relative pose error for pairs of estimate frames DELTA apart
(translation in m, rotation in deg; per second with --delta-unit s, per frame with f;
rmse, mean, median, max and the number of pairs) and the absolute trajectory error (m,
after the least-squares rigid alignment of the estimate to the ground truth). With --delta
and --delta-unit left at their defaults, an estimate shorter than 1 s is measured over 1
frame instead, with a note (as jaxvo run does). Poses are
associated by timestamp (nearest, within --max-dt s); ground truth that does not cover the
estimate is an error.

With --masks-dir (the folder written by jaxvo run --save-masks) and a GROUNDTRUTH folder
holding the true moving-pixel masks (masks/, as jaxvo synth and jaxvo augment write), also
the outlier mask's precision, recall and IoU (the moving class is the positive one),
pooled over all frames matched by timestamp.

--plot writes a figure: top view of the ground truth and the aligned estimate, and the
translational drift (RPE per pair) and ATE per frame over time.

{CONVENTIONS}
""")
@click.argument("groundtruth", type=click.Path(path_type=Path))
@click.argument("est", type=click.Path(path_type=Path))
@click.option("--delta", type=POSITIVE, default=1.0, show_default=True, help="RPE pair spacing (see --delta-unit).")
@click.option("--delta-unit", type=click.Choice(["s", "f"]), default="s", show_default=True,
              help="s = seconds (drift in m/s and deg/s, the paper's Table I), f = frames.")
@click.option("--max-dt", type=POSITIVE, default=0.02, show_default=True,
              help="Maximum estimate/ground-truth timestamp difference, seconds.")
@click.option("--json", "json_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Also write the results as JSON.")
@click.option("--plot", "plot_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the trajectory / drift figure (PNG, PDF, SVG by extension).")
@click.option("--masks-dir", type=click.Path(path_type=Path), default=None,
              help="Outlier masks saved by 'jaxvo run --save-masks' to score against the true masks.")
@click.option("--bonn/--no-bonn", default=None,
              help="Force / forbid the Bonn marker-to-camera ground-truth conversion. [default: by folder name]")
@click.option("--per-pair", is_flag=True, help="Include per-pair errors in the JSON output.")
@FORCE
@_handle_errors
def eval_cmd(groundtruth, est, delta, delta_unit, max_dt, json_file, plot_file, masks_dir, bonn, per_pair, force):
    for out, opt in ((json_file, "--json"), (plot_file, "--plot")):
        if out is not None:
            check_output(out, [groundtruth, est, masks_dir], force, opt)
    ctx = click.get_current_context()
    defaults = all(ctx.get_parameter_source(p) == click.core.ParameterSource.DEFAULT for p in ("delta", "delta_unit"))
    res = evaluate(groundtruth, est, delta, delta_unit, max_dt, masks_dir, bonn, short_frames=defaults)
    if (res["delta"], res["delta_unit"]) != (delta, delta_unit):
        es = res["est"][0]
        click.echo(f"note: {est} spans {es[-1] - es[0]:.2f} s, less than the default RPE delta of {delta:g} s: "
                   f"RPE over 1 frame instead")
        delta, delta_unit = res["delta"], res["delta_unit"]
    r, a, m = res["rpe"], res["ate"], res["masks"]
    u = "s" if delta_unit == "s" else "frame"
    dl = f"{delta:g} {'s' if delta_unit == 's' else 'frame(s)'}"
    rows = [(f"RPE trans [m/{u}]", r.trans_drift), (f"RPE rot [deg/{u}]", r.rot_drift), ("ATE [m]", a.stats)]
    lines = [f"ground truth {res['gt_file']}", f"estimate     {est}  ({res['est'][0].size} poses)",
             f"RPE delta {dl}, ATE after rigid alignment", "",
             f"{'':<20}{'rmse':>10}{'mean':>10}{'median':>10}{'max':>10}{'n':>7}"]
    for name, s in rows:
        nd = 3 if "deg" in name else 4
        lines.append(f"{name:<20}{fmt(s.rmse, nd):>10}{fmt(s.mean, nd):>10}{fmt(s.median, nd):>10}"
                     f"{fmt(s.max, nd):>10}{s.n:>7}")
    if m is not None:
        lines += ["", f"outlier mask vs true moving pixels ({res['mask_frames']} frames): precision "
                      f"{fmt(m.precision, 3)}, recall {fmt(m.recall, 3)}, IoU {fmt(m.iou_outlier, 3)}"]
    click.echo("\n".join(lines))
    if json_file is not None:
        d = {"groundtruth": str(res["gt_file"]), "estimate": str(est), "rpe": r.to_dict(per_pair=per_pair),
             "ate": a.to_dict(per_frame=per_pair), "masks": m.to_dict() if m is not None else None}
        if m is not None:
            d["mask_frames"] = res["mask_frames"]
        tmp = partial_path(json_file)
        try:
            tmp.write_text(json.dumps(d, indent=1) + "\n")
        except OSError as e:
            raise DatasetError(f"{json_file}: cannot write JSON ({e.strerror or e})") from None
        finish(tmp, json_file)
    if plot_file is not None:
        _eval_plot(res, plot_file, delta, delta_unit)


def _eval_plot(res, plot_file, delta, delta_unit):
    from jaxvo import viz

    gs, gP = res["gt"]
    es, _ = res["est"]
    a, r = res["ate"], res["rpe"]
    t0 = es[0]
    keep = (gs >= es[0] - 0.1) & (gs <= es[-1] + 0.1)
    u = "s" if delta_unit == "s" else "frame"
    fig = viz.plot_eval(gP[keep, :3, 3], a.aligned[:, :3, 3], r.stamps_j - t0, r.trans / r.delta,
                        a.stamps - t0, a.errors, rpe_label=f"RPE trans [m/{u}] (delta {delta:g} {u})",
                        title=f"{Path(str(res['gt_file'])).parent.name}")
    tmp = partial_path(plot_file, keep_suffix=True)
    try:
        viz.save_figure(fig, tmp)
    except (OSError, ValueError) as e:
        raise DatasetError(f"{plot_file}: cannot write figure ({_one_line(e)})") from None
    finish(tmp, plot_file)


# ----------------------------------------------------------------------------- synth / augment

def _progress_cb(pbar):
    def cb(done, total):
        if pbar.total != total:
            pbar.total = total
            pbar.refresh()
        pbar.update(done - pbar.n)
    return cb


@main.command("synth", help=f"""Write a synthetic dynamic RGB-D sequence with exact ground truth.

NAME picks the camera / person motion (the paper's Table II): seq0 hand-held camera, static
scene; seq1 fixed camera, one person walking; seq2 camera panning at 2 deg/s on a pan-tilt
head, one person; seq3 as seq2 with two persons; handheld-fast hand-held camera with a
person moving fast and close. Frames at 30 Hz, deterministic from --seed.

OUT_DIR gets the TUM layout (rgb/, depth/ 16-bit metres x 5000, rgb.txt, depth.txt,
groundtruth.txt as T_world_cam) plus masks/ (8-bit, 255 = pixel on a moving object),
masks.txt and info.json (intrinsics, used by jaxvo run), so jaxvo run and jaxvo eval
work on it unchanged.

{CONVENTIONS}
""")
@click.argument("name", type=click.Choice(["seq0", "seq1", "seq2", "seq3", "handheld-fast"]))
@click.argument("out_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--frames", type=click.IntRange(min=2), default=300, show_default=True, help="Number of frames (30 Hz).")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the scene, textures and motions.")
@click.option("--size", callback=_size_option, default="640x480", show_default=True,
              help="Image size WIDTHxHEIGHT (e.g. 640x480, 320x240, 424x240, 848x480); intrinsics are the "
                   "default 525/319.5/239.5 camera scaled to it (jaxvo.camera.camera_for_size).")
@click.option("--sensor/--no-sensor", default=False, show_default=True,
              help="Kinect-like sensor effects (depth noise ~Z^2, quantisation, missing depth at edges and "
                   "beyond 4 m, intensity noise, exposure changes).")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
@FORCE
@_handle_errors
def synth_cmd(name, out_dir, frames, seed, size, sensor, no_progress, force):
    from jaxvo.synthetic import SensorModel, generate

    check_output_folder(out_dir, [], force)
    cam = camera_for_size(DEFAULT, *size)
    tmp = partial_path(out_dir, fresh=True)
    pbar = None if no_progress else progress_bar(total=frames, unit="frame", desc=f"render {name}")
    try:
        generate(name, tmp, frames=frames, seed=seed, camera=cam, sensor=SensorModel() if sensor else None,
                 progress=_progress_cb(pbar) if pbar is not None else None)
    finally:
        if pbar is not None:
            pbar.close()
    out = finish(tmp, out_dir)
    click.echo(f"wrote {frames} frames of {name} ({size[0]}x{size[1]}, seed {seed}) to {out}")


@main.command("augment", help=f"""Composite synthetic moving persons into a real static sequence.

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
@_handle_errors
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
        augment(real_seq, tmp, persons=persons, coverage=coverage, seed=seed, max_frames=max_frames,
                camera=PRESETS[camera_preset] if camera_preset else None,
                progress=_progress_cb(pbar) if pbar is not None else None)
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


# ----------------------------------------------------------------------------- demo


@main.command("demo", help=f"""Synthetic dynamic scene -> classic vs Huber vs RANSAC, one table and figures.

Generates a short synthetic sequence with exact ground truth and moving-pixel masks (default
seq2, the paper's pan-tilt case: the camera pans at 2 deg/s while a person walks through the
view; Kinect-like sensor noise; handheld-fast is the hard case, a person fast and close
covering up to two thirds of the image), runs the three
estimators on it and prints one table:
RPE per frame (translation mm/frame, rotation deg/frame, RMSE over all consecutive pairs),
ATE (mm, after rigid alignment), frames/s after compilation, mean inlier ratio, and the
precision / recall of each estimator's outlier mask against the true moving pixels (on the
reference frame's pixels where the residuals are defined).

Writes into --out: sequence/ (the generated sequence, reused when it matches), traj_<method>.txt,
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
@click.option("--size", callback=_size_option, default="320x240", show_default=True,
              help="Image size WIDTHxHEIGHT.")
@click.option("--sensor/--no-sensor", default=True, show_default=True, help="Kinect-like sensor effects.")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
@_compilation_cache
@_handle_errors
def demo_cmd(out_dir, frames, seed, seq_name, size, sensor, no_progress):
    result = _CtrlC().run(lambda: run_demo(out_dir, frames=frames, seed=seed, seq_name=seq_name, size=size,
                                           sensor=sensor, progress=not no_progress),
                          lambda: click.echo("\ninterrupted (Ctrl-C)", err=True))
    click.echo(result["table"])
    click.echo(f"\nfigures and results in {out_dir}/ ({result['wall_s']:.0f} s)")


# ----------------------------------------------------------------------------- gt

@main.command("gt", help=f"""Write a sequence's ground truth as camera poses, for other tools (evo).

SEQUENCE_DIR is any folder jaxvo run reads. The ground truth (groundtruth.txt, or ICL-NUIM's
*.gt.freiburg) is written to --out as a TUM trajectory of camera poses T_world_cam; for Bonn
RGB-D Dynamic folders (rgbd_bonn_*) the motion-capture marker poses are converted to camera
poses first, as jaxvo eval does. Then evo gives jaxvo eval's numbers:

\b
  jaxvo gt SEQ -o gt.txt
  evo_ape tum gt.txt traj.txt -a --t_max_diff 0.02                          # ATE
  evo_rpe tum gt.txt traj.txt --delta 1 --delta_unit f --t_max_diff 0.02     # RPE 1 frame
  evo_rpe tum gt.txt traj.txt --delta 1 --delta_unit f --t_max_diff 0.02 --pose_relation angle_deg

{CONVENTIONS}
""")
@click.argument("sequence_dir", type=click.Path(path_type=Path))
@click.option("-o", "--out", "out", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="TUM trajectory file to write (camera poses T_world_cam).")
@click.option("--bonn/--no-bonn", default=None,
              help="Force / forbid the Bonn marker-to-camera conversion. [default: by folder name]")
@_handle_errors
def gt_cmd(sequence_dir, out, bonn):
    from jaxvo.data.layouts import open_sequence
    from jaxvo.data.trajectory import HEADER, write_tum_trajectory

    seq = open_sequence(sequence_dir, bonn=bonn, camera=DEFAULT)  # intrinsics are not needed here
    gt = seq.groundtruth
    if gt is None:
        raise DatasetError(f"{seq.groundtruth_path}: file not found (the sequence folder has no ground truth)")
    what = "Bonn marker poses converted to camera poses" if seq.is_bonn else "as stored"
    write_tum_trajectory(out, gt[0], gt[1], header=f"# ground truth of {seq.path} ({seq.groundtruth_path.name}, "
                                                    f"{what})\n{HEADER}")
    click.echo(f"wrote {len(gt[0])} ground-truth camera poses ({what}) to {out}")


# ----------------------------------------------------------------------------- map


def _sequence_with_trajectory(f):
    """The options of the commands that read a sequence folder with a trajectory (map, masks)."""
    options = [
        click.option("--camera", "camera_preset", type=click.Choice(sorted(PRESETS)), default=None,
                     help="Intrinsics preset. [default: as for 'jaxvo run': the folder's calibration file, else "
                          "from the folder name]"),
        click.option("--depth-scale", type=click.FloatRange(min=0, min_open=True), default=None,
                     help="Depth PNG value / depth-scale = metres. [default: the layout's, 5000 for TUM]"),
        click.option("--max-dt", type=POSITIVE, default=0.02, show_default=True,
                     help="Maximum frame/trajectory (and colour/depth) timestamp difference, seconds."),
        click.option("--no-progress", is_flag=True, help="No progress bar.")]
    for option in reversed(options):
        f = option(f)
    return f


def _read_trajectory(traj):
    """(timestamps, T_world_cam, number of held poses left out) of a trajectory file: the poses
    'jaxvo run' marked held (its estimate failed and the previous pose was kept: a guess) are left
    out. DatasetError when the file is missing or has no pose. A ground-truth file may repeat a
    timestamp (TUM's tools keep the first); an estimate may not."""
    from jaxvo.data.textfiles import read_pose_file
    from jaxvo.data.trajectory import read_held

    if not Path(traj).is_file():
        raise DatasetError(f"{traj}: trajectory file not found")
    t, T = read_pose_file(traj, duplicates="first" if Path(traj).name == "groundtruth.txt" else "error")
    if len(t) == 0:
        raise DatasetError(f"{traj}: no poses in the trajectory file")
    held = np.isin(t, read_held(traj))
    return t[~held], T[~held], int(held.sum())


@main.command("map", help=f"""Build a coloured 3-D point-cloud map (PLY) of a sequence from a trajectory.

SEQUENCE_DIR is a TUM-layout folder; TRAJ a TUM trajectory file (T_world_cam per line, e.g.
written by 'jaxvo run', or the sequence's groundtruth.txt) whose timestamps are matched to the
frames within --max-dt seconds (frames without a pose are skipped, and so are the poses 'jaxvo
run' marked held: its estimate failed and the previous pose was kept). Every N-th matched frame
(--every), the pixels with valid depth up to --max-depth metres are back-projected and moved
into the world with the trajectory's pose. Static points keep their RGB colour; moving points
(outliers of the estimator on the pair (frame, next frame): residuals defined but not an
inlier; with --hindsight, the masks of 'jaxvo masks', decided against earlier and later
frames; or, with --use-masks, the pixels of the sequence's masks/) are painted green, as the
outliers of the paper's Fig. 4/7. A voxel grid (--voxel metres; 0 = off) averages position and
colour per voxel, static and moving points apart.

OUT.ply is a binary little-endian PLY (float x y z, uchar red green blue) that Open3D, MeshLab
and CloudCompare open. --preview writes a PNG rendering of it (perspective + top view).

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
              help="Estimator whose outlier mask labels the moving points.")
@click.option("--max-frames", type=click.IntRange(min=1), default=None, help="Use at most N frames of the sequence.")
@click.option("--max-depth", type=click.FloatRange(min=0, min_open=True), default=4.0, show_default=True,
              help="Ignore depth beyond this (metres).")
@click.option("--preview", "preview", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Also write a PNG preview of the map.")
@click.option("--use-masks", is_flag=True,
              help="Label moving points from the sequence's masks/ (masks.txt) instead of running the estimator.")
@click.option("--hindsight", is_flag=True,
              help="Label moving points with the masks of 'jaxvo masks' (each frame against earlier and later "
                   "frames at the trajectory's poses) instead of one estimate's outliers.")
@click.option("--no-labels", is_flag=True, help="No moving/static labels: every point in its RGB colour.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the jax.random key (RANSAC sampling).")
@_sequence_with_trajectory
@FORCE
@_handle_errors
def map_cmd(sequence_dir, traj, out_ply, every, voxel, method, max_frames, max_depth, preview, use_masks,
            hindsight, no_labels, seed, camera_preset, depth_scale, max_dt, no_progress, force):
    from jaxvo.pipelines.mapping import build_map, render_preview, write_ply
    from jaxvo.config import Config

    if use_masks + hindsight + no_labels > 1:
        raise _Fail("--use-masks, --hindsight and --no-labels exclude each other")
    t_traj, T_traj, n_held = _read_trajectory(traj)
    check_output(out_ply, [sequence_dir, traj], force)
    if preview is not None:
        check_output(preview, [sequence_dir, traj, out_ply], force, "--preview")
    seq = load_sequence(sequence_dir, camera_preset, depth_scale=depth_scale, max_dt=max_dt, max_frames=max_frames)
    labels = None if no_labels else ("masks" if use_masks else "hindsight" if hindsight else "estimate")
    config = Config(method=method)
    click.echo(f"jaxvo map: {seq.name}, {len(seq)} frames ({n_held} held poses of {traj} left out), every {every}, labels "
               f"{labels if labels != 'estimate' else method}, {seq.camera!r}", err=True)
    pbar = None if no_progress else progress_bar(total=0, unit="frame", desc="map")

    def prog(done, total):
        if pbar is not None:
            pbar.total = total
            pbar.update(done - pbar.n)
    ctrl_c = _CtrlC()

    def prog_or_stop(done, total):
        ctrl_c.check()
        prog(done, total)
    try:
        res = ctrl_c.run(lambda: build_map(seq, t_traj, T_traj, every=every, voxel=voxel, max_depth=max_depth,
                                           labels=labels, config=config, seed=seed, max_dt=max_dt,
                                           progress=prog_or_stop))
    finally:
        if pbar is not None:
            pbar.close()
    cloud = res.cloud
    if len(cloud) == 0:
        raise DatasetError(f"{sequence_dir}: no pixel with valid depth <= {max_depth} m in the frames used")
    tmp = partial_path(out_ply, keep_suffix=True)
    write_ply(tmp, cloud.points, cloud.display_colors())
    finish(tmp, out_ply)
    lines = [f"frames        {len(res.frames)} used (every {every} of {len(seq)}; frames with a pose within "
             f"{max_dt} s)",
             f"points        {len(cloud)} after a {voxel:g} m voxel grid ({res.raw_points} back-projected), "
             f"{int(cloud.moving.sum())} moving ({100 * float(cloud.moving.mean()):.1f} %)",
             f"map           {out_ply} (binary PLY, static points in RGB, moving points green)"]
    if labels == "estimate":
        lines.insert(1, f"inlier ratio  {fmt(float(np.nanmean(res.inlier_ratio)), 3)} (mean, {method})")
    if preview is not None:
        tmp = partial_path(preview, keep_suffix=True)
        render_preview(cloud.points, cloud.display_colors(), tmp, poses=res.poses,
                       title=f"{seq.name}: {len(cloud)} points" + (", moving points green" if labels else ""))
        finish(tmp, preview)
        lines.append(f"preview       {preview}")
    lines.append(f"time          {res.seconds:.1f} s")
    click.echo("\n".join(lines))



# ----------------------------------------------------------------------------- masks

@main.command("masks", help=f"""Moving-pixel masks of a tracked sequence, decided in hindsight.

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
@_sequence_with_trajectory
@FORCE
@_handle_errors
def masks_cmd(sequence_dir, traj, out_dir, offsets, ratio, region_ratio, depth_slope, thresh_lum, thresh_depth,
              max_frames, camera_preset, depth_scale, max_dt, no_progress, force):
    import cv2

    from jaxvo.config import Config
    from jaxvo.tracking.hindsight import sequence_masks
    from jaxvo.pipelines.mapping import match_trajectory
    from jaxvo.pipelines.run import stamp_name

    try:
        offset_list = [int(o) for o in offsets.split(",") if o.strip()]
    except ValueError:
        raise _Fail(f"--offsets must be a comma list of integers, got {offsets!r}") from None
    if not any(offset_list):
        raise _Fail("--offsets must hold at least one nonzero frame offset")
    t_traj, T_traj, n_held = _read_trajectory(traj)
    check_output_folder(out_dir, [sequence_dir, traj], force)
    seq = load_sequence(sequence_dir, camera_preset, depth_scale=depth_scale, max_dt=max_dt, max_frames=max_frames)
    idx, T = match_trajectory(seq.timestamps, t_traj, T_traj, max_dt)
    if idx.size == 0:
        raise DatasetError(f"{traj}: no pose within {max_dt} s of a frame of {sequence_dir}")
    poses = np.full((len(seq), 4, 4), np.nan)
    poses[idx] = T
    config = Config().replace(**{k: v for k, v in (("thresh_lum", thresh_lum), ("thresh_depth", thresh_depth))
                                 if v is not None})
    params = HindsightParams(ratio=ratio, region_ratio=region_ratio, depth_slope=depth_slope)
    click.echo(f"jaxvo masks: {seq.name}, {idx.size} of {len(seq)} frames with a pose ({n_held} held poses of "
               f"{traj} left out), offsets "
               f"{','.join(str(o) for o in offset_list)}, {seq.camera!r}", err=True)
    tmp = partial_path(out_dir, fresh=True)
    tmp.mkdir(parents=True)
    pbar = None if no_progress else progress_bar(total=int(idx.size), unit="frame", desc="masks")
    moving, t0 = [], time.perf_counter()
    try:
        for i, m in sequence_masks(seq.frame, poses, seq.camera, config, params, offset_list):
            p = tmp / f"{stamp_name(seq.timestamps[i])}.png"
            if not cv2.imwrite(str(p), m.astype(np.uint8) * 255):
                raise DatasetError(f"{p}: could not write mask image")
            moving.append(float(m.mean()))
            if pbar is not None:
                pbar.update(1)
    except (DatasetError, ValueError, OSError) as e:
        raise DatasetError(_one_line(e) + (f" ({len(moving)} finished masks kept in {tmp})" if moving else "")) \
            from None
    finally:
        if pbar is not None:
            pbar.close()
    finish(tmp, out_dir)
    click.echo(f"wrote {len(moving)} masks to {out_dir} (moving pixels per frame: {100 * np.mean(moving):.1f} % "
               f"mean, {100 * np.max(moving):.1f} % max; {time.perf_counter() - t0:.1f} s)")


if __name__ == "__main__":  # pragma: no cover
    main()
