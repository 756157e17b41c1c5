"""Run sequences through the tracker: the library side of ``jaxvo run``.

One sequence: :func:`run_sequence` tracks a :class:`jaxvo.data.TumSequence` with
:func:`jaxvo.tracking.odometry.track`, writes the trajectory as it goes and returns a
:class:`RunResult`; :func:`run_sequences` does so for several sequences of one image size as
one batch. Folders, as ``jaxvo run`` takes them, in three steps:

* :func:`setup_run`: the config, keyframe policy, seed and reader options of a run, from
  options and a config file, which may be a trajectory written by an earlier run (its ``#``
  header, :func:`read_run_settings`, reruns it);
* :func:`plan_run`: the sequence folders opened (a folder of sequence folders stands for them,
  :func:`expand_sequences`), their first frames and ground truth read, the outputs checked,
  the sequences grouped into batches by image size;
* :func:`execute_run`: the tracking, each trajectory written under its ``.partial`` name and
  renamed when complete, the errors against ground truth; a :class:`RunReport`.

:func:`resolve_camera` finds a folder's intrinsics and :func:`load_config` reads a
:class:`jaxvo.config.Config` from a JSON file. Bad input raises
:class:`jaxvo.data.DatasetError` / ``ValueError`` with a one-line message naming the file.
"""
from __future__ import annotations

import dataclasses
import functools
import json
import time
from pathlib import Path
from typing import Callable, List, Optional, Sequence, Tuple, Union

import numpy as np

from jaxvo.runtime import machine
from jaxvo.camera import PRESETS, Camera, Lens
from jaxvo.data.outputs import check_output, check_output_folder, finish, partial_path, write_text
from jaxvo.data import DatasetError, TumSequence, find_sequences, open_sequence
from jaxvo.evaluation.scoring import TrajectoryErrors, trajectory_errors
from jaxvo.pipelines.mapping import moving_mask
from jaxvo.pipelines.messages import one_line

__all__ = ["RunResult", "run_sequence", "run_sequences", "load_config", "read_run_settings", "run_header",
           "load_sequence", "resolve_camera", "stamp_name", "RunSettings", "ReaderOptions", "RunSetup", "RunPlan",
           "SequenceRun", "RunReport", "track_policy", "expand_sequences", "setup_run", "plan_run", "execute_run",
           "count_poses", "check_camera_size", "mask_name", "MASK_INDEX", "unusable_message"]


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
    by :func:`run_sequence`, whose ``#`` header (:func:`run_header`) holds them all.
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
    """The ``#`` comment lines that start a trajectory file of :func:`run_sequence`: jaxvo's version,
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


def load_sequence(seq_dir, preset: Optional[str] = None, fx=None, fy=None, cx=None, cy=None, lens=None,
                  **kwargs) -> TumSequence:
    """Open a sequence folder of any supported layout (:func:`jaxvo.data.open_sequence`) with the
    intrinsics the CLI would use: the ``preset`` (fr1, fr2, fr3, bonn, default) if given, else the
    folder's own (calibration file, info.json, folder name; sized to the images); ``fx, fy, cx, cy``
    (pixels) override single values. ``lens`` (a :class:`jaxvo.camera.Lens`, or what
    :meth:`jaxvo.camera.Lens.parse` reads: ``"fr2"``, 5 numbers, ``"none"``): the images are
    undistorted as they are read (None: with the published lens of the preset, or of the folder
    name's sensor where the intrinsics are its preset; else as they are). ``kwargs`` (depth_scale,
    max_dt, start, max_frames, ...) go to the reader, which reads the depth likewise with the
    preset's published correction unless ``depth_scale`` says otherwise. ``seq.camera_source``
    says where the intrinsics came from.
    """
    seq = open_sequence(seq_dir, camera=PRESETS[preset] if preset is not None else None,
                        lens=None if lens is None else Lens.parse(lens), sensor=preset, **kwargs)
    if preset is not None:
        seq.camera_source = f"preset {preset}"
    over = {k: float(v) for k, v in (("fx", fx), ("fy", fy), ("cx", cx), ("cy", cy)) if v is not None}
    if over:
        seq.camera = dataclasses.replace(seq.camera, **over)
        seq.camera_source += " with " + ", ".join(f"{k}={v:g}" for k, v in over.items())
        seq.camera.validate()
    return seq


def check_camera_size(seq: TumSequence) -> None:
    """Intrinsics for another image size than the sequence's first frame raise DatasetError with
    what fixes it: the size is the images', so leave a preset out (the folder's own intrinsics,
    else its name's preset scaled to the images) or write the calibration file for that size."""
    _, depth = seq.read_images(0)
    h, w = depth.shape[:2]
    c = seq.camera
    if (c.width, c.height) == (w, h):
        return
    source = seq.camera_source
    if source.startswith("preset"):
        fix = (f"the {source} is for {c.width}x{c.height}; leave --camera out to use the folder's own "
               f"intrinsics, else its name's preset scaled to {w}x{h}")
    else:
        fix = (f"the intrinsics from {source} are for {c.width}x{c.height}; write them for {w}x{h} there (or move "
               f"that file away: the folder name's preset is then scaled to {w}x{h})")
    raise DatasetError(f"{seq.path}: the images are {w}x{h}, which does not match the camera: {fix}")


