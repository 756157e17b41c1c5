"""RGB-D sequence readers (TUM, Bonn, ETH3D, ICL-NUIM, Redwood), timestamp association, ground truth.

:func:`open_sequence` picks the reader from what the folder holds:

* TUM RGB-D layout (TUM, Bonn RGB-D Dynamic, ETH3D SLAM, jaxvo synthetic): :class:`TumSequence`::

    SEQ/rgb.txt          "timestamp filename" lines (# = comment), 8-bit colour PNGs
    SEQ/depth.txt        "timestamp filename" lines, 16-bit PNGs, metres = value / depth_scale (5000)
    SEQ/groundtruth.txt  optional, "timestamp tx ty tz qx qy qz qw" (T_world_cam for TUM)
    SEQ/calibration.txt  optional (ETH3D), "fx fy cx cy" in pixels

* ICL-NUIM (TUM-compatible release): ``associations.txt`` ("t depth/N.png t rgb/N.png" per line,
  either order), depth value / 5000, ground truth ``groundtruth.txt`` or ``*.gt.freiburg``:
  :class:`IclNuimSequence`;
* Redwood / Open3D: ``color/`` (or ``image/``) and ``depth/`` folders of numbered
  images taken in name order at 30 Hz, depth in millimetres (value / 1000), optional
  ``camera_intrinsic.json`` (Open3D's PinholeCameraIntrinsic): :class:`RedwoodSequence`.

Intrinsics, unless given: the layout's calibration file (``calibration.txt``,
``camera_intrinsic.json``, jaxvo's ``info.json``), else the preset for the folder name
(:func:`jaxvo.camera.camera_for_sequence`), scaled to the images' size when they are not
640x480 (see :func:`sequence_camera`). The first frame read is checked for a plausible depth
scale (:func:`check_depth_scale`).

The Bonn RGB-D Dynamic dataset uses the same layout, but its ground truth is the
pose of the motion-capture marker, not of the camera; :func:`bonn_marker_to_camera`
applies the published fixed transforms (``data/bonn/README.md``) so that
:attr:`TumSequence.groundtruth` is always ``T_world_cam`` (camera-to-world,
camera frame x right, y down, z forward).

Conventions: timestamps are float64 seconds; poses are (N, 4, 4) float64
``T_world_cam`` arrays (maps camera coordinates into world coordinates).
Every problem with the input raises :class:`DatasetError` (a ``ValueError``)
whose one-line message names the file and the problem.
"""
from __future__ import annotations

import collections
import concurrent.futures
import os
from pathlib import Path
from typing import Iterator, List, Optional, Tuple

import numpy as np

from jaxvo import geometry
from jaxvo.camera import Camera, camera_for_sequence, camera_for_size
from jaxvo.frame import Frame, make_frame

__all__ = [
    "DatasetError", "TumSequence", "IclNuimSequence", "RedwoodSequence", "open_sequence", "sequence_camera",
    "check_depth_scale", "read_calibration", "associate", "read_file_list", "read_groundtruth",
    "read_pose_file", "bonn_marker_to_camera", "is_bonn_sequence", "interpolate_poses",
    "find_sequences", "find_sequence", "data_root", "T_ROS", "T_M_BONN",
]


class DatasetError(ValueError):
    """Bad or unusable input data; the message is one line naming the file and the problem."""


# ----------------------------------------------------------------------------- paths

def data_root() -> Path:
    """Root of the bundled data: ``$JAXVO_DATA`` if set, else ``<repo>/../shared/data``.

    The TUM excerpts live in ``data_root() / "tum"``, the Bonn ones in ``data_root() / "bonn"``.
    The folder is not required to exist (callers check and report).
    """
    env = os.environ.get("JAXVO_DATA")
    if env:
        return Path(env).expanduser()
    return Path(__file__).resolve().parents[3] / "shared" / "data"


def _is_sequence_dir(p: Path) -> bool:
    return (p / "rgb.txt").is_file() and (p / "depth.txt").is_file()


def find_sequences(root=None, max_depth: int = 4) -> List[Path]:
    """Sorted list of sequence folders (folders holding ``rgb.txt`` and ``depth.txt``) under ``root``.

    ``root`` defaults to :func:`data_root`; it may itself be a sequence folder. The search
    does not descend into sequence folders and stops ``max_depth`` levels below ``root``.
    Returns an empty list when ``root`` does not exist.
    """
    root = Path(root) if root is not None else data_root()
    if not root.is_dir():
        return []
    found = []
    base_depth = len(root.resolve().parts)
    for dirpath, dirnames, _ in os.walk(root):
        p = Path(dirpath)
        if _is_sequence_dir(p):
            found.append(p)
            dirnames[:] = []
            continue
        if len(p.resolve().parts) - base_depth >= max_depth:
            dirnames[:] = []
        dirnames.sort()
    return sorted(found)


def find_sequence(name: str, root=None) -> Path:
    """Path of the sequence folder called ``name`` under ``root`` (default :func:`data_root`).

    Raises DatasetError naming the root when it or the sequence is missing.
    """
    root = Path(root) if root is not None else data_root()
    if not root.is_dir():
        raise DatasetError(f"{root}: data folder does not exist (set JAXVO_DATA to the data root)")
    for p in find_sequences(root):
        if p.name == name:
            return p
    raise DatasetError(f"{root}: no sequence folder named {name!r} (with rgb.txt and depth.txt) found")


# ----------------------------------------------------------------------------- text files

