"""Dynamic augmentation of a real static TUM RGB-D sequence with synthetic moving occluders.

:func:`augment` composites ``persons`` textured person-like objects (boxes /
cylinders, 0.5 x 1.7 m) into the colour and depth frames of a real sequence
with a per-pixel z-test, so the background keeps its real sensor noise and
the camera keeps its real ground truth:

* The camera pose of each frame is the real ground truth ``T_world_cam``
  interpolated at the rgb timestamp (linear translation, slerp rotation;
  ground truth that does not cover every frame is an error).
* Each occluder has a smooth trajectory in the real world frame: it stands
  upright (along the world's gravity axis, ``-z`` for TUM mocap worlds) at a
  point that follows a heavily smoothed (Gaussian, sigma 1.5 s) version of
  the camera's viewing direction, walking side to side, so it moves
  consistently in the world and stays roughly in view. Its distance is
  calibrated on the first frame so the occluders cover about ``coverage``
  of the image.
* The occluders are rendered once per frame (at the rgb timestamp) with the
  real intrinsics; in 16-bit depth units a pixel is composited where the
  occluder is hit and ``occ < real`` or ``real == 0``. Those pixels get the
  occluder's colour and depth in both images (depth and colour are treated
  as registered; the depth frame is the one associated with the rgb frame),
  and exactly those pixels are 255 in ``masks/``. With ``depth_time=True`` the depth image's
  occluders are rendered again at its own timestamp, from the camera's ground-truth pose then:
  a sensor that takes its depth apart from its colour (``jaxvo.Frame.depth_time``) sees the
  persons there, as it sees the room (the colour and the mask keep the colour image's render).

Output: ``rgb/``, ``depth/`` (same file names as the input), ``masks/<rgb ts>.png``,
``rgb.txt``, ``depth.txt``, ``masks.txt`` (only the written frames),
``groundtruth.txt`` copied byte for byte, and ``info.json``.
"""
from __future__ import annotations

import dataclasses
import json
import math
import shutil
from pathlib import Path
from typing import Callable, Optional

import cv2
import numpy as np

from jaxvo.camera import Camera
from jaxvo.data.errors import DatasetError
from jaxvo.data.stamps import interpolate_poses
from jaxvo.data.tum import TumSequence
from jaxvo.synthetic.render import render
from jaxvo.synthetic.scene import Scene, make_person
from jaxvo.synthetic.writer import depth_to_png, write_list

__all__ = ["augment", "WorldWalk"]

_DEPTH_SCALE = 5000.0


# --------------------------------------------------------------------------- occluder trajectories

@dataclasses.dataclass(eq=False)
class WorldWalk:
    """A person trajectory in a real sequence's world frame, following the camera's smoothed gaze.

    ``pose(t) -> T_world_obj`` (4, 4): body centre at
    ``c(t) + (lateral + amp * sin(2 pi t / period + phase)) * right(t)``
    where ``c(t)`` is the Gaussian-smoothed (``sigma`` s) point at ``distance``
    metres along the camera's optical axis and ``right(t)`` the smoothed
    horizontal right direction; the body's local y (down) is ``down`` (world),
    its local z faces away from the camera.
    """
    gt_stamps: np.ndarray
    gt_poses: np.ndarray
    down: np.ndarray
    distance: float
    lateral: float = 0.0
    amp: float = 0.4
    period: float = 4.0
    phase: float = 0.0
    sigma: float = 1.5
    t0: float = 0.0

    def _smoothed(self, t: float):
        s = self.gt_stamps
        lo, hi = np.searchsorted(s, [t - 3 * self.sigma, t + 3 * self.sigma])
        if hi <= lo:   # outside the ground truth: use the nearest pose
            k = int(np.clip(np.searchsorted(s, t), 0, len(s) - 1))
            lo, hi = k, k + 1
        P = self.gt_poses[lo:hi]
        w = np.exp(-0.5 * ((s[lo:hi] - t) / self.sigma) ** 2)
        w = w / w.sum()
        pos = (w[:, None] * P[:, :3, 3]).sum(0)
        fwd = (w[:, None] * P[:, :3, 2]).sum(0)
        return pos, fwd

    def pose(self, t: float) -> np.ndarray:
        pos, fwd = self._smoothed(float(t))
        down = self.down / np.linalg.norm(self.down)
        fwd = fwd / np.linalg.norm(fwd)
        centre = pos + self.distance * fwd
        fh = fwd - down * (fwd @ down)   # horizontal forward
        fh = fh / max(np.linalg.norm(fh), 1e-9)
        right = np.cross(down, fh)       # y-down, z-forward -> x = y cross z
        off = self.lateral + self.amp * math.sin(2 * math.pi * (t - self.t0) / self.period + self.phase)
        T = np.eye(4)
        T[:3, 0] = right
        T[:3, 1] = down
        T[:3, 2] = fh
        T[:3, 3] = centre + off * right
        return T


