"""SE(3) and SO(3) maths: hat, exp, log, compose, inverse, quaternions.

Conventions used everywhere in jaxvo:

* A twist is ``xi = (w1, w2, w3, v1, v2, v3)``: rotation (axis-angle, radians)
  first, then translation (metres), as in the paper. ``T = exp(hat(xi))`` is a
  4x4 homogeneous rigid transform.
* Transforms are named ``T_a_b``: they map a 3-D point expressed in frame ``b``
  into frame ``a`` (``P_a = T_a_b @ P_b``). The estimator returns ``T_cur_ref``;
  trajectories hold ``T_world_cam`` (camera-to-world, as TUM files do).
* Quaternions are ``(qx, qy, qz, qw)`` (scalar last, as TUM files and
  ``scipy.spatial.transform.Rotation`` use).

Every function accepts batched inputs (leading dimensions) and works on NumPy
arrays (computed in NumPy, keeping float64 for host-side trajectory work) as
well as on JAX arrays / tracers (computed in ``jax.numpy``, jit- and
grad-safe: no NaN in values or gradients at zero rotation).
"""
from __future__ import annotations

import numpy as np
import jax
import jax.numpy as jnp

__all__ = [
    "checked_transform", "consecutive_motions",
    "skew", "vee", "hat", "exp", "log", "exp_so3", "log_so3",
    "compose", "inverse", "matrix_from_quat", "quat_from_matrix",
    "transform_from_quat_trans", "quat_trans_from_transform",
    "transform_points", "rotation_angle", "project_to_so3", "interpolate", "fit_motion",
]


def _xp(*arrays):
    """NumPy for plain NumPy / Python inputs (host maths), jax.numpy otherwise."""
    for a in arrays:
        if isinstance(a, (jax.Array, jax.core.Tracer)):
            return jnp
    return np


def skew(w):
    """(..., 3) vector -> (..., 3, 3) skew-symmetric matrix with skew(w) @ x = w x x."""
    xp = _xp(w)
    w = xp.asarray(w)
    z = xp.zeros_like(w[..., 0])
    w1, w2, w3 = w[..., 0], w[..., 1], w[..., 2]
    return xp.stack([
        xp.stack([z, -w3, w2], -1),
        xp.stack([w3, z, -w1], -1),
        xp.stack([-w2, w1, z], -1),
    ], -2)


def vee(W):
    """(..., 3, 3) skew-symmetric -> (..., 3) vector; inverse of :func:`skew`."""
    xp = _xp(W)
    W = xp.asarray(W)
    return xp.stack([W[..., 2, 1], W[..., 0, 2], W[..., 1, 0]], -1)


def hat(xi):
    """(..., 6) twist (w, v) -> (..., 4, 4) element of se(3)."""
    xp = _xp(xi)
    xi = xp.asarray(xi)
    top = xp.concatenate([skew(xi[..., :3]), xi[..., 3:, None]], -1)
    bottom = xp.zeros(xi.shape[:-1] + (1, 4), dtype=top.dtype)
    return xp.concatenate([top, bottom], -2)


def _small_angle(dtype) -> float:
    """Below this angle the series are used: they are exact to rounding there, and the
    closed forms lose digits to cancellation (much earlier in float32 than in float64)."""
    return 1e-3 if dtype == np.float64 else 5e-2


def _so3_coeffs(w, xp):
    """A = sin t / t, B = (1 - cos t) / t^2, C = (t - sin t) / t^3 for t = |w|.

    B is computed as 0.5 * sinc(t/2)^2, which has no cancellation. The
    double-``where`` trick keeps both branches (and their gradients) finite at t = 0.
    """
    t2 = xp.sum(w * w, -1)
    small = t2 < _small_angle(w.dtype) ** 2
    t2s = xp.where(small, xp.ones_like(t2), t2)
    t = xp.sqrt(t2s)
    s = xp.sin(t)
    h = xp.sin(0.5 * t) / (0.5 * t)
    A = xp.where(small, 1.0 - t2 / 6.0 + t2 * t2 / 120.0, s / t)
    B = xp.where(small, 0.5 - t2 / 24.0 + t2 * t2 / 720.0, 0.5 * h * h)
    C = xp.where(small, 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0, (t - s) / (t2s * t))
    return A, B, C


