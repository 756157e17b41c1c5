"""The estimator end to end on synthetic pairs with exact ground truth.

Pairs are rendered at 640x480 by jaxvo.synthetic (exact ray casting, exact
depth): a static room, and the same room with a textured person-sized box
covering about 30 % of the image that moves 15 cm sideways between the frames
while the camera moves a few cm and degrees.
"""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxvo
from jaxvo import geometry
from jaxvo.camera import DEFAULT
from jaxvo.frame import Frame
from jaxvo.config import Config
from jaxvo.estimator import estimate_motion, trace_count
from jaxvo.synthetic import make_person, make_room, render
from jaxvo.synthetic.motions import _T, rot_y

CAM = DEFAULT
# T_cur_ref of every pair: 1.5/-2/1 deg and 2/-1/3 cm
MOTION = geometry.exp(np.array([np.radians(1.5), np.radians(-2.0), np.radians(1.0), 0.02, -0.01, 0.03]))


@dataclasses.dataclass(frozen=True)
class _Slide:
    """A body sliding along x at `speed` m/s (frames are rendered at t = 0 and t = 1)."""
    speed: float

    def pose(self, t):
        return _T(rot_y(0.3), (-0.2 + self.speed * t, 0.0, 1.4))


def _pair(dynamic: bool):
    scene = make_room(0)
    if dynamic:
        scene.add(make_person(np.random.default_rng(1), _Slide(0.15), kind="box", width=0.4, height=1.9,
                              depth=0.4))
    T0 = np.eye(4)
    a = render(scene, CAM, T0, t=0.0)
    b = render(scene, CAM, T0 @ np.linalg.inv(MOTION), t=1.0)
    return a, b


@pytest.fixture(scope="module")
def static_pair():
    return _pair(False)


@pytest.fixture(scope="module")
def dynamic_pair():
    return _pair(True)


def _errors(T):
    E = np.linalg.inv(MOTION) @ np.asarray(T, np.float64)
    return 1000 * np.linalg.norm(E[:3, 3]), np.degrees(geometry.rotation_angle(E[:3, :3]))