def _data_lines(path: Path):
    """Yield (line number, stripped line) for non-empty, non-comment lines of a text file."""
    try:
        with open(path, "r", encoding="utf-8", errors="replace") as fh:
            for n, line in enumerate(fh, 1):
                s = line.strip()
                if s and not s.startswith("#"):
                    yield n, s
    except FileNotFoundError:
        raise DatasetError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise DatasetError(f"{path}: is a folder, expected a text file") from None
    except OSError as e:
        raise DatasetError(f"{path}: cannot read file ({e.strerror or e})") from None


def _short(s: str, n: int = 60) -> str:
    return s if len(s) <= n else s[: n - 3] + "..."


def read_file_list(path) -> Tuple[np.ndarray, List[str]]:
    """Read a TUM ``rgb.txt`` / ``depth.txt``: ``timestamp filename`` per line, ``#`` comments.

    Returns (timestamps (N,) float64 sorted ascending, filenames (N,) relative to the folder).
    Extra columns after the filename are ignored (as TUM's associate.py does).

    Raises DatasetError: missing file, malformed line (with its line number), no entry,
    duplicate timestamp.
    """
    path = Path(path)
    stamps, names = [], []
    for n, s in _data_lines(path):
        parts = s.replace(",", " ").split()
        try:
            if len(parts) < 2:
                raise ValueError
            t = float(parts[0])
            if not np.isfinite(t):
                raise ValueError
        except ValueError:
            raise DatasetError(f"{path}:{n}: malformed line {_short(s)!r} (expected 'timestamp filename')") from None
        stamps.append(t)
        # the rest of the line is the name when such a file exists (a name with spaces);
        # otherwise extra columns after the first are ignored
        rest = s.split(None, 1)[1].strip()
        names.append(rest if rest != parts[1] and (path.parent / rest).is_file() else parts[1])
    if not stamps:
        raise DatasetError(f"{path}: no entries (only comments or empty)")
    t = np.asarray(stamps, dtype=np.float64)
    order = np.argsort(t, kind="stable")
    t = t[order]
    names = [names[i] for i in order]
    if np.any(np.diff(t) == 0):
        i = int(np.nonzero(np.diff(t) == 0)[0][0])
        raise DatasetError(f"{path}: duplicate timestamp {t[i]:.6f}")
    return t, names


def read_pose_file(path, what: str = "trajectory", duplicates: str = "first") -> Tuple[np.ndarray, np.ndarray]:
    """Read a TUM pose file (``timestamp tx ty tz qx qy qz qw`` per line, ``#`` comments).

    Returns (timestamps (N,) float64 ascending, poses (N, 4, 4) float64) exactly as stored
    (no Bonn conversion). Unsorted lines are sorted by time. Of lines with the same
    timestamp, ``duplicates="first"`` keeps the first (the original freiburg2_desk ground
    truth has one such duplicate); ``"error"`` raises naming both lines (an estimate must not
    give one frame two poses). Quaternions are normalised.

    Raises DatasetError: missing file, malformed line (number of fields, non-numeric,
    non-finite, zero quaternion; with its line number), empty file.
    """
    path = Path(path)
    rows = []
    line_of = {}
    for n, s in _data_lines(path):
        parts = s.replace(",", " ").split()
        if len(parts) != 8:
            raise DatasetError(f"{path}:{n}: malformed line {_short(s)!r} "
                               f"(expected 8 fields 'timestamp tx ty tz qx qy qz qw', got {len(parts)})")
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            raise DatasetError(f"{path}:{n}: malformed line {_short(s)!r} (non-numeric field)") from None
        if not np.all(np.isfinite(vals)):
            raise DatasetError(f"{path}:{n}: non-finite value in line {_short(s)!r}")
        qn = float(np.linalg.norm(vals[4:8]))
        if qn < 1e-6:
            raise DatasetError(f"{path}:{n}: quaternion has zero norm in line {_short(s)!r}")
        if duplicates == "error" and vals[0] in line_of:
            raise DatasetError(f"{path}:{n}: timestamp {parts[0]} repeats line {line_of[vals[0]]} "
                               f"(one pose per timestamp)")
        line_of.setdefault(vals[0], n)
        rows.append(vals)
    if not rows:
        raise DatasetError(f"{path}: no poses in {what} file (only comments or empty)")
    a = np.asarray(rows, dtype=np.float64)
    order = np.argsort(a[:, 0], kind="stable")
    a = a[order]
    keep = np.concatenate([[True], np.diff(a[:, 0]) > 0])
    a = a[keep]
    T = geometry.transform_from_quat_trans(a[:, 4:8], a[:, 1:4])
    return a[:, 0].copy(), np.ascontiguousarray(T, dtype=np.float64)


# ----------------------------------------------------------------------------- association

