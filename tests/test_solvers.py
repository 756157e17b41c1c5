"""Tests of jaxvo.solvers: robust scale, Huber weights, pose recovery on a rendered plane."""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxvo import geometry as G
from jaxvo.camera import DEFAULT
from jaxvo import pyramid
from jaxvo.residuals import reference_points
from jaxvo.solvers import huber_weights, irls, robust_scale, solve_pose

CAM = DEFAULT.at_level(2)          # 160 x 120
H, W = CAM.height, CAM.width
N_PLANE = np.array([0.15, -0.1, 1.0]) / np.linalg.norm([0.15, -0.1, 1.0])
D_PLANE = 2.0
XI_TRUE = np.array([0.012, -0.015, 0.008, 0.025, -0.015, 0.03])   # ~1.2 deg, ~4.2 cm
T_TRUE = G.exp(XI_TRUE)            # T_cur_ref

build_pyramid = jax.jit(pyramid.build_pyramid, static_argnums=(2,))


def _texture(P):
    """Smooth analytic texture on the plane (periods 0.3-0.6 m, ~20-40 px at 2 m)."""
    e1 = np.cross(N_PLANE, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(N_PLANE, e1)
    s, t = P @ e1, P @ e2
    return (128 + 50 * np.sin(2 * np.pi * s / 0.45 + 0.4) + 35 * np.cos(2 * np.pi * t / 0.35 - 0.3)
            + 25 * np.sin(2 * np.pi * (s + 0.7 * t) / 0.6))


def _render(T_cam_ref):
    """Intensity and exact depth of the plane n.P = d (reference frame) seen from camera T_cam_ref."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    rays = np.stack([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, np.ones_like(u)], -1)
    R, t = T_cam_ref[:3, :3], T_cam_ref[:3, 3]
    n_c = R @ N_PLANE                          # plane normal in this camera
    Z = (D_PLANE + n_c @ t) / (rays @ n_c)
    P_ref = (Z[..., None] * rays - t) @ R     # R^T (P_cam - t), row-wise
    return _texture(P_ref).astype(np.float32), Z.astype(np.float32)


@functools.partial(jax.jit, static_argnames=("maxiter",))
def _solve(T0, ref, cur, weights, maxiter=40):
    return solve_pose(T0, ref, cur, CAM, weights, maxiter)


def _errors(T):
    dT = G.inverse(T_TRUE) @ np.asarray(T, np.float64)
    return np.linalg.norm(dT[:3, 3]), np.degrees(G.rotation_angle(dT[:3, :3]))


@pytest.fixture(scope="module")
def pair():
    i0, d0 = _render(np.eye(4))
    i1, d1 = _render(T_TRUE)
    ref = build_pyramid(i0, d0, 1)[0]
    cur = build_pyramid(i1, d1, 1)[0]
    return ref, cur, reference_points(ref, CAM)


# --------------------------------------------------------------------------- scale and weights

@pytest.mark.parametrize("sigma", [2.0, 5.0, 20.0])
def test_robust_scale_of_gaussian_samples(sigma):
    rng = np.random.default_rng(int(sigma))
    r = rng.normal(0.0, sigma, 40000).astype(np.float32)
    s = float(robust_scale(jnp.asarray(r), jnp.ones(r.shape, bool)))
    assert s == pytest.approx(sigma, rel=0.03)
    # invalid entries (here huge outliers) are ignored
    r2 = np.concatenate([r, np.full(20000, 200.0, np.float32)])
    valid = np.concatenate([np.ones(40000, bool), np.zeros(20000, bool)])
    s2 = float(robust_scale(jnp.asarray(r2), jnp.asarray(valid)))
    assert s2 == pytest.approx(sigma, rel=0.03)
    # 20 % gross outliers move the MAD only moderately
    r3 = np.concatenate([r, rng.uniform(-250, 250, 10000).astype(np.float32)])
    s3 = float(robust_scale(jnp.asarray(r3), jnp.ones(r3.shape, bool)))
    assert sigma < s3 < 1.5 * sigma


def test_robust_scale_matches_numpy_mad():
    rng = np.random.default_rng(3)
    r = rng.laplace(0.0, 4.0, 30001).astype(np.float32)
    s = float(robust_scale(jnp.asarray(r), jnp.ones(r.shape, bool)))
    assert s == pytest.approx(1.4826 * np.median(np.abs(r)), rel=0.01)


def test_huber_weights_values():
    r = jnp.asarray([0.0, 1.0, -2.69, 4.0, -8.0, 100.0])
    valid = jnp.asarray([True, True, True, True, True, False])
    w = np.asarray(huber_weights(r, valid, 1.345, 2.0))
    c = 1.345 * 2.0
    np.testing.assert_allclose(w, [1.0, 1.0, 1.0, c / 4.0, c / 8.0, 0.0], rtol=1e-6)
    # weighted residual is bounded by c (Huber influence)
    wr = np.abs(np.asarray(huber_weights(jnp.asarray([10.0, 1e4]), jnp.ones(2, bool), 1.0, 3.0)) * [10.0, 1e4])
    np.testing.assert_allclose(wr, 3.0, rtol=1e-6)


# --------------------------------------------------------------------------- pose recovery

def test_rendered_pair_is_consistent(pair):
    """Sanity check of the test's own renderer: warping the reference depth with T_TRUE
    lands on the current depth."""
    ref, cur, pts = pair
    P = np.asarray(pts.points, np.float64)
    Q = G.transform_points(T_TRUE, P)
    u = CAM.fx * Q[:, 0] / Q[:, 2] + CAM.cx
    v = CAM.fy * Q[:, 1] / Q[:, 2] + CAM.cy
    inside = (u > 1) & (u < W - 2) & (v > 1) & (v < H - 2)
    _, Zc = _render(T_TRUE)
    # depth along the optical axis at the (rounded) warped pixel vs the transformed point
    zi = Zc[np.round(v[inside]).astype(int), np.round(u[inside]).astype(int)]
    np.testing.assert_allclose(zi, Q[inside, 2], atol=0.02)


def test_solve_pose_recovers_known_motion(pair):
    ref, cur, pts = pair
    sol = _solve(jnp.eye(4), pts, cur, jnp.ones(pts.u.shape))
    et, er = _errors(sol.T)
    assert et < 1e-3 and er < 0.05, (et, er)
    assert 0 < int(sol.iterations) <= 40
    Hs = np.asarray(sol.hessian)
    np.testing.assert_allclose(Hs, Hs.T, rtol=1e-4, atol=1e-3 * np.abs(Hs).max())
    assert np.linalg.eigvalsh(0.5 * (Hs + Hs.T)).min() > 0
    assert np.isfinite(float(sol.cost)) and float(sol.cost) >= 0
    # starting at the truth stays at the truth
    sol2 = _solve(jnp.asarray(T_TRUE, jnp.float32), pts, cur, jnp.ones(pts.u.shape))
    et2, er2 = _errors(sol2.T)
    assert et2 < 1e-3 and er2 < 0.05


def test_zero_weights_make_a_corrupted_region_irrelevant(pair):
    ref, cur, pts = pair
    i1 = np.asarray(cur.intensity).copy()
    d1 = np.asarray(cur.depth).copy()
    rng = np.random.default_rng(0)
    i1[:, 110:] = rng.uniform(0, 255, (H, W - 110))           # garbage in the right part
    cur_bad = build_pyramid(i1, d1, 1)[0]
    w = (np.asarray(pts.u) < 100).astype(np.float32)           # ignore reference pixels that land there
    sol = _solve(jnp.eye(4), pts, cur_bad, jnp.asarray(w))
    et, er = _errors(sol.T)
    assert et < 1e-3 and er < 0.05, (et, er)
    # with all weights 1 the garbage does matter
    sol_all = _solve(jnp.eye(4), pts, cur_bad, jnp.ones(pts.u.shape))
    et_all, er_all = _errors(sol_all.T)
    assert et_all > 3 * max(et, 1e-4) or er_all > 3 * max(er, 5e-3)


def test_irls_huber_recovers_known_motion(pair):
    ref, cur, pts = pair
    f = jax.jit(lambda T0, w: irls(T0, pts, cur, CAM, w, 1.345, 3, 15))
    sol = f(jnp.eye(4), jnp.ones(pts.u.shape))
    et, er = _errors(sol.T)
    assert et < 1e-3 and er < 0.05, (et, er)


# --------------------------------------------------------------------------- jaxopt through its public API

def test_jaxopt_and_jax_import_together_at_the_declared_versions(pair):
    """jaxopt and jax import together, at least at the versions jaxvo declares (which are the
    oldest tested), and one LM solve runs: an incompatible pair fails here, at import or on
    the first solve, instead of deep inside a run."""
    from importlib.metadata import requires, version

    import jaxopt
    from packaging.requirements import Requirement

    declared = {r.name: r for r in map(Requirement, requires("jaxvo")) if r.marker is None}
    for name in ("jax", "jaxopt"):
        assert declared[name].specifier.contains(version(name)), (name, version(name), str(declared[name]))
    assert hasattr(jaxopt, "LevenbergMarquardt")
    ref, cur, pts = pair
    sol = _solve(jnp.eye(4), pts, cur, jnp.ones(pts.u.shape))
    assert np.all(np.isfinite(np.asarray(sol.T))) and int(sol.iterations) >= 1


def test_solvers_use_only_the_public_jaxopt_api():
    """No subclass of a jaxopt class, no private attribute (``solver._x``), no reading of LM's
    internal bookkeeping (``increase_factor``): what a jaxopt release may change without notice."""
    import ast
    import inspect

    import jaxvo.solvers

    tree = ast.parse(inspect.getsource(jaxvo.solvers))
    for node in ast.walk(tree):
        if isinstance(node, ast.ClassDef):
            assert "jaxopt" not in " ".join(ast.unparse(b) for b in node.bases), node.name
        if isinstance(node, ast.Attribute):
            private = node.attr.startswith("_") and not node.attr.startswith("__")
            assert not private and node.attr != "increase_factor", ast.unparse(node)


def test_lm_uses_the_analytic_jacobian(pair):
    """The residual function jaxopt differentiates yields the analytic Jacobian of
    jaxvo.residuals.photometric_terms (a custom JVP), not autodiff through the sampler."""
    from jaxvo.residuals import photometric_terms
    from jaxvo.solvers import _weighted_residual_fun

    ref, cur, pts = pair
    T0 = jnp.asarray(G.exp(0.5 * XI_TRUE), jnp.float32)
    sqrt_w = jnp.full(pts.u.shape, 0.5, jnp.float32)
    fun = _weighted_residual_fun(T0, pts, cur, CAM, sqrt_w, None)
    J = jax.jit(jax.jacfwd(fun))(jnp.zeros(6, jnp.float32))
    r, J_ref, _ = photometric_terms(T0, pts, cur, CAM)
    np.testing.assert_allclose(np.asarray(J), 0.5 * np.asarray(J_ref), rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(np.asarray(fun(jnp.zeros(6))), 0.5 * np.asarray(r), rtol=1e-5, atol=1e-4)
