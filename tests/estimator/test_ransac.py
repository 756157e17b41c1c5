"""Tests of jaxvo.estimator.ransac: hypothesis count, inlier test, patch sampling, one RANSAC level."""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxvo import geometry as G
from jaxvo.camera import DEFAULT
from jaxvo.estimator import pyramid
from jaxvo.estimator.ransac import (_nth_true, inliers, num_hypotheses, ransac_level, sample_patches, sampling_table,
                          score_pose, score_weights)
from jaxvo.estimator.residuals import Residuals, reference_points

CAM = DEFAULT.at_level(3)          # 80 x 60
H, W = CAM.height, CAM.width

build_pyramid = jax.jit(pyramid.build_pyramid, static_argnums=(2,))


# --------------------------------------------------------------------------- k

# k = ceil(log(1 - p) / log(1 - (1 - w)^n)), evaluated by hand:
#   0.99, 0.3, 6: log 0.01 / log(1 - 0.117649) = -4.60517 / -0.125163 = 36.79 -> 37
#   0.99, 0.5, 6: -4.60517 / log(0.984375) = 292.4 -> 293
#   0.95, 0.3, 6: -2.99573 / -0.125163 = 23.93 -> 24
#   0.99, 0.3, 1: -4.60517 / log 0.3 = 3.82 -> 4
#   0.999, 0.3, 6: -6.90776 / -0.125163 = 55.19 -> 56
#   0.99, 0.3, 8: -4.60517 / log(1 - 0.7^8) = 77.56 -> 78
CASES = [(0.99, 0.3, 6, 37), (0.99, 0.5, 6, 293), (0.95, 0.3, 6, 24), (0.99, 0.3, 1, 4),
         (0.999, 0.3, 6, 56), (0.99, 0.3, 8, 78)]


@pytest.mark.parametrize("p,w,n,k", CASES)
def test_num_hypotheses_hand_computed(p, w, n, k):
    assert int(num_hypotheses(p, w, n)) == k


def test_num_hypotheses_traced():
    f = jax.jit(num_hypotheses, static_argnums=2)
    for p, w, n, k in CASES:
        assert int(f(jnp.float32(p), jnp.float32(w), n)) == k
    ws = jnp.asarray([0.3, 0.5], jnp.float32)
    ks = jax.jit(jax.vmap(lambda w: num_hypotheses(0.99, w, 6)))(ws)
    np.testing.assert_array_equal(np.asarray(ks), [37, 293])
    assert jnp.issubdtype(ks.dtype, jnp.integer)


def test_num_hypotheses_without_outliers_is_one():
    """w = 0: every sample is all-inlier, so one draw suffices (never zero draws)."""
    assert int(num_hypotheses(0.99, 0.0, 6)) == 1
    assert int(num_hypotheses(0.5, 0.0, 1)) == 1


# --------------------------------------------------------------------------- inliers

def test_inliers_thresholds():
    r_int = jnp.asarray([0.0, 29.9, 30.0, -29.9, -30.0, 10.0, 10.0, 10.0, 0.0])
    r_dep = jnp.asarray([0.0, 0.049, 0.0, -0.049, 0.0, 0.05, -0.05, 0.0, 0.0])
    valid = jnp.asarray([True] * 8 + [False])
    res = Residuals(r_int, valid, r_dep, valid, r_int, r_int, r_int)
    got = np.asarray(inliers(res, 30.0, 0.05))
    np.testing.assert_array_equal(got, [True, True, False, True, False, False, False, True, False])
    # valid_depth (not only valid_int) is required
    res2 = res._replace(valid_depth=jnp.zeros(9, bool))
    assert not np.asarray(inliers(res2, 30.0, 0.05)).any()
    # thresholds may be traced
    got = jax.jit(inliers)(res, jnp.float32(10.5), jnp.float32(0.01))
    np.testing.assert_array_equal(np.asarray(got), [True, False, False, False, False, False, False, True, False])


# --------------------------------------------------------------------------- patches

def _level(depth):
    rng = np.random.default_rng(0)
    return build_pyramid(rng.uniform(0, 255, depth.shape).astype(np.float32), depth, 1)[0]


_sample = jax.jit(sample_patches, static_argnames=("n", "batch", "radius"))


