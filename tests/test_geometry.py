"""Tests of jaxvo.geometry: SE(3)/SO(3) maps checked against SciPy and against each other."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from jaxvo import geometry as G


def _random_twists(rng, n, max_angle=3.0, max_trans=2.0):
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = rng.uniform(0.0, max_angle, size=(n, 1))
    v = rng.uniform(-max_trans, max_trans, size=(n, 3))
    return np.concatenate([axis * angle, v], 1)


def _hat_ref(xi):
    """4x4 se(3) matrix written out by hand (independent of G.hat)."""
    w1, w2, w3, v1, v2, v3 = xi
    return np.array([[0.0, -w3, w2, v1],
                     [w3, 0.0, -w1, v2],
                     [-w2, w1, 0.0, v3],
                     [0.0, 0.0, 0.0, 0.0]])


# --------------------------------------------------------------------------- hat / skew / vee

def test_skew_is_cross_product_and_vee_inverts_it():
    rng = np.random.default_rng(0)
    w, x = rng.normal(size=(2, 10, 3))
    W = G.skew(w)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", W, x), np.cross(w, x), atol=1e-12)
    np.testing.assert_allclose(W, -np.swapaxes(W, -1, -2))
    np.testing.assert_allclose(G.vee(W), w)


def test_hat_layout_rotation_first():
    xi = np.array([0.1, -0.2, 0.3, 1.0, 2.0, 3.0])
    np.testing.assert_array_equal(G.hat(xi), _hat_ref(xi))


# --------------------------------------------------------------------------- exp against scipy

def test_exp_matches_scipy_expm_of_hat():
    rng = np.random.default_rng(1)
    for xi in _random_twists(rng, 50):
        np.testing.assert_allclose(G.exp(xi), expm(_hat_ref(xi)), atol=1e-12)


@pytest.mark.parametrize("scale", [0.0, 1e-12, 1e-9, 1e-6, 1e-4, 2e-4, 1e-2])
def test_exp_matches_expm_for_tiny_rotations(scale):
    rng = np.random.default_rng(2)
    for _ in range(5):
        xi = np.concatenate([rng.normal(size=3) * scale, rng.normal(size=3)])
        np.testing.assert_allclose(G.exp(xi), expm(_hat_ref(xi)), atol=1e-14, rtol=1e-12)


def test_exp_so3_matches_scipy_rotvec():
    rng = np.random.default_rng(3)
    w = _random_twists(rng, 100, max_angle=np.pi)[:, :3]
    np.testing.assert_allclose(G.exp_so3(w), Rotation.from_rotvec(w).as_matrix(), atol=1e-12)
    # also the rotation block of exp
    np.testing.assert_allclose(G.exp(np.concatenate([w, np.zeros_like(w)], 1))[:, :3, :3],
                               Rotation.from_rotvec(w).as_matrix(), atol=1e-12)


def test_log_so3_matches_scipy_rotvec():
    rng = np.random.default_rng(4)
    w = _random_twists(rng, 100, max_angle=np.pi - 1e-3)[:, :3]
    R = Rotation.from_rotvec(w).as_matrix()
    np.testing.assert_allclose(G.log_so3(R), Rotation.from_matrix(R).as_rotvec(), atol=1e-10)
    np.testing.assert_allclose(G.log_so3(R), w, atol=1e-10)


# --------------------------------------------------------------------------- round trips

def test_exp_log_round_trip_random():
    rng = np.random.default_rng(5)
    xi = _random_twists(rng, 200, max_angle=np.pi - 1e-3)
    T = G.exp(xi)
    np.testing.assert_allclose(G.log(T), xi, atol=1e-9)
    np.testing.assert_allclose(G.exp(G.log(T)), T, atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-9, 1e-7, 1e-5, 1e-4, 1.01e-4, 1e-3])
def test_exp_log_round_trip_tiny_rotations(angle):
    rng = np.random.default_rng(6)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    xi = np.concatenate([axis * angle, [0.3, -0.2, 1.5]])
    T = G.exp(xi)
    np.testing.assert_allclose(G.log(T), xi, atol=1e-12, rtol=1e-9)
    # a pure tiny translation too
    xi_t = np.array([0, 0, 0, 1e-9, -2e-9, 3e-9])
    np.testing.assert_allclose(G.log(G.exp(xi_t)), xi_t, atol=1e-18, rtol=1e-9)


@pytest.mark.parametrize("eps", [1e-2, 1e-4, 1e-6, 1e-8])
def test_exp_log_round_trip_near_pi(eps):
    rng = np.random.default_rng(7)
    for _ in range(5):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        xi = np.concatenate([axis * (np.pi - eps), rng.normal(size=3)])
        T = G.exp(xi)
        xi2 = G.log(T)
        # the angle stays in [0, pi] and the transform is reproduced exactly
        assert np.linalg.norm(xi2[:3]) <= np.pi + 1e-12
        np.testing.assert_allclose(G.exp(xi2), T, atol=1e-9)
        np.testing.assert_allclose(G.rotation_angle(T[:3, :3]), np.pi - eps, atol=1e-9)
        if eps >= 1e-4:  # far enough from the antipodal ambiguity: the twist itself
            np.testing.assert_allclose(xi2, xi, atol=1e-6)


def test_log_at_exactly_pi():
    for axis in (np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0]),
                 np.array([1.0, 1.0, 0]) / np.sqrt(2)):
        R = Rotation.from_rotvec(np.pi * axis).as_matrix()
        w = G.log_so3(R)
        assert np.isfinite(w).all()
        np.testing.assert_allclose(np.linalg.norm(w), np.pi, atol=1e-9)
        np.testing.assert_allclose(G.exp_so3(w), R, atol=1e-9)


# --------------------------------------------------------------------------- quaternions

def test_quaternion_conversions_match_scipy():
    rng = np.random.default_rng(8)
    rots = Rotation.random(100, random_state=9)
    R = rots.as_matrix()
    q_ref = rots.as_quat()                      # (x, y, z, w)
    q_ref = np.where(q_ref[:, 3:4] < 0, -q_ref, q_ref)
    q = G.quat_from_matrix(R)
    np.testing.assert_allclose(q, q_ref, atol=1e-12)
    assert np.all(q[:, 3] >= 0)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-14)
    # matrix_from_quat accepts any sign and non-unit norm
    scale = rng.uniform(0.1, 10.0, size=(100, 1)) * rng.choice([-1.0, 1.0], size=(100, 1))
    np.testing.assert_allclose(G.matrix_from_quat(q_ref * scale), R, atol=1e-12)
    np.testing.assert_allclose(G.matrix_from_quat(q_ref), Rotation.from_quat(q_ref).as_matrix(), atol=1e-12)


def test_quaternion_of_known_rotations():
    # 90 degrees about z: q = (0, 0, sin 45, cos 45)
    R = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    np.testing.assert_allclose(G.quat_from_matrix(R), [0, 0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-15)
    np.testing.assert_allclose(G.quat_from_matrix(np.eye(3)), [0, 0, 0, 1], atol=1e-15)
    # 180 degrees about x: q = +-(1, 0, 0, 0)
    q = G.quat_from_matrix(np.diag([1.0, -1.0, -1.0]))
    np.testing.assert_allclose(np.abs(q), [1, 0, 0, 0], atol=1e-15)


def test_transform_quat_trans_round_trip():
    rots = Rotation.random(20, random_state=10)
    t = np.random.default_rng(11).normal(size=(20, 3))
    T = G.transform_from_quat_trans(rots.as_quat(), t)
    np.testing.assert_allclose(T[:, :3, :3], rots.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(T[:, :3, 3], t)
    np.testing.assert_array_equal(T[:, 3], np.tile([0, 0, 0, 1.0], (20, 1)))
    q2, t2 = G.quat_trans_from_transform(T)
    np.testing.assert_allclose(G.transform_from_quat_trans(q2, t2), T, atol=1e-12)


# --------------------------------------------------------------------------- compose / inverse / points

def test_inverse_compose_identity():
    rng = np.random.default_rng(12)
    T = G.exp(_random_twists(rng, 30))
    I = np.broadcast_to(np.eye(4), T.shape)
    np.testing.assert_allclose(G.compose(G.inverse(T), T), I, atol=1e-12)
    np.testing.assert_allclose(G.compose(T, G.inverse(T)), I, atol=1e-12)
    np.testing.assert_allclose(G.inverse(T), np.linalg.inv(T), atol=1e-12)
    # inverse of exp is exp of minus
    xi = _random_twists(rng, 5)
    np.testing.assert_allclose(G.inverse(G.exp(xi)), G.exp(-xi), atol=1e-12)


def test_compose_order_and_transform_points():
    rng = np.random.default_rng(13)
    T_ab, T_bc = G.exp(_random_twists(rng, 2))
    P_c = rng.normal(size=(7, 3))
    P_b = np.array([T_bc[:3, :3] @ p + T_bc[:3, 3] for p in P_c])
    P_a = np.array([T_ab[:3, :3] @ p + T_ab[:3, 3] for p in P_b])
    np.testing.assert_allclose(G.transform_points(T_bc, P_c), P_b, atol=1e-12)
    np.testing.assert_allclose(G.transform_points(G.compose(T_ab, T_bc), P_c), P_a, atol=1e-12)
    # batched transforms with their own point sets
    Ts = np.stack([T_ab, T_bc])
    Ps = np.stack([P_b, P_c])
    np.testing.assert_allclose(G.transform_points(Ts, Ps), np.stack([P_a, P_b]), atol=1e-12)


def test_rotation_angle_matches_scipy_magnitude():
    rots = Rotation.random(50, random_state=14)
    np.testing.assert_allclose(G.rotation_angle(rots.as_matrix()), rots.magnitude(), atol=1e-10)
    assert G.rotation_angle(np.eye(3)) == 0.0
    np.testing.assert_allclose(G.rotation_angle(Rotation.from_rotvec([0, 1e-9, 0]).as_matrix()), 1e-9,
                               rtol=1e-6)


def test_project_to_so3():
    R = Rotation.random(10, random_state=15).as_matrix()
    # a scaled rotation (as in the Bonn calibration) projects back onto the rotation
    np.testing.assert_allclose(G.project_to_so3(1.7 * R), R, atol=1e-12)
    # a perturbed matrix gives a proper rotation close to the original
    noisy = R + 1e-3 * np.random.default_rng(16).normal(size=R.shape)
    P = G.project_to_so3(noisy)
    np.testing.assert_allclose(P @ np.swapaxes(P, -1, -2), np.broadcast_to(np.eye(3), P.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(P), 1.0, atol=1e-12)
    assert np.all(G.rotation_angle(np.swapaxes(P, -1, -2) @ R) < 5e-3)
    # a reflection is turned into a rotation (det +1), not kept
    assert np.linalg.det(G.project_to_so3(np.diag([1.0, 1.0, -1.0]))) == pytest.approx(1.0)


# --------------------------------------------------------------------------- dtypes and batching

def test_numpy_inputs_stay_numpy_float64():
    xi = np.array([0.1, 0.2, -0.3, 0.5, 0.6, 0.7])
    for out in (G.exp(xi), G.log(G.exp(xi)), G.exp_so3(xi[:3]), G.log_so3(G.exp_so3(xi[:3])),
                G.inverse(G.exp(xi)), G.quat_from_matrix(G.exp_so3(xi[:3])), G.hat(xi)):
        assert isinstance(out, np.ndarray)
        assert out.dtype == np.float64
    # 1e-9 survives only in float64
    small = np.array([1e-9, 0, 0, 1e-9, 0, 0])
    np.testing.assert_allclose(G.log(G.exp(small)), small, rtol=1e-9)
    # plain Python lists are host inputs too
    assert np.asarray(G.exp([0.0] * 6)).dtype == np.float64


def test_jax_inputs_give_jax_arrays_matching_numpy():
    rng = np.random.default_rng(17)
    xi = _random_twists(rng, 10)
    out = jax.jit(G.exp)(jnp.asarray(xi, jnp.float32))
    assert isinstance(out, jax.Array)
    np.testing.assert_allclose(np.asarray(out), G.exp(xi), atol=2e-5)
    out_jit = jax.jit(G.log)(jnp.asarray(G.exp(xi), jnp.float32))
    np.testing.assert_allclose(np.asarray(out_jit), xi, atol=5e-4)


def test_batched_inputs():
    rng = np.random.default_rng(18)
    xi = _random_twists(rng, 15).reshape(3, 5, 6)
    T = G.exp(xi)
    assert T.shape == (3, 5, 4, 4)
    for i in range(3):
        for j in range(5):
            np.testing.assert_allclose(T[i, j], expm(_hat_ref(xi[i, j])), atol=1e-12)
    assert G.log(T).shape == (3, 5, 6)
    np.testing.assert_allclose(G.log(T), xi, atol=1e-9)
    assert G.hat(xi).shape == (3, 5, 4, 4)
    assert G.quat_from_matrix(T[..., :3, :3]).shape == (3, 5, 4)
    assert G.inverse(T).shape == (3, 5, 4, 4)
    # the JAX path batches the same way (and under vmap)
    Tj = jax.jit(jax.vmap(G.exp))(jnp.asarray(xi[0], jnp.float32))
    np.testing.assert_allclose(np.asarray(Tj), T[0], atol=2e-5)


# --------------------------------------------------------------------------- gradients at zero

def _generators():
    return np.stack([_hat_ref(e) for e in np.eye(6)], -1)   # (4, 4, 6)


def test_exp_jacobian_at_zero_is_finite_and_the_generators():
    J = jax.jit(jax.jacfwd(G.exp))(jnp.zeros(6))
    assert np.isfinite(np.asarray(J)).all()
    np.testing.assert_allclose(np.asarray(J), _generators(), atol=1e-6)
    Jr = jax.jit(jax.jacrev(G.exp))(jnp.zeros(6))
    np.testing.assert_allclose(np.asarray(Jr), _generators(), atol=1e-6)
    g = jax.jit(jax.grad(lambda x: jnp.sum(G.exp(x) ** 2)))(jnp.zeros(6))
    assert np.isfinite(np.asarray(g)).all()


def test_exp_so3_gradient_at_zero():
    J = jax.jit(jax.jacfwd(G.exp_so3))(jnp.zeros(3))
    assert np.isfinite(np.asarray(J)).all()
    np.testing.assert_allclose(np.asarray(J), _generators()[:3, :3, :3], atol=1e-6)


def test_log_values_and_gradients_at_identity():
    I = jnp.eye(4)
    assert np.all(np.asarray(G.log(I)) == 0.0)

    @jax.jit
    def derivatives(T, x):
        return (jax.jacfwd(G.log)(T), jax.grad(lambda T: jnp.sum(G.log(T) ** 2))(T),
                jax.jacrev(lambda x: G.log(G.exp(x)))(x))

    J, g, Jc = (np.asarray(a) for a in derivatives(I, jnp.zeros(6)))
    assert np.isfinite(J).all() and np.isfinite(g).all()
    # d log(exp(xi)) / d xi at 0 is the identity
    np.testing.assert_allclose(Jc, np.eye(6), atol=1e-5)


def test_log_exp_gradient_identity_away_from_zero():
    xi = jnp.asarray([0.3, -0.2, 0.1, 0.4, 0.5, -0.6])
    Jc = jax.jit(jax.jacfwd(lambda x: G.log(G.exp(x))))(xi)
    np.testing.assert_allclose(np.asarray(Jc), np.eye(6), atol=1e-4)


@pytest.mark.parametrize("angle", [0.0, 1e-5, 1.5e-4, 3e-4, 1e-3, 3e-3, 1e-2, 0.1])
def test_log_float32_jax_small_rotations(angle):
    """Typical frame-to-frame rotations (1e-4 .. 1e-2 rad) in the float32 JAX path:
    the translation part of log must stay accurate (float32 rounding, not worse)."""
    axis = np.array([1.0, 2.0, -2.0]) / 3.0
    xi = np.concatenate([axis * angle, [0.3, -0.2, 1.5]])
    T32 = jnp.asarray(G.exp(xi), jnp.float32)          # exact transform, rounded to float32
    out_jit = np.asarray(jax.jit(G.log)(T32))
    np.testing.assert_allclose(out_jit, xi, atol=2e-5)


def test_interpolate_endpoints_and_equal_halves():
    rng = np.random.default_rng(3)
    Ta, Tb = G.exp(rng.normal(0, 0.4, 6)), G.exp(rng.normal(0, 0.4, 6))
    np.testing.assert_allclose(G.interpolate(Ta, Tb, 0.0), Ta, atol=1e-12)
    np.testing.assert_allclose(G.interpolate(Ta, Tb, 1.0), Tb, atol=1e-12)
    M = G.interpolate(Ta, Tb, 0.5)
    # the midpoint splits the motion into two equal steps ...
    np.testing.assert_allclose(G.inverse(Ta) @ M, G.inverse(M) @ Tb, atol=1e-12)
    # ... and its rotation is scipy's slerp midpoint
    from scipy.spatial.transform import Slerp
    slerp = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([Ta[:3, :3], Tb[:3, :3]])))
    np.testing.assert_allclose(M[:3, :3], slerp([0.5]).as_matrix()[0], atol=1e-12)


def test_fit_motion_exact_on_screw_motion_and_averages_noise():
    xi = np.array([0.01, -0.02, 0.005, 0.004, -0.003, 0.006])   # per frame
    t = np.arange(1, 7)
    T_ref_f = G.exp(t[:, None] * xi)
    np.testing.assert_allclose(G.fit_motion(t, T_ref_f, 3), G.exp(3 * xi), atol=1e-12)
    # noisy observations: the fit is closer to the truth than the observation itself
    rng = np.random.default_rng(0)
    raw, fit = [], []
    for _ in range(200):
        noisy = np.stack([T @ G.exp(rng.normal(0, 0.003, 6)) for T in T_ref_f])
        truth = G.exp(3 * xi)
        raw.append(np.linalg.norm(G.log(G.inverse(truth) @ noisy[2])))
        fit.append(np.linalg.norm(G.log(G.inverse(truth) @ G.fit_motion(t, noisy, 3))))
    assert np.mean(fit) < 0.75 * np.mean(raw)


def test_consecutive_motions_are_each_pairs_T_cur_ref():
    """consecutive_motions: inv(T_world_{i+1}) @ T_world_i per pair (against numpy's general
    inverse), float64, none for fewer than two poses."""
    rng = np.random.default_rng(4)
    P = np.tile(np.eye(4), (5, 1, 1))
    P[:, :3, :3] = Rotation.random(5, random_state=4).as_matrix()
    P[:, :3, 3] = rng.normal(size=(5, 3))
    rel = G.consecutive_motions(P)
    assert rel.shape == (4, 4, 4) and rel.dtype == np.float64
    np.testing.assert_allclose(rel, [np.linalg.inv(P[i + 1]) @ P[i] for i in range(4)], atol=1e-12)
    assert G.consecutive_motions(P[:1]).shape == (0, 4, 4)


def test_checked_transform_takes_rigid_transforms_and_names_what_is_wrong():
    rng = np.random.default_rng(3)
    for _ in range(5):
        T = np.asarray(G.exp(rng.normal(size=6)))
        np.testing.assert_array_equal(G.checked_transform(T.astype(np.float32), "T"), T.astype(np.float32))
    # a float32 rotation chained a thousand times stays within the tolerance
    R = np.asarray(G.exp(np.array([0.01, 0.02, 0.03, 0, 0, 0])), np.float32)
    C = np.eye(4, dtype=np.float32)
    for _ in range(1000):
        C = C @ R
    G.checked_transform(C, "chain")
    bad = {"shape": np.eye(3), "NaN or inf": np.full((4, 4), np.inf)}
    for words, T in bad.items():
        with pytest.raises(ValueError, match=f"T_x .*{'4x4' if words == 'shape' else words}"):
            G.checked_transform(T, "T_x")
    sheared = np.eye(4)
    sheared[0, 1] = 0.01         # max |R^T R - I| = 0.01, over the 1e-3 allowed
    for T in (np.diag([1.0, 1.0, 1.1, 1.0]), np.diag([-1.0, 1.0, 1.0, 1.0]), sheared,
              np.vstack([np.eye(4)[:3], [0.0, 0.0, 0.1, 1.0]])):
        with pytest.raises(ValueError, match="T_x must be a rigid transform"):
            G.checked_transform(T, "T_x")
    G.checked_transform(np.diag([1.1, 1.0, 1.0, 1.0]), "T_x", rigid=False)   # only 4x4 and finite
