"""What a run is set up with: ``jaxvo run``'s options over a config file, which may be a trajectory
written by an earlier run (its ``#`` header reruns it).

:func:`read_run_settings` reads the settings a file holds (:class:`RunSettings`), :func:`run_header`
writes them at the top of a trajectory, :func:`load_config` makes the :class:`jaxvo.config.Config` of a
file, :func:`track_policy` the :class:`jaxvo.config.TrackConfig` of the options, and :func:`setup_run`
puts it all together as a :class:`RunSetup` (config, policy, seed, :class:`ReaderOptions`, and where
each setting came from). Bad input raises :class:`jaxvo.data.DatasetError` / ``ValueError`` with a
one-line message naming the file or the option.
"""
from __future__ import annotations

import dataclasses
import functools
import json
from pathlib import Path
from typing import List, Optional, Tuple, Union

import numpy as np

from jaxvo.camera import Lens
from jaxvo.data import DatasetError, TumSequence
from jaxvo.pipelines.sequences import load_sequence
from jaxvo.runtime import machine

__all__ = ["ReaderOptions", "RunSettings", "RunSetup", "load_config", "read_run_settings", "run_header", "setup_run",
           "track_policy"]


@dataclasses.dataclass(frozen=True)
class RunSettings:
    """The settings a config file holds (:func:`read_run_settings`), JSON values as read.

    config: Config fields. The rest only in a trajectory file's header (else None): track
    (TrackConfig fields), seed, sequence (the reader's settings: path, reader, start, frames,
    depth_scale, max_dt, camera, mask_dir) and machine (:func:`jaxvo.runtime.machine.record`
    of the machine that wrote it; older files lack it).
    """
    config: dict
    track: Optional[dict] = None
    seed: Optional[int] = None
    sequence: Optional[dict] = None
    machine: Optional[dict] = None


def read_run_settings(path) -> RunSettings:
    """The settings stored in ``path``: a JSON object of Config fields, or a trajectory file written
    by :func:`jaxvo.pipelines.run.run_sequence`, whose ``#`` header (:func:`run_header`) holds them all.
    Raises DatasetError naming the file when it is missing, malformed or has no jaxvo header.
    """
    p = Path(path)
    try:
        text = p.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise DatasetError(f"{p}: config file not found") from None
    except IsADirectoryError:
        raise DatasetError(f"{p}: is a folder, expected a JSON config file") from None
    except UnicodeDecodeError as e:
        raise DatasetError(f"{p}: config file is not UTF-8 text (byte {e.start})") from None
    except OSError as e:
        raise DatasetError(f"{p}: cannot read config file ({e.strerror or e})") from None
    if text.lstrip().startswith("#"):
        found = {}
        for line in text.splitlines():
            if not line.startswith("#"):
                break
            key, sep, value = line[1:].strip().partition(": ")
            if sep and key in ("config", "track", "sequence", "seed", "machine"):
                try:
                    found[key] = json.loads(value)
                except json.JSONDecodeError as e:
                    raise DatasetError(f"{p}: malformed '# {key}:' header line ({e.msg})") from None
        if "config" not in found:
            raise DatasetError(f"{p}: no '# config: {{...}}' header line (not a trajectory written by jaxvo run)")
        return RunSettings(**found)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise DatasetError(f"{p}: not valid JSON ({e.msg} at line {e.lineno}) nor a jaxvo trajectory file") \
            from None
    if not isinstance(data, dict):
        raise DatasetError(f"{p}: expected a JSON object of Config fields, got {type(data).__name__}")
    return RunSettings(config=data)


def load_config(path=None, **overrides):
    """A :class:`jaxvo.config.Config` from a JSON file of Config fields, or from the header of a
    trajectory file written by ``jaxvo run`` (:func:`read_run_settings`), plus overrides (None = keep).

    Unknown fields, a malformed file or an invalid value raise ValueError / DatasetError naming the file.
    """
    from jaxvo.config import Config

    values = dict(read_run_settings(path).config) if path is not None else {}
    values.update({k: v for k, v in overrides.items() if v is not None})
    try:
        return Config.from_json(values)
    except (ValueError, TypeError) as e:
        raise DatasetError(f"{path}: {e}" if path is not None else str(e)) from None