def associate(stamps_a, stamps_b, max_dt: float = 0.02) -> Tuple[np.ndarray, np.ndarray]:
    """One-to-one association of two timestamp lists, as TUM's ``associate.py``.

    All candidate pairs with ``|a - b| <= max_dt`` are taken greedily in order of increasing
    ``|a - b|``, each stamp used at most once. Returns index arrays ``(ia, ib)`` (int64,
    same length M, possibly 0), sorted by ``stamps_a[ia]``. Inputs need not be sorted.
    """
    a = np.asarray(stamps_a, dtype=np.float64).reshape(-1)
    b = np.asarray(stamps_b, dtype=np.float64).reshape(-1)
    if a.size == 0 or b.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    ob = np.argsort(b, kind="stable")
    bs = b[ob]
    lo = np.searchsorted(bs, a - max_dt, side="left")
    hi = np.searchsorted(bs, a + max_dt, side="right")
    counts = hi - lo
    ia = np.repeat(np.arange(a.size), counts)
    if ia.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    offs = np.arange(ia.size) - np.repeat(np.cumsum(counts) - counts, counts)
    jb = ob[np.repeat(lo, counts) + offs]
    diff = np.abs(a[ia] - b[jb])
    ok = diff <= max_dt
    ia, jb, diff = ia[ok], jb[ok], diff[ok]
    order = np.lexsort((jb, ia, diff))
    used_a = np.zeros(a.size, bool)
    used_b = np.zeros(b.size, bool)
    out_a, out_b = [], []
    for k in order:
        i, j = ia[k], jb[k]
        if not used_a[i] and not used_b[j]:
            used_a[i] = used_b[j] = True
            out_a.append(i)
            out_b.append(j)
    out_a = np.asarray(out_a, dtype=np.int64)
    out_b = np.asarray(out_b, dtype=np.int64)
    s = np.argsort(a[out_a], kind="stable")
    return out_a[s], out_b[s]


# ----------------------------------------------------------------------------- poses

#: Fixed change of axes used by the Bonn dataset (a permutation with det +1).
T_ROS = np.array([[-1.0, 0.0, 0.0, 0.0],
                  [0.0, 0.0, 1.0, 0.0],
                  [0.0, 1.0, 0.0, 0.0],
                  [0.0, 0.0, 0.0, 1.0]])

#: Bonn marker-to-camera calibration as published (its 3x3 block is 1.059 x a rotation).
T_M_BONN = np.array([[1.0157, 0.1828, -0.2389, 0.0113],
                     [0.0009, -0.8431, -0.6413, -0.0098],
                     [-0.3009, 0.6147, -0.8085, 0.0111],
                     [0.0, 0.0, 0.0, 1.0]])


def bonn_marker_to_camera(T_gt) -> np.ndarray:
    """Bonn ground-truth marker poses (..., 4, 4) -> camera poses T_world_cam (..., 4, 4) float64.

    ``T_cam = T_ros @ T_gt @ T_ros @ T_m`` (``data/bonn/README.md``), then the rotation
    block is projected onto SO(3) (the published ``T_m`` has a 1.059-scaled rotation; the
    translation is unaffected by that scale). The resulting world frame is y-up.
    """
    T = T_ROS @ np.asarray(T_gt, dtype=np.float64) @ T_ROS @ T_M_BONN
    T = np.array(T, dtype=np.float64, copy=True)
    T[..., :3, :3] = geometry.project_to_so3(T[..., :3, :3])
    T[..., 3, :] = (0.0, 0.0, 0.0, 1.0)
    return T


def is_bonn_sequence(path) -> bool:
    """True for a folder named ``rgbd_bonn_*`` (Bonn RGB-D Dynamic dataset)."""
    return Path(path).name.lower().startswith("rgbd_bonn_")


def read_groundtruth(path, bonn: bool = False) -> Tuple[np.ndarray, np.ndarray]:
    """Read ``groundtruth.txt`` -> (timestamps (N,) float64, T_world_cam (N, 4, 4) float64).

    With ``bonn=True`` the marker poses are converted to camera poses
    (:func:`bonn_marker_to_camera`).
    """
    t, T = read_pose_file(path, what="ground-truth")
    if bonn:
        T = bonn_marker_to_camera(T)
    return t, T


def interpolate_poses(stamps, T_world_cam, query_stamps, tol: float = 1e-6,
                      max_gap: Optional[float] = None) -> np.ndarray:
    """Poses at ``query_stamps`` by interpolation: linear in translation, slerp in rotation.

    Args:
      stamps: (N,) float64 seconds, strictly increasing, N >= 1.
      T_world_cam: (N, 4, 4) poses at ``stamps``.
      query_stamps: (M,) seconds.
      tol: queries up to ``tol`` seconds outside ``[stamps[0], stamps[-1]]`` get the end pose.
      max_gap: if given, a query whose two bracketing poses are more than ``max_gap`` s
        apart raises (e.g. a motion-capture dropout).

    Returns (M, 4, 4) float64 T_world_cam. Raises DatasetError (a ValueError) when a
    query lies outside the covered span.
    """
    t = np.asarray(stamps, dtype=np.float64).reshape(-1)
    T = np.asarray(T_world_cam, dtype=np.float64)
    q = np.asarray(query_stamps, dtype=np.float64).reshape(-1)
    if T.shape != (t.size, 4, 4) or t.size == 0:
        raise ValueError(f"interpolate_poses: need (N,) stamps and (N, 4, 4) poses with N >= 1, "
                         f"got {t.shape} and {T.shape}")
    if t.size > 1 and not np.all(np.diff(t) > 0):
        raise ValueError("interpolate_poses: stamps must be strictly increasing")
    out_lo, out_hi = q < t[0] - tol, q > t[-1] + tol
    if np.any(out_lo | out_hi):
        bad = q[out_lo | out_hi]
        raise DatasetError(f"interpolate_poses: {bad.size} query time(s) outside the covered span "
                           f"{t[0]:.6f} .. {t[-1]:.6f} (first: {bad[0]:.6f})")
    qc = np.clip(q, t[0], t[-1])
    if t.size == 1:
        return np.repeat(T, q.size, axis=0)
    i1 = np.clip(np.searchsorted(t, qc, side="right"), 1, t.size - 1)
    i0 = i1 - 1
    if max_gap is not None:
        gap = t[i1] - t[i0]
        exact = (qc == t[i0]) | (qc == t[i1])
        if np.any((gap > max_gap) & ~exact):
            k = int(np.nonzero((gap > max_gap) & ~exact)[0][0])
            raise DatasetError(f"interpolate_poses: query {q[k]:.6f} falls in a {gap[k]:.3f} s gap "
                               f"(more than max_gap {max_gap} s)")
    a = (qc - t[i0]) / (t[i1] - t[i0])
    R0, R1 = T[i0, :3, :3], T[i1, :3, :3]
    w = geometry.log_so3(np.swapaxes(R0, -1, -2) @ R1)
    R = R0 @ geometry.exp_so3(a[:, None] * w)
    out = np.zeros((q.size, 4, 4))
    out[:, :3, :3] = R
    out[:, :3, 3] = (1 - a)[:, None] * T[i0, :3, 3] + a[:, None] * T[i1, :3, 3]
    out[:, 3, 3] = 1.0
    return out


