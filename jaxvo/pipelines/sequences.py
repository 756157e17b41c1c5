"""Opening a sequence folder as ``jaxvo run`` does: :func:`load_sequence` (any supported layout, the
intrinsics and lens the CLI would use), :func:`resolve_camera` (just its intrinsics) and
:func:`check_camera_size` (intrinsics that do not fit the images, with what fixes it). Bad input
raises :class:`jaxvo.data.DatasetError` with a one-line message naming the folder."""
from __future__ import annotations

import dataclasses
from typing import Optional

from jaxvo.camera import PRESETS, Camera, Lens
from jaxvo.data import DatasetError, TumSequence, open_sequence

__all__ = ["check_camera_size", "load_sequence", "resolve_camera"]


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
