"""Tests for jaxvo.data's sequence readers: TUM/Bonn reading, association, errors, lazy loading, ground truth."""
from __future__ import annotations

import threading
from pathlib import Path

import cv2
import numpy as np
import pytest

from jaxvo import geometry as G
from jaxvo.frame import undistort
from jaxvo.camera import (BONN, DEFAULT, DEPTH_CORRECTIONS, LENSES, NO_LENS, PRESETS, TUM_FR2, Camera, camera_for_size,
                          depth_correction_for_sequence)
from jaxvo.data import (T_M_BONN, T_ROS, DatasetError, TumSequence, associate, bonn_marker_to_camera,
                        data_root, find_sequence, find_sequences, interpolate_poses, read_file_list,
                        read_pose_file)

W, H = 8, 6
SMALL = Camera(10.0, 10.0, 3.5, 2.5, width=W, height=H)


def _pose_line(t, T):
    q, p = G.quat_trans_from_transform(T)
    return f"{t:.6f} " + " ".join(f"{x:.9f}" for x in (*p, *q))


def make_seq(root: Path, name="seq", n=5, rgb_dt=1 / 30, depth_offset=0.004, gt=True, gt_span=None,
             write_images=True, size=None):
    """Tiny TUM folder: n frames of W x H (or ``size`` (width, height)), rgb at rgb_dt, depth offset
    by depth_offset s."""
    w, h = (W, H) if size is None else size
    d = root / name
    (d / "rgb").mkdir(parents=True)
    (d / "depth").mkdir()
    t0 = 1000.0
    rgb_lines, depth_lines = ["# color images", "# timestamp filename"], ["# depth maps", "# timestamp filename"]
    for i in range(n):
        tr, td = t0 + i * rgb_dt, t0 + i * rgb_dt + depth_offset
        rgb_lines.append(f"{tr:.6f} rgb/{tr:.6f}.png")
        depth_lines.append(f"{td:.6f} depth/{td:.6f}.png")
        if write_images:
            img = np.full((h, w, 3), 10 * i, np.uint8)
            img[..., 2] = 200  # red channel in BGR order
            cv2.imwrite(str(d / f"rgb/{tr:.6f}.png"), img)
            cv2.imwrite(str(d / f"depth/{td:.6f}.png"), np.full((h, w), 5000 + 100 * i, np.uint16))
    (d / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (d / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    if gt:
        a, b = gt_span if gt_span is not None else (t0 - 0.1, t0 + n * rgb_dt + 0.1)
        ts = np.arange(a, b, 0.01)
        lines = ["# ground truth trajectory", "# timestamp tx ty tz qx qy qz qw"]
        for t in ts:
            T = G.exp(np.array([0.0, 0.1 * (t - t0), 0.0, 0.5 * (t - t0), 0.0, 0.0]))
            lines.append(_pose_line(t, T))
        (d / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    return d


# ----------------------------------------------------------------------------- basic reading

def test_read_small_sequence(tmp_path):
    d = make_seq(tmp_path, n=5)
    s = TumSequence(d, camera=SMALL)
    assert len(s) == 5
    assert s.timestamps.dtype == np.float64 and s.timestamps.shape == (5,)
    assert np.allclose(np.diff(s.timestamps), 1 / 30, atol=1e-6)
    f = s.frame(2)
    assert f.intensity.dtype == np.float32 and f.intensity.shape == (H, W)
    # BGR (20, 20, 200) -> luminance 0.299*200 + 0.587*20 + 0.114*20
    assert np.allclose(f.intensity, 0.299 * 200 + 0.587 * 20 + 0.114 * 20, atol=1e-3)
    assert np.allclose(f.depth, (5000 + 200) / 5000.0)
    items = list(s)
    assert [t for t, _ in items] == list(s.timestamps)
    assert np.array_equal(items[-1][1].depth, s.frame(-1).depth)
    with pytest.raises(IndexError):
        s.frame(5)


def test_start_and_max_frames(tmp_path):
    d = make_seq(tmp_path, n=6)
    full = TumSequence(d, camera=SMALL)
    s = TumSequence(d, camera=SMALL, start=2, max_frames=3)
    assert len(s) == 3
    assert np.array_equal(s.timestamps, full.timestamps[2:5])
    assert np.array_equal(s.frame(0).depth, full.frame(2).depth)
    with pytest.raises(DatasetError, match="past the end"):
        TumSequence(d, camera=SMALL, start=6)


def test_camera_from_folder_name(tmp_path):
    # the images are 8x6, not the presets' 640x480: the preset is scaled to them, and said to be a guess
    d = make_seq(tmp_path, name="rgbd_dataset_freiburg2_fake", n=2)
    s = TumSequence(d)
    assert s.camera == camera_for_size(TUM_FR2, W, H) and s.camera_source.startswith("a guess")
    d = make_seq(tmp_path, name="rgbd_bonn_fake", n=2)
    s = TumSequence(d)
    assert s.camera == camera_for_size(BONN, W, H) and s.is_bonn
    assert TumSequence(d, camera=SMALL, bonn=False).camera == SMALL


def test_lens_undistorts_frames_as_they_are_read(tmp_path):
    """No lens where the intrinsics are not the folder's sensor's preset (here a guess scaled to
    8x6 images); lens= (a Lens, a preset name or 5 numbers) undistorts each frame as it is read,
    exactly as jaxvo.frame.undistort does."""
    d = make_seq(tmp_path, name="rgbd_dataset_freiburg2_fake", n=2)
    assert TumSequence(d).lens == NO_LENS and TumSequence(d).sensor == "default"
    s = TumSequence(d, camera=SMALL, lens="fr2")
    assert s.lens == LENSES["fr2"]
    raw = TumSequence(d, camera=SMALL).frame(0)
    np.testing.assert_array_equal(s.frame(0).depth, undistort(raw, SMALL, LENSES["fr2"]).depth)
    with pytest.raises(ValueError, match="lens must be"):
        TumSequence(d, camera=SMALL, lens="0,1")


def test_real_sequence_read_with_its_published_lens_and_depth_correction():
    """fr2/desk by default: fr2's intrinsics from the folder name, and with them fr2's published lens
    and depth correction; every frame is the frame read as recorded at 1/5155 m, undistorted (corners
    read beyond the image get no depth). lens="none", depth_scale="recorded": the files as they are."""
    fr2 = data_root() / "tum" / "rgbd_dataset_freiburg2_desk"
    if not fr2.is_dir():
        pytest.skip(f"real data missing: {fr2} (set JAXVO_DATA to the data root)")
    s = TumSequence(fr2, max_frames=1)
    assert (s.sensor, s.camera_source, s.lens, s.depth_scale) == ("fr2", "folder name", LENSES["fr2"], 5000 * 1.031)
    unlensed = TumSequence(fr2, max_frames=1, lens="none", depth_scale="fr2")
    recorded = TumSequence(fr2, max_frames=1, lens="none", depth_scale="recorded")
    assert (recorded.lens, recorded.depth_scale) == (NO_LENS, 5000.0)
    f, g = s.frame(0), undistort(unlensed.frame(0), s.camera, LENSES["fr2"])
    np.testing.assert_array_equal(f.intensity, g.intensity)
    np.testing.assert_array_equal(f.depth, g.depth)
    raw = cv2.imread(str(s.depth_paths[0]), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(recorded.frame(0).depth, (raw / 5000.0).astype(np.float32))
    assert not np.array_equal(f.depth, recorded.frame(0).depth) and f.depth[0, 0] == 0


def test_published_calibration_follows_the_intrinsics(tmp_path):
    """A folder named for a sensor, at that sensor's image size, is read with its preset's
    intrinsics, lens and depth correction; intrinsics from the caller or from a calibration file say
    nothing of the lens or the depth (none applied), unless ``sensor`` names one; a folder named for
    no sensor gets none."""
    import json
    bonn = make_seq(tmp_path, name="rgbd_bonn_fake", n=1, size=(640, 480))
    s = TumSequence(bonn)
    assert (s.sensor, s.lens, s.depth_scale) == ("bonn", LENSES["bonn"], pytest.approx(5000 / 1.0593))
    given = TumSequence(bonn, camera=PRESETS["bonn"])
    assert (given.sensor, given.lens, given.depth_scale) == ("default", NO_LENS, 5000.0)
    named = TumSequence(bonn, camera=PRESETS["fr2"], sensor="fr2")
    assert (named.lens, named.depth_scale) == (LENSES["fr2"], 5000 * 1.031)
    assert TumSequence(bonn, depth_scale=4000, lens="none").depth_scale == 4000.0
    with pytest.raises(ValueError, match="sensor must be one of"):
        TumSequence(bonn, sensor="kinect")
    other = make_seq(tmp_path, name="my_room", n=1, size=(640, 480))
    assert (TumSequence(other).sensor, TumSequence(other).lens, TumSequence(other).depth_scale) == \
        ("default", NO_LENS, 5000.0)
    (bonn / "info.json").write_text(json.dumps({"camera": {"fx": 500, "fy": 500, "cx": 320, "cy": 240,
                                                            "width": 640, "height": 480}}))
    assert (TumSequence(bonn).sensor, TumSequence(bonn).depth_scale) == ("default", 5000.0)


def test_bonn_depth_correction_is_the_scale_of_its_published_marker_calibration(tmp_path):
    """Bonn's correction is 1 / the scale of T_m's 3x3 block (its three singular values, equal to
    1e-4): a camera point times that scale is the motion capture's metres, so the depth PNGs of a
    rgbd_bonn_* folder read with depth_scale="bonn" are 5000 / 1.0593 per metre."""
    from jaxvo.data.groundtruth import T_M_BONN
    sv = np.linalg.svd(T_M_BONN[:3, :3], compute_uv=False)
    assert np.ptp(sv) < 2e-4
    assert abs(DEPTH_CORRECTIONS["bonn"] - 1 / sv.mean()) < 1e-4
    d = make_seq(tmp_path, name="rgbd_bonn_fake", n=2)
    assert depth_correction_for_sequence(d.name) == DEPTH_CORRECTIONS["bonn"]
    s = TumSequence(d, camera=SMALL, depth_scale="bonn")
    assert s.depth_scale == pytest.approx(5000 / 1.0593)
    raw = cv2.imread(str(s.depth_paths[0]), cv2.IMREAD_UNCHANGED)
    np.testing.assert_allclose(s.frame(0).depth, raw * 1.0593 / 5000, rtol=1e-6)


def test_a_sensor_name_as_depth_scale_applies_its_published_correction(tmp_path):
    """depth_scale="fr2": the layout's 5000 times TUM's fr2 correction 1.031, so every depth is the
    PNG value / 5155 m (read independently with OpenCV); a sensor without a published correction
    reads as the layout's scale; any other name is one ValueError naming the choices."""
    d = make_seq(tmp_path, name="rgbd_dataset_freiburg2_fake", n=2)
    assert depth_correction_for_sequence(d.name) == DEPTH_CORRECTIONS["fr2"] == 1.031
    s = TumSequence(d, camera=SMALL, depth_scale="fr2")
    assert s.depth_scale == 5000 * 1.031
    raw = cv2.imread(str(s.depth_paths[0]), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw.any()
    np.testing.assert_array_equal(s.frame(0).depth, (raw / 5155.0).astype(np.float32))
    assert TumSequence(d, camera=SMALL, depth_scale="fr3").depth_scale == TumSequence(d, camera=SMALL).depth_scale
    with pytest.raises(ValueError, match=r"depth_scale must be a number > 0, a sensor .*fr1, fr2.*'fr9'"):
        TumSequence(d, camera=SMALL, depth_scale="fr9")


def test_camera_size_mismatch_is_reported(tmp_path):
    d = make_seq(tmp_path, n=2)
    s = TumSequence(d, camera=DEFAULT)  # a 640x480 camera, images are 8x6
    with pytest.raises(DatasetError, match="does not match the camera"):
        s.frame(0)


# ----------------------------------------------------------------------------- association

def test_associate_one_to_one_nearest_first():
    a = np.array([0.0, 0.033, 0.066, 0.5])
    b = np.array([0.010, 0.012, 0.070, 0.9])
    ia, ib = associate(a, b, 0.02)
    # 0.0 - 0.010 (0.010), 0.033 - 0.012 (0.021 > 0.02, none), 0.066 - 0.070
    assert ia.tolist() == [0, 2] and ib.tolist() == [0, 2]
    # b=0.012 is nearer to a=0.0 than 0.010? no: 0.010 wins for a=0.0, then 0.012 free for a=0.033 with bigger tol
    ia, ib = associate(a, b, 0.03)
    assert ia.tolist() == [0, 1, 2] and ib.tolist() == [0, 1, 2]
    ia, ib = associate(a, b, 0.001)
    assert ia.size == 0


def test_associate_matches_bruteforce():
    rng = np.random.default_rng(0)
    a = np.sort(rng.uniform(0, 10, 300))
    b = np.sort(rng.uniform(0, 10, 280))
    ia, ib = associate(a, b, 0.02)
    # brute force TUM associate.py
    cands = sorted((abs(x - y), i, j) for i, x in enumerate(a) for j, y in enumerate(b) if abs(x - y) <= 0.02)
    ua, ub, m = set(), set(), []
    for _, i, j in cands:
        if i not in ua and j not in ub:
            ua.add(i); ub.add(j); m.append((i, j))
    m.sort()
    assert list(zip(ia.tolist(), ib.tolist())) == m


def test_association_tolerance_configurable(tmp_path):
    d = make_seq(tmp_path, n=4, depth_offset=0.015)
    assert len(TumSequence(d, camera=SMALL)) == 4
    with pytest.raises(DatasetError, match=r"rgb\.txt: no rgb/depth pair within 0.01 s"):
        TumSequence(d, camera=SMALL, max_dt=0.01)


# ----------------------------------------------------------------------------- bad inputs

def test_missing_folder(tmp_path):
    with pytest.raises(DatasetError) as e:
        TumSequence(tmp_path / "nope")
    assert str(tmp_path / "nope") in str(e.value) and "does not exist" in str(e.value)
    assert "\n" not in str(e.value)


def test_missing_rgb_txt(tmp_path):
    d = make_seq(tmp_path, n=2)
    (d / "rgb.txt").unlink()
    with pytest.raises(DatasetError, match=r"rgb\.txt: file not found"):
        TumSequence(d, camera=SMALL)


def test_missing_depth_txt(tmp_path):
    d = make_seq(tmp_path, n=2)
    (d / "depth.txt").unlink()
    with pytest.raises(DatasetError, match=r"depth\.txt: file not found"):
        TumSequence(d, camera=SMALL)


def test_malformed_line(tmp_path):
    d = make_seq(tmp_path, n=2)
    with open(d / "rgb.txt", "a") as fh:
        fh.write("not-a-time rgb/x.png\n")
    with pytest.raises(DatasetError, match=r"rgb\.txt:5: malformed line 'not-a-time rgb/x.png'"):
        TumSequence(d, camera=SMALL)
    (d / "rgb.txt").write_text("# only comments\n")
    with pytest.raises(DatasetError, match=r"rgb\.txt: no entries"):
        TumSequence(d, camera=SMALL)


def test_listed_image_missing(tmp_path):
    d = make_seq(tmp_path, n=3)
    victim = sorted((d / "depth").iterdir())[1]
    victim.unlink()
    with pytest.raises(DatasetError, match=rf"{victim.name}: file not found \(listed in depth.txt\)"):
        TumSequence(d, camera=SMALL)


def test_undecodable_png(tmp_path):
    d = make_seq(tmp_path, n=3)
    victim = sorted((d / "rgb").iterdir())[1]
    victim.write_bytes(b"\x89PNG\r\n\x1a\n this is not a png")
    s = TumSequence(d, camera=SMALL)  # lazy: opening works
    s.frame(0)
    with pytest.raises(DatasetError) as e:
        s.frame(1)
    msg = str(e.value)
    assert str(victim) in msg and "does not decode" in msg and "\n" not in msg


def test_8bit_depth(tmp_path):
    d = make_seq(tmp_path, n=2)
    victim = sorted((d / "depth").iterdir())[0]
    cv2.imwrite(str(victim), np.full((H, W), 3, np.uint8))
    with pytest.raises(DatasetError) as e:
        TumSequence(d, camera=SMALL).frame(0)
    assert str(victim) in str(e.value) and "8-bit" in str(e.value) and "16-bit" in str(e.value)


def test_size_mismatch(tmp_path):
    d = make_seq(tmp_path, n=2)
    victim = sorted((d / "depth").iterdir())[0]
    cv2.imwrite(str(victim), np.full((H + 2, W), 5000, np.uint16))
    with pytest.raises(DatasetError) as e:
        TumSequence(d, camera=SMALL).frame(0)
    assert str(victim) in str(e.value) and "depth size 8x8 does not match colour image" in str(e.value)


def test_depth_without_valid_pixel_reads_as_a_frame_without_depth(tmp_path):
    """A covered sensor's all-zero depth image is a frame without depth (the odometry holds it);
    the depth scale is checked on the first frame that has depth."""
    from jaxvo.frame import has_depth
    d = make_seq(tmp_path, n=3)
    victim = sorted((d / "depth").iterdir())[0]
    cv2.imwrite(str(victim), np.zeros((H, W), np.uint16))
    seq = TumSequence(d, camera=SMALL)
    assert not has_depth(seq.frame(0)) and has_depth(seq.frame(1))
    # read in centimetres, the first frame with depth is 50 m away
    seq = TumSequence(d, camera=SMALL, depth_scale=100)
    seq.frame(0)
    with pytest.raises(DatasetError, match=r"median valid depth .* is implausible"):
        seq.frame(1)


def test_no_association(tmp_path):
    d = make_seq(tmp_path, n=3, depth_offset=0.5)
    with pytest.raises(DatasetError) as e:
        TumSequence(d, camera=SMALL)
    assert "rgb.txt" in str(e.value) and "no rgb/depth pair within 0.02 s" in str(e.value)


def test_groundtruth_not_covering(tmp_path):
    d = make_seq(tmp_path, n=10, gt_span=(1000.15, 1001.0))  # frames start at 1000.0: 0.15 s before
    s = TumSequence(d, camera=SMALL)
    with pytest.raises(DatasetError) as e:
        s.groundtruth
    msg = str(e.value)
    assert "groundtruth.txt" in msg and "does not cover the sequence" in msg and "\n" not in msg
    # the same frames minus the uncovered start are fine
    assert TumSequence(d, camera=SMALL, start=3).groundtruth is not None
    # a small overhang (within gt_slack = 0.1 s) is accepted, like TUM fr3 recordings
    d2 = make_seq(tmp_path, name="seq2", n=10, gt_span=(1000.05, 1001.0))
    t, T = TumSequence(d2, camera=SMALL).groundtruth
    assert T.shape == (t.size, 4, 4)
    mask, P = TumSequence(d2, camera=SMALL).groundtruth_at_frames()
    assert mask.tolist() == [False] + [True] * 9  # frame 1 is 0.017 s before gt: within max_dt
    assert np.isnan(P[0]).all() and np.isfinite(P[2:]).all()


def test_groundtruth_malformed_and_missing(tmp_path):
    d = make_seq(tmp_path, n=3)
    with open(d / "groundtruth.txt", "a") as fh:
        fh.write("1000.5 1 2 3 0 0 0\n")
    with pytest.raises(DatasetError, match=r"groundtruth\.txt:\d+: malformed line .*expected 8 fields"):
        TumSequence(d, camera=SMALL).groundtruth
    (d / "groundtruth.txt").unlink()
    assert TumSequence(d, camera=SMALL).groundtruth is None


def test_read_file_list_sorts(tmp_path):
    p = tmp_path / "rgb.txt"
    p.write_text("# c\n2.0 b.png\n1.0 a.png extra\n")
    t, names = read_file_list(p)
    assert t.tolist() == [1.0, 2.0] and names == ["a.png", "b.png"]


# ----------------------------------------------------------------------------- laziness / prefetch

def test_lazy_loading(tmp_path, monkeypatch):
    d = make_seq(tmp_path, n=6)
    calls = []
    real = cv2.imread
    monkeypatch.setattr(cv2, "imread", lambda p, *a: (calls.append(p), real(p, *a))[1])
    s = TumSequence(d, camera=SMALL)
    _ = s.groundtruth
    assert calls == []
    it = iter(s)
    next(it)
    assert len(calls) == 2  # one rgb + one depth
    next(it)
    assert len(calls) == 4


def test_prefetch_same_frames_in_order(tmp_path):
    d = make_seq(tmp_path, n=7)
    s = TumSequence(d, camera=SMALL)
    plain = list(s)
    for n in (1, 3):
        pre = list(s.prefetch(n))
        assert [t for t, _ in pre] == [t for t, _ in plain]
        for (_, a), (_, b) in zip(pre, plain):
            assert np.array_equal(a.intensity, b.intensity) and np.array_equal(a.depth, b.depth)


def test_prefetch_runs_ahead_in_background_and_stops(tmp_path, monkeypatch):
    d = make_seq(tmp_path, n=8)
    s = TumSequence(d, camera=SMALL)
    loaded = []
    real = s.frame
    lock = threading.Lock()

    def spy(i):
        f = real(i)
        with lock:
            loaded.append(i)
        return f
    monkeypatch.setattr(s, "frame", spy)
    gen = s.prefetch(2)
    next(gen)
    import time
    for _ in range(200):  # the worker fills the queue while we "work"
        if len(loaded) >= 3:
            break
        time.sleep(0.005)
    assert sorted(loaded) == [0, 1, 2]  # never more than n ahead
    gen.close()
    assert all(not t.name.startswith("jaxvo-prefetch") for t in threading.enumerate())
    assert len(loaded) <= 4


def test_prefetch_error_surfaces_at_that_frame(tmp_path):
    d = make_seq(tmp_path, n=4)
    victim = sorted((d / "rgb").iterdir())[2]
    victim.write_bytes(b"garbage")
    got = []
    with pytest.raises(DatasetError, match="does not decode"):
        for t, f in TumSequence(d, camera=SMALL).prefetch(1):
            got.append(t)
    assert len(got) == 2


# ----------------------------------------------------------------------------- interpolation

def test_interpolate_poses():
    t = np.array([0.0, 1.0, 3.0])
    T = np.tile(np.eye(4), (3, 1, 1))
    T[:, :3, :3] = G.exp_so3(np.array([[0, 0, 0], [0, 0, 0.4], [0, 0, 1.2]], float))
    T[:, :3, 3] = [[0, 0, 0], [1, 0, 0], [1, 2, 0]]
    q = np.array([0.0, 0.5, 1.0, 2.0, 3.0])
    P = interpolate_poses(t, T, q)
    assert np.allclose(P[[0, 2, 4]], T)
    assert np.allclose(P[1, :3, 3], [0.5, 0, 0]) and np.isclose(G.rotation_angle(P[1, :3, :3]), 0.2)
    assert np.allclose(P[3, :3, 3], [1, 1, 0]) and np.isclose(G.log_so3(P[3, :3, :3])[2], 0.8)
    with pytest.raises(ValueError, match="outside the covered span"):
        interpolate_poses(t, T, [3.5])
    with pytest.raises(DatasetError):
        interpolate_poses(t, T, [-0.1])
    with pytest.raises(DatasetError, match="gap"):
        interpolate_poses(t, T, [2.0], max_gap=1.5)


# ----------------------------------------------------------------------------- Bonn conversion

def test_bonn_conversion_formula():
    rng = np.random.default_rng(1)
    Tgt = G.exp(rng.normal(size=(5, 6)))
    Tc = bonn_marker_to_camera(Tgt)
    ref = T_ROS @ Tgt @ T_ROS @ T_M_BONN
    # translation exactly as the formula, rotation = formula / 1.059 (re-orthonormalised)
    assert np.allclose(Tc[:, :3, 3], ref[:, :3, 3])
    s = np.linalg.svd(T_M_BONN[:3, :3], compute_uv=False)
    assert np.allclose(s, s[0], rtol=2e-3) and abs(s[0] - 1.059) < 2e-3
    assert np.allclose(Tc[:, :3, :3], ref[:, :3, :3] / s.mean(), atol=2e-3)
    assert np.allclose(np.swapaxes(Tc[:, :3, :3], 1, 2) @ Tc[:, :3, :3], np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(Tc[:, :3, :3]), 1.0)


def test_bonn_groundtruth_applied_by_folder_name(tmp_path):
    d = make_seq(tmp_path, name="rgbd_bonn_fake", n=3)
    t, Tc = TumSequence(d, camera=SMALL).groundtruth
    t2, Traw = read_pose_file(d / "groundtruth.txt")
    assert np.allclose(Tc, bonn_marker_to_camera(Traw))
    t3, Tplain = TumSequence(d, camera=SMALL, bonn=False).groundtruth
    assert np.allclose(Tplain, Traw)


# ----------------------------------------------------------------------------- real data

def _real(name):
    root = data_root()
    if not root.is_dir():
        pytest.skip(f"data folder {root} is missing (set JAXVO_DATA)")
    try:
        return find_sequence(name, root)
    except DatasetError:
        pytest.skip(f"sequence {name} not found under {root}")


def test_find_sequences():
    root = data_root()
    if not root.is_dir():
        pytest.skip(f"data folder {root} is missing (set JAXVO_DATA)")
    names = [p.name for p in find_sequences(root)]
    assert "rgbd_dataset_freiburg2_desk" in names and "rgbd_bonn_crowd" in names


def test_real_freiburg2_desk():
    s = TumSequence(_real("rgbd_dataset_freiburg2_desk"))
    assert len(s) == 50 and s.camera == TUM_FR2 and not s.is_bonn
    assert np.isclose(s.timestamps[0], 1311868164.363181) and np.isclose(s.timestamps[-1], 1311868165.999133)
    assert np.all(np.abs(s.depth_timestamps - s.timestamps) <= 0.02)
    f = s.frame(0)
    assert f.shape == (480, 640)
    valid = f.depth > 0
    assert valid.mean() > 0.5 and 0.5 < np.median(f.depth[valid]) < 5.0
    t, T = s.groundtruth
    assert t.size == 20956  # 20957 lines, one duplicated timestamp dropped
    assert np.all(np.diff(t) > 0)
    mask, P = s.groundtruth_at_frames()
    assert mask.all()
    # consecutive frames move less than 5 cm / 3 deg
    rel = G.inverse(P[:-1]) @ P[1:]
    assert np.linalg.norm(rel[:, :3, 3], axis=1).max() < 0.05
    assert np.degrees(G.rotation_angle(rel[:, :3, :3])).max() < 3


def test_real_bonn_crowd():
    s = TumSequence(_real("rgbd_bonn_crowd"))
    assert len(s) == 160 and s.camera == BONN and s.is_bonn
    n = 0
    for t, f in s.prefetch(2):
        n += 1
        if n == 3:
            break
    assert f.shape == (480, 640)
    mask, P = s.groundtruth_at_frames()
    assert mask.all()
    # world frame y-up: camera about 1.46 m high, image "down" axis points down in the world,
    # viewing direction slightly downwards
    assert np.all(np.abs(P[:, 1, 3] - 1.46) < 0.1)
    down = P[:, :3, 1]
    forward = P[:, :3, 2]
    assert np.all(down[:, 1] < -0.9)
    assert np.all((forward[:, 1] < 0) & (forward[:, 1] > -0.5))


def test_real_bonn_relative_motion_matches_images():
    """Converted ground truth agrees with the motion the images show (ORB + depth + PnP on the
    first, people-free 0.8 s), clearly better than the unconverted marker poses."""
    s = TumSequence(_real("rgbd_bonn_crowd"))
    K = s.camera.K
    i, j = 10, 24
    (a, da), (b, _) = s.read_images(i), s.read_images(j)
    orb = cv2.ORB_create(3000)
    ka, fa = orb.detectAndCompute(cv2.cvtColor(a, cv2.COLOR_BGR2GRAY), None)
    kb, fb = orb.detectAndCompute(cv2.cvtColor(b, cv2.COLOR_BGR2GRAY), None)
    P3, p2 = [], []
    for m in cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(fa, fb):
        u, v = ka[m.queryIdx].pt
        z = da[int(round(v)), int(round(u))] / 5000.0
        if z > 0:
            P3.append([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z])
            p2.append(kb[m.trainIdx].pt)
    cv2.setRNGSeed(0)
    ok, rv, tv, inl = cv2.solvePnPRansac(np.array(P3), np.array(p2), K, None, reprojectionError=2.0,
                                         iterationsCount=2000)
    assert ok and len(inl) > 200
    T_img = np.eye(4)
    T_img[:3, :3], T_img[:3, 3] = cv2.Rodrigues(rv)[0], tv[:, 0]  # T_cur_ref from the images

    t, T_raw = read_pose_file(s.groundtruth_path)

    def err(T_world_cam):
        Pij = interpolate_poses(t, T_world_cam, s.timestamps[[i, j]])
        E = G.inverse(G.inverse(Pij[1]) @ Pij[0]) @ T_img
        return np.linalg.norm(E[:3, 3]), np.degrees(G.rotation_angle(E[:3, :3]))

    et, er = err(bonn_marker_to_camera(T_raw))
    et_raw, er_raw = err(T_raw)
    et_nom, er_nom = err(T_ROS @ T_raw @ T_ROS)
    assert er < 0.6 and et < 0.02
    assert er < er_raw / 3 and er < er_nom / 3


# ----------------------------------------------------------------------------- options and indexing

@pytest.mark.parametrize("kwargs, match", [
    ({"max_frames": "10"}, r"^open_sequence: max_frames must be an integer >= 1, or None \(all frames\), got '10'$"),
    ({"max_frames": 2.0}, r"max_frames must be an integer >= 1, or None \(all frames\), got 2\.0"),
    ({"max_frames": 0}, r"max_frames must be an integer >= 1"),
    ({"depth_scale": "5000"}, r"^open_sequence: depth_scale must be a number > 0, a sensor with a published depth "
                              r"correction \(bonn, default, fr1, fr2, fr3\), 'recorded' \(the layout's scale\) or None "
                              r"\(the folder's sensor's, else the layout's\), got '5000'$"),
    ({"depth_scale": -1.0}, r"depth_scale must be a number > 0"),
    ({"start": "2"}, r"^open_sequence: start must be an integer >= 0, got '2'$"),
    ({"start": 1.5}, r"start must be an integer >= 0, got 1\.5"),
    ({"start": True}, r"start must be an integer >= 0, got True"),
    ({"max_dt": "0.02"}, r"^open_sequence: max_dt must be a number > 0, got '0\.02'$"),
    ({"max_dt": [0.01, 0.02]}, r"max_dt must be a number > 0, got \[0\.01, 0\.02\]"),
    ({"max_dt": float("nan")}, r"max_dt must be a number > 0"),
    ({"bonn": "yes"}, r"bonn must be True or False, or None \(decided from the folder name\), got 'yes'"),
    ({"gt_slack": None}, r"gt_slack must be a number >= 0, got None"),
    ({"mask_dir": 3}, r"mask_dir must be a folder name \(str or os\.PathLike\) or None, got int"),
    ({"frames": 3}, r"unknown open_sequence field\(s\) 'frames' \(did you mean 'max_frames'\?\)"),
], ids=lambda v: str(v) if isinstance(v, dict) else "")
def test_wrong_option_types_name_the_option(tmp_path, kwargs, match):
    from jaxvo.data import open_sequence
    d = make_seq(tmp_path, n=2, gt=False)
    with pytest.raises(ValueError, match=match) as e:
        open_sequence(d, camera=SMALL, **kwargs)
    assert type(e.value) is ValueError and "\n" not in str(e.value)


@pytest.mark.parametrize("path", [3, 2.5, None, ["a"]])
def test_path_of_a_wrong_type(path):
    from jaxvo.data import open_sequence
    with pytest.raises(ValueError, match=r"^open_sequence: path must be a folder name \(str or os\.PathLike\), got "):
        open_sequence(path)


def test_redwood_fps_is_checked(tmp_path):
    from jaxvo.data import RedwoodSequence
    with pytest.raises(ValueError, match=r"^open_sequence: fps must be a number > 0, got '30'$"):
        RedwoodSequence(tmp_path, fps="30")


def test_slice_is_a_sequence_of_those_frames(tmp_path):
    d = make_seq(tmp_path, n=6)
    s = TumSequence(d, camera=SMALL, start=1)
    v = s[1:4]
    assert isinstance(v, TumSequence) and len(v) == 3 and v.start == 2 and len(s) == 5
    assert np.array_equal(v.timestamps, s.timestamps[1:4])
    assert [t for t, _ in v] == list(s.timestamps[1:4])
    assert np.array_equal(v[0].depth, s[1].depth) and np.array_equal(v.frame(-1).depth, s.frame(3).depth)
    assert v.camera == s.camera and v.groundtruth is not None
    # as the reader opened with those options: the same frames (what run_sequence records)
    again = TumSequence(d, camera=SMALL, start=v.start, max_frames=len(v))
    assert np.array_equal(again.timestamps, v.timestamps) and again.rgb_paths == v.rgb_paths
    assert len(s[-2:]) == 2 and s[-2:].start == 4 and len(s[:]) == 5 and len(s[3:100]) == 2
    assert len(v[1:]) == 2 and v[1:].start == 3


@pytest.mark.parametrize("index, match", [
    (slice(0, 4, 2), r"consecutive frames \(step 1\), got step 2; for every k-th frame use "
                     r"\[seq\.frame\(i\) for i in range\(0, 4, 2\)\]"),
    (slice(3, 3), r"sequence slice \[3:3\] holds no frame \(the sequence has 5\)"),
    (slice(9, None), r"holds no frame"),
    (slice(0.5, 2), r"slice bounds must be integers or None, got float"),
    (1.0, r"sequence index must be an integer or a slice a:b, got float"),
    ("0", r"got str"),
])
def test_bad_index_says_how(tmp_path, index, match):
    s = TumSequence(make_seq(tmp_path, n=5), camera=SMALL)
    with pytest.raises(ValueError, match=match):
        s[index]


def test_parse_depth_scale_reads_a_number_or_a_sensor():
    """--depth-scale's text (the CLI and experiments/table1.py): a positive number as a float, a
    sensor with a published correction as its name, anything else one ValueError naming it."""
    from jaxvo.data.calibration import parse_depth_scale
    assert parse_depth_scale("5155") == 5155.0 and parse_depth_scale(" fr2 ") == "fr2"
    assert parse_depth_scale("recorded") == "recorded"
    for bad in ("fr9", "-5", "0", "inf", "nan"):
        with pytest.raises(ValueError, match=f"got '{bad}'"):
            parse_depth_scale(bad)