# ----------------------------------------------------------------------------- the sequence

class TumSequence:
    """A TUM-layout RGB-D sequence (TUM RGB-D, Bonn RGB-D Dynamic, jaxvo synthetic).

    Opening reads only the text files (and checks that the listed PNGs exist); images are
    decoded lazily, one frame at a time, by :meth:`frame`, iteration or :meth:`prefetch`.

    Args:
      path: the sequence folder.
      camera: intrinsics; default :func:`sequence_camera` (calibration file, jaxvo's
        info.json, else the preset for the folder name, sized to the images);
        ``camera_source`` says which.
      max_dt: maximum |t_rgb - t_depth| (s) for associating colour and depth (one-to-one,
        nearest first, as TUM's associate.py). Also the tolerance of the ground-truth
        coverage check.
      depth_scale: depth PNG value / depth_scale = metres; None = the layout's (5000 for TUM,
        Bonn, ETH3D and ICL-NUIM; 1000, millimetres, for Redwood).
      start: index of the first associated frame to use.
      max_frames: use at most this many frames (None = all).
      bonn: treat ground truth as Bonn marker poses and convert it to camera poses;
        None = decide from the folder name (``rgbd_bonn_*``).
      gt_slack: see :attr:`groundtruth` (seconds, default 0.1).
      mask_dir: optional folder of user masks, one 8-bit PNG per colour frame (nonzero = the
        pixel may be used, e.g. 0 on a detector's people), named like the colour image or
        ``<timestamp>.png``; fills :attr:`jaxvo.frame.Frame.mask` (frames without one: None, all
        pixels usable).

    Attributes:
      camera, timestamps ((N,) float64 rgb timestamps of the used frames, seconds),
      depth_timestamps ((N,)), rgb_paths / depth_paths (lists of Path), name, path, is_bonn.
    """

    #: depth PNG value / DEPTH_SCALE = metres, where the layout does not say otherwise
    DEPTH_SCALE = 5000.0
    LAYOUT = "TUM RGB-D"

    def __init__(self, path, camera: Optional[Camera] = None, max_dt: float = 0.02,
                 depth_scale: Optional[float] = None, start: int = 0, max_frames: Optional[int] = None,
                 bonn: Optional[bool] = None, gt_slack: float = 0.1, mask_dir=None):
        self.path = Path(path)
        if not self.path.exists():
            raise DatasetError(f"{self.path}: sequence folder does not exist")
        if not self.path.is_dir():
            raise DatasetError(f"{self.path}: not a folder (expected a {self.LAYOUT} sequence folder)")
        self.name = self.path.resolve().name
        if not (max_dt > 0):
            raise ValueError(f"max_dt must be > 0 seconds, got {max_dt}")
        if depth_scale is not None and not (depth_scale > 0):
            raise ValueError(f"depth_scale must be > 0, got {depth_scale}")
        if start < 0:
            raise ValueError(f"start must be >= 0, got {start}")
        if max_frames is not None and max_frames < 1:
            raise ValueError(f"max_frames must be >= 1 or None, got {max_frames}")
        if camera is not None and not isinstance(camera, Camera):
            raise ValueError(f"camera must be a jaxvo.Camera, got {camera!r}"
                             + (f" (use jaxvo.camera.PRESETS[{camera!r}])" if isinstance(camera, str) else ""))
        self.max_dt = float(max_dt)
        self.depth_scale = float(self.DEPTH_SCALE if depth_scale is None else depth_scale)
        self._scale_given = depth_scale is not None
        self.is_bonn = is_bonn_sequence(self.path) if bonn is None else bool(bonn)
        self.gt_slack = float(gt_slack)

        t_rgb, t_dep, rgb_paths, depth_paths, listing = self._frame_lists()
        n_assoc = len(t_rgb)
        stop = None if max_frames is None else start + max_frames
        if start >= n_assoc:
            raise DatasetError(f"{self.path}: start={start} is past the end ({n_assoc} associated frames)")
        self.n_associated = int(n_assoc)
        self.start = int(start)
        self.timestamps = np.array(t_rgb[start:stop], np.float64)
        self.depth_timestamps = np.array(t_dep[start:stop], np.float64)
        self.rgb_paths = list(rgb_paths[start:stop])
        self.depth_paths = list(depth_paths[start:stop])
        for p, lst in ((self.rgb_paths, listing[0]), (self.depth_paths, listing[1])):
            for f in p:
                if not f.is_file():
                    raise DatasetError(f"{f}: file not found (listed in {lst})")
        self.mask_dir = None if mask_dir is None else Path(mask_dir)
        self.mask_paths = self._match_masks() if mask_dir is not None else [None] * len(self.rgb_paths)
        if camera is not None:
            self.camera, self.camera_source = camera, "given"
        else:
            self.camera, self.camera_source = sequence_camera(self.path, self._image_size(0), self.name)
        try:
            self.camera.validate()
        except ValueError as e:
            raise DatasetError(f"{self.path}: {e} (camera from {self.camera_source})") from None
        self._gt = None
        self._gt_loaded = False
        self._depth_checked = False

    def _frame_lists(self):
        """All associated frames in time order: (rgb stamps (N,), depth stamps (N,), rgb paths,
        depth paths, (what lists the rgb files, what lists the depth files))."""
        for f in ("rgb.txt", "depth.txt"):
            if not (self.path / f).is_file():
                raise DatasetError(f"{self.path / f}: file not found (a TUM sequence folder needs "
                                   f"rgb.txt and depth.txt)")
        rgb_txt, depth_txt = self.path / "rgb.txt", self.path / "depth.txt"
        t_rgb, f_rgb = read_file_list(rgb_txt)
        t_dep, f_dep = read_file_list(depth_txt)
        ia, ib = associate(t_rgb, t_dep, self.max_dt)
        if ia.size == 0:
            raise DatasetError(
                f"{rgb_txt}: no rgb/depth pair within {self.max_dt} s of each other (rgb "
                f"{t_rgb[0]:.6f} .. {t_rgb[-1]:.6f}, depth.txt {t_dep[0]:.6f} .. {t_dep[-1]:.6f})")
        return (t_rgb[ia], t_dep[ib], [self.path / f_rgb[i] for i in ia], [self.path / f_dep[j] for j in ib],
                ("rgb.txt", "depth.txt"))

    def _match_masks(self) -> List[Optional[Path]]:
        """Per used frame, the PNG in ``mask_dir`` with the colour image's file name (stem), else the one
        named ``<timestamp>.png`` nearest the frame's timestamp (within max_dt); None where there is none
        (every pixel usable). DatasetError when the folder is missing or matches no frame."""
        d = self.mask_dir
        if not d.is_dir():
            raise DatasetError(f"{d}: mask folder does not exist")
        files = {p.stem: p for p in d.iterdir() if p.suffix.lower() == ".png"}
        stamped = {}
        for stem, p in files.items():
            try:
                stamped[float(stem)] = p
            except ValueError:
                pass
        st = np.asarray(sorted(stamped), np.float64)
        ia, ib = associate(self.timestamps, st, self.max_dt) if st.size else (np.zeros(0, int), np.zeros(0, int))
        by_time = {int(i): stamped[float(st[j])] for i, j in zip(ia, ib)}
        out = [files.get(rp.stem, by_time.get(i)) for i, rp in enumerate(self.rgb_paths)]
        if not any(p is not None for p in out):
            raise DatasetError(f"{d}: no mask PNG matches a frame (expected the colour images' file names, e.g. "
                               f"{self.rgb_paths[0].stem}.png, or <timestamp>.png)")
        return out

    def _image_size(self, i: int) -> Tuple[int, int]:
        """(width, height) of frame i's colour image, read from the file."""
        import cv2
        p = self.rgb_paths[i]
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise DatasetError(f"{p}: image does not decode (corrupt or not an image file)")
        return int(img.shape[1]), int(img.shape[0])

    # -- frames -----------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.timestamps)

    def __repr__(self) -> str:
        return (f"{type(self).__name__}({str(self.path)!r}, frames={len(self)}, camera={self.camera!r}, "
                f"bonn={self.is_bonn})")

    def _check_index(self, i: int) -> int:
        n = len(self)
        i = int(i)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"frame index {i} out of range for a sequence of {n} frames")
        return i

    def read_images(self, i: int) -> Tuple[np.ndarray, np.ndarray]:
        """Decode frame ``i``'s PNGs -> (colour (H, W, 3) uint8 BGR, depth (H, W) uint16).

        Raises DatasetError (naming the file): not decodable, depth not 16-bit
        single-channel, colour and depth of different size.
        """
        import cv2
        i = self._check_index(i)
        rp, dp = self.rgb_paths[i], self.depth_paths[i]
        rgb = cv2.imread(str(rp), cv2.IMREAD_COLOR)
        if rgb is None:
            if not rp.is_file():
                raise DatasetError(f"{rp}: file not found (listed in rgb.txt)")
            raise DatasetError(f"{rp}: image does not decode (corrupt or not an image file)")
        depth = cv2.imread(str(dp), cv2.IMREAD_UNCHANGED)
        if depth is None:
            if not dp.is_file():
                raise DatasetError(f"{dp}: file not found (listed in depth.txt)")
            raise DatasetError(f"{dp}: depth image does not decode (corrupt or not an image file)")
        if depth.dtype != np.uint16 or depth.ndim != 2:
            ch = 1 if depth.ndim == 2 else depth.shape[2]
            bits = depth.dtype.itemsize * 8
            raise DatasetError(f"{dp}: depth image is {bits}-bit with {ch} channel(s), expected a "
                               f"16-bit single-channel PNG (value / {self.depth_scale:g} = metres)")
        if depth.shape != rgb.shape[:2]:
            raise DatasetError(f"{dp}: depth size {depth.shape[1]}x{depth.shape[0]} does not match "
                               f"colour image {rp.name} size {rgb.shape[1]}x{rgb.shape[0]}")
        return rgb, depth

    def frame(self, i: int) -> Frame:
        """Read and return frame ``i`` (negative indices allowed) as a :class:`jaxvo.frame.Frame`:
        intensity (H, W) float32 0-255, depth (H, W) float32 metres (0 = invalid), mask (H, W) bool
        from ``mask_dir`` or None.

        Raises DatasetError naming the file for undecodable images, non-16-bit depth, size
        mismatches (also with the camera's width/height) and depth without any valid pixel.
        """
        rgb, depth = self.read_images(i)
        i = self._check_index(i)
        h, w = depth.shape
        if (self.camera.width, self.camera.height) != (w, h):
            raise DatasetError(f"{self.rgb_paths[i]}: image size {w}x{h} does not match the camera "
                               f"intrinsics' {self.camera.width}x{self.camera.height} (camera from {self.camera_source}; "
                               f"pass intrinsics for this size: --camera / --fx --fy --cx --cy)")
        mask = None
        mp = self.mask_paths[i]
        if mp is not None:
            import cv2
            mask = cv2.imread(str(mp), cv2.IMREAD_GRAYSCALE)
            if mask is None:
                raise DatasetError(f"{mp}: mask image does not decode (corrupt or not an image file)")
            if mask.shape != depth.shape:
                raise DatasetError(f"{mp}: mask size {mask.shape[1]}x{mask.shape[0]} does not match the image "
                                   f"size {w}x{h}")
        try:
            fr = make_frame(rgb, depth, self.depth_scale, color_order="bgr", source=str(self.depth_paths[i]),
                            mask=mask)
        except ValueError as e:
            raise DatasetError(str(e)) from None
        if not self._depth_checked:
            check_depth_scale(fr.depth, self.depth_scale, self.depth_paths[i], explicit=self._scale_given)
            self._depth_checked = True
        return fr

    def __getitem__(self, i: int) -> Frame:
        return self.frame(i)

    def __iter__(self) -> Iterator[Tuple[float, Frame]]:
        """Yield ``(timestamp, Frame)`` lazily, one frame decoded per step."""
        for i in range(len(self)):
            yield float(self.timestamps[i]), self.frame(i)

    def prefetch(self, n: int = 1, start: int = 0) -> Iterator[Tuple[float, Frame]]:
        """Like iteration, but a background thread decodes the next ``n`` frames while the
        caller works on the current one (at most ``n + 1`` frames are held).

        Errors raised while reading a frame are re-raised when that frame is reached.
        Closing the generator early (``break``) stops the background thread.
        """
        if n < 1:
            raise ValueError(f"prefetch depth must be >= 1, got {n}")
        N = len(self)
        ex = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="jaxvo-prefetch")
        pending: collections.deque = collections.deque()
        nxt = start
        try:
            while True:
                # keep the frame about to be returned plus the next n in flight
                while nxt < N and len(pending) < n + 1:
                    pending.append((nxt, ex.submit(self.frame, nxt)))
                    nxt += 1
                if not pending:
                    break
                i, fut = pending.popleft()
                fr = fut.result()
                yield float(self.timestamps[i]), fr
        finally:
            for _, fut in pending:
                fut.cancel()
            ex.shutdown(wait=True, cancel_futures=True)

    def check(self, n: int = 1) -> None:
        """Read the first ``n`` frames now, so a bad file is reported before a long run starts."""
        for i in range(min(n, len(self))):
            self.frame(i)

    # -- ground truth ------------------------------------------------------------
    @property
    def groundtruth_path(self) -> Path:
        return self.path / "groundtruth.txt"

    @property
    def groundtruth(self) -> Optional[Tuple[np.ndarray, np.ndarray]]:
        """``(timestamps (M,) float64, T_world_cam (M, 4, 4) float64)`` or None without groundtruth.txt.

        The whole file is returned (not trimmed to the frames). For Bonn sequences the
        marker poses are converted to camera poses (:func:`bonn_marker_to_camera`).

        Coverage rule: the ground truth must span the used frames. Frames may stick out
        of ``[gt_first, gt_last]`` by at most ``max(max_dt, gt_slack)`` seconds at either
        end (0.1 s by default: TUM recordings often start a few frames before the
        motion-capture data, e.g. freiburg3_long_office_household by 0.07 s; such frames
        simply have no ground truth and are skipped by the metrics). Otherwise
        DatasetError naming groundtruth.txt. Gaps inside the ground truth are not checked.
        """
        if not self._gt_loaded:
            p = self.groundtruth_path
            if not p.exists():
                self._gt, self._gt_loaded = None, True
                return None
            t, T = read_groundtruth(p, bonn=self.is_bonn)
            slack = max(self.max_dt, self.gt_slack)
            f0, f1 = float(self.timestamps[0]), float(self.timestamps[-1])
            before = int(np.sum(self.timestamps < t[0] - slack))
            after = int(np.sum(self.timestamps > t[-1] + slack))
            if before or after:
                raise DatasetError(
                    f"{p}: ground truth ({t[0]:.6f} .. {t[-1]:.6f}) does not cover the sequence "
                    f"({f0:.6f} .. {f1:.6f}): {before + after} of {len(self)} frames are more than "
                    f"{slack:g} s outside it")
            self._gt, self._gt_loaded = (t, T), True
        return self._gt

    def groundtruth_at_frames(self, max_dt: Optional[float] = None):
        """Ground truth at the frame timestamps by interpolation.

        Returns ``(mask (N,) bool, T_world_cam (N, 4, 4))``: ``mask[i]`` says frame i lies
        inside the ground-truth span (within ``max_dt``, default ``self.max_dt``); rows of
        uncovered frames are NaN. Returns None without ground truth.
        """
        gt = self.groundtruth
        if gt is None:
            return None
        t, T = gt
        tol = self.max_dt if max_dt is None else float(max_dt)
        mask = (self.timestamps >= t[0] - tol) & (self.timestamps <= t[-1] + tol)
        out = np.full((len(self), 4, 4), np.nan)
        if mask.any():
            out[mask] = interpolate_poses(t, T, self.timestamps[mask], tol=tol)
        return mask, out


