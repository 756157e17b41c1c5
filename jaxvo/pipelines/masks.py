"""Moving-pixel masks of a tracked sequence decided in hindsight, written as PNG files: ``jaxvo masks``.

Each frame with a pose is compared with frames before and after it at the trajectory's relative
poses (:func:`jaxvo.tracking.hindsight.sequence_masks`); the masks go into a folder, one 8-bit
PNG per frame (255 = moving), named by the frame's timestamp, the format ``jaxvo eval
--masks-dir`` scores.
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Callable, Optional, Sequence, Union

import numpy as np

from jaxvo.data.outputs import check_output_folder, finish, partial_path
from jaxvo.data import DatasetError
from jaxvo.pipelines.mapping import match_trajectory, read_kept_poses
from jaxvo.pipelines.messages import one_line
from jaxvo.pipelines.run import stamp_name
from jaxvo.pipelines.sequences import check_camera_size, load_sequence

__all__ = ["MasksRun", "write_hindsight_masks"]


@dataclasses.dataclass(frozen=True)
class MasksRun:
    """What :func:`write_hindsight_masks` wrote: the folder, the sequence, the number of frames
    with a pose (``posed``) and of held poses left out, each written mask's moving-pixel fraction
    (``moving``, in frame order) and the wall time (s)."""
    out_dir: Path
    sequence: object
    posed: int
    held: int
    moving: np.ndarray
    seconds: float


def write_hindsight_masks(sequence_dir, traj, out_dir, *, offsets: Sequence[int], params=None, config=None,
                          max_frames: Optional[int] = None, camera_preset: Optional[str] = None,
                          depth_scale: Union[float, str, None] = None, max_dt: float = 0.02, force: bool = False,
                          on_start: Optional[Callable] = None, on_mask: Optional[Callable] = None) -> MasksRun:
    """``jaxvo masks``: hindsight masks of a sequence folder from a trajectory file, into ``out_dir``.

    The trajectory's held poses are left out (:func:`jaxvo.pipelines.mapping.read_kept_poses`);
    its poses are matched to the frames within ``max_dt`` s; frames without a pose get no mask
    and serve as no other frame's view. ``offsets`` (frames, negative = earlier), ``params``
    (:class:`jaxvo.tracking.hindsight.HindsightParams`) and ``config``'s thresholds go to
    :func:`jaxvo.tracking.hindsight.sequence_masks`. The masks are written as they are decided
    into ``out_dir``'s ``.partial`` folder, renamed to ``out_dir`` at the end; a failure raises
    DatasetError saying how many finished masks were kept there. ``on_start(seq, posed, held)``
    is called before the work, ``on_mask(frame index)`` after each mask.
    """
    import cv2

    from jaxvo.config import Config
    from jaxvo.tracking.hindsight import HindsightParams, sequence_masks

    kept = read_kept_poses(traj)
    check_output_folder(out_dir, [sequence_dir, traj], force)
    seq = load_sequence(sequence_dir, camera_preset, depth_scale=depth_scale, max_dt=max_dt, max_frames=max_frames)
    check_camera_size(seq)
    idx, T = match_trajectory(seq.timestamps, kept.stamps, kept.poses, max_dt)
    if idx.size == 0:
        raise DatasetError(f"{traj}: no pose within {max_dt} s of a frame of {sequence_dir}")
    poses = np.full((len(seq), 4, 4), np.nan)
    poses[idx] = T
    config = Config() if config is None else config
    params = HindsightParams() if params is None else params
    if on_start is not None:
        on_start(seq, int(idx.size), kept.held)
    tmp = partial_path(out_dir, fresh=True)
    tmp.mkdir(parents=True)
    moving, t0 = [], time.perf_counter()
    try:
        for i, m in sequence_masks(seq.frame, poses, seq.camera, config, params, list(offsets)):
            p = tmp / f"{stamp_name(seq.timestamps[i])}.png"
            if not cv2.imwrite(str(p), m.astype(np.uint8) * 255):
                raise DatasetError(f"{p}: could not write mask image")
            moving.append(float(m.mean()))
            if on_mask is not None:
                on_mask(i)
    except (DatasetError, ValueError, OSError) as e:
        raise DatasetError(one_line(e) + (f" ({len(moving)} finished masks kept in {tmp})" if moving else "")) \
            from None
    finish(tmp, out_dir)
    return MasksRun(Path(out_dir), seq, int(idx.size), kept.held, np.asarray(moving), time.perf_counter() - t0)