def resolve_camera(seq_dir, preset: Optional[str] = None, fx=None, fy=None, cx=None, cy=None) -> Camera:
    """The intrinsics :func:`load_sequence` gives a folder (see there)."""
    return load_sequence(seq_dir, preset, fx, fy, cx, cy, max_frames=1).camera


def stamp_name(t: float) -> str:
    return f"{float(t):.6f}"


#: the index of the outlier masks of ``jaxvo run --save-masks`` (in their folder)
MASK_INDEX = "masks.txt"
MASK_INDEX_HEADER = ("# outlier masks of jaxvo run --save-masks, one per pair; a mask lies on the reference "
                     "frame's pixels\n# reference_timestamp file current_timestamp\n")


def mask_name(ref_stamp: float, cur_stamp: float) -> str:
    """The file of one pair's outlier mask: named by the reference and the current frame
    (``<reference>-<current>.png``), so the pairs that share a keyframe keep one file each."""
    return f"{stamp_name(ref_stamp)}-{stamp_name(cur_stamp)}.png"


@dataclasses.dataclass(frozen=True)
class RunResult:
    """What :func:`run_sequence` did.

    stamps (n,) s and poses (n, 4, 4) T_world_cam of the frames written (frame 0 at the start pose);
    inlier_ratio, valid (n-1,) per finished pair; compile_s: wall time until the first pair was
    done (reading, compiling and running it); fps: pairs per second after the first pair (NaN
    with fewer than 2 pairs); interrupted: ended by Ctrl-C; error: the one-line reason a
    sequence of a batch stopped early (a frame that does not read), None when it did not.
    """
    method: str
    stamps: np.ndarray
    poses: np.ndarray
    inlier_ratio: np.ndarray
    valid: np.ndarray
    compile_s: float
    fps: float
    wall_s: float
    interrupted: bool = False
    error: Optional[str] = None

    @property
    def pairs(self) -> int:
        return int(self.inlier_ratio.size)

    @property
    def failures(self) -> int:
        return int(np.sum(~self.valid))

    @property
    def unusable(self) -> bool:
        """The run produced nothing usable: more than half of its pairs failed (their pose is the
        previous one held), as when the depth scale is wrong or masks hide every pixel."""
        return self.pairs > 0 and 2 * self.failures > self.pairs