# ----------------------------------------------------------------------------- other layouts

class IclNuimSequence(TumSequence):
    """An ICL-NUIM sequence in its TUM-compatible release: ``associations.txt`` lines
    ``t depth/N.png t rgb/N.png`` (or rgb first; the column whose path names ``depth`` is the depth),
    16-bit depth / 5000, ground truth ``groundtruth.txt`` or ``*.gt.freiburg`` (TUM pose format).
    Arguments as :class:`TumSequence`."""
    LAYOUT = "ICL-NUIM"

    def _frame_lists(self):
        lst = self.path / "associations.txt"
        t_rgb, t_dep, f_rgb, f_dep = [], [], [], []
        for n, line in _data_lines(lst):
            parts = line.split()
            try:
                if len(parts) < 4:
                    raise ValueError
                ta, tb = float(parts[0]), float(parts[2])
            except ValueError:
                raise DatasetError(f"{lst}:{n}: malformed line {_short(line)!r} "
                                   f"(expected 'timestamp file timestamp file')") from None
            (td, fd), (tr, fr) = ((ta, parts[1]), (tb, parts[3]))
            if "depth" not in fd.lower():
                (td, fd), (tr, fr) = (tr, fr), (td, fd)
            t_rgb.append(tr), t_dep.append(td), f_rgb.append(fr), f_dep.append(fd)
        if not t_rgb:
            raise DatasetError(f"{lst}: no entries (only comments or empty)")
        order = np.argsort(np.asarray(t_rgb), kind="stable")
        return (np.asarray(t_rgb)[order], np.asarray(t_dep)[order], [self.path / f_rgb[i] for i in order],
                [self.path / f_dep[i] for i in order], ("associations.txt", "associations.txt"))

    @property
    def groundtruth_path(self) -> Path:
        p = self.path / "groundtruth.txt"
        if not p.exists():
            found = sorted(self.path.glob("*.gt.freiburg"))
            if found:
                return found[0]
        return p


