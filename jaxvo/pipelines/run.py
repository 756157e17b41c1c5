"""Run a sequence through the tracker: the library side of ``jaxvo run``.

:func:`run_sequence` tracks a :class:`jaxvo.data.tum.TumSequence` with
:func:`jaxvo.tracking.odometry.track`, writes the trajectory as it goes and returns a
:class:`RunResult`; :func:`resolve_camera` finds a folder's intrinsics and
:func:`load_config` reads a :class:`jaxvo.config.Config` from a JSON file.
Bad input raises :class:`jaxvo.data.errors.DatasetError` / ``ValueError`` with a
one-line message naming the file.
"""
from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Callable, List, Optional

import numpy as np

from jaxvo.runtime import machine
from jaxvo.camera import PRESETS, Camera
from jaxvo.data.errors import DatasetError
from jaxvo.data.layouts import open_sequence
from jaxvo.data.tum import TumSequence
from jaxvo.pipelines.mapping import moving_mask

__all__ = ["RunResult", "run_sequence", "run_sequences", "load_config", "read_run_settings", "run_header", "load_sequence", "resolve_camera", "stamp_name"]


def read_run_settings(path) -> dict:
    """The settings stored in ``path``: a JSON object of Config fields (-> ``{"config": {...}}``), or a
    trajectory file written by :func:`run_sequence`, whose ``#`` header (:func:`run_header`) gives
    ``config`` and ``track`` (dicts of fields), ``seed`` (int), ``method``, ``sequence`` (the
    reader's settings: path, start, frames, depth_scale, max_dt, camera, mask_dir) and
    ``machine`` (:func:`jaxvo.runtime.machine.record` of the machine that wrote it; older files lack it).
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
        return found
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise DatasetError(f"{p}: not valid JSON ({e.msg} at line {e.lineno}) nor a jaxvo trajectory file") \
            from None
    if not isinstance(data, dict):
        raise DatasetError(f"{p}: expected a JSON object of Config fields, got {type(data).__name__}")
    return {"config": data}


def load_config(path=None, **overrides):
    """A :class:`jaxvo.config.Config` from a JSON file of Config fields, or from the header of a
    trajectory file written by ``jaxvo run`` (:func:`read_run_settings`), plus overrides (None = keep).

    Unknown fields, a malformed file or an invalid value raise ValueError / DatasetError naming the file.
    """
    from jaxvo.config import Config

    values = dict(read_run_settings(path)["config"]) if path is not None else {}
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
                "mask_dir": None if seq.mask_dir is None else str(seq.mask_dir)}
        lines.append(f"# sequence: {json.dumps(info)}")
    return lines


def load_sequence(seq_dir, preset: Optional[str] = None, fx=None, fy=None, cx=None, cy=None,
                  **kwargs) -> TumSequence:
    """Open a sequence folder of any supported layout (:func:`jaxvo.data.layouts.open_sequence`) with the
    intrinsics the CLI would use: the ``preset`` (fr1, fr2, fr3, bonn, default) if given, else the
    folder's own (calibration file, info.json, folder name; sized to the images); ``fx, fy, cx, cy``
    (pixels) override single values. ``kwargs`` (depth_scale, max_dt, start, max_frames, ...) go to
    the reader. ``seq.camera_source`` says where the intrinsics came from.
    """
    seq = open_sequence(seq_dir, camera=PRESETS[preset] if preset is not None else None, **kwargs)
    if preset is not None:
        seq.camera_source = f"preset {preset}"
    over = {k: float(v) for k, v in (("fx", fx), ("fy", fy), ("cx", cx), ("cy", cy)) if v is not None}
    if over:
        seq.camera = dataclasses.replace(seq.camera, **over)
        seq.camera_source += " with " + ", ".join(f"{k}={v:g}" for k, v in over.items())
        seq.camera.validate()
    return seq


def resolve_camera(seq_dir, preset: Optional[str] = None, fx=None, fy=None, cx=None, cy=None) -> Camera:
    """The intrinsics :func:`load_sequence` gives a folder (see there)."""
    return load_sequence(seq_dir, preset, fx, fy, cx, cy, max_frames=1).camera


def stamp_name(t: float) -> str:
    return f"{float(t):.6f}"


@dataclasses.dataclass
class RunResult:
    """What :func:`run_sequence` did.

    stamps (n,) s and poses (n, 4, 4) T_world_cam of the frames written (frame 0 at the start pose);
    inlier_ratio, valid (n-1,) per finished pair; compile_s: wall time until the first pair was
    done (reading, compiling and running it); fps: pairs per second after the first pair (NaN
    with fewer than 2 pairs); interrupted: ended by Ctrl-C.
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

    @property
    def pairs(self) -> int:
        return int(self.inlier_ratio.size)

    @property
    def failures(self) -> int:
        return int(np.sum(~self.valid))