def run_header(config, policy, seed: int, seq: Optional[TumSequence] = None) -> List[str]:
    """The ``#`` comment lines that start a trajectory file of :func:`jaxvo.pipelines.run.run_sequence`: jaxvo's version,
    method, seed, the full config and track policy (JSON, :meth:`jaxvo.config.Config.to_json`), the
    machine (:func:`jaxvo.runtime.machine.record`: on another CPU, core count or jaxlib the rerun may differ
    at float rounding) and the reader's settings; ``jaxvo run --config TRAJ`` reads them back (:func:`read_run_settings`)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        v = version("jaxvo")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree
        v = "unknown"
    lines = [f"# jaxvo {v}: jaxvo run SEQUENCE --config THIS_FILE reproduces this trajectory",
             f"# method: {config.method}", f"# seed: {int(seed)}", f"# config: {config.to_json()}",
             f"# track: {policy.to_json()}", f"# machine: {json.dumps(machine.record())}"]
    if seq is not None:
        c = seq.camera
        info = {"path": str(seq.path), "reader": type(seq).__name__, "start": int(seq.start), "frames": len(seq),
                "depth_scale": seq.depth_scale, "max_dt": seq.max_dt,
                "camera": {"fx": float(c.fx), "fy": float(c.fy), "cx": float(c.cx), "cy": float(c.cy),
                           "width": c.width, "height": c.height},
                "lens": seq.lens.to_list(),
                "mask_dir": None if seq.mask_dir is None else str(seq.mask_dir)}
        lines.append(f"# sequence: {json.dumps(info)}")
    return lines


def track_policy(gap: Optional[int] = None, lag: Optional[int] = None, base=None, frame_to_frame: bool = False,
                 segment: Optional[bool] = None, window: Optional[int] = None, poses: Optional[str] = None):
    """:class:`jaxvo.config.TrackConfig` from ``jaxvo run``'s options on top of ``base`` (default
    ``TrackConfig()``, jaxvo's segmented keyframes): ``frame_to_frame`` (the paper's chaining),
    ``gap`` / ``lag`` in frames (lag defaults to gap // 2; None keeps base's; a gap turns off the
    calm frame-to-frame mode), ``segment``, ``window`` (keyframes in the window) and ``poses``
    (the trajectory's poses, ``TrackConfig.poses``); None keeps base's. A bad combination raises
    ValueError naming the options."""
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
    if window is not None:
        policy = policy._replace(window=int(window))
    if poses is not None:
        policy = policy._replace(poses=str(poses))
    try:
        policy.validate()
    except ValueError:
        raise ValueError(f"--keyframe-lag {policy.lag} must be smaller than --keyframe-gap {policy.max_gap}") \
            from None
    return policy


@dataclasses.dataclass(frozen=True)
class ReaderOptions:
    """How :func:`jaxvo.pipelines.sequences.load_sequence` opens a folder: an intrinsics preset name and single values
    (pixels), depth scale (PNG value / scale = metres; None = the layout's; a sensor name such as "fr2":
    the layout's with that sensor's published depth correction), max_dt (largest
    colour/depth and estimate/ground-truth stamp difference, s), the first frame, the number of
    frames (None = all) and a folder of user masks."""
    camera_preset: Optional[str] = None
    fx: Optional[float] = None
    fy: Optional[float] = None
    cx: Optional[float] = None
    cy: Optional[float] = None
    depth_scale: Union[float, str, None] = None
    max_dt: float = 0.02
    start: int = 0
    max_frames: Optional[int] = None
    mask_dir: Optional[Path] = None
    camera_from: Optional[str] = None
    lens: Optional[Lens] = None

    def open(self, path) -> TumSequence:
        """The sequence folder ``path`` opened with these options (``camera_from``, when set, names
        where fx, fy, cx, cy came from, e.g. a trajectory header; ``lens`` None: none)."""
        seq = load_sequence(path, self.camera_preset, self.fx, self.fy, self.cx, self.cy, lens=self.lens,
                            depth_scale=self.depth_scale, max_dt=self.max_dt, start=self.start,
                            max_frames=self.max_frames, mask_dir=self.mask_dir)
        if self.camera_from is not None:
            seq.camera_source = self.camera_from
        return seq


@dataclasses.dataclass(frozen=True)
class RunSetup:
    """What a run uses (:func:`setup_run`): config, keyframe policy (TrackConfig), seed, reader
    options, and how the machine that wrote the config file differs from this one
    (``"name: recorded -> current"`` each; there a rerun may differ at float rounding).
    With a config file: ``sources`` (``"setting: where from"`` each: the file, the command line
    or today's default), ``missing`` (the settings a trajectory header lacks, filled with
    today's defaults: an older jaxvo wrote it) and ``header_sequence`` (the folder the header
    was written for)."""
    config: object
    policy: object
    seed: int
    reader: ReaderOptions
    machine_differences: Tuple[str, ...] = ()
    sources: Tuple[str, ...] = ()
    missing: Tuple[str, ...] = ()
    header_sequence: Optional[str] = None


def setup_run(config_file=None, *, method=None, thresh_lum=None, thresh_depth=None, finest_level=None,
              seed: Optional[int] = None, keyframe_gap=None, keyframe_lag=None, segment=None, window=None, poses=None,
              frame_to_frame: bool = False, paper: bool = False, camera_preset=None, fx=None, fy=None, cx=None,
              cy=None, depth_scale=None, max_dt=None, start=None, max_frames=None, mask_dir=None, lens=None,
              from_header: bool = True) -> RunSetup:
    """The settings of a run: options given (None = not given) over a config file's.

    ``config_file`` is a JSON object of Config fields, or a trajectory written by
    :func:`jaxvo.pipelines.run.run_sequence`: its header gives the config, seed, keyframe policy and, with
    ``from_header`` (one sequence), the reader's settings (start, frames, max_dt, depth scale,
    user masks, intrinsics, lens), so the run is reproduced bitwise on the same machine. Options not
    given and not in the file take their defaults (seed 0, start 0, max_dt 0.02 s).
    ``paper``: :meth:`jaxvo.config.Config.paper` and frame to frame; ``keyframe_gap``,
    ``keyframe_lag``, ``segment``, ``window``, ``poses``, ``frame_to_frame``: :func:`track_policy`.
    """
    from jaxvo.config import Config, TrackConfig

    settings = read_run_settings(config_file) if config_file is not None else RunSettings(config={})
    diffs: List[str] = []
    if settings.machine is not None:
        if not isinstance(settings.machine, dict):
            raise DatasetError(f"{config_file}: '# machine:' header: expected a JSON object, got "
                               f"{settings.machine!r}")
        diffs = machine.differences(settings.machine, machine.record())
    config = load_config(config_file, method=method, thresh_lum=thresh_lum, thresh_depth=thresh_depth,
                         finest_level=finest_level)
    if seed is None:
        seed = _header_value(config_file, "seed", settings.seed, "an integer >= 0", int, 0) \
            if settings.seed is not None else 0
    try:
        base = TrackConfig.from_json(settings.track) if settings.track is not None else None
    except (ValueError, TypeError) as e:
        raise DatasetError(f"{config_file}: '# track:' header: {e}") from None
    if paper:
        config = Config.paper(config.method, thresh_lum=config.thresh_lum, thresh_depth=config.thresh_depth,
                              finest_level=config.finest_level)
    policy = track_policy(keyframe_gap, keyframe_lag, base, frame_to_frame or paper, segment, window, poses)
    sq = (settings.sequence or {}) if from_header else {}
    if sq and not isinstance(sq, dict):
        raise DatasetError(f"{config_file}: '# sequence:' header: expected a JSON object, got {sq!r}")
    given = {"start": start, "frames": max_frames, "max_dt": max_dt, "depth_scale": depth_scale,
             "mask_dir": mask_dir, "camera": None if camera_preset is None and (fx, fy, cx, cy) == (None,) * 4
             else "given", "lens": lens}
    camera_from = None
    if sq:
        h = functools.partial(_header_value, config_file)
        start = h("start", sq.get("start"), "an integer >= 0", int, 0) if start is None else start
        max_frames = h("frames", sq.get("frames"), "an integer >= 2", int, 2) if max_frames is None else max_frames
        max_dt = h("max_dt", sq.get("max_dt"), "a number > 0 (seconds)", float, 0) if max_dt is None else max_dt
        depth_scale = h("depth_scale", sq.get("depth_scale"), "a number > 0", float, 0) \
            if depth_scale is None else depth_scale
        mask_dir = h("mask_dir", sq.get("mask_dir"), "a folder name", str) if mask_dir is None else mask_dir
        c = sq.get("camera")
        if c is not None and not isinstance(c, dict):
            raise DatasetError(f"{config_file}: '# sequence:' header: \"camera\" must be a JSON object of fx, fy, "
                               f"cx, cy, got {c!r}")
        if given["camera"] is None and isinstance(c, dict):
            fx, fy, cx, cy = (h(f"camera.{k}", c.get(k), "a number > 0 (pixels)", float, 0)
                              for k in ("fx", "fy", "cx", "cy"))
            camera_from = f"the header of {config_file}"
        if lens is None and sq.get("lens") is not None:
            try:
                lens = Lens.parse(sq["lens"])
            except ValueError as e:
                raise DatasetError(f"{config_file}: header field \"lens\": {e}") from None
    reader = ReaderOptions(camera_preset, fx, fy, cx, cy, depth_scale, 0.02 if max_dt is None else max_dt,
                           0 if start is None else start, max_frames, mask_dir, camera_from,
                           None if lens is None else Lens.parse(lens))
    sources, missing = _provenance(config_file, settings, sq, given, from_header)
    return RunSetup(config, policy, int(seed), reader, tuple(diffs), sources, missing,
                    sq.get("path") if sq else None)


def _header_value(path, name: str, value, what: str, kind, low=None):
    """A value of a trajectory header (None stays None) checked for its type: DatasetError naming
    the file and the field (``"frames" must be an integer >= 2, got 'all'``) otherwise."""
    if value is None:
        return None
    ok = isinstance(value, str) if kind is str else (
        isinstance(value, (int, float)) and not isinstance(value, bool) and
        (kind is float or float(value).is_integer()) and np.isfinite(value) and
        (low is None or (value >= low if kind is int else value > low)))
    if not ok:
        raise DatasetError(f"{path}: header field \"{name}\" must be {what}, got {value!r}")
    return kind(value)


#: the reader's settings a trajectory header of jaxvo run holds
_HEADER_SEQUENCE = ("start", "frames", "max_dt", "depth_scale", "camera", "lens", "mask_dir")


def _provenance(config_file, settings, sq: dict, given: dict, from_header: bool):
    """(``"setting: where from"`` each, the settings a trajectory header lacks) of a run with a
    config file; ((), ()) without one."""
    if config_file is None:
        return (), ()
    from jaxvo.config import Config, TrackConfig

    is_header = settings.track is not None or settings.seed is not None or settings.sequence is not None
    missing = [f"config.{f.name}" for f in dataclasses.fields(Config) if f.name not in settings.config]
    if not is_header:
        return (f"config: {config_file}",), ()
    missing += [f"track.{f}" for f in TrackConfig._fields if f not in (settings.track or {})]
    missing += ["seed"] if settings.seed is None else []
    sources = [f"config, track, seed: {config_file}"]
    if from_header:
        missing += [f"sequence.{k}" for k in _HEADER_SEQUENCE if k not in (settings.sequence or {})]
        for k in _HEADER_SEQUENCE:
            where = ("the command line" if given[k] is not None else config_file if k in sq
                     else "today's default")
            sources.append(f"{k.replace('_', ' ')}: {where}")
    return tuple(sources), tuple(missing)
