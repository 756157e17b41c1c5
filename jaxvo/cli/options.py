"""What the ``jaxvo`` commands share: the conventions text of every --help, option types and
options (seed, --force, the compilation cache, image size, a sequence folder with a trajectory),
the device line and progress callbacks."""
from __future__ import annotations

import functools
import math
from pathlib import Path

import click

from jaxvo.camera import PRESETS
from jaxvo.pipelines.demo import fmt, parse_size
from jaxvo.runtime import cache, notes

__all__ = ["CONVENTIONS", "SEED", "POSITIVE", "FORCE", "compilation_cache", "compile_note", "device", "size_option",
           "sequence_with_trajectory", "progress_cb"]

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


def compilation_cache(f):
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
            want = None
        if want is None:
            cache.disable()   # importing jaxvo switched the default folder on
        _RUN_CACHE[:] = [want]
        return f(*args, **kwargs)
    return wrapper


#: the cache folder of the command running (None: off), until compile_note looks at it
_RUN_CACHE: list = []


def compile_note() -> None:
    """Say once, before a progress bar that would sit at 0 %, that this run compiles: the
    compilation cache (:func:`compilation_cache`) holds nothing for this jaxvo, jax and device
    (:func:`jaxvo.runtime.cache.is_cold`) or is off. The library's own note of it is not given then."""
    if not _RUN_CACHE:
        return
    folder = _RUN_CACHE.pop()
    if cache.is_cold(folder):
        notes.suppress("compiling")
        where = (f"kept in {folder} for the next runs" if folder is not None
                 else "the compilation cache is off, so every run compiles")
        click.echo(f"note: compiling the estimator for this machine first (tens of seconds; {where})", err=True)


def device() -> str:
    """The device the estimator runs on (the first of jax.devices()), e.g. 'cpu:0' or 'gpu:0 (NVIDIA H100 ...)'."""
    import jax

    d = jax.devices()[0]
    kind = f" ({d.device_kind})" if d.device_kind != d.platform else ""
    return f"{d.platform}:{d.id}{kind}"


def size_option(ctx, param, value):
    """Click callback of --size: ``WIDTHxHEIGHT`` -> (width, height) pixels, or a usage error."""
    try:
        return parse_size(value)
    except ValueError as e:
        raise click.BadParameter(str(e).split(": ", 1)[-1]) from None


def depth_scale_option(ctx, param, value):
    """Click callback of --depth-scale: :func:`jaxvo.data.calibration.parse_depth_scale` (a number
    > 0, or the name of a sensor with a published depth correction, resolved by the reader against
    the layout's scale); None stays None; anything else a usage error."""
    if value is None:
        return None
    from jaxvo.data.calibration import parse_depth_scale
    try:
        return parse_depth_scale(value)
    except ValueError as e:
        raise click.BadParameter(str(e)) from None


DEPTH_SCALE_HELP = ("Depth PNG value / depth-scale = metres: 5000 for TUM, Bonn, ETH3D, ICL-NUIM; 1000 for "
                    "millimetres (Open3D, RealSense, Redwood); a sensor whose published depth correction to "
                    "apply to the layout's: fr1 (5000 x 1.035), fr2 (5000 x 1.031), bonn (5000 / 1.0593, the scale of "
                    "Bonn's marker-to-camera calibration); or 'recorded': the layout's as it is. [default: the "
                    "layout's, with the correction of the sensor the folder name identifies (freiburg1/2, "
                    "rgbd_bonn_*) where the intrinsics are its preset]")


def lens_option(ctx, param, value):
    """Click callback of --lens: :meth:`jaxvo.camera.Lens.parse` of the text (None stays None), or a
    usage error."""
    if value is None:
        return None
    from jaxvo.camera import Lens
    try:
        return Lens.parse(value)
    except ValueError as e:
        raise click.BadParameter(str(e)) from None


def sequence_with_trajectory(f):
    """The options of the commands that read a sequence folder with a trajectory (map, masks)."""
    options = [
        click.option("--camera", "camera_preset", type=click.Choice(sorted(PRESETS)), default=None,
                     help="Intrinsics preset. [default: as for 'jaxvo run': the folder's calibration file, else "
                          "from the folder name]"),
        click.option("--depth-scale", default=None, callback=depth_scale_option, metavar="SCALE",
                     help=DEPTH_SCALE_HELP),
        click.option("--max-dt", type=POSITIVE, default=0.02, show_default=True,
                     help="Maximum frame/trajectory (and colour/depth) timestamp difference, seconds."),
        click.option("--no-progress", is_flag=True, help="No progress bar.")]
    for option in reversed(options):
        f = option(f)
    return f


def progress_cb(pbar):
    """A ``progress(done, total)`` callback that moves a tqdm bar to ``done`` of ``total``."""
    def cb(done, total):
        if pbar.total != total:
            pbar.total = total
            pbar.refresh()
        pbar.update(done - pbar.n)
    return cb


def scale_text(scale: float, digits: int, note: str = "") -> str:
    """``"scale X"`` for the summaries of ``run`` and ``eval``: the similarity alignment's scale
    with ``digits`` decimals and ``note`` after it, or ``"scale -"`` with the reason where it is not
    finite (a ground truth that does not move has no length to scale)."""
    if math.isfinite(scale):
        return f"scale {fmt(scale, digits)}{note}"
    return "scale - (the ground truth does not move: no length to scale)"