class RedwoodSequence(TumSequence):
    """A Redwood / Open3D RGB-D folder: ``color/`` (or ``image/``) and ``depth/`` hold
    numbered images paired in name order; there are no timestamps, so frame k is at k / fps
    seconds (30 Hz). Depth defaults to millimetres (depth_scale 1000). An optional
    ``groundtruth.txt`` in TUM format (with those timestamps) is read like TUM's.
    Arguments as :class:`TumSequence`, plus ``fps``."""
    LAYOUT = "Redwood"
    DEPTH_SCALE = 1000.0
    COLOR_DIRS = ("color", "image")

    def __init__(self, path, *args, fps: float = 30.0, **kwargs):
        self.fps = float(fps)
        super().__init__(path, *args, **kwargs)

    def _frame_lists(self):
        exts = {".png", ".jpg", ".jpeg"}
        col = next((self.path / c for c in self.COLOR_DIRS if (self.path / c).is_dir()), None)
        if col is None or not (self.path / "depth").is_dir():
            raise DatasetError(f"{self.path}: a Redwood folder needs color/ (or image/) and depth/ folders")
        rgb = sorted(p for p in col.iterdir() if p.suffix.lower() in exts)
        dep = sorted(p for p in (self.path / "depth").iterdir() if p.suffix.lower() == ".png")
        if not rgb or len(rgb) != len(dep):
            raise DatasetError(f"{self.path}: {len(rgb)} colour images in {col.name}/ but {len(dep)} depth PNGs "
                               f"in depth/ (they are paired in name order)")
        t = np.arange(len(rgb), dtype=np.float64) / self.fps
        return t, t.copy(), rgb, dep, (f"{col.name}/", "depth/")


