"""Write synthetic sequences in the TUM RGB-D layout (plus moving-pixel masks).

Layout written by :func:`generate` / :func:`write_sequence` into ``out_dir``::

    rgb/<ts>.png      8-bit colour (cv2.imwrite, so BGR channel order on disk as usual)
    depth/<ts>.png    16-bit depth, metres * 5000, 0 = invalid
    masks/<ts>.png    8-bit, 255 = pixel whose nearest surface is a moving object
    rgb.txt, depth.txt, masks.txt   "timestamp filename" with TUM-style '#' headers
    groundtruth.txt   "timestamp tx ty tz qx qy qz qw", T_world_cam (camera-to-world)
    info.json         name, seed, frame count, fps, intrinsics (fx fy cx cy width height), sensor

``<ts>`` is the timestamp in seconds formatted with 6 decimals (frame k at k / 30 s).
Output is bitwise deterministic for a given (name, frames, seed, sensor, camera).
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Callable, Optional

import cv2
import numpy as np

from jaxvo import geometry
from jaxvo.camera import DEFAULT, Camera
from jaxvo.synthetic.motions import SyntheticSequence, make_sequence
from jaxvo.synthetic.render import SensorModel

__all__ = ["generate", "write_sequence", "depth_to_png", "write_list", "write_groundtruth", "DEPTH_SCALE"]

DEPTH_SCALE = 5000.0


def depth_to_png(depth: np.ndarray, scale: float = DEPTH_SCALE) -> np.ndarray:
    """(H, W) float metres (0 = invalid) -> (H, W) uint16 ``round(depth * scale)``, clipped to 65535."""
    d = np.nan_to_num(np.asarray(depth, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    return np.clip(np.rint(d * scale), 0, 65535).astype(np.uint16)


def write_list(path, header: str, entries) -> None:
    """Write a TUM ``timestamp filename`` list; ``header`` lines are prefixed with '# '."""
    lines = [f"# {h}" for h in header.splitlines()]
    lines += [f"{ts} {fn}" for ts, fn in entries]
    Path(path).write_text("\n".join(lines) + "\n")


def write_groundtruth(path, timestamps, poses, header: str = "ground truth trajectory") -> None:
    """Write ``timestamp tx ty tz qx qy qz qw`` lines for (N,) timestamps and (N, 4, 4) T_world_cam poses."""
    q, t = geometry.quat_trans_from_transform(np.asarray(poses, np.float64))
    lines = [f"# {header}", "# timestamp tx ty tz qx qy qz qw"]
    for ts, qq, tt in zip(timestamps, q, t):
        lines.append(f"{ts:.6f} " + " ".join(f"{x:.9f}" for x in (*tt, *qq)))
    Path(path).write_text("\n".join(lines) + "\n")


def _imwrite(path: Path, img: np.ndarray) -> None:
    if not cv2.imwrite(str(path), img):
        raise OSError(f"could not write {path}")


def write_sequence(seq: SyntheticSequence, out_dir, *, sensor: Optional[SensorModel] = None,
                   supersample: int = 1, progress: Optional[Callable[[int, int], None]] = None) -> Path:
    """Render every frame of ``seq`` and write it in the TUM layout into ``out_dir`` (created).

    Sensor effects for frame k use ``np.random.default_rng(SeedSequence([seq.seed, k]))``.
    ``progress(done, total)`` is called after each frame. Returns ``Path(out_dir)``.
    """
    out = Path(out_dir)
    for sub in ("rgb", "depth", "masks"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    n = len(seq)
    names = [f"{t:.6f}" for t in seq.timestamps]
    for k in range(n):
        rng = np.random.default_rng(np.random.SeedSequence([int(seq.seed), k, 0x5E50]))
        r = seq.render(k, sensor=sensor, rng=rng, supersample=supersample)
        _imwrite(out / "rgb" / f"{names[k]}.png", np.ascontiguousarray(r.rgb[..., ::-1]))
        _imwrite(out / "depth" / f"{names[k]}.png", depth_to_png(r.depth))
        _imwrite(out / "masks" / f"{names[k]}.png", r.moving_mask.astype(np.uint8) * 255)
        if progress is not None:
            progress(k + 1, n)
    desc = f"synthetic sequence '{seq.name}' (jaxvo.synthetic, seed {seq.seed})"
    write_list(out / "rgb.txt", f"color images\n{desc}\ntimestamp filename",
               [(s, f"rgb/{s}.png") for s in names])
    write_list(out / "depth.txt", f"depth maps\n{desc}\ntimestamp filename",
               [(s, f"depth/{s}.png") for s in names])
    write_list(out / "masks.txt", f"moving-object masks (255 = moving pixel)\n{desc}\ntimestamp filename",
               [(s, f"masks/{s}.png") for s in names])
    write_groundtruth(out / "groundtruth.txt", seq.timestamps, seq.poses,
                      header=f"ground truth trajectory (T_world_cam), {desc}")
    cam = seq.camera
    info = {
        "name": seq.name, "seed": int(seq.seed), "frames": n,
        "fps": float(1.0 / (seq.timestamps[1] - seq.timestamps[0])) if n > 1 else None,
        "camera": {"fx": float(cam.fx), "fy": float(cam.fy), "cx": float(cam.cx), "cy": float(cam.cy),
                   "width": int(cam.width), "height": int(cam.height)},
        "depth_scale": DEPTH_SCALE,
        "sensor": None if sensor is None else dataclasses.asdict(sensor),
        "supersample": int(supersample),
        "persons": len(seq.persons),
    }
    (out / "info.json").write_text(json.dumps(info, indent=1, sort_keys=True) + "\n")
    return out


def generate(name: str, out_dir, frames: int = 300, seed: int = 0, *, sensor: Optional[SensorModel] = None,
             camera: Camera = DEFAULT, supersample: int = 1,
             progress: Optional[Callable[[int, int], None]] = None) -> Path:
    """Make sequence ``name`` (see :data:`jaxvo.synthetic.motions.SEQUENCES`) and write it to ``out_dir``.

    ``frames`` at 30 Hz, deterministic from ``seed``; ``sensor`` adds
    Kinect-like effects (default: none, exact depth quantised to 1/5000 m by
    the PNG); ``progress(done, total)`` is called after each frame.
    Returns ``Path(out_dir)``.
    """
    seq = make_sequence(name, frames=frames, seed=seed, camera=camera)
    return write_sequence(seq, out_dir, sensor=sensor, supersample=supersample, progress=progress)
