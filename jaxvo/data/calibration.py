"""Intrinsics and depth scale of a recording.

Intrinsics, unless given: the layout's calibration file (``calibration.txt``,
``camera_intrinsic.json``, jaxvo's ``info.json``), else the preset for the folder name
(:func:`jaxvo.camera.camera_for_sequence`), scaled to the images' size when they are not
640x480 (see :func:`sequence_camera`). The first frame read is checked for a plausible depth
scale (:func:`check_depth_scale`). A depth scale may name a sensor instead of a number: the
layout's scale with that sensor's published depth correction (:func:`resolve_depth_scale`), or
``"recorded"``: the layout's scale as it is.

Where the intrinsics are the folder name's preset (a TUM fr1/fr2/fr3 or Bonn recording), the
readers also apply that sensor's published lens and depth correction unless told otherwise
(:func:`published_sensor`): a recording is read with its dataset's whole calibration, as with
its intrinsics.
"""
from __future__ import annotations

from pathlib import Path
from typing import Optional, Tuple

import numpy as np

from jaxvo.camera import DEPTH_CORRECTIONS, Camera, camera_for_sequence, camera_for_size, preset_for_sequence
from jaxvo.data.errors import DatasetError
from jaxvo.data.textfiles import _data_lines
from jaxvo.frame import PLAUSIBLE_DEPTH, suggest_depth_scale

__all__ = ["read_calibration", "sequence_camera", "check_depth_scale", "parse_depth_scale", "resolve_depth_scale", "PLAUSIBLE_DEPTH",
           "DEFAULT_SCALE_MIN_MEDIAN", "RECORDED", "published_sensor"]

#: the ``depth_scale`` that reads the depth PNGs at the layout's scale, without a sensor's correction
RECORDED = "recorded"

#: the intrinsics' source (:func:`sequence_camera`) under which a folder name also names its sensor
FOLDER_NAME = "folder name"


def published_sensor(name: str, camera_source: str) -> str:
    """The key of :data:`jaxvo.camera.LENSES` / :data:`jaxvo.camera.DEPTH_CORRECTIONS` whose published
    calibration a reader applies by default: the folder ``name``'s preset where the intrinsics came from
    it (``camera_source`` "folder name", the preset's own image size), else "default" (no lens, no
    correction): intrinsics from a calibration file, from the caller or scaled to other images say
    nothing of the lens or the depth."""
    return preset_for_sequence(name) if camera_source == FOLDER_NAME else "default"


def parse_depth_scale(text: str):
    """A depth scale given as text (``--depth-scale``): a number > 0 as a float, or the name of a
    sensor of :data:`jaxvo.camera.DEPTH_CORRECTIONS` as given (:func:`resolve_depth_scale` makes it a
    number against the layout's scale). ValueError (one line) for anything else."""
    name = text.strip()
    if name in DEPTH_CORRECTIONS or name == RECORDED:
        return name
    try:
        number = float(name)
    except ValueError:
        number = None
    if number is None or not number > 0 or number == float("inf"):
        raise ValueError(f"must be a number > 0, a sensor with a published depth correction "
                         f"({', '.join(sorted(DEPTH_CORRECTIONS))}) or {RECORDED!r}, got {text!r}")
    return number


def resolve_depth_scale(value, layout_scale: float):
    """A reader's ``depth_scale`` as a number: ``value`` itself (a number, or None: the reader decides),
    or, for a sensor name of :data:`jaxvo.camera.DEPTH_CORRECTIONS` (``"fr2"``), ``layout_scale``
    times its published correction (5000 x 1.031 = 5155 for TUM fr2: PNG value / 5155 = metres);
    :data:`RECORDED` gives ``layout_scale``. ValueError (one line) for any other text."""
    if not isinstance(value, str):
        return value
    name = value.strip()
    if name == RECORDED:
        return float(layout_scale)
    if name not in DEPTH_CORRECTIONS:
        raise ValueError(f"open_sequence: depth_scale must be a number > 0, a sensor with a published depth "
                         f"correction ({', '.join(sorted(DEPTH_CORRECTIONS))}), {RECORDED!r} (the layout's scale) "
                         f"or None (the folder's sensor's, else the layout's), got {value!r}")
    return float(layout_scale) * DEPTH_CORRECTIONS[name]


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
        return cam, FOLDER_NAME
    return camera_for_size(cam, w, h), f"a guess: the {cam.width}x{cam.height} preset for the folder name scaled to {w}x{h}"


#: with the layout's default depth scale, a median below this (metres) stops the run too: a
#: recording in millimetres read as TUM's 1/5000 m puts typical indoor scenes (median 1.5-3 m:
#: TUM fr2/desk 1.5, fr3/long_office 2.4, Bonn crowd 2.3-2.9) at 0.3-0.6 m
DEFAULT_SCALE_MIN_MEDIAN = 0.7


def check_depth_scale(depth_m, depth_scale: float, source, explicit: bool = True) -> None:
    """Raise DatasetError (one line naming ``source`` and the depth scale to pass,
    :func:`jaxvo.frame.suggest_depth_scale`) when the depth scale looks wrong: the median valid
    depth of ``depth_m`` (metres, 0 = invalid) outside :data:`jaxvo.frame.PLAUSIBLE_DEPTH`, or,
    when ``depth_scale`` is the layout's default rather than chosen (``explicit``), under
    :data:`DEFAULT_SCALE_MIN_MEDIAN` (millimetres read with TUM's 5000 come out 5x too small;
    passing the scale explicitly accepts such close scenes)."""
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
    best = suggest_depth_scale(raw, exclude=depth_scale)
    keep = "" if explicit or not low or med < lo else f"; if the scene really is that close pass --depth-scale {depth_scale:g}"
    raise DatasetError(f"{source}: median valid depth {med:.3g} m with depth scale {depth_scale:g} is implausible "
                       f"(expected {max(lo, DEFAULT_SCALE_MIN_MEDIAN) if low and not explicit else lo:g}-{hi:g} m); "
                       f"pass --depth-scale {best:g} (library: depth_scale={best:g}), which gives {raw / best:.2f} m"
                       f"{keep}")
