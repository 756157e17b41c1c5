"""Warp, sampling, photometric / depth residuals and the photometric Jacobian.

All functions are pure and jit-able, with static shapes: invalid pixels are
reported through masks, never removed.

For a reference pixel ``p = (u, v)`` with depth ``Z`` the warp is

    P = Z * ((u - cx) / fx, (v - cy) / fy, 1)     (reference camera frame)
    P' = T_cur_ref @ P                            (current camera frame)
    p' = (fx X'/Z' + cx, fy Y'/Z' + cy)

and the residuals are

    r_I = I_cur(p') - I_ref(p)        photometric, 0-255 luminance units
    r_Z = D_cur(p') - Z'              depth, metres (the current frame's depth
                                      at the warped pixel against the depth of
                                      the transformed point)

Jacobians are with respect to a *left* perturbation ``delta`` of the pose,
``T = exp(hat(delta)) @ T0`` at ``delta = 0``; with the twist order
``(w, v)`` that is ``dP'/d delta = [-[P']x | I]``.
"""
from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from jaxvo.camera import Camera, backproject
from jaxvo.geometry import transform_points
from jaxvo.estimator.pyramid import Level, flat_offset, level_size

__all__ = ["RefPoints", "Residuals", "reference_points", "select_points", "gather_points", "warp", "sample_bilinear",
           "sample_nearest", "residuals", "warp_jacobian", "photometric_terms", "rgbd_terms",
           "photometric_jacobian"]


class RefPoints(NamedTuple):
    """Reference-frame pixels prepared for warping; leading shape (N,).

    points: (N, 3) metres in the reference camera frame (0 where invalid).
    intensity: (N,) reference luminance. valid: (N,) bool, reference depth valid.
    u, v: (N,) pixel coordinates at this level (u = column, v = row).
    weight: (N,) float32, the level's static-trust weight at the pixel, 0 where depth is invalid.
    """
    points: jnp.ndarray
    intensity: jnp.ndarray
    valid: jnp.ndarray
    u: jnp.ndarray
    v: jnp.ndarray
    weight: jnp.ndarray


class Residuals(NamedTuple):
    """Per-point residuals and masks, shape (N,) each.

    r_int: photometric residual (0-255 units); valid_int: it is defined (valid
    reference depth, warped point in front of the camera and inside the image).
    r_depth: depth residual (metres); valid_depth: valid_int and the current
    depth at the warped pixel is valid. u, v, z: warped pixel and depth.
    """
    r_int: jnp.ndarray
    valid_int: jnp.ndarray
    r_depth: jnp.ndarray
    valid_depth: jnp.ndarray
    u: jnp.ndarray
    v: jnp.ndarray
    z: jnp.ndarray


def reference_points(level: Level, camera: Camera, stride: int = 1) -> RefPoints:
    """Every ``stride``-th pixel (in both directions) of a reference level as RefPoints, row-major."""
    h, w = level.depth.shape
    vv, uu = jnp.meshgrid(jnp.arange(0, h, stride, dtype=jnp.float32),
                          jnp.arange(0, w, stride, dtype=jnp.float32), indexing="ij")
    z = level.depth[::stride, ::stride]
    inten = level.intensity[::stride, ::stride]
    P = backproject(camera, uu, vv, z)
    wt = jnp.where(z > 0, level.weight[::stride, ::stride], 0.0)
    return RefPoints(P.reshape(-1, 3), inten.reshape(-1), (z > 0).reshape(-1), uu.reshape(-1), vv.reshape(-1),
                     wt.reshape(-1))


