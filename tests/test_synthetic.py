"""Tests of jaxvo.synthetic: exact geometry of renders, masks, determinism, augmentation."""
from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from jaxvo import geometry
from jaxvo.camera import DEFAULT
from jaxvo.synthetic import (Box, FixedPose, Rect, Scene, SensorModel, Walk, augment, generate, make_object,
                             make_person, make_room, make_sequence, render)
from jaxvo.synthetic.motions import rot_x, rot_y
from jaxvo.synthetic.scene import ROOM_BOUNDS

CAM = DEFAULT.at_level(2)          # 160 x 120
CAM1 = DEFAULT.at_level(1)         # 320 x 240
TUM_DESK = Path("/work/shared/data/tum/rgbd_dataset_freiburg2_desk")


def _T(R=np.eye(3), t=(0, 0, 0)):
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def _rays_world(cam, T_world_cam):
    """Independent float64 rays: origin (3,), directions (H, W, 3) with unit camera-z component."""
    v, u = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
    d = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], -1)
    return T_world_cam[:3, 3], d @ T_world_cam[:3, :3].T


@pytest.fixture(scope="module")
def room():
    return make_room(seed=0)


def test_room_depth_matches_plane_intersections(room):
    # camera inside the room, rotated; every pixel whose nearest hit is the room box must have the depth
    # of the nearest exit through the six wall planes, computed here by hand in float64.
    T = _T(rot_y(0.4) @ rot_x(-0.2), (0.1, -0.1, 0.2))
    r = render(room, CAM, T)
    o, d = _rays_world(CAM, T)
    ts = []
    for k in range(3):
        for bound in ROOM_BOUNDS[k]:
            with np.errstate(divide="ignore"):
                t = (bound - o[k]) / d[..., k]
            ts.append(np.where(t > 0, t, np.inf))
    t_wall = np.min(ts, axis=0)     # t along d (unit camera z) == depth
    wall = r.object_id == 0
    assert wall.mean() > 0.3
    np.testing.assert_allclose(r.depth[wall], t_wall[wall], rtol=2e-6, atol=2e-6)
    # everything else is nearer than the wall behind it
    assert np.all(r.depth[~wall] <= t_wall[~wall] + 1e-5)
    assert r.depth.dtype == np.float32 and r.rgb.dtype == np.uint8 and r.rgb.shape == (120, 160, 3)


def test_plane_and_box_depth_and_ids():
    rng = np.random.default_rng(1)
    n = np.array([0.2, -0.1, -1.0])
    n /= np.linalg.norm(n)
    # a tilted rectangle at 3 m (big enough to fill the view) and a box in front of it
    R_plane = geometry.exp_so3(np.array([0.1, -0.2, 0.05]))
    plane = make_object(rng, Rect(3.0, 3.0), _T(R_plane, (0.2, 0.1, 3.0)))
    box = make_object(rng, Box((0.3, 0.2, 0.25)), _T(rot_y(0.5), (-0.3, 0.1, 1.5)))
    scene = Scene([plane, box])
    T = _T(rot_x(0.05), (0.0, 0.05, 0.0))
    r = render(scene, CAM, T)
    o, d = _rays_world(CAM, T)
    nrm, p0 = R_plane[:, 2], np.array([0.2, 0.1, 3.0])
    t_plane = ((p0 - o) @ nrm) / (d @ nrm)
    # box: slab test in the box frame
    Tb = geometry.inverse(box.pose)
    ol = Tb[:3, :3] @ o + Tb[:3, 3]
    dl = d @ Tb[:3, :3].T
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-np.array([0.3, 0.2, 0.25]) - ol) / dl
        t2 = (np.array([0.3, 0.2, 0.25]) - ol) / dl
    tn = np.max(np.minimum(t1, t2), -1)
    tf = np.min(np.maximum(t1, t2), -1)
    hit_box = (tn <= tf) & (tn > 0)
    # ids agree except possibly on a handful of silhouette pixels (float32 vs float64)
    assert np.mean((r.object_id == 1) != hit_box) < 0.002
    assert hit_box.sum() > 200
    on_plane = (r.object_id == 0) & ~hit_box
    np.testing.assert_allclose(r.depth[on_plane], t_plane[on_plane], rtol=2e-6, atol=2e-6)
    inside = (r.object_id == 1) & hit_box
    np.testing.assert_allclose(r.depth[inside], tn[inside], rtol=2e-6, atol=2e-6)
    assert not r.moving_mask.any()