def _true_static(a, b):
    """Reference pixels that are static and still visible as static in the current frame."""
    h, w = a.depth.shape
    vv, uu = np.mgrid[0:h, 0:w]
    z = a.depth
    P = np.stack([(uu - CAM.cx) / CAM.fx * z, (vv - CAM.cy) / CAM.fy * z, z], -1).reshape(-1, 3)
    Pc = P @ MOTION[:3, :3].T + MOTION[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.round(CAM.fx * Pc[:, 0] / Pc[:, 2] + CAM.cx)
        v = np.round(CAM.fy * Pc[:, 1] / Pc[:, 2] + CAM.cy)
    ok = (z.reshape(-1) > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    lands_on_mover = np.zeros(h * w, bool)
    lands_on_mover[ok] = b.moving_mask[v[ok].astype(int), u[ok].astype(int)]
    return (~a.moving_mask.reshape(-1) & ~lands_on_mover).reshape(h, w)


@pytest.mark.parametrize("method", ["classic", "huber", "ransac"])
def test_static_scene_every_method_recovers_motion(static_pair, method):
    a, b = static_pair
    est = estimate_motion(a.frame(), b.frame(), CAM, Config(method=method), jax.random.key(0))
    t_err, r_err = _errors(est.T_cur_ref)
    assert t_err < 2.0 and r_err < 0.1, (method, t_err, r_err)
    assert bool(est.valid)
    assert est.inlier_ratio > 0.85
    np.testing.assert_allclose(np.asarray(geometry.exp(est.xi)), np.asarray(est.T_cur_ref), atol=1e-5)
    # information: symmetric positive definite
    info = np.asarray(est.information, np.float64)
    assert np.allclose(info, info.T, rtol=1e-4, atol=1e-3 * np.abs(info).max())
    assert np.linalg.eigvalsh(0.5 * (info + info.T)).min() > 0


def test_moving_object_ransac_robust_classic_not(dynamic_pair):
    a, b = dynamic_pair
    coverage = a.moving_mask.mean()
    assert 0.25 < coverage < 0.4
    ransac = estimate_motion(a.frame(), b.frame(), CAM, Config(method="ransac"), jax.random.key(0))
    classic = estimate_motion(a.frame(), b.frame(), CAM, Config(method="classic"), jax.random.key(0))
    t_r, r_r = _errors(ransac.T_cur_ref)
    t_c, r_c = _errors(classic.T_cur_ref)
    assert t_r < 5.0 and r_r < 0.2, (t_r, r_r)
    # measured: classic is off by ~220 mm and 3.5 deg on this pair
    assert t_c > 50.0 and r_c > 1.0, (t_c, r_c)
    assert t_c > 10 * t_r
    # the inlier mask is the static region (where the residuals are defined)
    static = _true_static(a, b)
    inl = np.asarray(ransac.inlier_mask)
    defined = np.asarray(ransac.valid_mask)
    iou = (inl & static & defined).sum() / ((inl | static) & defined).sum()
    assert iou > 0.85, iou


def test_ransac_on_coarse_levels_only(dynamic_pair):
    """ransac_finest=1 (the default): no hypotheses at level 0, whose refinement starts from the
    consensus carried up from level 1; ransac_finest=0 (the paper) draws them on every level."""
    a, b = dynamic_pair
    est = estimate_motion(a.frame(), b.frame(), CAM, Config(ransac_finest=1), jax.random.key(0))
    hyps = np.asarray(est.hypotheses)
    assert hyps[0] == 0 and hyps[1:].sum() > 0
    t_r, r_r = _errors(est.T_cur_ref)
    # measured 1.6 mm / 0.02 deg (classic: ~220 mm / 3.5 deg)
    assert t_r < 5.0 and r_r < 0.2, (t_r, r_r)
    # the paper's algorithm (ransac_finest=0; the program the --paper runs of test_bitwise compile)
    every = estimate_motion(a.frame(), b.frame(), CAM, Config.paper(), jax.random.key(0))
    assert Config.paper().ransac_finest == 0 and np.all(np.asarray(every.hypotheses) > 0)
    with pytest.raises(ValueError, match="ransac_finest"):
        Config(ransac_finest=-1).validate()


def test_blocks_choose_the_refinement_points(static_pair):
    """Config.blocks is one tile size per level for every method, (4, 4, 2, 1) by default:
    the default estimate is bitwise the one with those tiles given explicitly, and other tiles
    give another estimate."""
    assert Config().blocks == Config(method="classic").blocks == (4, 4, 2, 1)
    a, b = static_pair

    def T(cfg):
        return np.asarray(estimate_motion(a.frame(), b.frame(), CAM, cfg, jax.random.key(0)).T_cur_ref)

    own = T(Config(method="classic"))
    np.testing.assert_array_equal(own, T(Config(method="classic", blocks=(4, 4, 2, 1))))
    assert not np.array_equal(own, T(Config(method="classic", blocks=(4, 2, 1, 1))))


def test_user_mask_and_weights_remove_the_mover(dynamic_pair):
    """A reference mask that excludes the mover (Frame.mask, as a detector would give) makes
    plain least squares exact; the same as a weight map; a mask of every pixel changes nothing."""
    a, b = dynamic_pair
    static = ~a.moving_mask
    ref = a.frame()
    classic = Config(method="classic")
    masked = estimate_motion(ref._replace(mask=static), b.frame(), CAM, classic)
    weighted = estimate_motion(ref, b.frame(), CAM, classic, weights=static.astype(np.float32))
    t, r = _errors(masked.T_cur_ref)
    assert t < 5.0 and r < 0.2, (t, r)   # unmasked: > 50 mm (test above)
    np.testing.assert_array_equal(np.asarray(masked.T_cur_ref), np.asarray(weighted.T_cur_ref))
    full = estimate_motion(ref._replace(mask=np.ones_like(static)), b.frame(), CAM, classic)
    plain = estimate_motion(ref, b.frame(), CAM, classic)
    np.testing.assert_array_equal(np.asarray(full.T_cur_ref), np.asarray(plain.T_cur_ref))
    with pytest.raises(ValueError, match="mask"):
        estimate_motion(ref._replace(mask=static[:10]), b.frame(), CAM, classic)


def test_same_key_is_bitwise_identical(dynamic_pair):
    a, b = dynamic_pair
    cfg = Config(method="ransac")
    e1 = estimate_motion(a.frame(), b.frame(), CAM, cfg, jax.random.key(7))
    e2 = estimate_motion(a.frame(), b.frame(), CAM, cfg, jax.random.key(7))
    for x, y in zip(jax.tree_util.tree_leaves(e1), jax.tree_util.tree_leaves(e2)):
        assert np.array_equal(np.asarray(x), np.asarray(y))


def test_numpy_and_jax_inputs_give_the_same_estimate_and_one_program(dynamic_pair):
    """NumPy frames travel to the compiled call as they are (no per-array dispatch); JAX arrays,
    float64 inputs and explicit weights / init give bitwise the same estimate, without a retrace."""
    a, b = dynamic_pair
    fa, fb = a.frame(), b.frame()
    cfg, key = Config(method="ransac"), jax.random.key(3)
    ref = estimate_motion(fa, fb, CAM, cfg, key)
    before = trace_count()
    as_jax = Frame(jnp.asarray(fa.intensity), jnp.asarray(fa.depth)), Frame(jnp.asarray(fb.intensity), jnp.asarray(fb.depth))
    as_f64 = Frame(np.float64(fa.intensity), np.float64(fa.depth)), Frame(np.float64(fb.intensity), np.float64(fb.depth))
    ones = np.ones(fa.depth.shape)
    for r, c, kw in ((*as_jax, {}), (*as_f64, {}), (fa, fb, {"weights": ones, "init": np.eye(4)}),
                     (fa, fb, {"weights": jnp.asarray(ones, jnp.float32), "init": jnp.eye(4)})):
        e = estimate_motion(r, c, CAM, cfg, key, **kw)
        for x, y in zip(jax.tree_util.tree_leaves(ref), jax.tree_util.tree_leaves(e)):
            assert np.array_equal(np.asarray(x), np.asarray(y))
    assert trace_count() == before


def test_prepared_frames_give_the_frames_estimate_without_a_retrace(dynamic_pair):
    """A frame prepared once (its pyramid) serves as reference or current frame: the estimate is
    bitwise that of the plain frames (which estimate_motion prepares itself), with weights and an
    initial pose, mixed with a plain frame, for every method, traced once for all of them. A
    frame prepared for another config is refused."""
    from jaxvo.estimator import prepare_frame
    a, b = dynamic_pair
    fa, fb = a.frame(), b.frame()
    weights = np.where(a.moving_mask, 0.0, 1.0).astype(np.float32)
    init = np.asarray(MOTION, np.float32)
    key = jax.random.key(5)
    for cfg in (Config(method="ransac"), Config(method="classic")):
        pa, pb = prepare_frame(fa, CAM, cfg), prepare_frame(fb, CAM, cfg)
        assert len(pa.levels) == 4 and pa.levels[0].igrad.shape == (480, 640, 3) and pa.levels[0].weight is None
        ref = estimate_motion(fa, fb, CAM, cfg, key, init=init, weights=weights)
        before = trace_count()
        for r, c in ((pa, pb), (pa, fb), (fa, pb)):
            e = estimate_motion(r, c, CAM, cfg, key, init=init, weights=weights)
            for x, y in zip(jax.tree_util.tree_leaves(ref), jax.tree_util.tree_leaves(e)):
                assert np.array_equal(np.asarray(x), np.asarray(y))
        assert trace_count() == before
    cfg = Config(method="ransac")
    with pytest.raises(ValueError, match="prepared for another config"):
        estimate_motion(pa, pb, CAM, cfg.replace(max_depth=3.0), key)
    # the depth gradients: only on the levels an estimate reads them (the default: RANSAC's
    # hypotheses on levels 1-3; classic: none); a frame prepared with more serves, one with fewer not
    pr = prepare_frame(fa, CAM, cfg)
    assert [lv.dgrad is None for lv in pr.levels] == [True, False, False, False]
    assert pr.levels[1].dgrad.shape == (240, 320, 4)
    assert all(lv.dgrad is None for lv in pa.levels)   # classic, the last config above
    rgbd = Config(method="classic", terms="rgbd")
    full = prepare_frame(fa, CAM, rgbd)
    assert all(lv.dgrad is not None for lv in full.levels)
    e = estimate_motion(full, pb, CAM, Config(method="classic"), key)
    assert np.array_equal(np.asarray(e.T_cur_ref), np.asarray(estimate_motion(fa, fb, CAM, Config(method="classic"), key).T_cur_ref))
    with pytest.raises(ValueError, match=r"current frame was prepared for another config \(no depth gradients on pyramid levels \[0, 1, 2, 3\]"):
        estimate_motion(full, pa, CAM, rgbd, key)
    # the reference's are never read
    assert np.array_equal(np.asarray(estimate_motion(pa, prepare_frame(fb, CAM, rgbd), CAM, rgbd, key).T_cur_ref),
                          np.asarray(estimate_motion(fa, fb, CAM, rgbd, key).T_cur_ref))
    with pytest.raises(ValueError, match="prepared for another config"):
        estimate_motion(prepare_frame(fa, CAM, Config(num_levels=3)), pb, CAM, cfg, key)


def test_a_bad_config_is_refused_every_time(static_pair):
    """Checked (config, camera) pairs are remembered; a bad one never is, whatever came before."""
    a, b = static_pair
    estimate_motion(a.frame(), b.frame(), CAM, Config(method="classic"))
    for _ in range(2):
        with pytest.raises(ValueError, match="thresh_lum"):
            estimate_motion(a.frame(), b.frame(), CAM, Config(method="classic", thresh_lum=-1.0))
    bad_cam = dataclasses.replace(CAM, fx=-1.0)
    for _ in range(2):
        with pytest.raises(ValueError, match="fx"):
            estimate_motion(a.frame(), b.frame(), bad_cam, Config(method="classic"))


def test_compiled_once_per_shape_and_method(static_pair, dynamic_pair):
    cfg = Config(method="classic")
    frames = [static_pair[0].frame(), static_pair[1].frame(), dynamic_pair[0].frame(), dynamic_pair[1].frame()]
    estimate_motion(frames[0], frames[1], CAM, cfg)  # compiled here at the latest
    before = trace_count()
    for i in range(3):
        estimate_motion(frames[i], frames[i + 1], CAM, cfg, jax.random.key(i))
    # a numeric config change is a traced value, not a recompile
    estimate_motion(frames[0], frames[1], CAM, cfg.replace(thresh_lum=25.0))
    assert trace_count() == before


def test_vmap_over_threshold_equals_separate_calls(dynamic_pair):
    # a small level keeps the compile cheap; the mechanism is the same at any size
    cam = CAM.at_level(2)
    a, b = dynamic_pair
    small = [Frame(np.asarray(f.intensity).reshape(120, 4, 160, 4).mean((1, 3)).astype(np.float32),
                   np.asarray(f.depth)[::4, ::4].copy()) for f in (a, b)]
    cfg = Config()   # two levels at 160x120: the program of the default estimate at this size
    values = jnp.linspace(10.0, 45.0, 8)
    key = jax.random.key(3)
    batched = jax.vmap(lambda t: estimate_motion(small[0], small[1], cam, cfg.replace(thresh_lum=t), key))(values)
    for i, t in enumerate(values):
        single = estimate_motion(small[0], small[1], cam, cfg.replace(thresh_lum=t), key)
        np.testing.assert_allclose(np.asarray(batched.T_cur_ref[i]), np.asarray(single.T_cur_ref), atol=1e-5)
        assert abs(float(batched.inlier_ratio[i]) - float(single.inlier_ratio)) < 1e-3
        np.testing.assert_array_equal(np.asarray(batched.hypotheses[i]), np.asarray(single.hypotheses))
    # and the sweep really varies: the luminance threshold changes the inlier ratio
    assert float(batched.inlier_ratio[-1]) > float(batched.inlier_ratio[0])


def _frame(h=480, w=640, depth=1.0):
    rng = np.random.default_rng(0)
    return Frame(rng.uniform(0, 255, (h, w)).astype(np.float32), np.full((h, w), depth, np.float32))


@pytest.mark.parametrize("make, match", [
    (lambda: (_frame(), _frame(240, 320), CAM, Config()), "differ in size"),
    (lambda: (_frame(), Frame(np.zeros((480, 640), np.uint8), np.ones((480, 640), np.float32)), CAM, Config()),
     "floating point"),
    (lambda: (_frame(), Frame(np.zeros((480, 640, 3), np.float32), np.ones((480, 640), np.float32)), CAM, Config()),
     "2-D"),
    (lambda: (_frame(), _frame(depth=0.0), CAM, Config()), "no valid pixel"),
    (lambda: (_frame(240, 320), _frame(240, 320), CAM, Config()), "camera intrinsics are for 640x480"),
    (lambda: (_frame(), _frame(), CAM, Config(method="lsq")), "Config.method must be one of"),
    (lambda: (_frame(), _frame(), CAM, Config(batch_size=0)), "batch_size"),
    (lambda: (_frame(), _frame(), "fr2", Config()), "jaxvo.Camera"),
])
def test_bad_input_raises_clear_value_error(make, match):
    ref, cur, cam, cfg = make()
    with pytest.raises(ValueError, match=match):
        estimate_motion(ref, cur, cam, cfg)


def _turn(deg=10.0):
    """A rigid T_cur_ref: a turn about y and a step along x."""
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, 0, s, 0.05], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1]])


