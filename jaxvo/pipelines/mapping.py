"""Coloured 3-D maps of a sequence (the paper's Fig. 1/2): point clouds, PLY files, previews.

A map is built from a sequence and a trajectory (``T_world_cam`` per frame, e.g. the TUM file
``jaxvo run`` writes): every ``every``-th frame, the pixels with valid depth (``0 < z <= max_depth``
metres) are back-projected into the camera frame (x right, y down, z forward) and moved into
the world with ``T_world_cam``. Each point is labelled *static* (an inlier of the estimator)
or *moving* (an outlier): static points keep their RGB colour, moving points are painted
:data:`MOVING_COLOUR` (green, as the outliers of the paper's Fig. 4/7).

Labels come from :func:`jaxvo.estimator.motion.estimate_motion` on the pair (frame i, frame i+1) (for
the last frame, (i, i-1)): the estimator's inlier mask lives on the *reference* frame's pixels,
and ``valid_mask & ~inlier_mask`` are the outliers. Or, with ``labels="masks"``, from the
sequence's ``masks/`` folder (8-bit PNGs, 255 = moving pixel, listed by timestamp in
``masks.txt``; jaxvo synthetic and augmented sequences have them). ``labels=None``: all static.

Voxel-grid downsampling (:func:`voxel_downsample`) averages positions and colours per voxel,
static and moving points apart. :func:`render_preview` splats the cloud into a PNG (a
perspective view from behind and above the first camera, and a top view) with NumPy.
:func:`map_sequence` is ``jaxvo map``: a sequence folder and a trajectory file in, a PLY
(:mod:`jaxvo.data.ply`) and optionally a preview out.
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Callable, Dict, NamedTuple, Optional, Sequence, Tuple, Union

import numpy as np

from jaxvo.data.masks import load_mask_of_size as load_mask, true_masks as read_moving_masks
__all__ = ["MOVING_COLOUR", "PointCloud", "MapResult", "MapRun", "KeptPoses", "match_trajectory",
           "backproject_frame", "outlier_mask", "moving_mask", "read_moving_masks", "load_mask", "voxel_downsample",
           "build_map", "read_kept_poses", "map_sequence", "render_preview", "preview_image"]

#: Colour of moving (outlier) points, RGB 0-255: the paper's outlier green (``jaxvo.viz.OUTLIER_COLOUR``).
MOVING_COLOUR = (40, 220, 40)


@dataclasses.dataclass(frozen=True)
class PointCloud:
    """points (N, 3) float32 world metres, colors (N, 3) uint8 RGB, moving (N,) bool."""
    points: np.ndarray
    colors: np.ndarray
    moving: np.ndarray

    def __len__(self) -> int:
        return int(self.points.shape[0])

    @staticmethod
    def empty() -> "PointCloud":
        return PointCloud(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8), np.zeros(0, bool))

    @staticmethod
    def concat(clouds: Sequence["PointCloud"]) -> "PointCloud":
        clouds = [c for c in clouds if len(c)]
        if not clouds:
            return PointCloud.empty()
        return PointCloud(np.concatenate([c.points for c in clouds]).astype(np.float32),
                          np.concatenate([c.colors for c in clouds]).astype(np.uint8),
                          np.concatenate([c.moving for c in clouds]).astype(bool))

    def display_colors(self, moving_colour=MOVING_COLOUR) -> np.ndarray:
        """(N, 3) uint8: RGB colour for static points, ``moving_colour`` for moving ones."""
        c = self.colors.copy()
        c[self.moving] = np.asarray(moving_colour, np.uint8)
        return c


@dataclasses.dataclass(frozen=True)
class MapResult:
    """What :func:`build_map` made.

    cloud: the (downsampled) :class:`PointCloud` (true RGB colours + ``moving`` flags; use
    ``cloud.display_colors()`` for the map's colours). frames: sequence indices used.
    poses: (F, 4, 4) their T_world_cam. raw_points: points before downsampling.
    moving_fraction: per used frame, fraction of its valid-depth pixels labelled moving.
    inlier_ratio: per used frame, the estimator's inlier ratio (NaN when labels are not estimated).
    seconds: wall time.
    """
    cloud: PointCloud
    frames: np.ndarray
    poses: np.ndarray
    raw_points: int
    moving_fraction: np.ndarray
    inlier_ratio: np.ndarray
    seconds: float


# ----------------------------------------------------------------------------- geometry

def match_trajectory(frame_stamps, traj_stamps, traj_poses, max_dt: float = 0.02) -> Tuple[np.ndarray, np.ndarray]:
    """Poses for the frames: ``(frame indices (M,), T_world_cam (M, 4, 4))`` of the frames whose
    timestamp has a trajectory entry within ``max_dt`` seconds (one-to-one, nearest first)."""
    from jaxvo.data import associate

    P = np.asarray(traj_poses, np.float64)
    ia, ib = associate(frame_stamps, traj_stamps, max_dt)
    order = np.argsort(ia, kind="stable")
    return ia[order], P[ib[order]]


def backproject_frame(rgb, depth, camera, T_world_cam, max_depth: float = 4.0, stride: int = 1):
    """Back-project one RGB-D image into the world.

    rgb: (H, W, 3) uint8 RGB. depth: (H, W) metres (0 = invalid). camera: jaxvo Camera for
    (H, W). T_world_cam: (4, 4) camera-to-world. stride: use every stride-th row and column.
    Returns ``(points (N, 3) float64 world, colors (N, 3) uint8, (rows, cols) (N,) pixel
    indices)`` of the pixels with ``0 < depth <= max_depth``.
    """
    d = np.asarray(depth, np.float64)
    H, W = d.shape
    rows, cols = np.mgrid[0:H:stride, 0:W:stride]
    z = d[rows, cols]
    ok = np.isfinite(z) & (z > 0) & (z <= max_depth)
    r, c, z = rows[ok], cols[ok], z[ok]
    x = (c - float(camera.cx)) / float(camera.fx) * z
    y = (r - float(camera.cy)) / float(camera.fy) * z
    Pc = np.stack([x, y, z], 1)
    T = np.asarray(T_world_cam, np.float64)
    Pw = Pc @ T[:3, :3].T + T[:3, 3]
    return Pw, np.asarray(rgb)[r, c].astype(np.uint8), (r, c)


def _full_size(m, width: int, height: int) -> np.ndarray:
    """(h, w) bool -> (height, width), nearest neighbour (estimates that stopped at a coarser level)."""
    m = np.asarray(m, bool)
    if m.shape != (height, width):
        import cv2
        m = cv2.resize(m.astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST).astype(bool)
    return m


def outlier_mask(est, width: int, height: int, valid_too: bool = False):
    """(H, W) bool outlier mask ``valid_mask & ~inlier_mask`` of a MotionEstimate on the reference
    frame's pixels, at full size; with ``valid_too`` also the (H, W) valid mask."""
    val = _full_size(est.valid_mask, width, height)
    out = val & ~_full_size(est.inlier_mask, width, height)
    return (out, val) if valid_too else out


def moving_mask(est, width: int, height: int, static_mask=None, valid_too: bool = False):
    """(H, W) bool: the reference pixels an estimate explains as moving.

    Its outliers, less those hidden in the current frame (``est.occluded_mask``: something
    stepped in front of them, which says nothing about the pixel itself; on the synthetic
    sequences they were a third of the outliers that were not on a moving object), plus
    the pixels the segmentation did not trust as static (``static_mask`` False, the
    :class:`~jaxvo.tracking.odometry.TrackStep` field). With ``valid_too`` also the mask of pixels
    where this is decided (the estimate's valid pixels and the segmentation's dynamic ones).
    """
    out, val = outlier_mask(est, width, height, valid_too=True)
    if getattr(est, "occluded_mask", None) is not None:
        out = out & ~_full_size(est.occluded_mask, width, height)
    if static_mask is not None:
        dyn = ~np.asarray(static_mask, bool)
        out, val = out | dyn, val | dyn
    return (out, val) if valid_too else out


def voxel_downsample(points, colors, voxel: float, moving=None):
    """Average positions and colours per voxel of side ``voxel`` metres (static and moving apart).

    Returns ``(points (M, 3) float32, colors (M, 3) uint8, moving (M,) bool)``; ``voxel <= 0``
    or None returns the input unchanged (as those dtypes).
    """
    P = np.asarray(points, np.float64).reshape(-1, 3)
    C = np.asarray(colors).reshape(-1, 3)
    mv = np.zeros(len(P), bool) if moving is None else np.asarray(moving, bool).reshape(-1)
    if not voxel or voxel <= 0 or len(P) == 0:
        return P.astype(np.float32), C.astype(np.uint8), mv
    q = np.floor((P - P.min(0)) / float(voxel)).astype(np.int64)
    keys = np.concatenate([q, mv[:, None].astype(np.int64)], 1)
    _, inv, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    M = counts.size
    outP = np.stack([np.bincount(inv, P[:, k], M) for k in range(3)], 1) / counts[:, None]
    outC = np.stack([np.bincount(inv, C[:, k].astype(np.float64), M) for k in range(3)], 1) / counts[:, None]
    outM = np.zeros(M, bool)
    outM[inv] = mv
    return outP.astype(np.float32), np.clip(np.round(outC), 0, 255).astype(np.uint8), outM


# ----------------------------------------------------------------------------- the map

def build_map(seq, traj_stamps, traj_poses, every: int = 5, voxel: Optional[float] = 0.01,
              max_depth: float = 4.0, labels: Optional[str] = "estimate", config=None, seed: int = 0,
              stride: int = 1, max_dt: float = 0.02,
              progress: Optional[Callable[[int, int], None]] = None) -> MapResult:
    """Coloured point cloud of a :class:`jaxvo.data.TumSequence` from a trajectory.

    Args:
      seq: the sequence (its camera must match the images).
      traj_stamps, traj_poses: (M,) seconds and (M, 4, 4) T_world_cam (e.g.
        :func:`jaxvo.data.trajectory.read_tum_trajectory`); matched to the frames by timestamp
        within ``max_dt`` s. Frames without a pose are skipped.
      every: use every ``every``-th frame that has a pose.
      voxel: voxel size (m) for downsampling, None / 0 = keep every point.
      labels: "estimate" (outliers of ``estimate_motion`` on (i, i+1), or (i, i-1) where frame i+1
        has no depth, with ``config``, default ``Config()`` = ransac; key ``fold_in(key(seed), i)``;
        none where neither pair has depth), "hindsight" (the masks of
        :func:`jaxvo.tracking.hindsight.sequence_masks` from the trajectory's poses of every matched
        frame, ``config``'s thresholds), "masks" (the sequence's masks/), or None (everything
        static).
      stride: pixel subsampling of each frame before the voxel grid.
      progress: ``progress(done, total)`` after each used frame.

    Raises ValueError / DatasetError on bad input (no frame with a pose, no masks, ...).
    """
    from jaxvo.data import DatasetError
    from jaxvo.frame import has_depth, make_frame, undistort_images

    t0 = time.perf_counter()
    if every < 1:
        raise ValueError(f"every must be >= 1, got {every}")
    if labels not in (None, "estimate", "hindsight", "masks"):
        raise ValueError(f"labels must be 'estimate', 'hindsight', 'masks' or None, got {labels!r}")
    idx, poses = match_trajectory(seq.timestamps, traj_stamps, traj_poses, max_dt)
    if idx.size == 0:
        raise DatasetError(f"no trajectory pose within {max_dt} s of any frame of {seq.path} "
                           f"(frames {seq.timestamps[0]:.6f} .. {seq.timestamps[-1]:.6f})")
    all_poses = np.full((len(seq), 4, 4), np.nan)
    all_poses[idx] = poses
    sel = np.arange(0, idx.size, every)
    idx, poses = idx[sel], poses[sel]
    cam = seq.camera
    W, H = cam.width, cam.height
    masks = None
    if labels == "masks":
        masks = read_moving_masks(seq.path)
        if masks is None:
            raise DatasetError(f"{seq.path}: no masks.txt or masks/ folder (needed for mask labels)")
    if labels == "estimate":
        import jax

        from jaxvo.config import Config
        from jaxvo.estimator.motion import estimate_motion
        config = Config() if config is None else config
        key = jax.random.key(int(seed))

    if labels == "hindsight":   # every matched frame is a view; masks of the frames used, in order
        from jaxvo.tracking.hindsight import sequence_masks
        hindsight = sequence_masks(seq.frame, all_poses, cam, config, frames=[int(i) for i in idx])

    cache: Dict[int, tuple] = {}

    def load(i):
        if i not in cache:
            bgr, dep = seq.read_images(i)
            if (dep.shape[1], dep.shape[0]) != (W, H):
                raise DatasetError(f"{seq.rgb_paths[i]}: image size {dep.shape[1]}x{dep.shape[0]} does not "
                                   f"match the camera's {W}x{H}")
            # the images the trajectory was estimated on: undistorted for the reader's lens
            bgr, dep = undistort_images(bgr, dep, cam, seq.lens)
            rgb = np.ascontiguousarray(bgr[..., ::-1])
            try:
                fr = make_frame(bgr, dep, seq.depth_scale, color_order="bgr", source=str(seq.depth_paths[i]))
            except ValueError as e:
                raise DatasetError(str(e)) from None
            cache.clear() if len(cache) > 4 else None
            cache[i] = (rgb, dep.astype(np.float64) / seq.depth_scale, fr)
        return cache[i]

    clouds, mfrac, ratios = [], [], []
    n = len(idx)
    for k, (i, T) in enumerate(zip(idx, poses)):
        i = int(i)
        rgb, depth, fr = load(i)
        ratio = float("nan")
        # the next frame, else the one before, where both have depth (a covered sensor's frame has none)
        pair = [j for j in (i + 1, i - 1) if labels == "estimate" and 0 <= j < len(seq) and has_depth(fr)
                and has_depth(load(j)[2])][:1]
        if labels == "estimate" and not pair:
            moving_img = np.zeros((H, W), bool)
        elif labels == "estimate":
            est = estimate_motion(fr, load(pair[0])[2], cam, config, jax.random.fold_in(key, i))
            moving_img = moving_mask(est, W, H)
            ratio = float(est.inlier_ratio)
        elif labels == "hindsight":
            moving_img = next(hindsight)[1]
        elif labels == "masks":
            mt, mp = masks
            j = int(np.argmin(np.abs(mt - seq.timestamps[i])))
            if abs(mt[j] - seq.timestamps[i]) > max_dt:
                raise DatasetError(f"{seq.path}: no moving-pixel mask within {max_dt} s of frame "
                                   f"{seq.timestamps[i]:.6f}")
            moving_img = load_mask(mp[j], (H, W))
        else:
            moving_img = np.zeros((H, W), bool)
        P, C, (r, c) = backproject_frame(rgb, depth, cam, T, max_depth, stride)
        mv = moving_img[r, c]
        clouds.append(PointCloud(P.astype(np.float32), C, mv))
        mfrac.append(float(mv.mean()) if mv.size else float("nan"))
        ratios.append(ratio)
        if progress is not None:
            progress(k + 1, n)
    raw = PointCloud.concat(clouds)
    if voxel:
        p, c, m = voxel_downsample(raw.points, raw.colors, voxel, raw.moving)
        cloud = PointCloud(p, c, m)
    else:
        cloud = raw
    return MapResult(cloud, idx, poses, len(raw), np.asarray(mfrac), np.asarray(ratios),
                     time.perf_counter() - t0)


# ----------------------------------------------------------------------------- preview

def _splat(Pc, colors, fx, fy, cx, cy, W, H, radius=1, background=255):
    """Z-buffered point splat of camera-frame points (z forward) into an (H, W, 3) uint8 image."""
    z = Pc[:, 2]
    ok = z > 0.05
    Pc, colors, z = Pc[ok], colors[ok], z[ok]
    return _splat_ortho(fx * Pc[:, 0] / z + cx, fy * Pc[:, 1] / z + cy, z, colors, W, H, radius, background)


def _look_at(eye, target, up) -> np.ndarray:
    """T_world_view of a camera (x right, y down, z forward) at ``eye`` looking at ``target``."""
    z = target - eye
    z = z / max(np.linalg.norm(z), 1e-9)
    x = np.cross(z, -up)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(z, np.array([1.0, 0.0, 0.0]))
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], 1)
    T[:3, 3] = eye
    return T


