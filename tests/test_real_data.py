"""The estimator on real RGB-D frames against ground truth (TUM RGB-D and Bonn RGB-D Dynamic).

The data lives beside the repository in ``../shared/data`` (or ``$JAXVO_DATA``);
CI has it. Without it these tests skip, naming the missing folder.

Bounds are measured values with margin (run on 2026-11-21, default Config,
``jax.random.key(i)`` for pair i). Ground truth is interpolated at the colour
timestamps; its own frame-to-frame noise is a few mm and ~0.2 deg, which is
why per-pair errors are not smaller.
"""
from __future__ import annotations

import jax
import numpy as np
import pytest

from jaxvo import geometry
from jaxvo.data import TumSequence, data_root
from jaxvo.config import Config
from jaxvo.estimator.motion import estimate_motion

METHODS = ("classic", "huber", "ransac")


def _sequence(name, **reading):
    path = data_root() / name
    if not path.is_dir():
        pytest.skip(f"real data missing: {path} (set JAXVO_DATA or put shared/data beside the repo)")
    return TumSequence(path, **reading)


def _pair_errors(seq, pairs, method, gap=1):
    """Translational (mm) and rotational (deg) error of T_cur_ref of each pair (i, i + gap)."""
    covered, T_world_cam = seq.groundtruth_at_frames()
    cfg = Config(method=method)
    t_err, r_err = [], []
    for i in pairs:
        assert covered[i] and covered[i + gap]
        est = estimate_motion(seq.frame(i), seq.frame(i + gap), seq.camera, cfg, jax.random.key(i))
        gt = np.linalg.inv(T_world_cam[i + gap]) @ T_world_cam[i]
        E = np.linalg.inv(gt) @ np.asarray(est.T_cur_ref, np.float64)
        t_err.append(1000 * np.linalg.norm(E[:3, 3]))
        r_err.append(np.degrees(geometry.rotation_angle(E[:3, :3])))
    return np.array(t_err), np.array(r_err)


def _near_fraction(frame, near=2.0):
    """Fraction of valid-depth pixels nearer than ``near`` metres: in the Bonn crowd room (walls,
    desks ~2.5-4 m away) these are the people; measured <= 0.02 on frames 0-12, before they arrive."""
    d = np.asarray(frame.depth)
    valid = d > 0
    return np.count_nonzero(valid & (d < near)) / max(np.count_nonzero(valid), 1)


@pytest.fixture(scope="module")
def fr2_desk():
    return _sequence("tum/rgbd_dataset_freiburg2_desk")


@pytest.fixture(scope="module")
def bonn_crowd():
    return _sequence("bonn/rgbd_bonn_crowd")


@pytest.mark.parametrize("method", METHODS)
def test_fr2_desk_every_consecutive_pair(fr2_desk, method):
    # measured over the 49 pairs: max 6.3-6.8 mm, RMSE 2.7-2.8 mm, median rotation 0.19-0.20 deg
    t, r = _pair_errors(fr2_desk, range(len(fr2_desk) - 1), method)
    assert len(t) == 49
    assert t.max() < 10.0, t.max()
    assert np.sqrt(np.mean(t ** 2)) < 4.0
    assert np.median(r) < 0.3 and r.max() < 1.2


@pytest.mark.parametrize("method", METHODS)
def test_bonn_crowd_before_the_people_arrive(bonn_crowd, method):
    # frames 0-14: the room is (nearly) empty; measured max 12-16 mm, RMSE 7-10 mm
    # (this sequence's marker-based ground truth is noisier per frame than TUM's)
    t, r = _pair_errors(bonn_crowd, range(0, 14), method)
    assert t.max() < 25.0 and np.sqrt(np.mean(t ** 2)) < 14.0
    assert np.median(r) < 0.3


def test_bonn_crowd_with_people_walking(bonn_crowd):
    """Consecutive frames while people cover much of the image (frame ~60 on).

    Measured (pairs 60, 66, ..., 156): translational RMSE classic 24.8 mm, ransac 27.3 mm;
    the camera itself moves ~3 mm per frame. In 33 ms a person walking at ~1 m/s moves
    ~3 cm, under the paper's 5 cm depth threshold, and the persons are the nearest,
    best-textured surfaces: every estimator partly follows them, and no inlier test can
    tell them apart on one frame step. This test pins only that all stay bounded; the
    next test and ``jaxvo.TrackConfig`` (keyframes) are how jaxvo copes.
    """
    pairs = range(60, 159, 6)
    rmse = {}
    for method in ("classic", "ransac"):
        t, _ = _pair_errors(bonn_crowd, pairs, method)
        assert t.max() < 60.0, (method, t.max())
        rmse[method] = np.sqrt(np.mean(t ** 2))
    assert rmse["ransac"] < 1.4 * rmse["classic"], rmse


def test_bonn_crowd_pairs_six_frames_apart(bonn_crowd):
    """People cover much of the image and have moved well beyond the thresholds between the
    two frames (0.2 s apart): ransac's consensus is the static background, classic's least
    squares is dragged by the people.

    Measured (pairs (i, i+6), i = 60, 66, ..., 144, key(i), from identity): translational
    error median classic 133 mm, ransac 26 mm; RMSE 154 vs 114 mm (ransac fails on 3 of the
    15 pairs, 138-308 mm, where a near, motion-blurred person fills the right half).
    """
    pairs = range(60, 150, 6)
    # these are pairs "where people cover much of the image": at least 20 % of each reference
    # frame is nearer than 2 m (measured 0.24-0.67 on these frames, <= 0.02 on frames 0-12)
    cover = [_near_fraction(bonn_crowd.frame(i)) for i in pairs]
    assert min(cover) >= 0.2, cover
    med, rmse = {}, {}
    for method in ("classic", "ransac"):
        t, _ = _pair_errors(bonn_crowd, pairs, method, gap=6)
        med[method], rmse[method] = np.median(t), np.sqrt(np.mean(t ** 2))
    assert med["ransac"] < 0.35 * med["classic"], med
    assert rmse["ransac"] < rmse["classic"], rmse