def open_sequence(path, camera: Optional[Camera] = None, depth_scale: Optional[float] = None, **kwargs) -> TumSequence:
    """Open an RGB-D sequence folder with the reader its content calls for: ``rgb.txt`` + ``depth.txt``
    (TUM, Bonn, ETH3D, jaxvo synthetic) -> :class:`TumSequence`; ``associations.txt`` (ICL-NUIM) ->
    :class:`IclNuimSequence`; ``color/`` (or ``image/``) + ``depth/`` folders (Redwood) ->
    :class:`RedwoodSequence`. ``camera``, ``depth_scale`` (None = the layout's) and ``kwargs``
    (max_dt, start, max_frames, bonn, ...) go to the reader. Raises DatasetError for anything else.
    """
    p = Path(path)
    if not p.exists():
        raise DatasetError(f"{p}: sequence folder does not exist")
    if not p.is_dir():
        raise DatasetError(f"{p}: not a folder (expected an RGB-D sequence folder)")
    if _is_sequence_dir(p) or (p / "rgb.txt").is_file() or (p / "depth.txt").is_file():
        cls = TumSequence   # with one of the two lists only, TumSequence names the missing one
    elif (p / "associations.txt").is_file():
        cls = IclNuimSequence
    elif (p / "depth").is_dir() and any((p / c).is_dir() for c in RedwoodSequence.COLOR_DIRS):
        cls = RedwoodSequence
    else:
        raise DatasetError(f"{p}: not an RGB-D sequence folder: expected rgb.txt and depth.txt (TUM, Bonn, "
                           f"ETH3D), associations.txt (ICL-NUIM), or color/ and depth/ folders (Redwood)")
    return cls(p, camera=camera, depth_scale=depth_scale, **kwargs)