class _Recorder:
    """What a run keeps of one sequence: the trajectory written as it grows (after the ``#``
    header of :func:`run_header`), optional outlier masks, poses, inlier ratios and timings.
    ``step(TrackStep)`` records one frame; ``result(interrupted)`` gives the RunResult. A line is
    written once the step says it is final (``TrackStep.settled``: with ``TrackConfig.poses``
    "refined" a few frames later, from ``TrackStep.refined``; with "tracked" at once), the frames still open
    at :meth:`close` as they stand then (the end of the run, or Ctrl-C)."""

    def __init__(self, seq: TumSequence, config, seed: int, out=None, save_masks=None,
                 on_pair: Optional[Callable] = None, pbar=None, policy=None):
        from jaxvo.config import TrackConfig
        from jaxvo.data.trajectory import HEADER, TrajectoryWriter

        self.seq, self.method, self.on_pair, self.pbar = seq, config.method, on_pair, pbar
        self.stamps = np.asarray(seq.timestamps, np.float64)
        self.mask_dir, self.mask_index, self.error = None, [], None
        if save_masks is not None:
            self.mask_dir = Path(save_masks)
            try:
                self.mask_dir.mkdir(parents=True, exist_ok=True)
            except OSError as e:
                raise DatasetError(f"{self.mask_dir}: cannot create mask folder ({e.strerror or e})") from None
        header = "\n".join(run_header(config, policy if policy is not None else TrackConfig(), seed, seq) + [HEADER])
        self.writer = TrajectoryWriter(out, header=header) if out is not None else None
        self.open_poses: dict = {}    # frame -> pose, the frames not settled yet
        self.poses = [np.eye(4)]
        self.ratios: List[float] = []
        self.valids: List[bool] = []
        self.times: List[float] = []
        self.t0 = time.perf_counter()

    def open(self) -> None:
        if self.writer is not None:
            self.writer.open()
            self.writer.write_first(self.stamps[0])

    def close(self) -> None:
        for i in sorted(self.open_poses):
            self._line(i, self.open_poses[i])
        self.open_poses = {}
        if self.writer is not None:
            self.writer.close()
        if self.mask_dir is not None:
            write_text(self.mask_dir / MASK_INDEX, MASK_INDEX_HEADER + "".join(self.mask_index))

    def frames(self, frames):
        """``frames`` until one does not read: then the error is kept (``self.error``) and the
        sequence ends there, so the other sequences of its batch go on."""
        try:
            yield from frames
        except (DatasetError, ValueError, OSError) as e:
            self.error = one_line(e)

    def step(self, step) -> None:
        import cv2

        i, est, pose, ref = step.frame - 1, step.estimate, step.T_world_cur, step.reference
        self.ratios.append(float(est.inlier_ratio))
        self.valids.append(bool(step.valid))
        # the frames this step settles, in order; the others wait
        self.open_poses.update({step.frame: pose} if step.refined is None else step.refined)
        for k in range(len(self.poses), step.settled):
            self._line(k, self.open_poses.pop(k))
        if self.mask_dir is not None:
            m = moving_mask(est, self.seq.camera.width, self.seq.camera.height, step.static_mask)
            name = mask_name(self.stamps[ref], self.stamps[i + 1])
            p = self.mask_dir / name
            if not cv2.imwrite(str(p), m.astype(np.uint8) * 255):
                raise DatasetError(f"{p}: cannot write the mask image (disk full or no permission?)")
            self.mask_index.append(f"{stamp_name(self.stamps[ref])} {name} {stamp_name(self.stamps[i + 1])}\n")
        if self.on_pair is not None:
            self.on_pair(step)
        self.times.append(time.perf_counter())
        if self.pbar is not None:
            fps = self.fps()
            self.pbar.set_postfix(inliers=f"{self.ratios[-1]:.2f}", refresh=False,
                                  **({"fps": f"{fps:.2f}"} if np.isfinite(fps) else {}))
            self.pbar.update(1)

    def _line(self, k: int, pose) -> None:
        """Frame k's pose, the next one in order: kept, and written to the trajectory."""
        self.poses.append(np.asarray(pose, np.float64))
        if self.writer is not None:
            self.writer.write(self.stamps[k], pose, held=not self.valids[k - 1])

    def fps(self) -> float:
        """Pairs per second after the first pair (compilation): the summary's frames/s."""
        times = self.times
        return (len(times) - 1) / (times[-1] - times[0]) if len(times) >= 2 and times[-1] > times[0] \
            else float("nan")

    def result(self, interrupted: bool) -> "RunResult":
        times, n = self.times, len(self.poses)
        compile_s = (times[0] - self.t0) if times else float("nan")
        fps = self.fps()
        return RunResult(self.method, self.stamps[:n].copy(), np.stack(self.poses), np.asarray(self.ratios),
                         np.asarray(self.valids, bool), compile_s, fps, time.perf_counter() - self.t0, interrupted,
                         self.error)


def run_sequence(seq: TumSequence, config, seed: int = 0, out=None, save_masks=None,
                 on_pair: Optional[Callable] = None, pbar=None, policy=None) -> RunResult:
    """Track ``seq`` with :func:`jaxvo.tracking.odometry.track` and ``policy`` (a
    :class:`jaxvo.config.TrackConfig`; default the library's TrackConfig()) and the key
    ``jax.random.key(seed)``, so results equal the library's. The trajectory goes to ``out`` as
    it grows (first frame at identity), after the ``#`` header of :func:`run_header` (version,
    method, seed, config, policy, reader settings). Optionally each estimate's outlier mask goes
    into ``save_masks``: one PNG per pair named by the reference and the current frame
    (:func:`mask_name`; the mask lives on the reference image's pixels), listed in its index
    ``MASK_INDEX`` (``reference_timestamp file current_timestamp`` per line). ``on_pair(step)`` is called with each
    :class:`jaxvo.tracking.odometry.TrackStep`; ``pbar`` (tqdm) is advanced once per frame. Ctrl-C ends the
    run early (``interrupted=True``) keeping everything written so far.
    """
    import jax

    from jaxvo.tracking.odometry import track

    rec = _Recorder(seq, config, seed, out, save_masks, on_pair, pbar, policy)
    interrupted = False
    frames_it = seq.prefetch(2)
    frames = (f for _, f in frames_it)
    try:
        rec.open()
        track(frames, seq.camera, config, jax.random.key(int(seed)), callback=rec.step, policy=policy)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        frames.close()
        frames_it.close()
        rec.close()
    return rec.result(interrupted)