def test_fr2_desk_with_persons_default_flags_them_and_beats_pairwise_ransac(fr2_desk, tmp_path):
    """The real fr2_desk's first 30 frames with two synthetic persons walking in front of the
    desk (``jaxvo augment``, seeds 3 and 6: exact moving masks, real ground truth and sensor
    noise). The default tracking's moving mask (jaxvo.pipelines.mapping.moving_mask on each reference)
    covers the persons and little else, and its trajectory beats the paper's frame-to-frame
    RANSAC by at least a tenth (seed 6: ATE 9.5 against RANSAC's 11.2 mm with the keyframe
    window, 6.4 mm with the single reference: docs/decisions/window.md)."""
    from jaxvo.evaluation import metrics
    from jaxvo.data.masks import load_mask_of_size as load_mask, true_masks as read_moving_masks
    from jaxvo.pipelines.mapping import moving_mask
    from jaxvo.config import TrackConfig
    from jaxvo.tracking.odometry import track
    from jaxvo.synthetic import augment

    counts = np.zeros(3)          # true positives, false positives, false negatives
    for seed in (3, 6):
        folder = augment(fr2_desk.path, tmp_path / f"aug{seed}", persons=2, coverage=0.3, seed=seed, max_frames=30)
        seq = TumSequence(folder)
        cam = seq.camera
        stamps, paths = read_moving_masks(folder)
        truth = [load_mask(paths[int(np.argmin(np.abs(stamps - t)))], (cam.height, cam.width)) for t in seq.timestamps]

        def score(step):
            pred, decided = moving_mask(step.estimate, cam.width, cam.height, step.static_mask, valid_too=True)
            t = truth[step.reference]
            counts[:] += [(pred & t & decided).sum(), (pred & ~t & decided).sum(), (~pred & t & decided).sum()]

        frames = [seq.frame(i) for i in range(len(seq))]
        default = track(frames, cam, Config(), jax.random.key(seed), callback=score)
        pairwise = track(frames, cam, Config(), jax.random.key(seed), policy=TrackConfig.frame_to_frame())
        covered, T_world_cam = seq.groundtruth_at_frames()
        ts = np.asarray(seq.timestamps)
        ate = [metrics.ate(ts[covered], T_world_cam[covered], ts, tr.poses).rmse for tr in (default, pairwise)]
        assert ate[0] < 0.9 * ate[1], (seed, ate)
    tp, fp, fn = counts
    assert tp / (tp + fp) > 0.75 and tp / (tp + fn) > 0.7, counts


def test_second_opinion_fuses_where_people_cover_the_reference():
    """TrackConfig.second_opinion (on by default) on the Bonn crowd excerpt read as recorded (no
    lens, the depth at 1/5000 m: an input on which seed 0 needs it; read with Bonn's calibration it
    asks for none): where the people walking ahead of the camera cover most of the references
    (frames 110-130), a few frames are estimated against the window's next-older keyframe too; none
    before the people come, none with it off, and the track ends no worse than with it off by more
    than the seeds' spread (3 mm). Measured on 2-core AMD EPYCs with AVX-512, seed 0: family 25
    model 17, 3 such frames, ATE 0.0221 against 0.0255 m; family 26 model 2, 0.0223 against 0.0203
    m, and over seeds 0-5 there 0.0211 against 0.0230 m, off from 0.0203 to 0.0280 (`python -m
    experiments.diagnostics.levers` on this reading, ground truth interpolated at the frames).
    Both runs test the motion once per reference (``motion_retest`` 0): with the default's test
    at every frame the references trust enough of their pixels here that no frame asks."""
    bonn_crowd = _sequence("bonn/rgbd_bonn_crowd", lens="none", depth_scale="recorded")
    from jaxvo.config import TrackConfig
    from jaxvo.evaluation.metrics import ate
    from jaxvo.tracking.odometry import Odometry

    class Asking(Odometry):
        def _estimate(self, purpose, ref, cur, *args):
            if purpose == "second opinion":
                self.asked.append(cur)
            return super()._estimate(purpose, ref, cur, *args)

    frames = [bonn_crowd.frame(i) for i in range(len(bonn_crowd))]
    gt_t, gt_T = bonn_crowd.groundtruth
    result = {}
    # with the motion test once per reference: at every frame (motion_retest, the default) the map
    # flags the walkers soon enough that seed 0's references trust 45 % or more and none is asked
    for name, policy in (("off", TrackConfig(second_opinion=0.0, motion_retest=0)),
                         ("default", TrackConfig(motion_retest=0))):
        odo = Asking(bonn_crowd.camera, Config(), key=jax.random.key(0), policy=policy)
        odo.asked = []
        for f in frames:
            odo.add(f)
        result[name] = (ate(gt_t, gt_T, bonn_crowd.timestamps, np.stack(odo.poses)).rmse, odo.asked)
    assert TrackConfig().second_opinion > 0 and result["off"][1] == []
    assert 1 <= len(result["default"][1]) <= 15 and min(result["default"][1]) > 60, result["default"][1]
    assert result["default"][0] <= result["off"][0] + 0.003, (result["default"][0], result["off"][0])