def select_points(level: Level, camera: Camera, block: int = 1) -> RefPoints:
    """One reference point per ``block`` x ``block`` tile: the valid-depth pixel with the largest
    intensity gradient (squared norm) in the tile. ``block = 1`` gives every pixel.

    Static shapes ((h // block) * (w // block) points, tiles without valid depth give an
    invalid point) and an even spread over the image, while keeping the pixels that
    carry photometric information (as in semi-dense direct methods).
    """
    if block == 1:
        return reference_points(level, camera, 1)
    h, w = level.depth.shape
    hb, wb = h // block, w // block
    g2 = level.igrad[..., 1] ** 2 + level.igrad[..., 2] ** 2
    # trusted pixels first; the tiny floor keeps a valid pixel when a whole tile is untrusted
    score = jnp.where(level.depth > 0, (g2 + 1e-3) * (level.weight + 1e-6), 0.0)[: hb * block, : wb * block]
    # k: the row-major index in its tile of the tile's best pixel, jnp.argmax's rule over the
    # tile's pixels (the first maximum; a NaN before any number) in two reductions: the best
    # column of each of the tile's rows, then the first row holding the tile's maximum. Both
    # reduce over a contiguous axis. A (hb, block, wb, block) reshape reduced over its interleaved
    # axes 1 and 3 runs slowly on the CPU, and an argmax over block * block strided views, stacked,
    # compiles one kernel per view; two contiguous reductions are faster and compile fewer
    # kernels (docs/decisions/cpu-kernels.md)
    rows = score.reshape(hb * block, wb, block)                 # (image row, tile column, pixel)
    row_best = jnp.max(rows, -1).reshape(hb, block, wb)
    row_k = jnp.argmax(rows, -1).reshape(hb, block, wb)
    i = jnp.argmax(row_best, 1)                                 # (hb, wb): the tile row
    k = i * block + jnp.take_along_axis(row_k, i[:, None, :], 1)[:, 0, :]
    vi = jnp.arange(hb)[:, None] * block + k // block
    ui = jnp.arange(wb)[None, :] * block + k % block
    return gather_points(level, camera, ui.reshape(-1), vi.reshape(-1))


def gather_points(level: Level, camera: Camera, u_idx, v_idx) -> RefPoints:
    """RefPoints at integer pixel coordinates (any shape; clipped into the image)."""
    h, w = level.depth.shape[-2:]
    ui = jnp.clip(u_idx, 0, w - 1)
    vi = jnp.clip(v_idx, 0, h - 1)

    def at(x):  # a stacked level (jaxvo.estimator.pyramid.stack_padded) reads its own entry
        return x[vi, ui] if x.ndim == 2 else x[level.size[0], vi, ui]
    z = at(level.depth)
    uf, vf = ui.astype(jnp.float32), vi.astype(jnp.float32)
    P = backproject(camera, uf, vf, z)
    return RefPoints(P, at(level.intensity), z > 0, uf, vf, jnp.where(z > 0, at(level.weight), 0.0))


def warp(T_cur_ref, points, camera: Camera):
    """Transform (N, 3) reference points by T_cur_ref (4, 4) and project.

    Returns (P' (N, 3), u', v', in_front (N,) bool).
    """
    Pc = transform_points(T_cur_ref, points)
    z = Pc[:, 2]
    in_front = z > 1e-3
    zs = jnp.where(in_front, z, 1.0)
    u = camera.fx * Pc[:, 0] / zs + camera.cx
    v = camera.fy * Pc[:, 1] / zs + camera.cy
    return Pc, u, v, in_front


def _inside(u, v, h, w):
    return (u >= 0.0) & (u <= w - 1.0) & (v >= 0.0) & (v <= h - 1.0)