def preview_image(points, colors, poses=None, size: Tuple[int, int] = (640, 480), view: str = "perspective",
                  max_points: int = 2_000_000, seed: int = 0) -> np.ndarray:
    """(H, W, 3) uint8 RGB splat of a coloured cloud.

    view "perspective": from behind and above the first camera of ``poses`` ((F, 4, 4)
    T_world_cam; without poses the world frame is taken as a y-down camera frame), looking at
    the cloud's median point. view "top": orthographic, looking down the cameras' mean up axis
    (world -y without poses).
    """
    P = np.asarray(points, np.float64).reshape(-1, 3)
    C = np.asarray(colors, np.uint8).reshape(-1, 3)
    W, H = size
    if len(P) > max_points:
        keep = np.random.default_rng(seed).choice(len(P), max_points, replace=False)
        P, C = P[keep], C[keep]
    if len(P) == 0:
        return np.full((H, W, 3), 255, np.uint8)
    if poses is not None and len(poses):
        Tp = np.asarray(poses, np.float64)
        up = -Tp[:, :3, 1].mean(0)
        fwd = Tp[0, :3, 2]
        origin = Tp[0, :3, 3]
    else:
        up, fwd, origin = np.array([0.0, -1.0, 0.0]), np.array([0.0, 0.0, 1.0]), np.zeros(3)
    up = up / max(np.linalg.norm(up), 1e-9)
    target = np.median(P, 0)
    lo, hi = np.percentile(P, 2, 0), np.percentile(P, 98, 0)
    ext = float(np.linalg.norm(hi - lo))
    if view == "top":
        # orthographic along -up: image x along the forward direction's horizontal part's normal
        f = fwd - up * np.dot(fwd, up)
        f = f / max(np.linalg.norm(f), 1e-9)
        r = np.cross(f, -up)   # right = forward x down
        a = (P - target) @ r
        b = -(P - target) @ f   # forward = up in the image
        h = P @ up
        if poses is not None and len(poses):   # leave out the ceiling (> 0.5 m above the highest camera)
            below = h <= float(np.max(np.asarray(poses)[:, :3, 3] @ up)) + 0.5
            if below.any():
                a, b, h, C = a[below], b[below], h[below], C[below]
        s = 0.9 * min(W, H) / max(np.percentile(np.abs(np.r_[a, b]), 99) * 2, 1e-6)
        return _splat_ortho(a * s + W / 2, b * s + H / 2, -h, C, W, H)
    eye = origin - fwd * 0.6 * ext + up * 0.35 * ext
    T = _look_at(eye, target, up)
    Pc = (P - T[:3, 3]) @ T[:3, :3]
    f = 0.9 * W
    return _splat(Pc, C, f, f, W / 2 - 0.5, H / 2 - 0.5, W, H, radius=1 if len(P) > 200_000 else 2)