def run_sequences(seqs: List[TumSequence], config, seed: int = 0, outs=None, on_pair: Optional[Callable] = None,
                  pbar=None, policy=None) -> List[RunResult]:
    """:func:`run_sequence` for several sequences of one image size as one batch
    (:func:`jaxvo.tracking.batch.track_batch`: their estimates vmapped together, in lockstep, over the
    available devices). Each sequence uses the key ``jax.random.key(seed)`` as it would alone and
    writes its trajectory to its entry of ``outs`` (None = none). ``on_pair(s, step)`` is called
    with sequence index and :class:`jaxvo.tracking.odometry.TrackStep`. A frame that does not read
    ends its sequence there (its RunResult's ``error``); the others go on. Returns one RunResult
    per sequence.
    """
    import functools

    import jax

    from jaxvo.tracking.batch import track_batch

    outs = [None] * len(seqs) if outs is None else list(outs)
    recs = [_Recorder(seq, config, seed, out, None, None if on_pair is None else functools.partial(on_pair, s),
                      pbar, policy) for s, (seq, out) in enumerate(zip(seqs, outs))]
    interrupted = False
    iters = [seq.prefetch(2) for seq in seqs]
    frames = [rec.frames(f for _, f in it) for rec, it in zip(recs, iters)]
    try:
        for rec in recs:
            rec.open()
        track_batch(frames, [seq.camera for seq in seqs], config, [jax.random.key(int(seed))] * len(seqs),
                    policy, callbacks=[rec.step for rec in recs])
    except KeyboardInterrupt:
        interrupted = True
    finally:
        for f, it in zip(frames, iters):
            f.close()
            it.close()
        for rec in recs:
            rec.close()
    return [rec.result(interrupted) for rec in recs]


# ----------------------------------------------------------------------------- folders, as jaxvo run takes them

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


def expand_sequences(paths) -> List[Path]:
    """The sequence folders ``paths`` name: each path as it is, except a folder that is not a
    sequence itself but holds sequence folders (rgb.txt + depth.txt), which stands for them."""
    dirs = []
    for p in map(Path, paths):
        inner = find_sequences(p) if p.is_dir() else []
        if inner == [p]:
            inner = []              # a TUM-layout sequence folder itself
        if inner:
            try:
                open_sequence(p, max_frames=1)
                inner = []          # a sequence of another layout (ICL-NUIM, Redwood): itself
            except (DatasetError, ValueError):
                pass
        dirs += inner or [p]
    return dirs


