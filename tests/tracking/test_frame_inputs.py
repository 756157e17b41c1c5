"""What :class:`jaxvo.Odometry` and :func:`jaxvo.track` say when given something other than frames:
a ValueError naming what was passed, and for the ``(timestamp, Frame)`` pairs that iterating a
sequence yields, how to pass the frames (before anything is estimated or compiled)."""
from __future__ import annotations

import cv2
import jax
import numpy as np
import pytest

from jaxvo.camera import Camera
from jaxvo.data import TumSequence
from jaxvo.tracking.odometry import Odometry, track

W, H = 8, 6
CAM = Camera(10.0, 10.0, 3.5, 2.5, width=W, height=H)
PAIRS = r"got tuple; iterating a sequence yields \(timestamp, Frame\) pairs: pass the frames, e\.g\. \(f for _, f in seq\)"


@pytest.fixture
def seq(tmp_path):
    """A two-frame TUM folder of 8x6 images."""
    (tmp_path / "rgb").mkdir()
    (tmp_path / "depth").mkdir()
    for i in range(2):
        cv2.imwrite(str(tmp_path / f"rgb/{i}.png"), np.full((H, W, 3), 50 * i, np.uint8))
        cv2.imwrite(str(tmp_path / f"depth/{i}.png"), np.full((H, W), 10000, np.uint16))
    (tmp_path / "rgb.txt").write_text("0.0 rgb/0.png\n0.1 rgb/1.png\n")
    (tmp_path / "depth.txt").write_text("0.0 depth/0.png\n0.1 depth/1.png\n")
    return TumSequence(tmp_path, camera=CAM)


@pytest.mark.parametrize("frames, match", [
    (lambda s: iter(s), PAIRS),
    (lambda s: s, PAIRS),
    (lambda s: [(f.intensity, f.depth) for _, f in s], r"^frame must be a jaxvo\.Frame .*got tuple$"),
    (lambda s: [None], r"^frame must be a jaxvo\.Frame .*got NoneType$"),
    (lambda s: [np.zeros((H, W))], r"got ndarray$"),
], ids=["iter-seq", "seq", "array-tuple", "none", "array"])
def test_track_of_anything_but_frames_says_how(seq, frames, match):
    with pytest.raises(ValueError, match=match):
        track(frames(seq), CAM, key=jax.random.key(0))


@pytest.mark.parametrize("item, match", [
    (lambda s: next(iter(s)), PAIRS),
    (lambda s: "frame.png", r"got str$"),
], ids=["pair", "str"])
def test_odometry_add_of_anything_but_a_frame(seq, item, match):
    odo = Odometry(CAM, key=jax.random.key(0))
    with pytest.raises(ValueError, match=match):
        odo.add(item(seq))
    assert len(odo) == 0    # nothing recorded
    odo.add(seq.frame(0))   # the frames themselves go in
    assert len(odo) == 1