def sample_bilinear(images, u, v, offset=0):
    """Bilinear sampling of (h, w, C) ``images`` at float pixel coords (N,) -> (N, C).

    Coordinates outside the image are clamped; callers mask them with their own
    inside test. Pixel centres at integers. ``images`` may also be (n, h, w, C) levels stacked
    by :func:`jaxvo.estimator.pyramid.stack_padded`, ``offset`` the sampled entry's first pixel
    (:func:`jaxvo.estimator.pyramid.flat_offset`); there a point on the image's last row or column reads
    the pad with weight 0: the same value.
    """
    h, w = images.shape[-3:-1]
    u0 = jnp.clip(jnp.floor(u), 0, w - 2)
    v0 = jnp.clip(jnp.floor(v), 0, h - 2)
    a = jnp.clip(u - u0, 0.0, 1.0)[:, None]
    b = jnp.clip(v - v0, 0.0, 1.0)[:, None]
    flat = images.reshape(-1, images.shape[-1])
    i00 = (v0 * w + u0).astype(jnp.int32) + offset
    top = flat[i00] * (1 - a) + flat[i00 + 1] * a
    bot = flat[i00 + w] * (1 - a) + flat[i00 + w + 1] * a
    return top * (1 - b) + bot * b


def sample_nearest(image, u, v, offset=0):
    """Nearest-pixel sampling of (h, w) ``image`` at float coords (N,) -> (N,); clamped.
    ``image`` (n, h, w) and ``offset``: a stacked level, as in :func:`sample_bilinear`.

    Used for depth: interpolating across a depth edge would invent surfaces.
    """
    h, w = image.shape[-2:]
    ui = jnp.clip(jnp.round(u), 0, w - 1).astype(jnp.int32)
    vi = jnp.clip(jnp.round(v), 0, h - 1).astype(jnp.int32)
    return image.reshape(-1)[vi * w + ui + offset]


def residuals(T_cur_ref, ref: RefPoints, cur: Level, camera: Camera) -> Residuals:
    """Photometric and depth residuals of reference points warped into the current level."""
    h, w = level_size(cur)
    Pc, u, v, in_front = warp(T_cur_ref, ref.points, camera)
    valid = ref.valid & in_front & _inside(u, v, h, w)
    i_cur = sample_bilinear(cur.intensity[..., None], u, v, flat_offset(cur))[:, 0]
    d_cur = sample_nearest(cur.depth, u, v, flat_offset(cur))
    r_int = jnp.where(valid, i_cur - ref.intensity, 0.0)
    valid_d = valid & (d_cur > 0)
    r_depth = jnp.where(valid_d, d_cur - Pc[:, 2], 0.0)
    return Residuals(r_int, valid, r_depth, valid_d, u, v, Pc[:, 2])


def warp_jacobian(Pc, camera: Camera):
    """d(u', v') / d delta for warped points Pc (N, 3) -> (N, 2, 6), left perturbation, twist (w, v)."""
    x, y, z = Pc[:, 0], Pc[:, 1], Pc[:, 2]
    zi = 1.0 / jnp.where(jnp.abs(z) > 1e-6, z, 1e-6)
    fx, fy = camera.fx, camera.fy
    # d(u,v)/dP' (2x3) times [-[P']x | I] (3x6), written out
    xz, yz = x * zi, y * zi
    ju = jnp.stack([-fx * xz * yz, fx * (1 + xz * xz), -fx * yz, fx * zi, jnp.zeros_like(z), -fx * xz * zi], -1)
    jv = jnp.stack([-fy * (1 + yz * yz), fy * xz * yz, fy * xz, jnp.zeros_like(z), fy * zi, -fy * yz * zi], -1)
    return jnp.stack([ju, jv], 1)


# A warped point is hidden in the current frame when the current depth at its
# pixel is nearer than the point by more than this fraction of its depth.
OCCLUSION_MARGIN = 0.05


def _visible(Pc, u, v, cur: Level):
    """(N,) bool: not occluded in the current frame (unknown current depth counts as visible)."""
    d = sample_nearest(cur.depth, u, v, flat_offset(cur))
    return ~((d > 0) & (d < Pc[:, 2] * (1.0 - OCCLUSION_MARGIN)))