def _gravity_down(poses: np.ndarray) -> np.ndarray:
    """World 'down' direction: the world axis most aligned with the cameras' mean y (down) axis."""
    m = poses[:, :3, 1].mean(0)
    k = int(np.argmax(np.abs(m)))
    d = np.zeros(3)
    d[k] = np.sign(m[k])
    return d


# --------------------------------------------------------------------------- augmentation

def _composite(rgb_bgr, depth_u16, occ):
    """z-test composite of a RenderResult ``occ`` into real (H,W,3) uint8 BGR / (H,W) uint16 -> (rgb, depth, mask)."""
    occ_d = depth_to_png(occ.depth, _DEPTH_SCALE)
    win = (occ_d > 0) & ((depth_u16 == 0) | (occ_d < depth_u16))
    out_rgb = np.where(win[..., None], occ.rgb[..., ::-1], rgb_bgr)
    out_d = np.where(win, occ_d, depth_u16).astype(np.uint16)
    return np.ascontiguousarray(out_rgb), out_d, win


def augment(real_seq_dir, out_dir, persons: int = 1, coverage: float = 0.3, seed: int = 0,
            max_frames: Optional[int] = None, *, camera: Optional[Camera] = None, depth_time: bool = False,
            progress: Optional[Callable[[int, int], None]] = None) -> Path:
    """Composite ``persons`` moving occluders into a real TUM sequence and write it to ``out_dir``.

    Args:
      real_seq_dir: TUM folder (rgb/, depth/ 16-bit /5000, rgb.txt, depth.txt, groundtruth.txt).
      out_dir: output folder (created), TUM layout plus ``masks/`` and ``masks.txt``.
      persons: number of occluders K >= 1. coverage: target fraction of the image they cover
        together (calibrated on the first frame; actual coverage varies as they move and are
        hidden behind nearer real surfaces).
      seed: textures, shapes and walking phases. max_frames: use only the first N associated frames
        (of which those outside the ground truth's time span are left out: they have no pose).
      camera: intrinsics (default: from the folder name, e.g. freiburg2 -> TUM_FR2), at the images' size.
      depth_time: the depth image's occluders at its own timestamp and pose (see the module
        docstring); False: at the colour image's, in both images.
      progress: ``progress(done, total)`` after each frame.
    Returns ``Path(out_dir)``. Output is deterministic for a given input and arguments.
    """
    src = Path(real_seq_dir)
    if persons < 1:
        raise ValueError(f"persons must be >= 1, got {persons}")
    if not 0 < coverage < 1:
        raise ValueError(f"coverage must be in (0, 1), got {coverage}")
    # the same reader as every command: association, listed files, ground-truth coverage
    seq = TumSequence(src, camera=camera, max_frames=max_frames)
    if not seq.groundtruth_path.is_file():
        raise DatasetError(f"{seq.groundtruth_path}: file not found (augment needs the real ground truth)")
    gt_t, gt_T = seq.groundtruth
    covered, frame_poses = seq.groundtruth_at_frames()
    # TUM recordings often start a few frames before the motion capture (fr3 long_office by
    # 0.07 s): a person cannot be placed in a frame without a pose, so those frames are left out
    # and the augmentation starts at the first frame the ground truth covers (max_frames counts
    # the frames written, so the sequence is reopened with as many more as were left out)
    lead = int(np.argmax(covered)) if covered.any() else 0
    if lead and max_frames is not None:
        seq = TumSequence(src, camera=camera, max_frames=max_frames + lead)
        gt_t, gt_T = seq.groundtruth
        covered, frame_poses = seq.groundtruth_at_frames()
    keep = np.flatnonzero(covered)[:max_frames]
    if keep.size and depth_time:
        depth_poses = interpolate_poses(gt_t, gt_T, seq.depth_timestamps[keep], tol=seq.gt_slack)
    if keep.size == 0:
        raise DatasetError(f"{seq.groundtruth_path}: no ground truth at any of the {len(seq)} frames "
                           f"({seq.timestamps[0]:.6f} .. {seq.timestamps[-1]:.6f} s); it covers "
                           f"{gt_t[0]:.6f} .. {gt_t[-1]:.6f}")
    rgb0, dep0 = seq.read_images(int(keep[0]))
    H, W = rgb0.shape[:2]
    cam = seq.camera.with_size(W, H)
    stamps = [f"{t:.6f}" for t in seq.timestamps]
    dstamps = [f"{t:.6f}" for t in seq.depth_timestamps]
    names = [p.relative_to(src).as_posix() for p in seq.rgb_paths]
    dnames = [p.relative_to(src).as_posix() for p in seq.depth_paths]

    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0xA06, int(persons)]))
    down = _gravity_down(gt_T)
    t0 = float(seq.timestamps[keep[0]])
    # person sizes and initial distances from the coverage target
    kinds = ["cylinder" if k % 2 == 0 else "box" for k in range(persons)]
    widths = rng.uniform(0.45, 0.6, persons)
    heights = rng.uniform(1.6, 1.8, persons)
    f2 = float(cam.fx) * float(cam.fy)
    per = coverage / persons
    dist0 = np.sqrt(f2 * widths * heights / (per * W * H))
    jitter = rng.uniform(0.85, 1.15, persons)
    spread = 0.6
    laterals = (np.arange(persons) - (persons - 1) / 2) * spread
    periods = rng.uniform(3.0, 5.0, persons)
    phases = rng.uniform(0, 2 * np.pi, persons)
    walks = [WorldWalk(gt_t, gt_T, down, float(dist0[k] * jitter[k]), float(laterals[k]), 0.4,
                       float(periods[k]), float(phases[k]), 1.5, t0) for k in range(persons)]
    scene = Scene([], seed)
    for k in range(persons):
        scene.add(make_person(rng, walks[k], kind=kinds[k], width=float(widths[k]), height=float(heights[k]),
                              name=f"person{k}"))

    # calibrate the distance on the first frame so the composited coverage is about `coverage`
    T0 = frame_poses[keep[0]]
    scale = 1.0
    for _ in range(4):
        for k, w in enumerate(walks):
            w.distance = float(np.clip(dist0[k] * jitter[k] * scale, 0.5, 4.0))
        occ = render(scene, cam, T0, t0)
        cov = _composite(rgb0, dep0, occ)[2].mean()
        if cov <= 0 or abs(cov - coverage) < 0.03:
            if cov <= 0:
                scale *= 0.7
                continue
            break
        scale *= float(np.clip(math.sqrt(cov / coverage), 0.7, 1.4))

    out = Path(out_dir)
    for sub in ("rgb", "depth", "masks"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    rgb_entries, dep_entries, mask_entries, covs = [], [], [], []
    for done, n in enumerate(keep, 1):
        rgb, dep = seq.read_images(n)
        t = float(seq.timestamps[n])
        occ = render(scene, cam, frame_poses[n], t)
        out_rgb, out_dep, win = _composite(rgb, dep, occ)
        if depth_time:
            td = float(seq.depth_timestamps[n])
            out_dep = _composite(rgb, dep, render(scene, cam, depth_poses[done - 1], td))[1]
        (out / names[n]).parent.mkdir(parents=True, exist_ok=True)
        (out / dnames[n]).parent.mkdir(parents=True, exist_ok=True)
        for path, img in ((out / names[n], out_rgb), (out / dnames[n], out_dep),
                          (out / "masks" / f"{stamps[n]}.png", win.astype(np.uint8) * 255)):
            if not cv2.imwrite(str(path), img):
                raise OSError(f"{path}: could not write image")
        rgb_entries.append((stamps[n], names[n]))
        dep_entries.append((dstamps[n], dnames[n]))
        mask_entries.append((stamps[n], f"masks/{stamps[n]}.png"))
        covs.append(float(win.mean()))
        if progress is not None:
            progress(done, len(keep))
    desc = f"augmented from '{src.name}' by jaxvo.synthetic.augment ({persons} persons, seed {seed})"
    write_list(out / "rgb.txt", f"color images\n{desc}\ntimestamp filename", rgb_entries)
    write_list(out / "depth.txt", f"depth maps\n{desc}\ntimestamp filename", dep_entries)
    write_list(out / "masks.txt", f"composited-occluder masks (255 = changed pixel), aligned with rgb\n{desc}\n"
               "timestamp filename", mask_entries)
    shutil.copyfile(src / "groundtruth.txt", out / "groundtruth.txt")
    info = {"source": str(src.name), "persons": int(persons), "coverage_target": float(coverage),
            "coverage_mean": float(np.mean(covs)), "seed": int(seed), "frames": int(keep.size),
            "frames_outside_groundtruth": int(np.count_nonzero(~covered[:keep[-1] + 1])),
            "camera": {"fx": float(cam.fx), "fy": float(cam.fy), "cx": float(cam.cx), "cy": float(cam.cy),
                       "width": int(cam.width), "height": int(cam.height)},
            "distances_m": [round(w.distance, 4) for w in walks]}
    if depth_time:
        info["depth_time"] = True
    (out / "info.json").write_text(json.dumps(info, indent=1, sort_keys=True) + "\n")
    return out
