"""Tests of jaxvo.estimator.residuals: warp, sampling, residual masks, warp and photometric Jacobians."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxvo import geometry as G
from jaxvo.camera import DEFAULT
from jaxvo.estimator import pyramid
from jaxvo.estimator.residuals import (photometric_terms, reference_points, residuals, sample_bilinear,
                             sample_nearest, select_points, warp, warp_jacobian)

CAM = DEFAULT.at_level(2)          # 160 x 120, fx = 131.25, c = (79.5, 59.5)
H, W = CAM.height, CAM.width
XI0 = np.array([0.02, -0.03, 0.015, 0.05, -0.03, 0.08])
T0 = G.exp(XI0)                    # float64, non-trivial

build_pyramid = jax.jit(pyramid.build_pyramid, static_argnums=(2,))


def _image(u, v):
    """Smooth analytic texture on 0-255 (periods of 40-70 pixels)."""
    return (128.0 + 60.0 * np.sin(2 * np.pi * u / 50 + 0.3) * np.cos(2 * np.pi * v / 40 - 0.2)
            + 20.0 * np.sin(2 * np.pi * (u + v) / 70))


def _depth(u, v):
    return 2.0 + 0.004 * (u - 80.0) - 0.003 * (v - 60.0)


def _grid():
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    return u, v


def _level(intensity, depth):
    return build_pyramid(np.asarray(intensity, np.float32), np.asarray(depth, np.float32), 1)[0]


@pytest.fixture(scope="module")
def scene():
    u, v = _grid()
    return _level(_image(u, v), _depth(u, v))


# --------------------------------------------------------------------------- warp

def test_warp_identity_returns_pixel_grid(scene):
    ref = reference_points(scene, CAM)
    assert ref.points.shape == (H * W, 3)
    Pc, u, v, front = jax.jit(warp, static_argnums=2)(jnp.eye(4), ref.points, CAM)
    uu, vv = _grid()
    np.testing.assert_allclose(np.asarray(u), uu.reshape(-1), atol=2e-4)
    np.testing.assert_allclose(np.asarray(v), vv.reshape(-1), atol=2e-4)
    np.testing.assert_allclose(np.asarray(Pc[:, 2]), _depth(uu, vv).reshape(-1), rtol=1e-6)
    assert np.all(np.asarray(front))
    np.testing.assert_array_equal(np.asarray(ref.u), uu.reshape(-1))
    np.testing.assert_array_equal(np.asarray(ref.v), vv.reshape(-1))


def test_warp_against_hand_made_float64_warp(scene):
    ref = reference_points(scene, CAM)
    Pc, u, v, front = warp(jnp.asarray(T0, jnp.float32), ref.points, CAM)
    fx, fy, cx, cy = 131.25, 131.25, 79.5, 59.5
    R, t = T0[:3, :3], T0[:3, 3]
    for (pu, pv) in [(0, 0), (159, 0), (0, 119), (159, 119), (80, 60), (17, 93), (131, 7)]:
        Z = _depth(pu, pv)
        P = np.array([(pu - cx) / fx * Z, (pv - cy) / fy * Z, Z])
        Q = [sum(R[r, c] * P[c] for c in range(3)) + t[r] for r in range(3)]
        eu = fx * Q[0] / Q[2] + cx
        ev = fy * Q[1] / Q[2] + cy
        i = pv * W + pu
        np.testing.assert_allclose(float(u[i]), eu, atol=2e-3)
        np.testing.assert_allclose(float(v[i]), ev, atol=2e-3)
        np.testing.assert_allclose(np.asarray(Pc[i]), Q, atol=1e-5)
        assert bool(front[i])


# --------------------------------------------------------------------------- sampling

def test_sample_bilinear_of_linear_function_is_exact():
    uu, vv = _grid()
    f = 3.0 * uu - 2.0 * vv + 5.0
    imgs = jnp.asarray(np.stack([f, 2 * f, -f + 300], -1), jnp.float32)
    rng = np.random.default_rng(0)
    u = np.concatenate([rng.uniform(0, W - 1, 300), [0, W - 1, 0, W - 1, 12.5, W - 1.0]])
    v = np.concatenate([rng.uniform(0, H - 1, 300), [0, 0, H - 1, H - 1, 7.25, 33.0]])
    out = np.asarray(sample_bilinear(imgs, jnp.asarray(u, jnp.float32), jnp.asarray(v, jnp.float32)))
    fe = 3.0 * u - 2.0 * v + 5.0
    np.testing.assert_allclose(out, np.stack([fe, 2 * fe, -fe + 300], -1), atol=2e-3)


def test_sample_bilinear_known_values():
    img = np.arange(12, dtype=np.float32).reshape(3, 4) ** 2
    u = jnp.asarray([0.5, 2.0, 1.0, 3.0])
    v = jnp.asarray([0.5, 1.0, 1.5, 2.0])
    out = np.asarray(sample_bilinear(jnp.asarray(img)[..., None], u, v))[:, 0]
    np.testing.assert_allclose(out, [img[:2, :2].mean(), img[1, 2], 0.5 * (img[1, 1] + img[2, 1]), img[2, 3]],
                               rtol=1e-6)


def test_sample_nearest_rounds():
    img = np.arange(12, dtype=np.float32).reshape(3, 4)
    out = np.asarray(sample_nearest(jnp.asarray(img), jnp.asarray([0.4, 0.6, 2.9, 3.0, -5.0]),
                                    jnp.asarray([0.0, 1.4, 1.6, 2.0, 0.0])))
    np.testing.assert_array_equal(out, [img[0, 0], img[1, 1], img[2, 3], img[2, 3], img[0, 0]])


# --------------------------------------------------------------------------- Jacobians

def test_warp_jacobian_matches_autodiff_of_left_perturbation():
    rng = np.random.default_rng(1)
    P = np.column_stack([rng.uniform(-1, 1, 30), rng.uniform(-0.8, 0.8, 30), rng.uniform(0.8, 4.0, 30)])
    P = jnp.asarray(P, jnp.float32)
    T0j = jnp.asarray(T0, jnp.float32)

    def uv(delta):
        _, u, v, _ = warp(G.exp(delta) @ T0j, P, CAM)
        return jnp.stack([u, v], -1)              # (N, 2)

    J_ad = np.asarray(jax.jit(jax.jacfwd(uv))(jnp.zeros(6)))     # (N, 2, 6)
    Pc = warp(T0j, P, CAM)[0]
    J = np.asarray(warp_jacobian(Pc, CAM))
    assert J.shape == (30, 2, 6)
    np.testing.assert_allclose(J, J_ad, rtol=1e-3, atol=1e-2)
    # and against float64 central differences of an independent NumPy projection
    Pn, h = np.asarray(P, np.float64), 1e-6
    fx, cx, cy = 131.25, 79.5, 59.5
    for k in range(6):
        e = np.zeros(6)
        e[k] = h
        q = [G.transform_points(G.exp(s * e) @ T0, Pn) for s in (1, -1)]
        uvs = [np.stack([fx * x[:, 0] / x[:, 2] + cx, fx * x[:, 1] / x[:, 2] + cy], -1) for x in q]
        np.testing.assert_allclose(J[:, :, k], (uvs[0] - uvs[1]) / (2 * h), rtol=2e-3, atol=2e-2)


def test_photometric_jacobian_matches_finite_differences(scene):
    uu, vv = _grid()
    # reference: the same depth, any intensity (the Jacobian does not depend on it)
    ref_level = _level(_image(uu, vv), _depth(uu, vv))
    ref = reference_points(ref_level, CAM, stride=3)
    T = jnp.asarray(G.exp(np.array([0.01, -0.02, 0.01, 0.03, -0.02, 0.05])), jnp.float32)
    r0, J, valid = jax.jit(photometric_terms, static_argnums=3)(T, ref, scene, CAM)

    res = jax.jit(lambda T: residuals(T, ref, scene, CAM))
    steps = np.array([1e-2, 1e-2, 1e-2, 2e-2, 2e-2, 4e-2])   # ~1-2 pixels each
    J_fd = np.zeros(J.shape)
    ok = np.asarray(valid).copy()
    for k in range(6):
        e = np.zeros(6)
        e[k] = steps[k]
        rp = res(jnp.asarray(G.exp(e) @ np.asarray(T, np.float64), jnp.float32))
        rm = res(jnp.asarray(G.exp(-e) @ np.asarray(T, np.float64), jnp.float32))
        ok &= np.asarray(rp.valid_int) & np.asarray(rm.valid_int)
        J_fd[:, k] = (np.asarray(rp.r_int) - np.asarray(rm.r_int)) / (2 * steps[k])
    J = np.asarray(J)
    assert ok.sum() > 1000
    # invalid rows are zero
    assert np.all(J[~np.asarray(valid)] == 0) and np.all(np.asarray(r0)[~np.asarray(valid)] == 0)
    for k in range(6):
        a, b = J[ok, k], J_fd[ok, k]
        rel = np.linalg.norm(a - b) / np.linalg.norm(b)
        assert rel < 0.03, (k, rel)
    # the residual of photometric_terms is the residual of `residuals`
    np.testing.assert_allclose(np.asarray(r0), np.asarray(res(T).r_int), atol=1e-3)


# --------------------------------------------------------------------------- residual values and masks

def _flat_scene(z_ref=2.0, z_cur=2.0, offset=0.0):
    uu, vv = _grid()
    img = _image(uu, vv)
    ref = _level(img, np.full((H, W), z_ref))
    cur = _level(img + offset, np.full((H, W), z_cur))
    return ref, cur


def test_residual_values_identity_and_depth():
    ref_l, cur_l = _flat_scene(2.0, 2.1, offset=5.0)
    ref = reference_points(ref_l, CAM)
    r = residuals(jnp.eye(4), ref, cur_l, CAM)
    assert np.all(np.asarray(r.valid_int)) and np.all(np.asarray(r.valid_depth))
    np.testing.assert_allclose(np.asarray(r.r_int), 5.0, atol=1e-3)
    np.testing.assert_allclose(np.asarray(r.r_depth), 0.1, atol=1e-5)
    # moving the camera 0.1 m forward: the point's depth matches the current depth
    T = np.eye(4)
    T[2, 3] = 0.1
    r = residuals(jnp.asarray(T, jnp.float32), ref, cur_l, CAM)
    v = np.asarray(r.valid_depth)
    assert v.sum() > 0.5 * H * W
    np.testing.assert_allclose(np.asarray(r.r_depth)[v], 0.0, atol=1e-5)
    np.testing.assert_allclose(np.asarray(r.z), 2.1, atol=1e-5)


def test_residual_masks():
    ref_l, cur_l = _flat_scene()
    # invalid reference depth in the left quarter, invalid current depth in the bottom rows
    ref_d = np.asarray(ref_l.depth).copy()
    ref_d[:, :40] = 0.0
    cur_d = np.asarray(cur_l.depth).copy()
    cur_d[100:, :] = 0.0
    ref_l = ref_l._replace(depth=jnp.asarray(ref_d))
    cur_l = cur_l._replace(depth=jnp.asarray(cur_d))
    ref = reference_points(ref_l, CAM)
    r = residuals(jnp.eye(4), ref, cur_l, CAM)
    vi = np.asarray(r.valid_int).reshape(H, W)
    vd = np.asarray(r.valid_depth).reshape(H, W)
    assert not vi[:, :40].any() and vi[:, 40:].all()
    assert not vd[100:].any() and vd[:100, 40:].all() and not vd[:, :40].any()
    assert np.all(np.asarray(r.r_int).reshape(H, W)[:, :40] == 0)
    assert np.all(np.asarray(r.r_depth).reshape(H, W)[100:] == 0)

    # outside the image: shift by 40 pixels to the right (x translation of 40 / fx * Z)
    T = np.eye(4)
    T[0, 3] = 40 / CAM.fx * 2.0
    r = residuals(jnp.asarray(T, jnp.float32), ref, cur_l, CAM)
    vi = np.asarray(r.valid_int).reshape(H, W)
    u = np.asarray(r.u).reshape(H, W)
    np.testing.assert_allclose(u[0, 50], 90.0, atol=1e-3)
    assert not vi[:, 120:].any()            # warped to u >= 160
    assert vi[:, 40:119].all()
    assert np.all(np.asarray(r.r_int).reshape(H, W)[:, 120:] == 0)

    # behind the camera: half a turn about the y axis
    T = G.exp(np.array([0, np.pi, 0, 0, 0, 0]))
    r = residuals(jnp.asarray(T, jnp.float32), ref, cur_l, CAM)
    assert not np.asarray(r.valid_int).any() and not np.asarray(r.valid_depth).any()
    assert np.all(np.asarray(r.r_int) == 0) and np.all(np.asarray(r.r_depth) == 0)
    assert np.all(np.asarray(r.z)[np.asarray(ref.valid)] < 0)


def test_photometric_terms_invalid_rows_are_zero():
    ref_l, cur_l = _flat_scene()
    ref = reference_points(ref_l, CAM)
    T = np.eye(4)
    T[0, 3] = 0.5
    r, J, valid = photometric_terms(jnp.asarray(T, jnp.float32), ref, cur_l, CAM)
    valid = np.asarray(valid)
    assert valid.any() and not valid.all()
    assert np.all(np.asarray(J)[~valid] == 0) and np.all(np.asarray(r)[~valid] == 0)
    assert np.all(np.isfinite(np.asarray(J)))


def test_select_points_picks_strongest_gradient_with_valid_depth():
    h, w, b = 8, 8, 4
    img = np.zeros((h, w), np.float32)
    # tile (0, 0): a bright spike at (row 1, col 2) -> strongest gradients at its neighbours
    img[1, 2] = 100.0
    depth = np.ones((h, w), np.float32)
    depth[4:, 4:] = 0.0                       # tile (1, 1): no valid depth
    lev = build_pyramid(img, depth, 1)[0]
    cam = DEFAULT.at_level(2).with_size(w, h)
    pts = select_points(lev, cam, b)
    assert pts.u.shape == ((h // b) * (w // b),)
    g2 = np.asarray(lev.igrad[..., 1] ** 2 + lev.igrad[..., 2] ** 2)
    tile = np.where(depth[:4, :4] > 0, g2[:4, :4], -1)
    r, c = np.unravel_index(np.argmax(tile), tile.shape)
    assert (float(pts.u[0]), float(pts.v[0])) == (c, r)
    assert g2[int(pts.v[0]), int(pts.u[0])] > 0
    valid = np.asarray(pts.valid)
    np.testing.assert_array_equal(valid, [True, True, True, False])
    # every selected point lies in its own tile
    for k in range(4):
        tr, tc = divmod(k, 2)
        assert tc * b <= float(pts.u[k]) < (tc + 1) * b and tr * b <= float(pts.v[k]) < (tr + 1) * b
    # block 1 is every pixel
    assert select_points(lev, cam, 1).u.shape == (h * w,)


@pytest.mark.parametrize("b", [2, 3, 4])
def test_select_points_matches_a_per_tile_loop(b):
    """Against an independent NumPy loop over the tiles: the pixel of largest score
    (gradient^2 + 1e-3) * (weight + 1e-6) among valid depth, the first in the tile's row-major
    order on ties (a flat image ties everywhere), on a size that is not a multiple of the tile."""
    rng = np.random.default_rng(b)
    h, w = 13, 18
    img = np.round(rng.uniform(0, 4, (h, w))).astype(np.float32)   # small integers: many ties
    img[:, :6] = 7.0                                                  # flat columns: all ties
    depth = np.where(rng.uniform(size=(h, w)) < 0.8, 1.5, 0.0).astype(np.float32)
    weight = np.where(rng.uniform(size=(h, w)) < 0.7, 1.0, 0.2).astype(np.float32)
    lev = build_pyramid(img, depth, 1, weight=weight)[0]
    cam = DEFAULT.at_level(2).with_size(w, h)
    pts = select_points(lev, cam, b)
    g2 = np.asarray(lev.igrad[..., 1] ** 2 + lev.igrad[..., 2] ** 2)
    score = np.where(depth > 0, (g2 + np.float32(1e-3)) * (weight + np.float32(1e-6)), 0.0)
    want = []
    for tr in range(h // b):
        for tc in range(w // b):
            tile = score[tr * b:(tr + 1) * b, tc * b:(tc + 1) * b]
            r, c = np.unravel_index(np.argmax(tile), tile.shape)   # first maximum, row-major
            want.append((tc * b + c, tr * b + r))
    got = list(zip(np.asarray(pts.u).astype(int).tolist(), np.asarray(pts.v).astype(int).tolist()))
    assert got == want