@pytest.mark.parametrize("kwargs, match", [
    (dict(init=np.eye(3)), r"init \(the initial T_cur_ref\) must be a 4x4 matrix"),
    (dict(init=np.full((4, 4), np.nan)), "init .* contains NaN or inf"),
    (dict(init=np.diag([2.0, 2.0, 2.0, 1.0])), "init .* must be a rigid transform"),            # scaled
    (dict(init=np.diag([1.0, 1.0, -1.0, 1.0])), "init .* must be a rigid transform"),           # a reflection
    (dict(init=np.vstack([_turn()[:3], [0, 0, 1, 1]])), "init .* must be a rigid transform"),   # last row
    (dict(weights=np.where(np.eye(480, 640) > 0, np.nan, 1.0)), r"weights must lie in \[0, 1\].* got NaN$"),
    (dict(weights=np.full((480, 640), 255.0)), "got values from 255 to 255 .*divide it by 255"),
    (dict(weights=np.full((480, 640), -0.5)), "got values from -0.5 to -0.5$"),
])
def test_a_bad_guess_or_bad_weights_raise_clear_value_error(kwargs, match):
    """What the estimate would otherwise take silently (a NaN pose out, a scaled pose refined as
    if rigid, weights whose sums make no sense) is refused before anything runs."""
    with pytest.raises(ValueError, match=match):
        estimate_motion(_frame(), _frame(), CAM, Config(), **kwargs)