# ----------------------------------------------------------------------------- intrinsics and depth scale

def read_calibration(seq_dir) -> Optional[Tuple[Camera, str]]:
    """(camera, file name) from a sequence folder's calibration file, or None without one.

    Looked for in this order: ``calibration.txt`` (ETH3D: ``fx fy cx cy``; its size is 0x0 here,
    meaning "take it from the images"), ``camera_intrinsic.json`` / ``intrinsic.json`` (Open3D's
    PinholeCameraIntrinsic: width, height, column-major intrinsic_matrix), ``info.json``'s
    ``camera`` entry (written by ``jaxvo synth`` / ``jaxvo augment``). A malformed file raises
    DatasetError naming it.
    """
    import json

    d = Path(seq_dir)
    cal = d / "calibration.txt"
    if cal.is_file():
        lines = [s for _, s in _data_lines(cal)]
        try:
            fx, fy, cx, cy = (float(v) for v in lines[0].split()[:4])
        except (IndexError, ValueError):
            raise DatasetError(f"{cal}: expected a line 'fx fy cx cy' (pixels)") from None
        return Camera(fx, fy, cx, cy, 0, 0), cal.name
    for name in ("camera_intrinsic.json", "intrinsic.json"):
        f = d / name
        if f.is_file():
            try:
                j = json.loads(f.read_text())
                K = [float(v) for v in j["intrinsic_matrix"]]
                return Camera(K[0], K[4], K[6], K[7], int(j["width"]), int(j["height"])), name
            except (ValueError, KeyError, TypeError, IndexError) as e:
                raise DatasetError(f"{f}: malformed Open3D intrinsics (need width, height, intrinsic_matrix; "
                                   f"{type(e).__name__}: {e})") from None
    info = d / "info.json"
    if info.is_file():
        try:
            c = json.loads(info.read_text()).get("camera")
            if isinstance(c, dict):
                return Camera(float(c["fx"]), float(c["fy"]), float(c["cx"]), float(c["cy"]),
                              int(c.get("width", 640)), int(c.get("height", 480))), info.name
        except (ValueError, KeyError, TypeError, AttributeError) as e:
            raise DatasetError(f"{info}: malformed camera entry ({e})") from None
    return None


def sequence_camera(seq_dir, image_size: Tuple[int, int], name: Optional[str] = None) -> Tuple[Camera, str]:
    """(camera, where it came from) for a folder whose images are ``image_size`` (width, height).

    The calibration file (:func:`read_calibration`) if there is one (a size-less ETH3D
    calibration takes the images' size); else the preset for the folder ``name``
    (:func:`jaxvo.camera.camera_for_sequence`), or, when the images are not that preset's
    size, the preset scaled to them (:func:`jaxvo.camera.camera_for_size`): a guess, said so
    in the returned source.
    """
    w, h = image_size
    found = read_calibration(seq_dir)
    if found is not None:
        cam, src = found
        return (cam.with_size(w, h) if cam.width == 0 else cam), src
    name = Path(seq_dir).resolve().name if name is None else name
    cam = camera_for_sequence(name)
    if (cam.width, cam.height) == (w, h):
        return cam, "folder name"
    return camera_for_size(cam, w, h), f"a guess: the {cam.width}x{cam.height} preset for the folder name scaled to {w}x{h}"


#: where a median valid depth (metres) is taken as plausible for an RGB-D camera
PLAUSIBLE_DEPTH = (0.2, 10.0)
#: with the layout's default depth scale, a median below this (metres) stops the run too: a
#: recording in millimetres read as TUM's 1/5000 m puts typical indoor scenes (median 1.5-3 m:
#: TUM fr2/desk 1.5, fr3/long_office 2.4, Bonn crowd 2.3-2.9) at 0.3-0.6 m
DEFAULT_SCALE_MIN_MEDIAN = 0.7


def check_depth_scale(depth_m, depth_scale: float, source, explicit: bool = True) -> None:
    """Raise DatasetError (one line naming ``source`` and the depth scale to pass) when the depth
    scale looks wrong: the median valid depth of ``depth_m`` (metres, 0 = invalid) outside
    :data:`PLAUSIBLE_DEPTH`, or, when ``depth_scale`` is the layout's default rather than
    chosen (``explicit``), under :data:`DEFAULT_SCALE_MIN_MEDIAN` (millimetres read with TUM's
    5000 come out 5x too small; passing the scale explicitly accepts such close scenes)."""
    d = np.asarray(depth_m)
    v = d[d > 0]
    if v.size == 0:
        return
    med = float(np.median(v))
    lo, hi = PLAUSIBLE_DEPTH
    low = med < (lo if explicit else max(lo, DEFAULT_SCALE_MIN_MEDIAN))
    if not low and med <= hi:
        return
    raw = med * depth_scale
    fits = [c for c in (1000.0, 5000.0, 10000.0, 4000.0, 100.0, 1.0) if c != depth_scale and lo <= raw / c <= hi]
    best = min(fits, key=lambda c: abs(np.log(raw / c / 2.0))) if fits else raw / 2.0
    keep = "" if explicit or not low or med < lo else f"; if the scene really is that close pass --depth-scale {depth_scale:g}"
    raise DatasetError(f"{source}: median valid depth {med:.3g} m with depth scale {depth_scale:g} is implausible "
                       f"(expected {max(lo, DEFAULT_SCALE_MIN_MEDIAN) if low and not explicit else lo:g}-{hi:g} m); "
                       f"pass --depth-scale {best:g} (library: depth_scale={best:g}), which gives {raw / best:.2f} m"
                       f"{keep}")
