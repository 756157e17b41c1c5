"""Image pyramids for coarse-to-fine alignment (pure JAX, jit-able).

Level 0 is the full-resolution image; each level averages 2x2 blocks of the
one above, so pixel centres follow ``c_l = (c + 0.5) / 2^l - 0.5`` (see
:meth:`jaxvo.camera.Camera.at_level`). Depth is averaged over the *valid*
pixels of each block only, so an invalid (0) reading never pulls an average
towards the camera; a block with no valid pixel stays invalid. Intensity
gradients (central differences, in intensity units per pixel of that level)
are computed per level for the photometric Jacobian.
"""
from __future__ import annotations

from typing import Any, NamedTuple, Optional, Sequence, Tuple

import jax.numpy as jnp

__all__ = ["Level", "level_size", "flat_offset", "level_slice", "stack_padded", "sanitize_depth", "downsample", "gradients", "depth_gradients", "build_pyramid", "weight_pyramid",
           "num_levels_for"]


class Level(NamedTuple):
    """One pyramid level of one frame, float32.

    intensity: (h, w) luminance 0-255. depth: (h, w) metres, 0 = invalid.
    igrad: (h, w, 3) intensity, d intensity / d u (column), d intensity / d v (row)
    stacked, so that one bilinear gather samples all three at a warped pixel.
    dgrad: (h, w, 4) depth, d depth / d u, d depth / d v (metres per pixel) and a
    smoothness flag (1 where the pixel and its 4 neighbours have valid depth with
    no discontinuity, else 0), for the depth term of the joint RGB-D residual.
    weight: (h, w) in [0, 1], how far each pixel may be trusted as static scene (a user
    mask, a static-probability prior; 1 = fully, 0 = ignore); 2x2 block mean per level.
    It multiplies a reference pixel's weight everywhere it is used; a current frame's is unused.
    size: None (the image fills the arrays), or for levels stacked by :func:`stack_padded`,
    (3,) int32 (index, h, w), possibly traced: the arrays hold several levels along a leading
    axis, each padded at the bottom and right (depth 0, weight 0), and this level is entry
    ``index`` with an (h, w) image. Validity tests use (h, w); indexing the arrays' own shape.
    (2-D arrays with a size: one such entry, ``index`` unused; see :func:`level_slice`.)
    """
    intensity: jnp.ndarray
    depth: jnp.ndarray
    igrad: jnp.ndarray
    dgrad: jnp.ndarray
    weight: jnp.ndarray
    size: Optional[Any] = None


def level_size(level: Level):
    """(h, w) of the image of ``level``: Python ints, or traced int32 scalars for a stacked level."""
    if level.size is None:
        return level.depth.shape[-2:]
    return level.size[1], level.size[2]


def flat_offset(level: Level):
    """Index of the level's first pixel in its (h, w) arrays flattened (0 unless stacked)."""
    if level.size is None or level.depth.ndim == 2:
        return 0
    return level.size[0] * (level.depth.shape[1] * level.depth.shape[2])


def level_slice(level: Level) -> Level:
    """A stacked level's own entry: its (padded) 2-D arrays, the size kept (fields that are None stay None)."""
    if level.depth.ndim == 2:
        return level
    return Level(*(None if x is None else x[level.size[0]] for x in level[:5]), level.size)


def stack_padded(levels: Sequence[Level], fields: Sequence[str] = Level._fields[:5]) -> Level:
    """Levels of different sizes as one Level whose arrays have a leading axis (one entry per
    level), each padded with zeros at the bottom and right to the largest (h, w) among them, and
    ``size`` (n, 3) int32 (index, h, w), so that ``jax.lax.scan`` over it runs one program for
    all of them. Only ``fields`` are stacked (the others are None: what a reader does not need
    is not copied)."""
    H = max(l.depth.shape[0] for l in levels)
    W = max(l.depth.shape[1] for l in levels)

    def pad(x):
        return jnp.pad(x, [(0, H - x.shape[0]), (0, W - x.shape[1])] + [(0, 0)] * (x.ndim - 2))

    arrays = [jnp.stack([pad(getattr(l, f)) for l in levels]) if f in fields else None for f in Level._fields[:5]]
    size = [(i,) + tuple(l.depth.shape) for i, l in enumerate(levels)]
    return Level(*arrays, jnp.asarray(size, jnp.int32))


def sanitize_depth(depth, max_depth, min_depth=0.0):
    """Depth (metres) with NaN/inf, values <= min_depth and values beyond max_depth set to 0 (invalid)."""
    d = jnp.asarray(depth, jnp.float32)
    ok = jnp.isfinite(d) & (d > min_depth) & (d <= max_depth)
    return jnp.where(ok, d, 0.0)