def test_frames_of_lists_name_what_they_must_be():
    f = _frame(8, 8)
    with pytest.raises(ValueError, match="intensity and depth must be arrays .*got list and list"):
        estimate_motion(_frame(), Frame(f.intensity.tolist(), f.depth.tolist()), CAM, Config())


def test_public_api_exports():
    for name in ("estimate_motion", "track", "Config", "MotionEstimate", "Camera", "Frame", "make_frame",
                 "TrackConfig", "TrackStep", "Track", "Odometry"):
        assert hasattr(jaxvo, name), name


def test_sample_gate_drops_pixels_something_stepped_in_front_of():
    """RANSAC's sample centres skip reference pixels whose depth residual at the starting pose
    exceeds Config.sample_gate (an occluder that arrived after the reference), and the gate
    stands down when it would leave fewer than 10 % of the trusted pixels."""
    from jaxvo.estimator.levels import _gated
    from jaxvo.estimator.pyramid import build_pyramid
    cam = DEFAULT.at_level(2)
    h, w = cam.height, cam.width
    rng = np.random.default_rng(0)
    img = rng.uniform(0, 255, (h, w)).astype(np.float32)
    wall = np.full((h, w), 2.0, np.float32)
    ref_l = build_pyramid(jnp.asarray(img), jnp.asarray(wall), 1)[0]
    I = jnp.eye(4, dtype=jnp.float32)

    def gated(occluded, gate):
        d = wall.copy()
        d[occluded] = 1.2
        cur_l = build_pyramid(jnp.asarray(img), jnp.asarray(d), 1)[0]
        return np.asarray(_gated(ref_l, cur_l, cam, I, gate).weight)

    person = np.zeros((h, w), bool)
    person[20:100, 40:80] = True
    wt = gated(person, 0.2)
    assert (wt[person] == 0).all() and (wt[~person] == 1).all()
    assert (gated(person, 0.0) == 1).all()                 # 0: off (Config.paper())
    assert (gated(person, 1.0) == 1).all()                 # 0.8 m in front is under a 1 m gate
    crowd = np.ones((h, w), bool)
    crowd[:, :10] = False                                   # ~6 % of the wall still in view
    assert (gated(crowd, 0.2) == 1).all()