def _splat_ortho(u, v, depth, colors, W, H, radius=2, background=255):
    """Splat points at pixel coordinates (u, v) into an (H, W, 3) uint8 image, nearest (smallest
    ``depth``) drawn last so it wins."""
    img = np.full((H, W, 3), background, np.uint8)
    ui, vi = np.round(u).astype(np.int64), np.round(v).astype(np.int64)
    order = np.argsort(-depth, kind="stable")
    ui, vi, col = ui[order], vi[order], colors[order]
    for du in range(radius):
        for dv in range(radius):
            uu, vv = ui + du, vi + dv
            m = (uu >= 0) & (uu < W) & (vv >= 0) & (vv < H)
            img[vv[m], uu[m]] = col[m]
    return img


def render_preview(points, colors, path_png, poses=None, size: Tuple[int, int] = (640, 480),
                   title: str = "") -> Path:
    """Write a PNG preview of a coloured cloud: a perspective view and a top view side by side
    (see :func:`preview_image`), rendered with NumPy and laid out with matplotlib (Agg)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    persp = preview_image(points, colors, poses, size, "perspective")
    top = preview_image(points, colors, poses, (size[1], size[1]), "top")
    W, H = size
    fig, axs = plt.subplots(1, 2, figsize=((W + H) / 100 + 0.6, H / 100 + 0.7), dpi=100,
                            gridspec_kw={"width_ratios": [W, H]})
    for ax, img, t in ((axs[0], persp, "perspective (behind/above first camera)"), (axs[1], top, "top view")):
        ax.imshow(img)
        ax.set_title(t, fontsize=8)
        ax.set_axis_off()
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path = Path(path_png)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


# ----------------------------------------------------------------------------- jaxvo map

class KeptPoses(NamedTuple):
    """The poses of a trajectory file that a map or masks may use (:func:`read_kept_poses`):
    stamps (M,) s, poses (M, 4, 4) T_world_cam, held: how many held poses were left out."""
    stamps: np.ndarray
    poses: np.ndarray
    held: int


def read_kept_poses(traj) -> KeptPoses:
    """The poses of a trajectory file less those ``jaxvo run`` marked held (its estimate failed and
    the previous pose was kept: a guess). DatasetError when the file is missing or has no pose.
    A ground-truth file (groundtruth.txt) may repeat a timestamp (TUM's tools keep the first);
    an estimate may not."""
    from jaxvo.data import DatasetError, read_pose_file
    from jaxvo.data.trajectory import read_held

    if not Path(traj).is_file():
        raise DatasetError(f"{traj}: trajectory file not found")
    t, T = read_pose_file(traj, duplicates="first" if Path(traj).name == "groundtruth.txt" else "error")
    if len(t) == 0:
        raise DatasetError(f"{traj}: no poses in the trajectory file")
    held = np.isin(t, read_held(traj))
    return KeptPoses(t[~held], T[~held], int(held.sum()))


@dataclasses.dataclass(frozen=True)
class MapRun:
    """What :func:`map_sequence` wrote: the map (:class:`MapResult`), the sequence, the held
    poses of the trajectory left out, the labels used, the PLY file and the preview (or None)."""
    map: MapResult
    sequence: object
    held: int
    labels: Optional[str]
    ply: Path
    preview: Optional[Path]


def map_sequence(sequence_dir, traj, out_ply, *, every: int = 5, voxel: float = 0.01, method: str = "ransac",
                 max_frames: Optional[int] = None, max_depth: float = 4.0, preview=None,
                 labels: Optional[str] = "hindsight", seed: int = 0, camera_preset: Optional[str] = None,
                 depth_scale: Union[float, str, None] = None, max_dt: float = 0.02, force: bool = False,
                 on_start: Optional[Callable] = None,
                 progress: Optional[Callable[[int, int], None]] = None) -> MapRun:
    """``jaxvo map``: the map of a sequence folder from a trajectory file, as a PLY file.

    The trajectory's held poses are left out (:func:`read_kept_poses`); the rest go to
    :func:`build_map` (``labels``, ``every``, ``voxel`` metres, ``max_depth`` metres, estimator
    ``method``, ``seed``, ``max_dt`` s) with the sequence opened as ``jaxvo run`` would
    (:func:`jaxvo.pipelines.sequences.load_sequence`). ``out_ply`` gets the cloud in its display
    colours and each point's label as the vertex property ``moving`` (with ``labels``; the default,
    "hindsight", marks what moves, people included, with :func:`jaxvo.tracking.hindsight.sequence_masks`),
    ``preview`` a PNG rendering (:func:`render_preview`); both are written under
    ``.partial`` names and renamed when complete, and refused where they would replace or land
    inside an input (unless ``force``). ``on_start(seq, held)`` is called once the sequence is
    open, before the work; ``progress(done, total)`` after each frame used.
    """
    from jaxvo.config import Config
    from jaxvo.data.outputs import check_output, writing
    from jaxvo.data.ply import write_ply
    from jaxvo.data import DatasetError
    from jaxvo.pipelines.sequences import check_camera_size, load_sequence

    kept = read_kept_poses(traj)
    check_output(out_ply, [sequence_dir, traj], force)
    if preview is not None:
        check_output(preview, [sequence_dir, traj, out_ply], force, "--preview")
    seq = load_sequence(sequence_dir, camera_preset, depth_scale=depth_scale, max_dt=max_dt, max_frames=max_frames)
    check_camera_size(seq)
    if on_start is not None:
        on_start(seq, kept.held)
    res = build_map(seq, kept.stamps, kept.poses, every=every, voxel=voxel, max_depth=max_depth, labels=labels,
                    config=Config(method=method), seed=seed, max_dt=max_dt, progress=progress)
    cloud = res.cloud
    if len(cloud) == 0:
        raise DatasetError(f"{sequence_dir}: no pixel with valid depth <= {max_depth} m in the frames used")
    writing(out_ply, lambda p: write_ply(p, cloud.points, cloud.display_colors(),
                                         cloud.moving if labels else None))
    if preview is not None:
        writing(preview, lambda p: render_preview(
            cloud.points, cloud.display_colors(), p, poses=res.poses,
            title=f"{seq.name}: {len(cloud)} points" + (", moving points green" if labels else "")))
    return MapRun(res, seq, kept.held, labels, Path(out_ply), None if preview is None else Path(preview))
