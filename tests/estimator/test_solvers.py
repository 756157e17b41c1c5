"""Tests of jaxvo.estimator.solvers: robust scale, Huber weights, pose recovery on a rendered plane."""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxvo import geometry as G
from jaxvo.camera import DEFAULT
from jaxvo.estimator import pyramid
from jaxvo.estimator.residuals import reference_points
from jaxvo.estimator.solvers import _cholesky_solve6, huber_weights, irls, robust_scale, solve_pose, solve_pose_small

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


def test_cholesky_solve6_matches_numpy():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(6, 6))
    A = (A @ A.T + 0.1 * np.eye(6)).astype(np.float32)
    b = rng.normal(size=6).astype(np.float32)
    np.testing.assert_allclose(np.asarray(_cholesky_solve6(jnp.asarray(A), jnp.asarray(b))),
                               np.linalg.solve(A.astype(np.float64), b), rtol=2e-3, atol=2e-4)


@pytest.mark.parametrize("depth_weight", [None, 600.0])
def test_solve_pose_small_follows_jaxopt(pair, depth_weight):
    """The written-out LM takes jaxopt's iterates: same iteration count, same pose, also on a
    54-pixel sample (the RANSAC hypothesis size) with some weights zero."""
    ref, cur, pts = pair
    rng = np.random.default_rng(1)
    idx = jnp.asarray(rng.choice(np.flatnonzero(np.asarray(pts.valid)), 54, replace=False))
    small_pts = type(pts)(*[x[idx] for x in pts])
    for p, wts in ((pts, jnp.ones(pts.u.shape)), (small_pts, jnp.asarray(rng.random(54) > 0.2, jnp.float32))):
        a = jax.jit(lambda T, p, w: solve_pose(T, p, cur, CAM, w, 8, depth_weight=depth_weight))(jnp.eye(4), p, wts)
        b = jax.jit(lambda T, p, w: solve_pose_small(T, p, cur, CAM, w, 8, depth_weight=depth_weight))(
            jnp.eye(4), p, wts)
        assert int(a.iterations) == int(b.iterations) > 0
        np.testing.assert_allclose(np.asarray(b.T), np.asarray(a.T), atol=2e-4)
        np.testing.assert_allclose(np.asarray(b.hessian), np.asarray(a.hessian), rtol=2e-3,
                                   atol=1e-3 * float(jnp.abs(a.hessian).max()))
    et, er = _errors(jax.jit(lambda T: solve_pose_small(T, pts, cur, CAM, jnp.ones(pts.u.shape), 40).T)(jnp.eye(4)))
    assert et < 1e-3 and er < 0.05, (et, er)


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

    import jaxvo.estimator.solvers

    tree = ast.parse(inspect.getsource(jaxvo.estimator.solvers))
    for node in ast.walk(tree):
        if isinstance(node, ast.ClassDef):
            assert "jaxopt" not in " ".join(ast.unparse(b) for b in node.bases), node.name
        if isinstance(node, ast.Attribute):
            private = node.attr.startswith("_") and not node.attr.startswith("__")
            assert not private and node.attr != "increase_factor", ast.unparse(node)


def test_lm_uses_the_analytic_jacobian(pair):
    """The residual function jaxopt differentiates is the square-root form of the weighted
    problem built from the analytic Jacobian of jaxvo.estimator.residuals.photometric_terms (a custom
    JVP), not autodiff through the sampler: its Jacobian R and residual rho give the same
    Gauss-Newton matrix, gradient and cost as the N weighted residuals."""
    from jaxvo.estimator.residuals import photometric_terms
    from jaxvo.estimator.solvers import _JITTER, _square_root_fun

    ref, cur, pts = pair
    T0 = jnp.asarray(G.exp(0.5 * XI_TRUE), jnp.float32)
    w = jnp.full(pts.u.shape, 0.25, jnp.float32)
    fun = _square_root_fun(T0, pts, cur, CAM, w, None)
    R = np.asarray(jax.jit(jax.jacfwd(lambda d: fun(d)[0]))(jnp.zeros(6, jnp.float32)), np.float64)
    rho, M = [np.asarray(x, np.float64) for x in jax.jit(fun)(jnp.zeros(6, jnp.float32))]
    r, J, _ = [np.asarray(x, np.float64) for x in photometric_terms(T0, pts, cur, CAM)]
    H, g, c = 0.25 * J.T @ J, 0.25 * J.T @ r, 0.25 * r @ r
    np.testing.assert_allclose(M[:6, :6], H, rtol=1e-4, atol=1e-5 * np.abs(H).max())
    np.testing.assert_allclose(M[:6, 6], g, rtol=1e-4, atol=1e-5 * np.abs(g).max())
    assert R.shape == (7, 6) and np.all(R[6] == 0)
    loaded = H + _JITTER * np.abs(np.diag(H)).max() * np.eye(6)
    np.testing.assert_allclose(R.T @ R, loaded, rtol=1e-3, atol=1e-4 * np.abs(H).max())
    np.testing.assert_allclose(R.T @ rho, g, rtol=1e-3, atol=1e-4 * np.abs(g).max())
    assert rho @ rho == pytest.approx(c, rel=1e-4)


def test_consensus_refinement_evaluates_once_per_iteration(pair):
    """With :data:`jaxvo.estimator.solvers.COMPILER_OPTIONS` XLA merges the evaluations jaxopt's update
    makes at one point (residual, auxiliary output, Jacobian): the LM loop's body samples the
    current image once per iteration (5 gathers: 4 bilinear corners, 1 depth for the
    occlusion test), not three times."""
    import re

    from jaxvo.estimator.solvers import jit

    ref, cur, pts = pair
    text = jit(lambda T, w: solve_pose(T, pts, cur, CAM, w, 6)).lower(jnp.eye(4), jnp.ones(pts.u.shape)).compile() \
        .as_text()
    comps, name = {}, None
    for line in text.splitlines():
        m = re.match(r"^(?:ENTRY )?%?([\w.\-]+) .*\{$", line)
        if m:
            name = m.group(1)
            comps[name] = []
        elif name:
            comps[name].append(line)
    gathering = {n for n, lines in comps.items() if any(" gather(" in ln for ln in lines)}
    bodies = [m for lines in comps.values() for ln in lines for m in re.findall(r"while\(.*body=%([\w.\-]+)", ln)]
    assert len(bodies) == 1

    def image_gathers(body):
        calls = [re.search(r"calls=%([\w.\-]+)", ln) for ln in comps[body]]
        return sum(1 for ln, c in zip(comps[body], calls) if c and c.group(1) in gathering
                   and re.search(r"= f32\[\d+,1(,3)?\]", ln))
    assert image_gathers(bodies[0]) == 5