def test_brightness_offset_recovers_an_exposure_change(static_pair):
    """The current frame 40 grey levels brighter (auto exposure): at the true pose every pixel
    fails |luminance residual| < 30, so the paper's RANSAC loses the motion; Config.brightness
    = "offset" fits the offset on the pixels whose depth agrees and recovers it."""
    from jaxvo.estimator.brightness import apply, fit_offset
    from jaxvo.estimator.pyramid import build_pyramid
    from jaxvo.estimator.residuals import reference_points
    a, b = static_pair
    bright = Frame(np.clip(b.frame().intensity + 40.0, 0, 255).astype(np.float32), b.frame().depth)
    # the paper's algorithm compares luminance as it is (brightness "none"; the program test_bitwise's
    # --paper runs compile)
    plain = estimate_motion(a.frame(), bright, CAM, Config.paper(), jax.random.key(0))
    assert Config.paper().brightness == "none"
    fitted = estimate_motion(a.frame(), bright, CAM, Config(), jax.random.key(0))   # "offset": the default
    t_err, r_err = _errors(fitted.T_cur_ref)
    assert t_err < 3.0 and r_err < 0.15, (t_err, r_err)
    assert bool(fitted.valid) and not bool(plain.valid)
    assert _errors(plain.T_cur_ref)[0] > 3 * t_err
    assert 35.0 < float(fitted.brightness) < 42.0          # clipping at 255 pulls a little under 40
    assert float(plain.brightness) == 0.0
    # the fit itself, at the true pose: the median offset, and 0 under thresh_lum / 3 (each step
    # jitted, as in the estimator: one compilation each, not one per operation)
    pyramid_of = jax.jit(build_pyramid, static_argnums=2)
    ref_l = pyramid_of(a.frame().intensity, a.frame().depth, 1)[0]
    pts = jax.jit(reference_points, static_argnums=2)(ref_l, CAM, 4)
    fit = jax.jit(fit_offset)
    for shift, expected in [(25.0, 25.0), (-25.0, -25.0), (8.0, 0.0)]:
        cur_l = pyramid_of(np.clip(b.frame().intensity + shift, 0, 255), b.frame().depth, 1)[0]
        off = float(fit(jnp.asarray(MOTION, jnp.float32), pts, cur_l, CAM, 30.0, 0.05))
        assert abs(off - expected) < 2.5, (shift, off)
    moved = apply(ref_l, jnp.float32(5.0))
    np.testing.assert_allclose(np.asarray(moved.intensity), np.asarray(ref_l.intensity) + 5.0, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(moved.igrad[..., 1:]), np.asarray(ref_l.igrad[..., 1:]))


