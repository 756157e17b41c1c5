"""The TUM RGB-D layout (TUM, Bonn RGB-D Dynamic, ETH3D SLAM, jaxvo synthetic): :class:`TumSequence`::

    SEQ/rgb.txt          "timestamp filename" lines (# = comment), 8-bit colour PNGs
    SEQ/depth.txt        "timestamp filename" lines, 16-bit PNGs, metres = value / depth_scale (5000)
    SEQ/groundtruth.txt  optional, "timestamp tx ty tz qx qy qz qw" (T_world_cam for TUM)
    SEQ/calibration.txt  optional (ETH3D), "fx fy cx cy" in pixels

The other layouts subclass it and replace only how the frame list is read.

Conventions: timestamps are float64 seconds; poses are (N, 4, 4) float64
``T_world_cam`` arrays (maps camera coordinates into world coordinates).
Every problem with the input raises :class:`jaxvo.data.errors.DatasetError` (a ``ValueError``)
whose one-line message names the file and the problem.
"""
from __future__ import annotations

import collections
import concurrent.futures
import copy
import os
from pathlib import Path
from typing import Iterator, Optional, Tuple, Union

import numpy as np

from jaxvo.camera import DEPTH_CORRECTIONS, LENSES, Camera, Lens
from jaxvo.data.calibration import check_depth_scale, published_sensor, resolve_depth_scale, sequence_camera
from jaxvo.data.errors import DatasetError
from jaxvo.data.groundtruth import is_bonn_sequence, read_groundtruth
from jaxvo.data.masks import match_masks, read_frame_mask
from jaxvo.data.stamps import associate, interpolate_poses
from jaxvo.data.textfiles import read_file_list
from jaxvo.frame import Frame, has_depth, make_frame, undistort
from jaxvo.validation import Rule, check_values, integer, number

__all__ = ["TumSequence", "check_reader_options"]

#: what the readers' options may hold (:func:`check_reader_options`)
READER_RULES = {
    "max_dt": number(0, lo_open=True),
    "depth_scale": number(0, lo_open=True, none_means="the layout's, with the folder's sensor's correction"),
    "start": integer(0),
    "max_frames": integer(1, none_means="all frames"),
    "bonn": Rule("bool", none=True, none_means="decided from the folder name"),
    "gt_slack": number(0),
    "fps": number(0, lo_open=True),
}