def exp_so3(w):
    """(..., 3) axis-angle (radians) -> (..., 3, 3) rotation matrix (Rodrigues)."""
    xp = _xp(w)
    w = xp.asarray(w)
    A, B, _ = _so3_coeffs(w, xp)
    W = skew(w)
    I = xp.eye(3, dtype=W.dtype)
    return I + A[..., None, None] * W + B[..., None, None] * (W @ W)


def exp(xi):
    """(..., 6) twist (w, v) -> (..., 4, 4) rigid transform ``exp(hat(xi))``."""
    xp = _xp(xi)
    xi = xp.asarray(xi)
    w, v = xi[..., :3], xi[..., 3:]
    A, B, C = _so3_coeffs(w, xp)
    W = skew(w)
    W2 = W @ W
    I = xp.eye(3, dtype=W.dtype)
    R = I + A[..., None, None] * W + B[..., None, None] * W2
    V = I + B[..., None, None] * W + C[..., None, None] * W2
    t = (V @ v[..., None])[..., 0]
    top = xp.concatenate([R, t[..., None]], -1)
    # (0, 0, 0, 1) from literals, not an array constant: traced code keeps no captured constant that
    # would be threaded through loops and block XLA from merging repeated evaluations
    lead = top.shape[:-2] + (1,)
    bottom = xp.concatenate([xp.zeros(lead + (3,), R.dtype), xp.ones(lead + (1,), R.dtype)], -1)
    return xp.concatenate([top, bottom], -2)


def quat_from_matrix(R):
    """(..., 3, 3) rotation -> (..., 4) unit quaternion (qx, qy, qz, qw), qw >= 0.

    Shepperd's method: picks the numerically largest of the four candidate
    pivots, so it is accurate for every angle including 180 degrees.
    """
    xp = _xp(R)
    R = xp.asarray(R)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    tr = m00 + m11 + m22
    # four candidate (unnormalised) quaternions, each scaled by 4*pivot
    cands = xp.stack([
        xp.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1], 1.0 + tr], -1),
        xp.stack([1.0 + m00 - m11 - m22, R[..., 0, 1] + R[..., 1, 0], R[..., 0, 2] + R[..., 2, 0], R[..., 2, 1] - R[..., 1, 2]], -1),
        xp.stack([R[..., 0, 1] + R[..., 1, 0], 1.0 - m00 + m11 - m22, R[..., 1, 2] + R[..., 2, 1], R[..., 0, 2] - R[..., 2, 0]], -1),
        xp.stack([R[..., 0, 2] + R[..., 2, 0], R[..., 1, 2] + R[..., 2, 1], 1.0 - m00 - m11 + m22, R[..., 1, 0] - R[..., 0, 1]], -1),
    ], -2)
    pivots = xp.stack([1.0 + tr, 1.0 + m00 - m11 - m22, 1.0 - m00 + m11 - m22, 1.0 - m00 - m11 + m22], -1)
    idx = xp.argmax(pivots, -1)
    q = xp.take_along_axis(cands, idx[..., None, None], axis=-2)[..., 0, :]
    q = q / xp.linalg.norm(q, axis=-1, keepdims=True)
    return xp.where(q[..., 3:4] < 0, -q, q)