def test_scan_levels_equals_the_per_level_estimate(dynamic_pair):
    """Config.scan_levels (the default: the levels as one lax.scan over padded, stacked levels)
    against the per-level code, compiled separately for each level's own shapes: the same RANSAC
    draws and iterations at every level and the same pose to float32 rounding. Consecutive RANSAC
    levels share a scan while their padding stays within 10 % of all levels' refinement points:
    the default's levels 3-1 (4800 points each; level 0 refines only, per level), the paper's
    levels 3-2 (every pixel: 4800 and 19200 points, so level 3's point list and scoring grid are
    padded), and with the (4, 2, 1, 1) tiles [3], [2, 1], [0] (level 3's 4800 points padded to
    19200 would be 23 %). Classic and Huber run per level."""
    from jaxvo.estimator.levels import _level_groups
    assert _level_groups(Config(), 4, 640, 480) == [[3, 2, 1], [0]]
    assert _level_groups(Config.paper(), 4, 640, 480) == [[3, 2], [1], [0]]
    assert _level_groups(Config(blocks=(4, 2, 1, 1)), 4, 640, 480) == [[3], [2, 1], [0]]
    assert _level_groups(Config(method="classic"), 4, 640, 480) == [[3], [2], [1], [0]]
    assert _level_groups(Config(scan_levels=False), 4, 640, 480) == [[3], [2], [1], [0]]
    a, b = dynamic_pair
    cfg = Config.paper(scan_levels=False)
    assert Config().scan_levels
    per_level = estimate_motion(a.frame(), b.frame(), CAM, cfg, jax.random.key(0))
    scanned = estimate_motion(a.frame(), b.frame(), CAM, cfg.replace(scan_levels=True), jax.random.key(0))
    np.testing.assert_array_equal(np.asarray(scanned.hypotheses), np.asarray(per_level.hypotheses))
    np.testing.assert_array_equal(np.asarray(scanned.iterations), np.asarray(per_level.iterations))
    assert np.asarray(per_level.hypotheses)[1:].min() > 0
    # measured: 1e-7 (sums over padded point lists add in another order)
    np.testing.assert_allclose(np.asarray(scanned.T_cur_ref), np.asarray(per_level.T_cur_ref), atol=1e-5)
    assert np.mean(np.asarray(scanned.inlier_mask) == np.asarray(per_level.inlier_mask)) > 0.999
    assert bool(scanned.valid) == bool(per_level.valid)


def test_pixel_counts_are_the_sums_of_the_masks():
    """The estimator's and the map's pixel counts come from one variadic reduction: the same
    integers as a jnp.sum per mask, for 1-D and 2-D masks."""
    from jaxvo.estimator import pixel_counts
    rng = np.random.default_rng(3)
    for shape in ((307,), (48, 64)):
        masks = [jnp.asarray(rng.random(shape) < p) for p in (0.0, 0.2, 0.5, 1.0)]
        counts = pixel_counts(*masks)
        assert [int(c) for c in counts] == [int(jnp.sum(m)) for m in masks]
        assert all(c.dtype == jnp.int32 for c in counts)