def _quads(x):
    """The four pixels of each 2x2 block of (h, w) ``x`` as four (h//2, w//2) strided views.

    Strided slices and element-wise sums instead of a reshape and a mean over axes 1 and 3:
    XLA on CPU reduces over those interleaved axes an order of magnitude slower
    (docs/decisions/cpu-kernels.md).
    """
    h2, w2 = x.shape[0] // 2, x.shape[1] // 2
    x = x[: 2 * h2, : 2 * w2]
    return x[0::2, 0::2], x[0::2, 1::2], x[1::2, 0::2], x[1::2, 1::2]


def block_mean(x):
    """2x2 block mean of (h, w) ``x`` -> (h//2, w//2)."""
    a, b, c, d = _quads(x)
    return 0.25 * ((a + b) + (c + d))


def downsample(intensity, depth):
    """Halve (h, w) -> (h//2, w//2): 2x2 block mean of intensity, valid-only mean of depth."""
    d = _quads(depth)
    n = sum((q > 0).astype(jnp.float32) for q in d)
    dsum = (d[0] + d[1]) + (d[2] + d[3])
    return block_mean(intensity), jnp.where(n > 0, dsum / jnp.maximum(n, 1.0), 0.0)


def gradients(intensity):
    """Central-difference gradients (one-sided at the border) -> (d/du, d/dv), intensity units per pixel."""
    I = intensity
    gu = jnp.concatenate([I[:, 1:2] - I[:, 0:1], 0.5 * (I[:, 2:] - I[:, :-2]), I[:, -1:] - I[:, -2:-1]], axis=1)
    gv = jnp.concatenate([I[1:2] - I[0:1], 0.5 * (I[2:] - I[:-2]), I[-1:] - I[-2:-1]], axis=0)
    return gu, gv


def depth_gradients(depth, max_jump=0.05):
    """(h, w) depth -> (h, w, 4): depth, d/du, d/dv, smooth flag.

    Central differences; the flag is 1 only where the pixel and its four
    neighbours are valid and neighbouring depths differ by less than
    ``max_jump`` metres per metre of depth (a depth edge has no useful derivative).
    """
    d = depth
    p = jnp.pad(d, 1, mode="edge")
    left, right, up, down = p[1:-1, :-2], p[1:-1, 2:], p[:-2, 1:-1], p[2:, 1:-1]
    gu, gv = 0.5 * (right - left), 0.5 * (down - up)
    allvalid = (d > 0) & (left > 0) & (right > 0) & (up > 0) & (down > 0)
    smooth = allvalid & (jnp.abs(right - left) < 2 * max_jump * d) & (jnp.abs(down - up) < 2 * max_jump * d)
    f = smooth.astype(jnp.float32)
    return jnp.stack([d, gu * f, gv * f, f], -1)


def build_pyramid(intensity, depth, num_levels: int, max_depth=4.0, weight=None) -> Tuple[Level, ...]:
    """(H, W) intensity and depth -> tuple of ``num_levels`` Levels, index 0 = full resolution.

    Depth beyond ``max_depth`` metres (and NaN / non-positive) is invalid at every level.
    weight: optional (H, W) per-pixel trust in [0, 1] (default all 1), see :class:`Level`.
    """
    i = jnp.asarray(intensity, jnp.float32)
    d = sanitize_depth(depth, max_depth)
    weights = weight_pyramid(jnp.ones_like(i) if weight is None else weight, num_levels)
    levels = []
    for l in range(num_levels):
        if l > 0:
            i, d = downsample(i, d)
        gu, gv = gradients(i)
        levels.append(Level(i, d, jnp.stack([i, gu, gv], -1), depth_gradients(d), weights[l]))
    return tuple(levels)


def weight_pyramid(weight, num_levels: int) -> Tuple[jnp.ndarray, ...]:
    """(H, W) trust in [0, 1] (clipped to it) -> its ``num_levels`` levels, 2x2 block means (the
    ``weight`` of :func:`build_pyramid`'s levels)."""
    wt = jnp.clip(jnp.asarray(weight, jnp.float32), 0.0, 1.0)
    levels = [wt]
    for _ in range(1, num_levels):
        levels.append(block_mean(levels[-1]))
    return tuple(levels)


def num_levels_for(width: int, height: int, coarsest=(80, 60)) -> int:
    """How many halvings keep the coarsest level at least ``coarsest`` (w, h): 4 for 640x480."""
    n = 1
    while width // 2 >= coarsest[0] and height // 2 >= coarsest[1]:
        width, height, n = width // 2, height // 2, n + 1
    return n