@dataclasses.dataclass(frozen=True)
class ReaderOptions:
    """How :func:`load_sequence` opens a folder: an intrinsics preset name and single values
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
    :func:`run_sequence`: its header gives the config, seed, keyframe policy and, with
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


@dataclasses.dataclass(frozen=True)
class RunPlan:
    """A run ready to go (:func:`plan_run`): its setup, the sequences (opened, first frame and
    ground truth read), each one's trajectory file, the outlier-mask folder (one sequence only)
    and the batches: indices of the sequences of one image size, tracked together."""
    setup: RunSetup
    sequences: Tuple[TumSequence, ...]
    outputs: Tuple[Path, ...]
    batches: Tuple[Tuple[int, ...], ...]
    save_masks: Optional[Path] = None


def plan_run(sequence_dirs: Sequence, setup: RunSetup, out=None, out_dir=".", save_masks=None,
             config_file=None, force: bool = False) -> RunPlan:
    """Open the sequence folders and check the outputs before anything is tracked.

    One folder: its trajectory goes to ``out`` (default traj.txt), its outlier masks to
    ``save_masks``. Several: each trajectory to ``out_dir/<sequence name>.txt`` (``-k`` appended
    to names that repeat), created here. Outputs that would replace or land inside an input
    (the folders, ``config_file``, the user masks) raise DatasetError unless ``force``; so do a
    sequence of fewer than 2 frames, a first frame that does not read and ground truth that does
    not cover the frames.
    """
    dirs = [Path(d) for d in sequence_dirs]
    if len(dirs) == 1:
        out = Path("traj.txt") if out is None else Path(out)
        inputs = [dirs[0], config_file, setup.reader.mask_dir]
        check_output(out, inputs, force, "--out")
        if save_masks is not None:
            check_output_folder(save_masks, inputs, force, "--save-masks")
        seq = setup.reader.open(dirs[0])
        if len(seq) < 2:
            raise DatasetError(f"{dirs[0]}: only {len(seq)} frame(s) to use, need at least 2")
        check_camera_size(seq)
        seq.check(1)                 # a bad first image is reported before compiling
        seq.groundtruth              # and so is ground truth that does not cover the frames
        return RunPlan(setup, (seq,), (out,), ((0,),), None if save_masks is None else Path(save_masks))
    seqs = [setup.reader.open(d) for d in dirs]
    names = [seq.name for seq in seqs]
    out_dir = Path(out_dir)
    outs = [out_dir / (f"{n}.txt" if names.count(n) == 1 else f"{n}-{k}.txt") for k, n in enumerate(names)]
    for seq, o in zip(seqs, outs):
        if len(seq) < 2:
            raise DatasetError(f"{seq.path}: only {len(seq)} frame(s) to use, need at least 2")
        check_output(o, [s.path for s in seqs] + [config_file], force, "--out-dir")
        check_camera_size(seq)
        seq.check(1)
    groups: dict = {}
    for k, seq in enumerate(seqs):
        groups.setdefault((seq.camera.width, seq.camera.height), []).append(k)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise DatasetError(f"--out-dir {out_dir}: cannot create it ({e.strerror or e})") from None
    return RunPlan(setup, tuple(seqs), tuple(outs), tuple(tuple(g) for g in groups.values()))


@dataclasses.dataclass(frozen=True)
class SequenceRun:
    """One sequence of a :class:`RunReport`: the sequence, its :class:`RunResult` (None: its
    batch was not reached before Ctrl-C), where its trajectory is (under its ``.partial`` name
    unless it ran to the end), its errors against the sequence's ground truth (None without
    ground truth) and why it is not a success (None when it is): a frame that did not read, or
    :func:`unusable_message`."""
    sequence: TumSequence
    result: Optional[RunResult]
    trajectory: Path
    errors: Optional[TrajectoryErrors]
    problem: Optional[str] = None


@dataclasses.dataclass(frozen=True)
class RunReport:
    """What :func:`execute_run` did: one :class:`SequenceRun` per sequence of the plan (in its
    order) and whether Ctrl-C ended it."""
    runs: Tuple[SequenceRun, ...]
    interrupted: bool

    @property
    def problems(self) -> Tuple[str, ...]:
        """The one-line reasons, per sequence that is not a success."""
        return tuple(r.problem for r in self.runs if r.problem is not None)


def count_poses(path) -> int:
    """The number of pose lines in a trajectory file (0 when it cannot be read)."""
    try:
        return sum(1 for ln in Path(path).read_text().splitlines() if ln.strip() and not ln.startswith("#"))
    except OSError:
        return 0


def unusable_message(seq: TumSequence, res: RunResult, trajectory) -> Optional[str]:
    """The one-line error of a run that produced nothing usable (:attr:`RunResult.unusable`:
    more than half of the pairs failed), naming the likely cause from the first frame: masks that
    hide (nearly) every pixel, or a depth whose median is implausible at the scale used; else
    every usual cause. None for a usable run."""
    if not res.unusable:
        return None
    from jaxvo.data import read_frame_mask

    cause = None
    try:
        _, depth = seq.read_images(0)
        valid = depth[depth > 0]
        median = float(np.median(valid)) / seq.depth_scale if valid.size else float("nan")
        mp = seq.mask_paths[0] if getattr(seq, "mask_paths", None) else None
        used = float((read_frame_mask(mp, depth.shape) > 0).mean()) if mp is not None else 1.0
    except (DatasetError, ValueError, OSError):
        median, used = float("nan"), 1.0
    if used < 0.05:
        cause = (f"the masks of {seq.mask_dir} leave {100 * used:.1f} % of the pixels (nonzero = use the pixel; "
                 f"a 16-bit 0/1 mask reads as all 0: write 8-bit 0/255)")
    elif not valid.size:
        cause = "the first frame has no valid depth"
    else:
        cause = (f"a wrong --depth-scale? ({seq.depth_scale:g} makes the first frame's median depth "
                 f"{median:.2f} m; TUM/Bonn/ETH3D/ICL-NUIM use 5000, Redwood/Open3D/RealSense millimetres 1000), "
                 f"masks that hide the scene, or images without texture")
    return (f"{seq.path}: nothing usable: {res.failures} of {res.pairs} pairs failed (more than half); likely "
            f"cause: {cause}; the trajectory is kept in {trajectory}")


def _sequence_run(seq: TumSequence, res: RunResult, out: Path, max_dt: float) -> SequenceRun:
    """A :class:`SequenceRun` of a finished (or stopped) tracking: the trajectory is renamed to
    ``out`` when the sequence ran to its end (a run with nothing usable too: it is complete)."""
    partial = partial_path(out)
    done = not res.interrupted and res.error is None
    if done:
        finish(partial, out)
    trajectory = out if done else partial
    gt = seq.groundtruth
    errors = trajectory_errors(gt, res.stamps, res.poses, max_dt) if gt is not None and len(res.stamps) else None
    problem = None
    if res.error is not None:
        n = count_poses(partial)
        problem = res.error + (f" ({n} finished poses kept in {partial})" if n else "")
    elif not res.interrupted:
        problem = unusable_message(seq, res, trajectory)
    return SequenceRun(seq, res, trajectory, errors, problem)


def execute_run(plan: RunPlan, pbar=None, on_pair: Optional[Callable] = None) -> RunReport:
    """Track the plan's sequences: one alone with :func:`run_sequence`, several batch by batch with
    :func:`run_sequences`. Each trajectory grows under its ``.partial`` name (flushed line by line)
    and gets its name when its sequence is done (a finished batch's at once). ``on_pair(k, step)``
    is called with the sequence's index in the plan and each
    :class:`jaxvo.tracking.odometry.TrackStep`; ``pbar`` (tqdm) advances once per frame.

    One sequence: a failure raises DatasetError saying where the finished poses are kept.
    Several: a frame that does not read stops only its sequence, a failing batch only its
    sequences; each one's reason is its SequenceRun's ``problem``, as is a run with nothing
    usable (:func:`unusable_message`).
    """
    s = plan.setup
    if len(plan.sequences) == 1:
        seq, out = plan.sequences[0], plan.outputs[0]
        partial = partial_path(out)
        masks = None if plan.save_masks is None else partial_path(plan.save_masks, fresh=True)
        try:
            res = run_sequence(seq, s.config, s.seed, out=partial, save_masks=masks, pbar=pbar,
                               policy=s.policy, on_pair=None if on_pair is None else functools.partial(on_pair, 0))
        except (DatasetError, ValueError, OSError) as e:
            n = count_poses(partial)
            raise DatasetError(one_line(e) + (f" ({n} finished poses kept in {partial})" if n else "")) from None
        if masks is not None and not res.interrupted:
            finish(masks, plan.save_masks)
        return RunReport((_sequence_run(seq, res, out, s.reader.max_dt),), res.interrupted)
    runs: dict = {}
    interrupted = False
    for ks in plan.batches:
        if interrupted:
            break
        seqs = [plan.sequences[k] for k in ks]
        try:
            res = run_sequences(seqs, s.config, s.seed, [partial_path(plan.outputs[k]) for k in ks], pbar=pbar,
                                policy=s.policy,
                                on_pair=None if on_pair is None else (lambda j, step, ks=ks: on_pair(ks[j], step)))
        except (DatasetError, ValueError, OSError) as e:
            for k in ks:
                partial = partial_path(plan.outputs[k])
                n = count_poses(partial)
                runs[k] = SequenceRun(plan.sequences[k], None, partial, None,
                                      one_line(e) + (f" ({n} finished poses kept in {partial})" if n else ""))
            continue
        for k, seq, r in zip(ks, seqs, res):
            runs[k] = _sequence_run(seq, r, plan.outputs[k], seq.max_dt)
        interrupted = any(r.interrupted for r in res)
    out = [runs.get(k) or SequenceRun(seq, None, partial_path(plan.outputs[k]), None)
           for k, seq in enumerate(plan.sequences)]
    return RunReport(tuple(out), interrupted)