def _bilinear(img, u, v):
    return cv2.remap(img.astype(np.float32), u.astype(np.float32), v.astype(np.float32), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


def test_two_views_are_photometrically_consistent(room):
    # back-project view A with its depth, move the 3-D points with the true T_B_A, and compare intensities
    TA = _T(rot_y(0.05) @ rot_x(-0.1), (0.0, 0.0, 0.0))
    TB = TA @ _T(geometry.exp_so3(np.array([0.01, -0.03, 0.02])), (0.04, -0.02, 0.03))
    a = render(room, CAM1, TA)
    b = render(room, CAM1, TB)
    v, u = np.mgrid[0:CAM1.height, 0:CAM1.width].astype(np.float64)
    z = a.depth.astype(np.float64)
    P_a = np.stack([(u - CAM1.cx) / CAM1.fx * z, (v - CAM1.cy) / CAM1.fy * z, z], -1)
    T_b_a = geometry.inverse(TB) @ TA
    P_b = P_a @ T_b_a[:3, :3].T + T_b_a[:3, 3]
    ub = CAM1.fx * P_b[..., 0] / P_b[..., 2] + CAM1.cx
    vb = CAM1.fy * P_b[..., 1] / P_b[..., 2] + CAM1.cy
    inside = (ub > 1) & (ub < CAM1.width - 2) & (vb > 1) & (vb < CAM1.height - 2)
    zb = _bilinear(b.depth, ub, vb)
    # visible in B (not occluded) and away from depth discontinuities in both views
    edge_a = cv2.dilate((np.abs(cv2.Laplacian(a.depth, cv2.CV_32F)) > 0.02).astype(np.uint8), np.ones((5, 5)))
    ok = inside & (np.abs(zb - P_b[..., 2]) < 0.005 * P_b[..., 2]) & (edge_a == 0)
    assert ok.mean() > 0.5
    ib = _bilinear(b.intensity, ub, vb)
    err = np.abs(ib - a.intensity)[ok]
    assert np.median(err) < 2.0, np.median(err)
    assert np.percentile(err, 90) < 8.0, np.percentile(err, 90)
    # a wrong pose is clearly worse (the texture has something to lock on to)
    T_wrong = T_b_a @ _T(t=(0.02, 0.0, 0.0))
    P_w = P_a @ T_wrong[:3, :3].T + T_wrong[:3, 3]
    uw = CAM1.fx * P_w[..., 0] / P_w[..., 2] + CAM1.cx
    vw = CAM1.fy * P_w[..., 1] / P_w[..., 2] + CAM1.cy
    err_w = np.abs(_bilinear(b.intensity, uw, vw) - a.intensity)[ok]
    assert np.median(err_w) > 3 * np.median(err)


def test_moving_mask_is_exactly_the_person():
    scene = make_room(seed=2)
    rng = np.random.default_rng(5)
    centre = np.array([0.3, 0.2, 1.2])
    pid = scene.add(make_person(rng, FixedPose(_T(rot_y(0.3), centre)), kind="box", width=0.5, height=1.7))
    r = render(scene, CAM, np.eye(4), t=0.0)
    assert np.array_equal(r.moving_mask, r.object_id == pid)
    # independent slab test for the person box (nothing is between the camera and the person at 1.2 m)
    o, d = _rays_world(CAM, np.eye(4))
    R = rot_y(0.3)
    ol = R.T @ (o - centre)
    dl = d @ R
    h = np.array([0.25, 0.85, 0.15])
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (-h - ol) / dl, (h - ol) / dl
    tn, tf = np.max(np.minimum(t1, t2), -1), np.min(np.maximum(t1, t2), -1)
    hit = (tn <= tf) & (tn > 0)
    assert hit.sum() > 1000
    assert np.sum(hit != r.moving_mask) <= 3
    np.testing.assert_allclose(r.depth[hit & r.moving_mask], tn[hit & r.moving_mask], rtol=2e-6, atol=2e-6)
    # moving persons move: another time, another mask; the static background is unchanged where uncovered
    seq = make_sequence("seq1", frames=31, seed=0, camera=CAM)
    r0, r1 = seq.render(0), seq.render(30)
    assert r0.moving_mask.any() and r1.moving_mask.any()
    assert not np.array_equal(r0.moving_mask, r1.moving_mask)
    both_static = ~r0.moving_mask & ~r1.moving_mask
    assert np.array_equal(r0.rgb[both_static], r1.rgb[both_static])   # fixed camera


def test_sequences_motion():
    seq2 = make_sequence("seq2", frames=31, seed=0, camera=CAM)
    rates = [math.degrees(geometry.rotation_angle(seq2.relative_pose(k)[:3, :3])) * 30 for k in range(30)]
    np.testing.assert_allclose(rates, 2.0, rtol=1e-6)
    assert np.allclose(seq2.relative_pose(0)[:3, 3], 0, atol=1e-12)
    assert len(make_sequence("seq3", frames=2, camera=CAM).persons) == 2
    seq0 = make_sequence("seq0", frames=60, seed=3, camera=CAM)
    assert not seq0.persons
    steps = [np.linalg.norm(seq0.relative_pose(k)[:3, 3]) for k in range(59)]
    assert 0.002 < np.mean(steps) < 0.05
    fast = make_sequence("handheld-fast", frames=90, seed=0, camera=CAM)
    cov = [fast.render(k).moving_mask.mean() for k in range(0, 90, 10)]
    assert max(cov) > 0.4
    with pytest.raises(ValueError):
        make_sequence("seq9")


def test_walk_dwell_stands_at_each_end_then_walks_from_rest_to_rest():
    """Walk(dwell=0.25, period=8 s): at a for t in [0, 2), walking for [2, 4), at b for [4, 6),
    back for [6, 8): each walk the half cosine from rest to rest, halfway at its middle; dwell 0 is
    the plain cosine."""
    a, b = (-1.0, 0.0, 2.0), (1.0, 0.0, 1.0)
    walk = Walk(a, b, period=8.0, dwell=0.25, sway=0.0)
    x = {t: walk.pose(t)[:3, 3] for t in (0.0, 1.0, 1.99, 3.0, 4.0, 5.5, 7.0, 8.0, 9.0)}
    for t in (0.0, 1.0, 1.99, 8.0, 9.0):
        np.testing.assert_allclose(x[t], a, atol=1e-12)
    for t in (4.0, 5.5):
        np.testing.assert_allclose(x[t], b, atol=1e-12)
    for t in (3.0, 7.0):   # the middle of each walk: (1 - cos(pi / 2)) / 2 = 1 / 2 of the way
        np.testing.assert_allclose(x[t], 0.5 * (np.asarray(a) + np.asarray(b)), atol=1e-12)
    # from rest: a 10 ms step just after the stand moves the body under a millimetre, one in the
    # middle of the walk about 10 ms x pi |b - a| / 4 s
    step = lambda t: np.linalg.norm(walk.pose(t + 0.01)[:3, 3] - walk.pose(t)[:3, 3])
    assert step(2.0) < 1e-3 and step(2.99) == pytest.approx(0.01 * math.pi * math.sqrt(5) / 4, rel=1e-3)
    with pytest.raises(ValueError, match="dwell"):
        Walk(a, b, dwell=0.5)
    plain = Walk(a, b, period=8.0, phase=0.3)
    for t in (0.0, 1.7, 5.2):
        s = 0.5 * (1 - math.cos(2 * math.pi * t / 8.0 + 0.3))
        np.testing.assert_allclose(plain.pose(t)[:3, 3], np.asarray(a) + s * (np.asarray(b) - np.asarray(a)),
                                   atol=1e-12)


def test_crowd_close_persons_stand_in_view_and_cover_much_of_it():
    """crowd-close: each person stands still for a good part of the run, and together they cover
    more than half of some frames; the camera moves as in crowd (the same hand-held sweep)."""
    close = make_sequence("crowd-close", frames=900, seed=1, camera=CAM)
    crowd = make_sequence("crowd", frames=900, seed=1, camera=CAM)
    np.testing.assert_array_equal(close.poses, crowd.poses)
    for p in close.persons:
        pos = np.array([p.pose(t)[:3, 3] for t in close.timestamps])
        still = np.linalg.norm(np.diff(pos, axis=0), axis=1) * 30 < 0.05    # under 5 cm/s
        assert 0.25 < still.mean() < 0.7
    cov = [close.render(k).moving_mask.mean() for k in range(0, 900, 30)]
    assert max(cov) > 0.5


def test_sensor_model():
    seq = make_sequence("seq0", frames=1, seed=0, camera=CAM)
    ideal = seq.render(0)
    a = seq.render(0, sensor=SensorModel(max_range=2.5), rng=np.random.default_rng(1))
    b = seq.render(0, sensor=SensorModel(max_range=2.5), rng=np.random.default_rng(1))
    assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.depth, b.depth)
    assert not np.array_equal(a.rgb, ideal.rgb)
    assert np.all(a.depth[ideal.depth > 2.6] == 0)
    v = a.depth > 0
    assert v.mean() > 0.2
    np.testing.assert_allclose(a.depth[v] * 5000, np.rint(a.depth[v] * 5000), atol=2e-3)
    assert np.abs(a.depth[v] - ideal.depth[v]).max() < 0.05


