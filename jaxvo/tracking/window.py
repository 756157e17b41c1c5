"""The keyframe window's pose graph: the poses of the last K keyframes refined against every
estimate between them (:func:`refine`), one compiled program for a given K.

Nodes are keyframes, ordered oldest first; node 0 is held fixed (it fixes the gauge, and its pose
was already used to chain frames that are written). An edge (a, b) is a measured
``Z = T_b_a`` (T_cur_ref with reference a, current b) with its information matrix ``Lambda``
(6x6, twist order (w, v), a left perturbation of T_cur_ref, as
:attr:`jaxvo.estimator.MotionEstimate.information`). With node poses ``X_i = T_0_i`` (relative to
node 0) the edge's error is the left perturbation that takes the measurement to the prediction,

    e_ab = log( inv(X_b) X_a inv(Z_ab) ),      cost = sum_ab e_ab^T Lambda_ab e_ab,

and the free poses move by left increments ``X_i <- exp(d_i) X_i``. Shapes are static: K nodes
and K (K - 1) / 2 edge slots, absent ones with weight 0, so the window compiles once.
"""
from __future__ import annotations

import threading
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxvo import geometry
from jaxvo.estimator import least_squares
from jaxvo.runtime import aot

__all__ = ["PoseGraph", "compile_ahead", "cost", "edge_slots", "make_graph", "refine", "residuals"]

#: Weight of the small prior that holds each free pose where it starts, relative to the mean
#: edge information after normalisation (1 per unit twist): it only decides poses no edge reaches
#: (empty slots) and leaves the others where the edges put them.
_PRIOR = 1e-6


class PoseGraph(NamedTuple):
    """A window of K keyframe poses and the estimates between them (a pytree of arrays).

    poses: (K, 4, 4) float32 ``T_0_i``, node i relative to node 0 (identity for node 0).
    free: (K,) float32, 1 where the node may move (0 for node 0 and unused nodes).
    ref, cur: (E,) int32 node indices of each edge slot, E = K (K - 1) / 2.
    Z: (E, 4, 4) float32 measured ``T_cur_ref``. sqrt_info: (E, 6, 6) float32 ``L^T`` with
    ``Lambda = L L^T`` (normalised to a mean trace of 6 over the used edges). weight: (E,) float32, 1 for a
    used slot, 0 otherwise.
    """
    poses: jnp.ndarray
    free: jnp.ndarray
    ref: jnp.ndarray
    cur: jnp.ndarray
    Z: jnp.ndarray
    sqrt_info: jnp.ndarray
    weight: jnp.ndarray


def edge_slots(K: int):
    """(ref (E,), cur (E,)) int32: every ordered pair a < b of K nodes, in a fixed order."""
    a, b = np.triu_indices(K, 1)
    return a.astype(np.int32), b.astype(np.int32)


def make_graph(poses, edges, K: int) -> PoseGraph:
    """The :class:`PoseGraph` of host values.

    poses: n <= K (4, 4) float64 ``T_world_i`` of the window's nodes, oldest first.
    edges: {(a, b): (Z (4, 4) T_b_a, Lambda (6, 6))} with node indices a < b < n; an edge
    whose information is not finite or not positive definite is left out.
    """
    n = len(poses)
    if not 1 <= n <= K:
        raise ValueError(f"a window holds 1 to {K} poses, got {n}")
    inv0 = geometry.inverse(np.asarray(poses[0], np.float64))
    rel = np.tile(np.eye(4), (K, 1, 1))
    rel[:n] = [inv0 @ np.asarray(P, np.float64) for P in poses]
    free = np.zeros(K, np.float32)
    free[1:n] = 1.0
    ref, cur = edge_slots(K)
    slot = {(int(a), int(b)): e for e, (a, b) in enumerate(zip(ref, cur))}
    Z = np.tile(np.eye(4, dtype=np.float32), (len(ref), 1, 1))
    info = np.zeros((len(ref), 6, 6))
    weight = np.zeros(len(ref), np.float32)
    for (a, b), (Z_ab, lam) in edges.items():
        lam = 0.5 * (np.asarray(lam, np.float64) + np.asarray(lam, np.float64).T)
        if not (np.all(np.isfinite(lam)) and np.all(np.isfinite(Z_ab))) or np.linalg.eigvalsh(lam)[0] <= 0:
            continue
        e = slot[(a, b)]
        Z[e], info[e], weight[e] = Z_ab, lam, 1.0
    used = weight > 0
    # a common scale (the minimum is unchanged): the numbers stay near 1 in float32
    scale = 6.0 / np.mean(np.trace(info[used], axis1=1, axis2=2)) if used.any() else 1.0
    sqrt_info = np.zeros_like(info)
    for e in np.flatnonzero(used):
        sqrt_info[e] = np.linalg.cholesky(info[e] * scale).T
    return PoseGraph(jnp.asarray(rel, jnp.float32), jnp.asarray(free), jnp.asarray(ref), jnp.asarray(cur),
                     jnp.asarray(Z), jnp.asarray(sqrt_info, jnp.float32), jnp.asarray(weight))


