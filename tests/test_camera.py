"""Tests of jaxvo.camera: pyramid scaling convention, projection round trip, presets."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxvo import camera as C
from jaxvo.camera import BONN, DEFAULT, TUM_FR1, TUM_FR2, TUM_FR3, Camera, backproject, camera_for_sequence, project


def _project_np(cam, P):
    P = np.asarray(P, np.float64)
    return (float(cam.fx) * P[..., 0] / P[..., 2] + float(cam.cx),
            float(cam.fy) * P[..., 1] / P[..., 2] + float(cam.cy))


def test_at_level_formula_and_sizes():
    cam = TUM_FR2
    for level in range(4):
        c = cam.at_level(level)
        s = 2.0 ** level
        assert c.fx == pytest.approx(cam.fx / s) and c.fy == pytest.approx(cam.fy / s)
        assert c.cx == pytest.approx((cam.cx + 0.5) / s - 0.5)
        assert c.cy == pytest.approx((cam.cy + 0.5) / s - 0.5)
        assert (c.width, c.height) == (640 // 2 ** level, 480 // 2 ** level)
    c2 = DEFAULT.at_level(2)
    assert (c2.fx, c2.cx, c2.cy, c2.width, c2.height) == (131.25, 79.5, 59.5, 160, 120)
    # levels compose: level 1 of level 1 is level 2
    cc = cam.at_level(1).at_level(1)
    c2 = cam.at_level(2)
    for a in ("fx", "fy", "cx", "cy", "width", "height"):
        assert getattr(cc, a) == pytest.approx(getattr(c2, a))


@pytest.mark.parametrize("cam", [DEFAULT, TUM_FR1, BONN])
def test_projection_follows_2x2_block_mean_convention(cam):
    rng = np.random.default_rng(0)
    P = np.column_stack([rng.uniform(-1, 1, 50), rng.uniform(-1, 1, 50), rng.uniform(0.5, 4, 50)])
    u0, v0 = _project_np(cam, P)
    for level in (1, 2, 3):
        ul, vl = _project_np(cam.at_level(level), P)
        s = 2 ** level
        np.testing.assert_allclose((u0 + 0.5) / s - 0.5, ul, atol=1e-9)
        np.testing.assert_allclose((v0 + 0.5) / s - 0.5, vl, atol=1e-9)
    # level-1 pixel (i, j) is the mean of level-0 pixels 2i, 2i+1 (and 2j, 2j+1): its centre
    # back-projected and re-projected at level 0 lands at 2i + 0.5
    c1 = cam.at_level(1)
    i = np.arange(5.0)
    Q = np.asarray(backproject(c1, jnp.asarray(i), jnp.asarray(i + 3), jnp.full(5, 2.0)))
    u, v = _project_np(cam, Q)
    np.testing.assert_allclose(u, 2 * i + 0.5, atol=1e-4)
    np.testing.assert_allclose(v, 2 * (i + 3) + 0.5, atol=1e-4)


def test_block_mean_of_a_ramp_matches_level_intrinsics():
    """A level-0 image equal to u (its column coordinate) averaged over 2x2 blocks
    equals the level-0 coordinate of each level-1 pixel centre."""
    cam = DEFAULT.at_level(2)  # 160 x 120
    img = np.tile(np.arange(cam.width, dtype=np.float64), (cam.height, 1))
    half = img.reshape(cam.height // 2, 2, cam.width // 2, 2).mean(axis=(1, 3))
    c1 = cam.at_level(1)
    # a level-1 pixel at column j sees the ray with level-0 column u0 = f0/f1 * (j - c1x) + c0x
    j = np.arange(c1.width)
    u0 = cam.fx / c1.fx * (j - c1.cx) + cam.cx
    np.testing.assert_allclose(half[0], u0, atol=1e-12)


def test_backproject_project_round_trip():
    cam = TUM_FR3
    rng = np.random.default_rng(1)
    u = jnp.asarray(rng.uniform(0, 639, 100), jnp.float32)
    v = jnp.asarray(rng.uniform(0, 479, 100), jnp.float32)
    z = jnp.asarray(rng.uniform(0.3, 5.0, 100), jnp.float32)
    P = backproject(cam, u, v, z)
    assert P.shape == (100, 3)
    np.testing.assert_allclose(np.asarray(P[:, 2]), np.asarray(z))
    u2, v2, z2, front = project(cam, P)
    assert np.all(np.asarray(front))
    np.testing.assert_allclose(np.asarray(u2), np.asarray(u), atol=2e-3)
    np.testing.assert_allclose(np.asarray(v2), np.asarray(v), atol=2e-3)
    np.testing.assert_allclose(np.asarray(z2), np.asarray(z))
    # explicit numbers: the principal point back-projects onto the optical axis
    P0 = np.asarray(backproject(cam, jnp.float32(cam.cx), jnp.float32(cam.cy), jnp.float32(2.0)))
    np.testing.assert_allclose(P0, [0, 0, 2.0], atol=1e-5)
    Px = np.asarray(backproject(cam, jnp.float32(cam.cx + cam.fx), jnp.float32(cam.cy), jnp.float32(2.0)))
    np.testing.assert_allclose(Px, [2.0, 0, 2.0], atol=1e-5)


def test_project_behind_camera_is_flagged():
    P = jnp.asarray([[0.1, 0.2, 1.0], [0.1, 0.2, 0.0], [0.1, 0.2, -1.0]])
    u, v, z, front = project(DEFAULT, P)
    np.testing.assert_array_equal(np.asarray(front), [True, False, False])
    assert np.all(np.asarray(u)[1:] < -1e5) and np.all(np.asarray(v)[1:] < -1e5)
    np.testing.assert_allclose(np.asarray(u)[0], 525 * 0.1 + 319.5, rtol=1e-6)


def test_presets_numbers():
    assert (TUM_FR1.fx, TUM_FR1.fy, TUM_FR1.cx, TUM_FR1.cy) == (517.3, 516.5, 318.6, 255.3)
    assert (TUM_FR2.fx, TUM_FR2.fy, TUM_FR2.cx, TUM_FR2.cy) == (520.9, 521.0, 325.1, 249.7)
    assert (TUM_FR3.fx, TUM_FR3.fy, TUM_FR3.cx, TUM_FR3.cy) == (535.4, 539.2, 320.1, 247.6)
    assert (DEFAULT.fx, DEFAULT.fy, DEFAULT.cx, DEFAULT.cy) == (525.0, 525.0, 319.5, 239.5)
    assert BONN.fx == pytest.approx(542.822841) and BONN.fy == pytest.approx(542.576870)
    assert BONN.cx == pytest.approx(315.593520) and BONN.cy == pytest.approx(237.756098)
    for cam in (TUM_FR1, TUM_FR2, TUM_FR3, BONN, DEFAULT):
        assert (cam.width, cam.height) == (640, 480)
    assert C.PRESETS["fr2"] is TUM_FR2 and C.PRESETS["bonn"] is BONN and C.PRESETS["default"] is DEFAULT
    np.testing.assert_allclose(TUM_FR2.K, [[520.9, 0, 325.1], [0, 521.0, 249.7], [0, 0, 1]])


@pytest.mark.parametrize("name,expected", [
    ("rgbd_dataset_freiburg1_xyz", TUM_FR1),
    ("rgbd_dataset_freiburg1_desk", TUM_FR1),
    ("rgbd_dataset_freiburg2_desk", TUM_FR2),
    ("rgbd_dataset_freiburg2_pioneer_360", TUM_FR2),
    ("rgbd_dataset_freiburg3_walking_xyz", TUM_FR3),
    ("rgbd_dataset_freiburg3_sitting_static", TUM_FR3),
    ("rgbd_bonn_crowd", BONN),
    ("rgbd_bonn_person_tracking2", BONN),
    ("RGBD_BONN_BALLOON", BONN),
    ("my_own_sequence", DEFAULT),
])
def test_camera_for_sequence(name, expected):
    assert camera_for_sequence(name) is expected


def test_camera_is_a_pytree_with_static_size():
    leaves, treedef = jax.tree_util.tree_flatten(DEFAULT)
    assert len(leaves) == 4
    cam = jax.tree_util.tree_unflatten(treedef, leaves)
    assert (cam.width, cam.height) == (640, 480)

    @jax.jit
    def f(cam, x):
        return backproject(cam.at_level(1), x, x, x)[..., 0] + cam.width

    out = f(DEFAULT, jnp.float32(2.0))
    expected = (2.0 - ((319.5 + 0.5) / 2 - 0.5)) / (525.0 / 2) * 2.0 + 640
    np.testing.assert_allclose(float(out), expected, rtol=1e-6)
    # vmap over a focal length
    fxs = jnp.asarray([500.0, 525.0, 550.0])
    cams = Camera(fxs, 525.0, 319.5, 239.5)
    u = jax.vmap(lambda c: project(c, jnp.asarray([[0.1, 0.0, 1.0]]))[0][0],
                 in_axes=(Camera(0, None, None, None),))(cams)
    np.testing.assert_allclose(np.asarray(u), np.asarray(fxs) * 0.1 + 319.5, rtol=1e-6)


# ----------------------------------------------------------------------------- lens distortion

@pytest.mark.parametrize("name", ["fr1", "fr2", "bonn"])
def test_lens_distorts_as_opencv_projects_and_maps_as_opencv_undistorts(name):
    """Lens.distort against cv2.projectPoints (the same model, OpenCV's own code), and
    undistortion_map against cv2.initUndistortRectifyMap with newCameraMatrix = K."""
    import cv2

    cam, lens = C.PRESETS[name], C.LENSES[name]
    rng = np.random.default_rng(0)
    P = np.column_stack([rng.uniform(-1.2, 1.2, 50), rng.uniform(-0.9, 0.9, 50), rng.uniform(1.5, 3.0, 50)])
    uv, _ = cv2.projectPoints(P, np.zeros(3), np.zeros(3), cam.K, np.array(lens))
    xd, yd = lens.distort(P[:, 0] / P[:, 2], P[:, 1] / P[:, 2])
    np.testing.assert_allclose(np.column_stack([cam.fx * xd + cam.cx, cam.fy * yd + cam.cy]), uv[:, 0], atol=1e-6)
    m1, m2 = cv2.initUndistortRectifyMap(cam.K, np.array(lens), None, cam.K, (cam.width, cam.height), cv2.CV_32FC1)
    u, v = C.undistortion_map(cam, lens)
    np.testing.assert_allclose(u, m1, atol=1e-3)
    np.testing.assert_allclose(v, m2, atol=1e-3)


def test_undistort_puts_a_distorted_point_at_its_pinhole_pixel():
    """A depth reading where the fr2 lens images a point (near the corner: over 10 px from where a pinhole
    would) lands, after undistort, at the point's pinhole projection; intensity and mask follow."""
    from jaxvo.frame import Frame, undistort

    cam, lens = TUM_FR2, C.LENSES["fr2"]
    P = np.array([-1.1, -0.85, 2.0])
    u0, v0 = _project_np(cam, P)
    xd, yd = lens.distort(P[0] / P[2], P[1] / P[2])
    ud, vd = cam.fx * xd + cam.cx, cam.fy * yd + cam.cy
    assert np.hypot(ud - u0, vd - v0) > 10
    depth = np.zeros((cam.height, cam.width), np.float32)
    intensity = np.zeros_like(depth)
    mask = np.zeros(depth.shape, bool)
    r, c = int(round(vd)), int(round(ud))
    depth[r - 2:r + 3, c - 2:c + 3] = 2.0
    intensity[r - 2:r + 3, c - 2:c + 3] = 200.0
    mask[r - 2:r + 3, c - 2:c + 3] = True
    out = undistort(Frame(intensity, depth, mask), cam, lens)
    rows, cols = np.nonzero(out.depth)
    assert abs(rows.mean() - v0) < 1.0 and abs(cols.mean() - u0) < 1.0
    assert set(np.unique(out.depth)) == {0.0, 2.0}          # nearest: never a blend of depths
    np.testing.assert_array_equal(out.mask, out.depth > 0)
    assert out.intensity[int(round(v0)), int(round(u0))] == pytest.approx(200.0, abs=1.0)
    frame = Frame(intensity, depth)
    assert undistort(frame, cam, C.NO_LENS) is frame         # a pinhole lens: the frame itself
    # every pixel reads the nearest one (rounded, not floored: depth stays on the intensity's grid)
    import cv2
    rng = np.random.default_rng(1)
    noisy = Frame(rng.uniform(0, 255, depth.shape).astype(np.float32), rng.uniform(0.5, 4, depth.shape).astype(np.float32))
    m1, m2 = cv2.initUndistortRectifyMap(cam.K, np.array(lens), None, cam.K, (cam.width, cam.height), cv2.CV_32FC1)
    np.testing.assert_array_equal(undistort(noisy, cam, lens).depth, cv2.remap(noisy.depth, m1, m2, cv2.INTER_NEAREST))
    np.testing.assert_allclose(undistort(noisy, cam, lens).intensity,
                               cv2.remap(noisy.intensity, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE),
                               atol=1e-3)


def test_lens_presets_and_parse():
    assert C.lens_for_sequence("rgbd_dataset_freiburg2_desk") == C.LENSES["fr2"]
    assert C.lens_for_sequence("rgbd_dataset_freiburg3_walking_xyz").is_pinhole
    assert C.lens_for_sequence("rgbd_bonn_crowd") == C.LENSES["bonn"]
    assert C.lens_for_sequence("my_room").is_pinhole
    assert C.Lens.parse("fr1") == C.LENSES["fr1"] and C.Lens.parse("none") == C.NO_LENS
    assert C.Lens.parse("0.1,-0.2,0,0,0.05") == C.Lens(0.1, -0.2, 0.0, 0.0, 0.05)
    assert C.Lens.parse([0.1, -0.2, 0, 0, 0.05]) == C.Lens(0.1, -0.2, 0.0, 0.0, 0.05)
    for bad in ("0.1,0.2", "a,b,c,d,e", "fr9", [0, 0, 0, 0, float("nan")], 3):
        with pytest.raises(ValueError, match="lens must be 5 finite numbers"):
            C.Lens.parse(bad)