def matrix_from_quat(q):
    """(..., 4) quaternion (qx, qy, qz, qw), any norm > 0 -> (..., 3, 3) rotation."""
    xp = _xp(q)
    q = xp.asarray(q)
    q = q / xp.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return xp.stack([
        xp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        xp.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        xp.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def log_so3(R):
    """(..., 3, 3) rotation -> (..., 3) axis-angle with angle in [0, pi].

    Goes through the quaternion (atan2 of its vector and scalar parts), which
    stays accurate near 0 and near pi where the arccos-of-trace form does not.
    """
    xp = _xp(R)
    q = quat_from_matrix(R)
    qv, qw = q[..., :3], q[..., 3]
    n2 = xp.sum(qv * qv, -1)
    small = n2 < 1e-16
    n = xp.sqrt(xp.where(small, xp.ones_like(n2), n2))
    angle = 2.0 * xp.arctan2(n, qw)
    # near zero: angle/n -> 2/qw (series of 2*atan2(n, qw)/n)
    scale = xp.where(small, 2.0 / qw * (1.0 - n2 / (3.0 * qw * qw)), angle / n)
    return scale[..., None] * qv


def log(T):
    """(..., 4, 4) rigid transform -> (..., 6) twist (w, v) with T = exp(hat(xi))."""
    xp = _xp(T)
    T = xp.asarray(T)
    R, t = T[..., :3, :3], T[..., :3, 3]
    w = log_so3(R)
    A, B, _ = _so3_coeffs(w, xp)
    t2 = xp.sum(w * w, -1)
    small = t2 < _small_angle(w.dtype) ** 2
    t2s = xp.where(small, xp.ones_like(t2), t2)
    # V^-1 = I - W/2 + D W^2 with D = (1 - A / (2B)) / t^2 (-> 1/12 as t -> 0)
    D = xp.where(small, 1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0,
                 (1.0 - A / (2.0 * xp.where(small, 1.0, B))) / t2s)
    W = skew(w)
    I = xp.eye(3, dtype=W.dtype)
    Vinv = I - 0.5 * W + D[..., None, None] * (W @ W)
    v = (Vinv @ t[..., None])[..., 0]
    return xp.concatenate([w, v], -1)


def compose(T_a_b, T_b_c):
    """T_a_c = T_a_b @ T_b_c (batched)."""
    return T_a_b @ T_b_c


def inverse(T_a_b):
    """(..., 4, 4) rigid transform -> T_b_a, using R^T rather than a general inverse."""
    xp = _xp(T_a_b)
    T = xp.asarray(T_a_b)
    Rt = xp.swapaxes(T[..., :3, :3], -1, -2)
    t = -(Rt @ T[..., :3, 3:4])
    top = xp.concatenate([Rt, t], -1)
    return xp.concatenate([top, T[..., 3:4, :]], -2)


#: how far a rigid transform's rotation block may be from orthonormal (largest entry of R^T R - I):
#: float32 rotations and long float64 chains are within 1e-6; a scaled or sheared matrix is not
RIGID_TOLERANCE = 1e-3


def checked_transform(T, what: str = "transform", rigid: bool = True) -> np.ndarray:
    """``T`` as a (4, 4) float64 NumPy array, or ValueError naming ``what`` and the problem: not
    4x4, NaN or inf, and (``rigid``) not a rigid transform: rotation block orthonormal within
    :data:`RIGID_TOLERANCE` with determinant +1 (no reflection), last row (0, 0, 0, 1). For the
    poses and initial guesses users pass in (host values; a JAX array is read back first)."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"{what} must be a 4x4 matrix, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise ValueError(f"{what} contains NaN or inf")
    if rigid:
        R = T[:3, :3]
        off = float(np.max(np.abs(R.T @ R - np.eye(3))))
        if off > RIGID_TOLERANCE or np.linalg.det(R) <= 0 or np.any(T[3] != (0.0, 0.0, 0.0, 1.0)):
            raise ValueError(f"{what} must be a rigid transform (rotation block orthonormal with determinant +1, "
                             f"last row 0 0 0 1), got rotation block with max |R^T R - I| = {off:.3g}, "
                             f"det {np.linalg.det(R):.3g}, last row {T[3].tolist()}")
    return T


def consecutive_motions(T_world_cam) -> np.ndarray:
    """(N-1, 4, 4) float64 T_cur_ref of each consecutive pair (frame i -> i+1) of (N, 4, 4)
    camera-to-world poses: ``inv(T_world_{i+1}) @ T_world_i`` (empty for fewer than two poses)."""
    P = np.asarray(T_world_cam, np.float64)
    if len(P) < 2:
        return np.zeros((0, 4, 4))
    return np.stack([inverse(P[i + 1]) @ P[i] for i in range(len(P) - 1)])


def transform_points(T_a_b, P_b):
    """Apply (..., 4, 4) T_a_b to (..., N, 3) points in frame b -> points in frame a.

    Written as three multiply-adds rather than a (N, 3) x (3, 3) matrix product: XLA on CPU
    runs the product as a general matrix multiply, an order of magnitude slower for this shape
    (docs/decisions/cpu-kernels.md), and the warp of every residual evaluation is this product.
    """
    R, t = T_a_b[..., None, :3, :3], T_a_b[..., None, :3, 3]
    return P_b[..., 0:1] * R[..., 0] + P_b[..., 1:2] * R[..., 1] + P_b[..., 2:3] * R[..., 2] + t


def transform_from_quat_trans(q, t):
    """(..., 4) quaternion (qx, qy, qz, qw) and (..., 3) translation -> (..., 4, 4)."""
    xp = _xp(q, t)
    R = matrix_from_quat(xp.asarray(q))
    t = xp.asarray(t, dtype=R.dtype)
    top = xp.concatenate([R, t[..., None]], -1)
    # (0, 0, 0, 1) from literals, not an array constant: traced code keeps no captured constant that
    # would be threaded through loops and block XLA from merging repeated evaluations
    lead = top.shape[:-2] + (1,)
    bottom = xp.concatenate([xp.zeros(lead + (3,), R.dtype), xp.ones(lead + (1,), R.dtype)], -1)
    return xp.concatenate([top, bottom], -2)


def quat_trans_from_transform(T):
    """(..., 4, 4) -> ((..., 4) quaternion (qx, qy, qz, qw) with qw >= 0, (..., 3) translation)."""
    return quat_from_matrix(T[..., :3, :3]), T[..., :3, 3]


def rotation_angle(R):
    """Rotation angle in radians of (..., 3, 3) rotation matrices (robust near 0 and pi)."""
    xp = _xp(R)
    return xp.linalg.norm(log_so3(R), axis=-1)


def project_to_so3(M):
    """Nearest rotation (Frobenius) to a (..., 3, 3) matrix, via SVD with det = +1.

    Used for inputs that are only approximately rotations, e.g. the Bonn
    ground-truth calibration whose 3x3 block is a scaled rotation.
    """
    xp = _xp(M)
    U, _, Vt = xp.linalg.svd(xp.asarray(M))
    d = xp.sign(xp.linalg.det(U @ Vt))
    D = xp.ones(U.shape[:-1], dtype=U.dtype)
    D = xp.concatenate([D[..., :2], d[..., None]], -1)
    return (U * D[..., None, :]) @ Vt


def interpolate(T_a, T_b, s):
    """Pose a fraction ``s`` of the way from ``T_a`` to ``T_b`` (both (4, 4) T_world_x) along the
    twist between them: ``T_a @ exp(s * log(T_a^-1 @ T_b))``; s = 0.5 is the midpoint."""
    return T_a @ exp(s * log(inverse(T_a) @ T_b))


def fit_motion(t, T_ref_f, t_query):
    """Least-squares smooth motion through observed poses, evaluated at ``t_query``.

    t: (N,) times of the observations after the reference (any unit; the reference is at 0).
    T_ref_f: (N, 4, 4) pose of each observation in the reference's frame (T_ref_f = T_cur_ref^-1).
    Fits the twists ``log(T_ref_f) ~ a t + b t^2`` (through the identity at t = 0, as the
    reference is where it is by definition) and returns (4, 4) ``exp(a tq + b tq^2)``. Exact for
    a constant screw motion (log(T) = xi t). Needs N >= 2 distinct non-zero times.
    """
    t = np.asarray(t, np.float64)
    X = log(np.asarray(T_ref_f, np.float64))
    coef = np.linalg.lstsq(np.stack([t, t * t], 1), X, rcond=None)[0]
    tq = float(t_query)
    return exp(np.array([tq, tq * tq]) @ coef)