def _moved(d, graph: PoseGraph):
    """(K, 4, 4) poses after the left increments ``d`` (K, 6) on the free nodes."""
    return geometry.exp(d * graph.free[:, None]) @ graph.poses


def residuals(params, graph: PoseGraph):
    """(6 E + 6 K,) whitened edge errors ``L^T e_ab`` (0 on unused slots), then the prior on each
    increment; ``params``: (6 K,) the flattened increments."""
    K = graph.poses.shape[0]
    d = params.reshape(K, 6)
    X = _moved(d, graph)
    pred = geometry.inverse(X[graph.cur]) @ X[graph.ref]                   # T_cur_ref
    e = geometry.log(pred @ geometry.inverse(graph.Z))
    r = jnp.einsum("eij,ej->ei", graph.sqrt_info, e) * graph.weight[:, None]
    return jnp.concatenate([r.ravel(), np.sqrt(_PRIOR) * params])


def cost(graph: PoseGraph, poses=None) -> jnp.ndarray:
    """sum over used edges of e^T Lambda e (normalised information) at ``poses`` (K, 4, 4)
    ``T_0_i`` (default: the graph's own)."""
    g = graph if poses is None else graph._replace(poses=jnp.asarray(poses, jnp.float32))
    r = residuals(jnp.zeros(6 * g.poses.shape[0], jnp.float32), g)
    return jnp.sum(jnp.square(r[: 6 * g.ref.shape[0]]))


def _solve(graph: PoseGraph):
    """((K, 4, 4) refined ``T_0_i``, iterations) of the graph."""
    K = graph.poses.shape[0]
    params, iterations = least_squares(lambda p: residuals(p, graph), jnp.zeros(6 * K, jnp.float32),
                                       maxiter=10)
    ok = jnp.all(jnp.isfinite(params))
    return _moved(jnp.where(ok, params, 0.0).reshape(K, 6), graph), iterations


# exported into the cache folder (jaxvo.runtime.aot) like the estimator: a process that finds it
# there loads it instead of tracing
_refine = aot.Program("window_refine", _solve)


def refine(poses, edges, K: int) -> np.ndarray:
    """The window's poses refined against its edges (Gauss-Newton / Levenberg-Marquardt, jaxopt).

    poses: n <= K (4, 4) float64 ``T_world_i``, oldest first (node 0 stays). edges: as
    :func:`make_graph`. Returns (n, 4, 4) float64 ``T_world_i``, rotations re-orthonormalised.
    One compiled program per K (the graph is padded to K nodes).
    """
    poses = [np.asarray(P, np.float64) for P in poses]
    graph = make_graph(poses, edges, K)
    X, _ = _refine(graph)
    X = np.asarray(X, np.float64)[: len(poses)]
    out = []
    for i, rel in enumerate(X):
        rel[:3, :3] = geometry.project_to_so3(rel[:3, :3])
        out.append(poses[0] @ rel if i else poses[0])
    return np.stack(out)


def compile_ahead(K: int):
    """Make :func:`refine`'s program for K nodes ready in a background thread (started when the
    third frame is added, once the first pose is out; ready by the first window join): read from
    the cache folder where an earlier process exported it, else traced, exported and compiled
    (:meth:`jaxvo.runtime.aot.Program.compile_ahead`); returns the thread. An error is left for
    the real call to raise. Not a daemon thread, even when started from one (as the CLI's job
    thread is): an interpreter that exits while XLA compiles in a daemon thread may crash, and
    the CLI waits for the thread before it exits, so that the program is kept for later runs."""
    E = K * (K - 1) // 2

    def f32(*shape):
        return jax.ShapeDtypeStruct(shape, jnp.float32)

    def i32(*shape):
        return jax.ShapeDtypeStruct(shape, jnp.int32)

    def compile_it():
        try:
            _refine.compile_ahead(PoseGraph(f32(K, 4, 4), f32(K), i32(E), i32(E), f32(E, 4, 4), f32(E, 6, 6),
                                            f32(E)))
        except Exception:  # noqa: BLE001 - the real call compiles it and raises what is wrong
            return

    thread = threading.Thread(target=compile_it, name="jaxvo-compile-window", daemon=False)
    thread.start()
    return thread