def test_sample_patches_are_3x3_neighbourhoods_of_valid_centres():
    depth = np.zeros((H, W), np.float32)
    depth[10:50, 5:60] = 2.0
    depth[0, :] = 1.0                       # valid, but on the border: never a centre
    depth[:, W - 1] = 1.0
    lev = _level(depth)
    n, batch = 6, 16
    pu, pv = _sample(jax.random.PRNGKey(0), lev, n=n, batch=batch, radius=1)
    pu, pv = np.asarray(pu), np.asarray(pv)
    assert pu.shape == (batch, n * 9) and pv.shape == (batch, n * 9)
    pu, pv = pu.reshape(batch, n, 9), pv.reshape(batch, n, 9)
    cu, cv = pu[..., 4], pv[..., 4]
    du, dv = pu - cu[..., None], pv - cv[..., None]
    offsets = sorted(zip(du[0, 0].tolist(), dv[0, 0].tolist()))
    assert offsets == [(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1)]
    assert np.all(du == du[0, 0]) and np.all(dv == dv[0, 0])
    assert np.all(depth[cv, cu] > 0)
    assert np.all((cu >= 1) & (cu <= W - 2) & (cv >= 1) & (cv <= H - 2))
    assert np.all((pu >= 0) & (pu < W) & (pv >= 0) & (pv < H))
    assert np.all((cu >= 5) & (cu < 60) & (cv >= 10) & (cv < 50))


def test_sample_patches_radius_2():
    depth = np.full((H, W), 2.0, np.float32)
    pu, pv = _sample(jax.random.PRNGKey(3), _level(depth), n=2, batch=4, radius=2)
    pu, pv = np.asarray(pu).reshape(4, 2, 25), np.asarray(pv).reshape(4, 2, 25)
    cu, cv = pu[..., 12], pv[..., 12]
    assert np.all((cu >= 2) & (cu <= W - 3) & (cv >= 2) & (cv <= H - 3))
    assert set(np.unique(pu - cu[..., None])) == {-2, -1, 0, 1, 2}


def test_sample_patches_deterministic_per_key():
    lev = _level(np.full((H, W), 2.0, np.float32))
    a = _sample(jax.random.PRNGKey(7), lev, n=6, batch=8, radius=1)
    b = _sample(jax.random.PRNGKey(7), lev, n=6, batch=8, radius=1)
    c = _sample(jax.random.PRNGKey(8), lev, n=6, batch=8, radius=1)
    np.testing.assert_array_equal(np.asarray(a[0]), np.asarray(b[0]))
    np.testing.assert_array_equal(np.asarray(a[1]), np.asarray(b[1]))
    assert not (np.array_equal(np.asarray(a[0]), np.asarray(c[0])) and
                np.array_equal(np.asarray(a[1]), np.asarray(c[1])))