def photometric_terms(T_cur_ref, ref: RefPoints, cur: Level, camera: Camera):
    """Photometric residual r (N,), Jacobian J (N, 6) (left perturbation) and validity (N,) in one pass.

    J = [dI/du, dI/dv](p') @ d(u', v')/d delta, with the current image's
    gradient images sampled bilinearly at the warped pixel (the classic
    Lucas-Kanade forward-additive Jacobian). Invalid rows are zero: no reference
    depth, behind the camera, outside the image, or occluded in the current frame
    (its depth there is nearer by more than ``OCCLUSION_MARGIN``): such a point is
    not visible, so its intensity says nothing about the pose.
    """
    h, w = level_size(cur)
    Pc, u, v, in_front = warp(T_cur_ref, ref.points, camera)
    valid = ref.valid & in_front & _inside(u, v, h, w) & _visible(Pc, u, v, cur)
    s = sample_bilinear(cur.igrad, u, v, flat_offset(cur))
    r = jnp.where(valid, s[:, 0] - ref.intensity, 0.0)
    Jw = warp_jacobian(Pc, camera)
    J = s[:, 1:2] * Jw[:, 0] + s[:, 2:3] * Jw[:, 1]
    return r, jnp.where(valid[:, None], J, 0.0), valid


def rgbd_terms(T_cur_ref, ref: RefPoints, cur: Level, camera: Camera, depth_weight):
    """Joint photometric + depth residuals and Jacobians in one pass.

    Returns r (N, 2), J (N, 2, 6) and validity (N, 2): column 0 is the
    photometric term of :func:`photometric_terms`; column 1 is
    ``depth_weight * (D_cur(p') - Z')`` with D_cur sampled bilinearly (only where
    all four neighbours are smooth, valid depth) and Jacobian
    ``depth_weight * ([dD/du, dD/dv] d(u', v')/d delta - dZ'/d delta)``,
    ``dZ'/d delta = (y', -x', 0, 0, 0, 1)``. ``depth_weight`` converts metres
    into luminance-equivalent units (e.g. 30 / 0.05 = 600 makes the two
    RANSAC inlier thresholds equally strong).
    """
    h, w = level_size(cur)
    Pc, u, v, in_front = warp(T_cur_ref, ref.points, camera)
    valid = ref.valid & in_front & _inside(u, v, h, w) & _visible(Pc, u, v, cur)
    # two gathers, not one from the images concatenated: that concatenation is a copy of both
    # images per evaluation (inside the solvers' loops), of every level for stacked levels
    if cur.depth.ndim == 2:  # one gather of all seven channels
        s = sample_bilinear(jnp.concatenate([cur.igrad, cur.dgrad], -1), u, v)
    else:  # stacked levels: their concatenation would be a copy of every level per evaluation
        s = jnp.concatenate([sample_bilinear(cur.igrad, u, v, flat_offset(cur)),
                             sample_bilinear(cur.dgrad, u, v, flat_offset(cur))], -1)
    Jw = warp_jacobian(Pc, camera)
    r_i = jnp.where(valid, s[:, 0] - ref.intensity, 0.0)
    J_i = s[:, 1:2] * Jw[:, 0] + s[:, 2:3] * Jw[:, 1]
    valid_d = valid & (s[:, 6] > 0.999)
    x, y = Pc[:, 0], Pc[:, 1]
    zero = jnp.zeros_like(x)
    dz = jnp.stack([y, -x, zero, zero, zero, jnp.ones_like(x)], -1)
    r_d = jnp.where(valid_d, depth_weight * (s[:, 3] - Pc[:, 2]), 0.0)
    J_d = depth_weight * (s[:, 4:5] * Jw[:, 0] + s[:, 5:6] * Jw[:, 1] - dz)
    r = jnp.stack([r_i, r_d], -1)
    J = jnp.stack([jnp.where(valid[:, None], J_i, 0.0), jnp.where(valid_d[:, None], J_d, 0.0)], 1)
    return r, J, jnp.stack([valid, valid_d], -1)


def photometric_jacobian(T_cur_ref, ref: RefPoints, cur: Level, camera: Camera):
    """(N, 6) photometric Jacobian; see :func:`photometric_terms`."""
    return photometric_terms(T_cur_ref, ref, cur, camera)[1]