def check_reader_options(path, **options) -> None:
    """Raise ValueError (one line: ``open_sequence: <option> must be <what is allowed>, got <value>``)
    unless ``path`` is a path (str or os.PathLike) and each of ``options`` (names of
    :data:`READER_RULES`) has an allowed type and value; e.g. ``max_frames="10"``."""
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"open_sequence: path must be a folder name (str or os.PathLike), got {type(path).__name__}")
    check_values(options, READER_RULES, "open_sequence")


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
      depth_scale: depth PNG value / depth_scale = metres. None: the layout's (5000 for TUM,
        Bonn, ETH3D and ICL-NUIM; 1000, millimetres, for Redwood) times the published depth
        correction of the sensor the folder name identifies, where the intrinsics are that
        sensor's preset (:func:`jaxvo.data.calibration.published_sensor`: TUM fr1 x 1.035, fr2
        x 1.031, Bonn / 1.0593; none for fr3 or any other folder); ``"recorded"``: the layout's
        as it is; a sensor name of :data:`jaxvo.camera.DEPTH_CORRECTIONS` (``"fr2"``): the
        layout's times that sensor's correction (:func:`jaxvo.data.calibration.resolve_depth_scale`).
      start: index of the first associated frame to use.
      max_frames: use at most this many frames (None = all).
      bonn: treat ground truth as Bonn marker poses and convert it to camera poses;
        None = decide from the folder name (``rgbd_bonn_*``).
      gt_slack: see :attr:`groundtruth` (seconds, default 0.1).
      mask_dir: optional folder of user masks, one 8-bit PNG per colour frame (nonzero = the
        pixel may be used, e.g. 0 on a detector's people), named like the colour image or
        ``<timestamp>.png``; fills :attr:`jaxvo.frame.Frame.mask` (frames without one: None, all
        pixels usable).
      lens: the :class:`jaxvo.camera.Lens` the images were taken through (or what
        :meth:`jaxvo.camera.Lens.parse` reads: ``"fr2"``, 5 numbers, ``"none"``): each frame is
        undistorted to ``camera`` as it is read (:func:`jaxvo.frame.undistort`; the published
        lenses of TUM fr1, fr2 and Bonn: :data:`jaxvo.camera.LENSES`). None: the published lens
        of the sensor the folder name identifies, as for ``depth_scale`` (TUM fr1, fr2, Bonn),
        else none; ``"none"``: the images as they are (a pinhole camera).
      sensor: the key of :data:`jaxvo.camera.LENSES` (``"fr2"``) whose published lens and depth
        correction apply where ``lens`` / ``depth_scale`` are None; None: the folder name's
        where the intrinsics are its preset (:func:`jaxvo.data.calibration.published_sensor`).

    Attributes:
      camera, lens, sensor (the key of :data:`jaxvo.camera.LENSES` whose calibration applies by
      default: :func:`jaxvo.data.calibration.published_sensor`), timestamps ((N,) float64 rgb
      timestamps of the used frames, seconds),
      depth_timestamps ((N,)), rgb_paths / depth_paths (lists of Path), name, path, is_bonn.
    """

    #: depth PNG value / DEPTH_SCALE = metres, where the layout does not say otherwise
    DEPTH_SCALE = 5000.0
    LAYOUT = "TUM RGB-D"

    def __init__(self, path, camera: Optional[Camera] = None, max_dt: float = 0.02,
                 depth_scale: Union[float, str, None] = None, start: int = 0, max_frames: Optional[int] = None,
                 bonn: Optional[bool] = None, gt_slack: float = 0.1, mask_dir=None, lens=None,
                 sensor: Optional[str] = None):
        depth_scale = resolve_depth_scale(depth_scale, self.DEPTH_SCALE)
        check_reader_options(path, max_dt=max_dt, depth_scale=depth_scale, start=start, max_frames=max_frames,
                             bonn=bonn, gt_slack=gt_slack)
        if mask_dir is not None and not isinstance(mask_dir, (str, os.PathLike)):
            raise ValueError(f"open_sequence: mask_dir must be a folder name (str or os.PathLike) or None, "
                             f"got {type(mask_dir).__name__}")
        self.path = Path(path)
        if not self.path.exists():
            raise DatasetError(f"{self.path}: sequence folder does not exist")
        if not self.path.is_dir():
            raise DatasetError(f"{self.path}: not a folder (expected a {self.LAYOUT} sequence folder)")
        self.name = self.path.resolve().name
        if camera is not None and not isinstance(camera, Camera):
            raise ValueError(f"camera must be a jaxvo.Camera, got {camera!r}"
                             + (f" (use jaxvo.camera.PRESETS[{camera!r}])" if isinstance(camera, str) else ""))
        self.max_dt = float(max_dt)
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
        self.mask_paths = (match_masks(self.mask_dir, self.rgb_paths, self.timestamps, self.max_dt)
                           if mask_dir is not None else [None] * len(self.rgb_paths))
        if camera is not None:
            self.camera, self.camera_source = camera, "given"
        else:
            self.camera, self.camera_source = sequence_camera(self.path, self._image_size(0), self.name)
        try:
            self.camera.validate()
        except ValueError as e:
            raise DatasetError(f"{self.path}: {e} (camera from {self.camera_source})") from None
        # a folder named for a known sensor, read with that sensor's intrinsics, is read with its
        # lens and depth correction too (docs/decisions/sensor-calibration.md)
        if sensor is not None and sensor not in LENSES:
            raise ValueError(f"open_sequence: sensor must be one of {', '.join(sorted(LENSES))} or None, got {sensor!r}")
        self.sensor = published_sensor(self.name, self.camera_source) if sensor is None else sensor
        self.depth_scale = float(self.DEPTH_SCALE * DEPTH_CORRECTIONS[self.sensor] if depth_scale is None
                                 else depth_scale)
        self.lens = LENSES[self.sensor] if lens is None else Lens.parse(lens)
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
        from ``mask_dir`` or None, time and depth_time the rgb.txt and depth.txt timestamps.

        A depth image without any valid pixel (a covered sensor, a scene inside its minimum
        range) gives a frame without depth (:func:`jaxvo.frame.has_depth` False), whose pose the
        odometry holds.

        Raises DatasetError naming the file for undecodable images, non-16-bit depth, size
        mismatches (also with the camera's width/height), and the first frame with depth whose
        depth scale is implausible.
        """
        rgb, depth = self.read_images(i)
        i = self._check_index(i)
        h, w = depth.shape
        if (self.camera.width, self.camera.height) != (w, h):
            raise DatasetError(f"{self.rgb_paths[i]}: image size {w}x{h} does not match the camera "
                               f"intrinsics' {self.camera.width}x{self.camera.height} (camera from {self.camera_source}; "
                               f"pass intrinsics for this size: --camera / --fx --fy --cx --cy)")
        mp = self.mask_paths[i]
        mask = None if mp is None else read_frame_mask(mp, depth.shape)
        try:
            fr = make_frame(rgb, depth, self.depth_scale, color_order="bgr", source=str(self.depth_paths[i]),
                            mask=mask)
        except ValueError as e:
            raise DatasetError(str(e)) from None
        # the capture times of both images, which the odometry may align (TrackConfig.retime_depth)
        fr = undistort(fr, self.camera, self.lens)._replace(time=float(self.timestamps[i]),
                                                           depth_time=float(self.depth_timestamps[i]))
        if not self._depth_checked and has_depth(fr):   # a frame without depth has no scale to check
            check_depth_scale(fr.depth, self.depth_scale, self.depth_paths[i], explicit=self._scale_given)
            self._depth_checked = True
        return fr

    def __getitem__(self, i):
        """``seq[i]``: frame i (:meth:`frame`); ``seq[a:b]``: the frames a to b - 1 as a sequence of
        their own (a view: nothing is read until its frames are; its ``start`` counts from the
        folder's first frame, so ``run_sequence(seq[a:b], ...)`` records the frames it ran)."""
        if isinstance(i, slice):
            return self._view(i)
        if isinstance(i, (bool, np.bool_)) or not isinstance(i, (int, np.integer)):
            raise ValueError(f"sequence index must be an integer or a slice a:b, got {type(i).__name__}")
        return self.frame(i)

    def _view(self, s: slice) -> "TumSequence":
        """The sequence of the frames ``s`` selects, which must be consecutive and at least one."""
        for v in (s.start, s.stop, s.step):
            if v is not None and (isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer))):
                raise ValueError(f"sequence slice bounds must be integers or None, got {type(v).__name__}")
        a, b, step = s.indices(len(self))
        if step != 1:
            raise ValueError(f"a sequence slice takes consecutive frames (step 1), got step {step}; for every "
                             f"k-th frame use [seq.frame(i) for i in range({a}, {b}, {step})]")
        if b <= a:
            raise ValueError(f"sequence slice [{s.start}:{s.stop}] holds no frame (the sequence has {len(self)})")
        view = copy.copy(self)
        view.start = self.start + a
        for name in ("timestamps", "depth_timestamps", "rgb_paths", "depth_paths", "mask_paths"):
            setattr(view, name, getattr(self, name)[a:b])
        return view

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
