"""Run a sequence through the tracker: the library side of ``jaxvo run``.

:func:`run_sequence` tracks a :class:`jaxvo.datasets.TumSequence` with
:func:`jaxvo.odometry.track`, writes the trajectory as it goes and returns a
:class:`RunResult`; :func:`resolve_camera` finds a folder's intrinsics and
:func:`load_config` reads a :class:`jaxvo.config.Config` from a JSON file.
Bad input raises :class:`jaxvo.datasets.DatasetError` / ``ValueError`` with a
one-line message naming the file.
"""
from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Callable, List, Optional

import numpy as np

from jaxvo.camera import PRESETS, Camera, camera_for_sequence
from jaxvo.datasets import DatasetError, TumSequence

__all__ = ["RunResult", "run_sequence", "load_config", "resolve_camera", "outlier_mask", "stamp_name"]


def load_config(path=None, **overrides):
    """A :class:`jaxvo.config.Config` from a JSON file of Config fields plus overrides (None = keep).

    Lists become tuples (``blocks``). Unknown fields, a malformed file or an invalid value
    (checked by :meth:`Config.validate`: type, finiteness, range) raise ValueError /
    DatasetError naming the file and the field.
    """
    from jaxvo.config import Config

    cfg = Config()
    if path is not None:
        p = Path(path)
        try:
            data = json.loads(p.read_bytes().decode("utf-8"))
        except UnicodeDecodeError as e:
            raise DatasetError(f"{p}: config file is not UTF-8 text (byte {e.start})") from None
        except json.JSONDecodeError as e:
            raise DatasetError(f"{p}: not valid JSON ({e.msg} at line {e.lineno})") from None
        except IsADirectoryError:
            raise DatasetError(f"{p}: is a folder, expected a JSON config file") from None
        except FileNotFoundError:
            raise DatasetError(f"{p}: config file not found") from None
        if not isinstance(data, dict):
            raise DatasetError(f"{p}: expected a JSON object of Config fields, got {type(data).__name__}")
        try:
            cfg = Config.from_dict(data)
        except ValueError as e:
            raise DatasetError(f"{p}: {e}") from None
    return Config.from_dict({k: v for k, v in overrides.items() if v is not None}, base=cfg)


def resolve_camera(seq_dir, preset: Optional[str] = None, fx=None, fy=None, cx=None, cy=None) -> Camera:
    """Intrinsics for a sequence folder.

    ``preset`` (fr1, fr2, fr3, bonn, default) if given; else the ``camera`` entry of the
    folder's ``info.json`` (written by ``jaxvo synth`` / ``jaxvo augment``); else chosen from
    the folder name (freiburg1/2/3, rgbd_bonn_*, otherwise the default 525/319.5/239.5 camera).
    ``fx, fy, cx, cy`` (pixels) override single values.
    """
    seq_dir = Path(seq_dir)
    info = seq_dir / "info.json"
    cam = None
    if preset is not None:
        cam = PRESETS[preset]
    else:
        if info.is_file():
            try:
                c = json.loads(info.read_text()).get("camera")
                if isinstance(c, dict):
                    cam = Camera(float(c["fx"]), float(c["fy"]), float(c["cx"]), float(c["cy"]),
                                 int(c.get("width", 640)), int(c.get("height", 480)))
            except (ValueError, KeyError, TypeError, AttributeError) as e:
                raise DatasetError(f"{info}: malformed camera entry ({e})") from None
        if cam is None:
            cam = camera_for_sequence(seq_dir.resolve().name)
    over = {k: float(v) for k, v in (("fx", fx), ("fy", fy), ("cx", cx), ("cy", cy)) if v is not None}
    if over:
        cam = dataclasses.replace(cam, **over)
    try:
        cam.validate()
    except ValueError as e:
        raise DatasetError(f"{info}: {e}" if not over and preset is None and info.is_file() else str(e)) from None
    return cam


def outlier_mask(est, width: int, height: int, valid_too: bool = False):
    """Full-size (H, W) bool outlier mask (valid & ~inlier) of an estimate (and the valid mask)."""
    import cv2

    inl = np.asarray(est.inlier_mask, bool)
    val = np.asarray(est.valid_mask, bool)
    out = val & ~inl
    if out.shape != (height, width):
        out = cv2.resize(out.astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST).astype(bool)
        val = cv2.resize(val.astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST).astype(bool)
    return (out, val) if valid_too else out


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


def run_sequence(seq: TumSequence, config, seed: int = 0, out=None, save_masks=None,
                 on_pair: Optional[Callable] = None, pbar=None, policy=None) -> RunResult:
    """Track ``seq`` with :func:`jaxvo.odometry.track` and ``policy`` (a
    :class:`jaxvo.odometry.TrackConfig`; default frame to frame), so results equal the library's,
    writing the trajectory to ``out`` as it goes (first frame at identity) and optionally each
    estimate's outlier mask into ``save_masks`` (PNG named by the *reference* frame's
    timestamp: the mask lives on the reference image's pixels; with keyframes the last
    estimate against a reference, the longest baseline, is the one kept).
    ``on_pair(step)`` is called with each :class:`jaxvo.odometry.TrackStep`; ``pbar`` (tqdm) is advanced once per frame. Ctrl-C ends the run early
    (``interrupted=True``) keeping everything written so far.
    """
    import cv2
    import jax

    from jaxvo.odometry import track
    from jaxvo.trajectory import TrajectoryWriter

    stamps = np.asarray(seq.timestamps, np.float64)
    W, H = seq.camera.width, seq.camera.height
    mask_dir = None
    if save_masks is not None:
        mask_dir = Path(save_masks)
        try:
            mask_dir.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise DatasetError(f"{mask_dir}: cannot create mask folder ({e.strerror or e})") from None
    writer = TrajectoryWriter(out) if out is not None else None
    poses = [np.eye(4)]
    ratios: List[float] = []
    valids: List[bool] = []
    times: List[float] = []
    t0 = time.perf_counter()

    def callback(step):
        i, est, pose, ref = step.frame - 1, step.estimate, step.T_world_cur, step.reference
        ratios.append(float(est.inlier_ratio))
        valids.append(bool(step.valid))
        poses.append(np.asarray(pose, np.float64))
        if writer is not None:
            writer.write(stamps[i + 1], pose)
        if mask_dir is not None:
            m = outlier_mask(est, W, H)
            p = mask_dir / f"{stamp_name(stamps[ref])}.png"
            if not cv2.imwrite(str(p), m.astype(np.uint8) * 255):
                raise OSError(f"{p}: could not write mask image")
        if on_pair is not None:
            on_pair(step)
        times.append(time.perf_counter())
        if pbar is not None:
            pbar.update(1)
            pbar.set_postfix(inliers=f"{ratios[-1]:.2f}", refresh=False)

    interrupted = False
    frames_it = seq.prefetch(2)
    frames = (f for _, f in frames_it)
    try:
        if writer is not None:
            writer.open()
            writer.write_first(stamps[0])
        track(frames, seq.camera, config, jax.random.key(int(seed)), callback=callback, policy=policy)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        frames.close()
        frames_it.close()
        if writer is not None:
            writer.close()
    t_end = time.perf_counter()
    n = len(poses)
    compile_s = (times[0] - t0) if times else float("nan")
    fps = (len(times) - 1) / (times[-1] - times[0]) if len(times) >= 2 and times[-1] > times[0] else float("nan")
    return RunResult(config.method, stamps[:n].copy(), np.stack(poses), np.asarray(ratios),
                     np.asarray(valids, bool), compile_s, fps, t_end - t0, interrupted)