def test_sample_patches_draws_the_centres_of_a_batch_n_randint():
    """The centres are the drawable pixels ranked by ``jax.random.randint(key, (batch, n), 0, total)``
    (the draw every result so far was made with; sample_patches draws them flat and reshapes,
    which XLA compiles faster), checked through the sampling table's rank-to-pixel lookup."""
    rng = np.random.default_rng(3)
    depth = np.where(rng.random((H, W)) < 0.6, 1.5, 0.0).astype(np.float32)
    lev = _level(depth)
    key = jax.random.PRNGKey(11)
    pu, pv = _sample(key, lev, n=6, batch=8, radius=1)
    table = jax.jit(sampling_table, static_argnames="radius")(lev, radius=1)
    ranks = jax.random.randint(key, (8, 6), 0, int(table.rows[-1]))
    flat = np.asarray(jax.jit(_nth_true)(table, ranks))
    w = table.ok.shape[1]
    np.testing.assert_array_equal(np.asarray(pu).reshape(8, 6, 9)[..., 4], flat % w)
    np.testing.assert_array_equal(np.asarray(pv).reshape(8, 6, 9)[..., 4], flat // w)


def test_sample_patches_sparse_valid_pixels():
    depth = np.zeros((H, W), np.float32)
    allowed = {(10, 10), (30, 20), (70, 50)}          # (u, v)
    for u, v in allowed:
        depth[v, u] = 1.5
    depth[0, 0] = depth[59, 79] = 1.0                 # border: excluded
    pu, pv = _sample(jax.random.PRNGKey(1), _level(depth), n=6, batch=64, radius=1)
    cu = np.asarray(pu).reshape(64, 6, 9)[..., 4].ravel()
    cv = np.asarray(pv).reshape(64, 6, 9)[..., 4].ravel()
    seen = set(zip(cu.tolist(), cv.tolist()))
    assert seen == allowed


def test_sampling_table_finds_the_jth_drawable_pixel():
    """Every rank j maps to the j-th drawable pixel in row-major order (numpy's flatnonzero), on a
    width that is not a whole number of chunks, in a padded stacked level (its own entry only),
    and past the end (no drawable pixel) to the flat size."""
    rng = np.random.default_rng(5)
    depth = np.where(rng.random((37, 53)) < 0.3, 1.0, 0.0).astype(np.float32)
    small = np.where(rng.random((20, 29)) < 0.5, 2.0, 0.0).astype(np.float32)
    levels = [_level(depth), _level(small)]
    stacked = pyramid.stack_padded(levels)
    cases = [(levels[0], depth), (stacked._replace(size=stacked.size[1]), small)]
    for lev, d in cases:
        table = jax.jit(sampling_table, static_argnames="radius")(lev, radius=1)
        h, w = d.shape
        ok = np.zeros(table.ok.shape, bool)
        ok[1:h - 1, 1:w - 1] = d[1:h - 1, 1:w - 1] > 0
        want = np.flatnonzero(ok)
        assert int(table.rows[-1]) == want.size
        got = jax.jit(_nth_true)(table, jnp.arange(want.size + 1, dtype=jnp.int32))
        np.testing.assert_array_equal(np.asarray(got[:-1]), want)
        assert int(got[-1]) == ok.size


# --------------------------------------------------------------------------- one level

N_PLANE = np.array([0.1, -0.15, 1.0]) / np.linalg.norm([0.1, -0.15, 1.0])
T_TRUE = G.exp(np.array([0.01, -0.012, 0.006, 0.02, -0.01, 0.025]))


def _render(T_cam_ref):
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    rays = np.stack([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, np.ones_like(u)], -1)
    R, t = T_cam_ref[:3, :3], T_cam_ref[:3, 3]
    n_c = R @ N_PLANE
    Z = (2.0 + n_c @ t) / (rays @ n_c)
    P = (Z[..., None] * rays - t) @ R
    e1 = np.cross(N_PLANE, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    s, q = P @ e1, P @ np.cross(N_PLANE, e1)
    img = 128 + 50 * np.sin(2 * np.pi * s / 0.7) + 40 * np.cos(2 * np.pi * q / 0.55 + 0.5)
    return img.astype(np.float32), Z.astype(np.float32)


@pytest.fixture(scope="module")
def level_pair():
    ref = build_pyramid(*_render(np.eye(4)), 1)[0]
    cur = build_pyramid(*_render(T_TRUE), 1)[0]
    return ref, cur, reference_points(ref, CAM, stride=2)


@functools.partial(jax.jit, static_argnames=("max_hypotheses",))
def _ransac(T_init, ref, cur, pts, key, thresh_lum, max_hypotheses=8):
    return ransac_level(T_init, ref, cur, CAM, pts, key, p=0.99, w=0.3, thresh_lum=thresh_lum,
                        thresh_depth=0.05, early_exit_ratio=0.9, n=6, radius=1,
                        max_hypotheses=max_hypotheses, batch_size=4, hypothesis_iterations=8)


def test_ransac_level(level_pair):
    ref, cur, pts = level_pair
    key = jax.random.PRNGKey(0)
    # starting at the truth: the initial pose passes the early exit, no hypothesis is drawn
    r = _ransac(jnp.asarray(T_TRUE, jnp.float32), ref, cur, pts, key, jnp.float32(30.0))
    assert int(r.hypotheses) == 0 and float(r.inlier_ratio) > 0.9
    np.testing.assert_allclose(np.asarray(r.T), T_TRUE, atol=1e-6)
    # from the identity with a strict threshold: hypotheses are drawn (at most the cap)
    # and the best one scores at least as well as the start
    r0 = _ransac(jnp.eye(4), ref, cur, pts, jnp.asarray(key), jnp.float32(3.0))
    r_id = _ransac(jnp.eye(4), ref, cur, pts, key, jnp.float32(3.0))
    assert 0 < int(r_id.hypotheses) <= 8 and int(r_id.hypotheses) % 4 == 0
    assert 0.0 <= float(r_id.inlier_ratio) <= 1.0
    # same key -> bitwise identical
    np.testing.assert_array_equal(np.asarray(r0.T), np.asarray(r_id.T))
    assert float(r0.inlier_ratio) == float(r_id.inlier_ratio)
    # the hypotheses move the pose towards the truth
    d_id = np.linalg.norm(G.log(np.asarray(r_id.T, np.float64) @ G.inverse(T_TRUE)))
    assert d_id < np.linalg.norm(G.log(G.inverse(T_TRUE)))


def test_adaptive_count_stops_once_the_best_ratio_makes_p(level_pair):
    """Adaptive RANSAC: with the best inlier ratio r so far, k(r) = log(1 - p) / log(1 - r^n) draws
    reach the success probability p; the level stops at the first batch boundary past it (and
    never past k from w). Without the early exit, a start at the truth (r near 1) needs one batch
    where the fixed count draws all 37; a start that explains nothing draws all 37 either way."""
    ref, cur, pts = level_pair
    key = jax.random.key(3)

    @functools.partial(jax.jit, static_argnames=("adaptive",))
    def run(T_init, thresh_lum, adaptive):
        return ransac_level(T_init, ref, cur, CAM, pts, key, p=0.99, w=0.3, thresh_lum=thresh_lum,
                            thresh_depth=0.05, early_exit_ratio=1.0, n=6, radius=1, max_hypotheses=64,
                            batch_size=4, hypothesis_iterations=8, adaptive=adaptive)

    truth = jnp.asarray(T_TRUE, jnp.float32)
    fixed, adaptive = run(truth, 30.0, False), run(truth, 30.0, True)
    assert int(fixed.hypotheses) == 37
    r = float(adaptive.inlier_ratio)
    k_r = np.log(0.01) / np.log(1.0 - r ** 6)  # independent of the code's float32 form
    assert r > 0.95 and k_r <= 4 and int(adaptive.hypotheses) == 4
    # a start far off with a strict threshold: no hypothesis explains much, so the cap is k
    far = jnp.asarray(G.exp(np.array([0.0, 0.0, 0.0, 0.3, 0.0, 0.0])), jnp.float32)
    lost_fixed, lost_adaptive = run(far, 1.0, False), run(far, 1.0, True)
    k_lost = np.log(0.01) / np.log(1.0 - float(lost_adaptive.inlier_ratio) ** 6)
    assert k_lost > 37 and int(lost_adaptive.hypotheses) == 37
    np.testing.assert_array_equal(np.asarray(lost_adaptive.T), np.asarray(lost_fixed.T))


def test_second_candidate_is_kept_when_it_scores_better(level_pair):
    """T_other (the pose carried up from the coarser level, which a mover may have dragged the
    plain fit away from) is scored beside T_init: with no hypotheses drawn, the better of the
    two is returned, whichever argument it came in as; hypotheses still start from T_init."""
    ref, cur, pts = level_pair
    key = jax.random.key(0)
    good = jnp.asarray(T_TRUE, jnp.float32)
    bad = jnp.asarray(G.exp(np.array([0.0, 0.0, 0.0, 0.05, 0.0, 0.0])) @ T_TRUE, jnp.float32)

    @jax.jit
    def run(T_init, T_other):
        return ransac_level(T_init, ref, cur, CAM, pts, key, p=0.99, w=0.3, thresh_lum=30.0,
                            thresh_depth=0.05, early_exit_ratio=0.9, n=6, radius=1, max_hypotheses=0,
                            batch_size=4, hypothesis_iterations=8, scoring="msac", T_other=T_other)

    for T_init, T_other in ((bad, good), (good, bad)):
        r = run(T_init, T_other)
        assert int(r.hypotheses) == 0
        np.testing.assert_array_equal(np.asarray(r.T), np.asarray(good))
    # and without it, the start is all there is
    alone = run(bad, None)
    np.testing.assert_array_equal(np.asarray(alone.T), np.asarray(bad))


def test_depth_power_ranks_hypotheses_by_the_surface_their_inliers_cover(level_pair):
    """A near object (0.7 m, 60 % of the pixels) that moved with the camera, in front of the far
    textured plane (about 2 m) that shows the true motion: counted by pixels, "the camera stood
    still" (the identity) explains more of the picture; weighted by z^2, the surface each pixel
    images, the true motion explains more of the scene. depth_power 0 is the plain count."""
    move = G.exp(np.array([0.0, 0.05, 0.0, 0.12, 0.0, 0.0]))   # larger than T_TRUE: "still" fails the plane
    ref_i, ref_z = _render(np.eye(4))
    cur_i, cur_z = _render(move)
    near = np.broadcast_to(np.arange(W)[None, :] >= int(0.4 * W), (H, W))
    v, u = np.mgrid[0:H, 0:W]
    near_i = (128 + 90 * np.sign(np.sin(2 * np.pi * u / 5.0) * np.sin(2 * np.pi * v / 4.0))).astype(np.float32)
    for img, z in ((ref_i, ref_z), (cur_i, cur_z)):   # the same near object in both frames
        img[near], z[near] = near_i[near], 0.7
    ref = build_pyramid(jnp.asarray(ref_i), jnp.asarray(ref_z), 1)[0]
    cur = build_pyramid(jnp.asarray(cur_i), jnp.asarray(cur_z), 1)[0]
    pts = reference_points(ref, CAM, stride=1)
    truth, still = jnp.asarray(move, jnp.float32), jnp.eye(4)

    def scores(T, power):
        return [float(x) for x in score_pose(T, pts, cur, CAM, 30.0, 0.05, "count", score_weights(pts, power))]

    (q_truth, n_truth, s_truth), (q_still, n_still, s_still) = scores(truth, 0.0), scores(still, 0.0)
    assert q_truth == n_truth == s_truth and q_still == n_still == s_still   # power 0: the count itself
    assert n_still > 1.1 * n_truth                         # more pixels follow the near object
    (a_truth, c_truth, s_truth), (a_still, c_still, s_still) = scores(truth, 2.0), scores(still, 2.0)
    assert (c_truth, c_still) == (n_truth, n_still)        # the count (inlier ratio) is unchanged
    assert (a_truth, a_still) == (s_truth, s_still)        # "count" scoring: the quality is the surface
    assert a_truth > 3.0 * a_still                         # more surface follows the true motion

    @functools.partial(jax.jit, static_argnames="scoring")
    def best(power, scoring):
        return ransac_level(still, ref, cur, CAM, pts, jax.random.key(0), p=0.99, w=0.3, thresh_lum=30.0,
                            thresh_depth=0.05, early_exit_ratio=0.9, n=6, radius=1, max_hypotheses=0,
                            batch_size=4, hypothesis_iterations=8, scoring=scoring, depth_power=power,
                            T_other=truth).T

    for scoring in ("count", "msac"):
        np.testing.assert_array_equal(np.asarray(best(0.0, scoring)), np.asarray(still))
        np.testing.assert_array_equal(np.asarray(best(2.0, scoring)), np.asarray(truth))


def test_stacked_padded_level_samples_and_warps_as_the_level_itself():
    """A level padded and stacked with larger ones (jaxvo.estimator.pyramid.stack_padded, for the scan over
    levels) draws the same patch pixels for the same key (the k-th drawable pixel is the same
    pixel), gathers the same reference points, and gives the same residuals, validity included
    at the image border and beyond it (where the pad must not count as image). Each function
    runs jitted, as in the estimator (one compilation each, not one per operation)."""
    from jaxvo.estimator import residuals as R
    gather_points, residuals, photometric_terms, rgbd_terms = (
        jax.jit(f) for f in (R.gather_points, R.residuals, R.photometric_terms, R.rgbd_terms))
    points_of = jax.jit(reference_points)
    sample = jax.jit(sample_patches, static_argnums=(2, 3, 4))
    table = jax.jit(sampling_table, static_argnums=1)
    rng = np.random.default_rng(0)
    h, w = 48, 64
    img = jnp.asarray(rng.uniform(0, 255, (h, w)), jnp.float32)
    depth = jnp.asarray(rng.uniform(1.0, 3.0, (h, w)) * (rng.uniform(size=(h, w)) > 0.2), jnp.float32)
    levels = jax.jit(pyramid.build_pyramid, static_argnums=2)(img, depth, 3)
    stack = jax.jit(pyramid.stack_padded)([levels[2], levels[1], levels[0]])
    cam = DEFAULT.with_size(w, h).at_level(2)
    small = pyramid.Level(*stack[:5], stack.size[0])       # level 2 (16x12) padded to 64x48
    assert small.depth.shape == (3, h, w)
    assert int(table(small, 1).rows[-1]) == int(table(levels[2], 1).rows[-1]) > 0
    key = jax.random.key(3)
    pu, pv = sample(key, levels[2], 6, 4, 1)
    qu, qv = sample(key, small, 6, 4, 1)
    np.testing.assert_array_equal(np.asarray(qu), np.asarray(pu))
    np.testing.assert_array_equal(np.asarray(qv), np.asarray(pv))
    for x, y in zip(gather_points(small, cam, pu, pv), gather_points(levels[2], cam, pu, pv)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    # every pixel of the level, moved so that some land on the border, outside, or in the pad
    pts = points_of(levels[2], cam)
    T = G.exp(np.array([0.0, 0.02, 0.0, 0.15, 0.05, 0.0]))
    a, b = residuals(T, pts, small, cam), residuals(T, pts, levels[2], cam)
    assert 0 < int(np.sum(b.valid_int)) < int(np.sum(pts.valid))
    for x, y in zip(a, b):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    for f in (photometric_terms, lambda *a: rgbd_terms(*a, 600.0)):
        for x, y in zip(f(T, pts, small, cam), f(T, pts, levels[2], cam)):
            np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-6, atol=1e-4)


def test_batches_per_trip_gives_the_estimate_of_one_batch_per_trip(level_pair):
    """Several batches fitted in one vmapped call (``batches_per_trip``) still stop after the batch
    where one batch per trip stops: the same pose, inlier ratio and hypothesis count, whether the
    stop is the early exit in the middle of a trip, the count k, or the adaptive count."""
    ref, cur, pts = level_pair
    key = jax.random.key(5)

    @functools.partial(jax.jit, static_argnames=("adaptive", "trip"))
    def run(T_init, thresh_lum, exit_ratio, adaptive, trip):
        return ransac_level(T_init, ref, cur, CAM, pts, key, p=0.99, w=0.3, thresh_lum=thresh_lum,
                            thresh_depth=0.05, early_exit_ratio=exit_ratio, n=6, radius=1, max_hypotheses=64,
                            batch_size=4, hypothesis_iterations=8, adaptive=adaptive, batches_per_trip=trip)

    near = jnp.asarray(G.exp(np.array([0.0, 0.0, 0.0, 0.01, 0.0, 0.0])) @ T_TRUE, jnp.float32)
    far = jnp.asarray(G.exp(np.array([0.0, 0.0, 0.0, 0.3, 0.0, 0.0])), jnp.float32)
    counts = set()
    for T_init, thresh, ratio, adaptive in [(jnp.eye(4), 30.0, 0.9, False), (near, 3.0, 0.5, False),
                                            (jnp.eye(4), 3.0, 0.9, False), (far, 1.0, 0.9, True),
                                            (jnp.asarray(T_TRUE, jnp.float32), 30.0, 1.0, True)]:
        one = run(T_init, thresh, ratio, adaptive, 1)
        counts.add(int(one.hypotheses))
        many = run(T_init, thresh, ratio, adaptive, 10)   # 10 x 4 covers k = 37 in one trip, as 5 x 8 does
        assert int(many.hypotheses) == int(one.hypotheses), (thresh, ratio, adaptive)
        assert float(many.inlier_ratio) == pytest.approx(float(one.inlier_ratio), abs=1e-6)
        np.testing.assert_allclose(np.asarray(many.T), np.asarray(one.T), atol=1e-5)
    # the cases stop at different batches, some before k: inside the one trip, after the batch
    # where one batch per trip stops
    assert len(counts) >= 3 and any(c < 37 for c in counts), counts