class _Recorder:
    """What a run keeps of one sequence: the trajectory written as it grows (after the ``#``
    header of :func:`run_header`), optional outlier masks, poses, inlier ratios and timings.
    ``step(TrackStep)`` records one frame; ``result(interrupted)`` gives the RunResult."""

    def __init__(self, seq: TumSequence, config, seed: int, out=None, save_masks=None,
                 on_pair: Optional[Callable] = None, pbar=None, policy=None):
        from jaxvo.config import TrackConfig
        from jaxvo.data.trajectory import HEADER, TrajectoryWriter

        self.seq, self.method, self.on_pair, self.pbar = seq, config.method, on_pair, pbar
        self.stamps = np.asarray(seq.timestamps, np.float64)
        self.mask_dir = None
        if save_masks is not None:
            self.mask_dir = Path(save_masks)
            try:
                self.mask_dir.mkdir(parents=True, exist_ok=True)
            except OSError as e:
                raise DatasetError(f"{self.mask_dir}: cannot create mask folder ({e.strerror or e})") from None
        header = "\n".join(run_header(config, policy if policy is not None else TrackConfig(), seed, seq) + [HEADER])
        self.writer = TrajectoryWriter(out, header=header) if out is not None else None
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
        if self.writer is not None:
            self.writer.close()

    def step(self, step) -> None:
        import cv2

        i, est, pose, ref = step.frame - 1, step.estimate, step.T_world_cur, step.reference
        self.ratios.append(float(est.inlier_ratio))
        self.valids.append(bool(step.valid))
        self.poses.append(np.asarray(pose, np.float64))
        if self.writer is not None:
            self.writer.write(self.stamps[i + 1], pose, held=not step.valid)
        if self.mask_dir is not None:
            m = moving_mask(est, self.seq.camera.width, self.seq.camera.height, step.static_mask)
            p = self.mask_dir / f"{stamp_name(self.stamps[ref])}.png"
            if not cv2.imwrite(str(p), m.astype(np.uint8) * 255):
                raise OSError(f"{p}: could not write mask image")
        if self.on_pair is not None:
            self.on_pair(step)
        self.times.append(time.perf_counter())
        if self.pbar is not None:
            self.pbar.update(1)
            self.pbar.set_postfix(inliers=f"{self.ratios[-1]:.2f}", refresh=False)

    def result(self, interrupted: bool) -> "RunResult":
        times, n = self.times, len(self.poses)
        compile_s = (times[0] - self.t0) if times else float("nan")
        fps = (len(times) - 1) / (times[-1] - times[0]) if len(times) >= 2 and times[-1] > times[0] \
            else float("nan")
        return RunResult(self.method, self.stamps[:n].copy(), np.stack(self.poses), np.asarray(self.ratios),
                         np.asarray(self.valids, bool), compile_s, fps, time.perf_counter() - self.t0, interrupted)


def run_sequence(seq: TumSequence, config, seed: int = 0, out=None, save_masks=None,
                 on_pair: Optional[Callable] = None, pbar=None, policy=None) -> RunResult:
    """Track ``seq`` with :func:`jaxvo.tracking.odometry.track` and ``policy`` (a
    :class:`jaxvo.config.TrackConfig`; default the library's TrackConfig()) and the key
    ``jax.random.key(seed)``, so results equal the library's. The trajectory goes to ``out`` as
    it grows (first frame at identity), after the ``#`` header of :func:`run_header` (version,
    method, seed, config, policy, reader settings). Optionally each estimate's outlier mask goes
    into ``save_masks`` (PNG named by the *reference* frame's timestamp: the mask lives on the
    reference image's pixels; with keyframes the last estimate against a reference, the longest
    baseline, is the one kept). ``on_pair(step)`` is called with each
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
    with sequence index and :class:`jaxvo.tracking.odometry.TrackStep`. Returns one RunResult per sequence.
    """
    import functools

    import jax

    from jaxvo.tracking.batch import track_batch

    outs = [None] * len(seqs) if outs is None else list(outs)
    recs = [_Recorder(seq, config, seed, out, None, None if on_pair is None else functools.partial(on_pair, s),
                      pbar, policy) for s, (seq, out) in enumerate(zip(seqs, outs))]
    interrupted = False
    iters = [seq.prefetch(2) for seq in seqs]
    frames = [(f for _, f in it) for it in iters]
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