def _tree(d: Path):
    return {p.relative_to(d).as_posix(): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


def test_generate_is_bitwise_deterministic(tmp_path):
    kw = dict(frames=3, seed=7, camera=CAM, sensor=SensorModel())
    calls = []
    a = generate("seq1", tmp_path / "a", progress=lambda i, n: calls.append((i, n)), **kw)
    b = generate("seq1", tmp_path / "b", **kw)
    c = generate("seq1", tmp_path / "c", **{**kw, "seed": 8})
    ta, tb, tc = _tree(a), _tree(b), _tree(c)
    assert calls == [(1, 3), (2, 3), (3, 3)]
    assert ta == tb
    assert ta.keys() == tc.keys() and ta != tc
    assert len([k for k in ta if k.startswith("rgb/")]) == 3
    for sub in ("rgb", "depth", "masks"):
        assert (a / f"{sub}.txt").read_text().startswith("# ")
    depth = cv2.imread(str(a / "depth" / "0.000000.png"), cv2.IMREAD_UNCHANGED)
    assert depth.dtype == np.uint16 and depth.shape == (120, 160)
    mask = cv2.imread(str(a / "masks" / "0.033333.png"), cv2.IMREAD_UNCHANGED)
    assert set(np.unique(mask)) <= {0, 255} and mask.max() == 255
    # ground truth: T_world_cam, parses back to the sequence poses
    gt = np.loadtxt(a / "groundtruth.txt")
    seq = make_sequence("seq1", frames=3, seed=7, camera=CAM)
    T = geometry.transform_from_quat_trans(gt[:, 4:8], gt[:, 1:4])
    np.testing.assert_allclose(T, seq.poses, atol=1e-8)
    rgb = cv2.imread(str(a / "rgb" / "0.000000.png"))[..., ::-1]
    r = seq.render(0, sensor=SensorModel(), rng=np.random.default_rng(np.random.SeedSequence([7, 0, 0x5E50])))
    assert np.array_equal(rgb, r.rgb)


def test_augment_keeps_groundtruth_and_masks_changed_pixels(tmp_path):
    if not TUM_DESK.is_dir():
        pytest.skip(f"real TUM data not found: {TUM_DESK}")
    out = augment(TUM_DESK, tmp_path / "aug", persons=2, coverage=0.3, seed=0, max_frames=3)
    assert (out / "groundtruth.txt").read_bytes() == (TUM_DESK / "groundtruth.txt").read_bytes()
    lines = lambda p: [l.split() for l in p.read_text().splitlines() if not l.startswith("#")]
    rgb_list, dep_list, mask_list = lines(out / "rgb.txt"), lines(out / "depth.txt"), lines(out / "masks.txt")
    assert len(rgb_list) == len(dep_list) == len(mask_list) == 3
    covs = []
    for (ts, rgb_name), (dts, dep_name), (mts, mask_name) in zip(rgb_list, dep_list, mask_list):
        assert mts == ts and abs(float(dts) - float(ts)) <= 0.02
        real_rgb = cv2.imread(str(TUM_DESK / rgb_name), cv2.IMREAD_UNCHANGED)
        new_rgb = cv2.imread(str(out / rgb_name), cv2.IMREAD_UNCHANGED)
        real_d = cv2.imread(str(TUM_DESK / dep_name), cv2.IMREAD_UNCHANGED)
        new_d = cv2.imread(str(out / dep_name), cv2.IMREAD_UNCHANGED)
        mask = cv2.imread(str(out / mask_name), cv2.IMREAD_UNCHANGED)
        assert new_d.dtype == np.uint16 and set(np.unique(mask)) <= {0, 255}
        changed = np.any(new_rgb != real_rgb, -1) | (new_d != real_d)
        assert np.array_equal(mask == 255, changed)
        # z-test: composited depth is nearer than the real one (or the real one was missing)
        m = mask == 255
        assert np.all((new_d[m] < real_d[m]) | (real_d[m] == 0)) and np.all(new_d[m] > 0)
        covs.append(m.mean())
    assert 0.1 < np.mean(covs) < 0.5


def test_augment_leaves_out_frames_before_the_ground_truth(tmp_path):
    """fr3_long_office starts recording 0.07 s before its motion capture: those frames have no
    pose to place a person at, so the augmentation starts at the first covered frame and
    max_frames still counts the frames written."""
    fr3 = TUM_DESK.parent / "rgbd_dataset_freiburg3_long_office_household"
    if not fr3.is_dir():
        pytest.skip(f"real TUM data not found: {fr3}")
    out = augment(fr3, tmp_path / "aug", persons=2, coverage=0.3, seed=0, max_frames=3)
    rows = lambda p: [l.split() for l in p.read_text().splitlines() if l.strip() and not l.startswith("#")]
    stamps = [float(r[0]) for r in rows(out / "rgb.txt")]
    gt_start = min(float(r[0]) for r in rows(fr3 / "groundtruth.txt"))
    first_real = float(rows(fr3 / "rgb.txt")[0][0])
    assert len(stamps) == 3 and stamps[0] >= gt_start - 0.02 > first_real
    info = json.loads((out / "info.json").read_text())
    assert info["frames"] == 3 and info["frames_outside_groundtruth"] == 2
    masks = [out / r[1] for r in rows(out / "masks.txt")]
    assert len(masks) == 3 and all(cv2.imread(str(m), cv2.IMREAD_UNCHANGED).any() for m in masks)


def test_augment_at_the_depth_time_moves_only_the_persons_of_the_depth(tmp_path):
    """depth_time=True: the colour, the masks and the real depth stay those of the plain
    augmentation; the persons of each depth image are rendered where the camera was at the
    depth's own timestamp, a few millimetres of camera motion away (fr2/desk moves ~8 mm a frame)."""
    if not TUM_DESK.is_dir():
        pytest.skip(f"real TUM data not found: {TUM_DESK}")
    plain = augment(TUM_DESK, tmp_path / "plain", persons=2, coverage=0.3, seed=0, max_frames=3)
    timed = augment(TUM_DESK, tmp_path / "timed", persons=2, coverage=0.3, seed=0, max_frames=3, depth_time=True)
    lines = lambda p: [l.split() for l in p.read_text().splitlines() if not l.startswith("#")]
    assert json.loads((timed / "info.json").read_text())["depth_time"] is True
    assert "depth_time" not in json.loads((plain / "info.json").read_text())
    moved = 0
    for (ts, rgb_name), (dts, dep_name), (_, mask_name) in zip(lines(plain / "rgb.txt"), lines(plain / "depth.txt"),
                                                               lines(plain / "masks.txt")):
        read = lambda folder, name: cv2.imread(str(folder / name), cv2.IMREAD_UNCHANGED)  # noqa: E731
        assert np.array_equal(read(plain, rgb_name), read(timed, rgb_name))
        assert np.array_equal(read(plain, mask_name), read(timed, mask_name))
        real_d, d0, d1 = read(TUM_DESK, dep_name), read(plain, dep_name), read(timed, dep_name)
        # every pixel is the real depth or a person's, nearer than the real one
        person = d1 != real_d
        assert np.all((d1[person] < real_d[person]) | (real_d[person] == 0)) and np.all(d1[person] > 0)
        moved += int(np.count_nonzero(d0 != d1))
    assert moved > 0
