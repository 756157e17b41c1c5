"""Tests of jaxvo.estimator.pyramid: valid-only depth averaging, max-depth cut, shapes, gradients."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxvo.estimator import pyramid
from jaxvo.estimator.pyramid import downsample, gradients, num_levels_for, sanitize_depth

# jit once per shape: op-by-op dispatch of the eager version is slow on a busy machine
build_pyramid = jax.jit(pyramid.build_pyramid, static_argnums=(2,))


def test_downsample_intensity_is_block_mean():
    rng = np.random.default_rng(0)
    img = rng.uniform(0, 255, (6, 8)).astype(np.float32)
    i, _ = downsample(jnp.asarray(img), jnp.ones((6, 8)))
    expected = np.array([[img[2 * r:2 * r + 2, 2 * c:2 * c + 2].mean() for c in range(4)] for r in range(3)])
    np.testing.assert_allclose(np.asarray(i), expected, rtol=1e-6)


def test_downsample_depth_averages_only_valid_pixels():
    d = np.array([[1.0, 0.0, 0.0, 0.0, 2.0, 4.0],
                  [2.0, 0.0, 0.0, 0.0, 3.0, 5.0]], np.float32)
    _, dd = downsample(jnp.zeros((2, 6)), jnp.asarray(d))
    np.testing.assert_allclose(np.asarray(dd), [[1.5, 0.0, 3.5]], rtol=1e-6)
    # one valid pixel: its value, not a quarter of it
    d = np.array([[0.0, 0.0], [0.0, 3.0]], np.float32)
    _, dd = downsample(jnp.zeros((2, 2)), jnp.asarray(d))
    assert float(dd[0, 0]) == pytest.approx(3.0)


def test_all_invalid_block_stays_zero_through_levels():
    d = np.full((16, 16), 2.0, np.float32)
    d[:8, :8] = 0.0
    levels = build_pyramid(np.zeros((16, 16), np.float32), d, 4)
    for l, lev in enumerate(levels[1:], 1):
        dl = np.asarray(lev.depth)
        n = 8 // 2 ** l
        assert np.all(dl[:n, :n] == 0.0)
        np.testing.assert_allclose(dl[n:, :], 2.0)
        np.testing.assert_allclose(dl[:, n:], 2.0)


def test_depth_beyond_max_depth_and_bad_values_are_invalid():
    top = np.array([[1.0, 4.5, np.nan, -1.0],
                    [4.0, 4.0, np.inf, 2.0]], np.float32)
    d = np.concatenate([top, np.full((2, 4), 1.0, np.float32)])          # 4 x 4
    levels = build_pyramid(np.zeros((4, 4), np.float32), d, 2, max_depth=4.0)
    np.testing.assert_allclose(np.asarray(levels[0].depth)[:2], [[1.0, 0.0, 0.0, 0.0], [4.0, 4.0, 0.0, 2.0]])
    # 4.5 is removed before averaging: (1 + 4 + 4) / 3, and (2) alone
    np.testing.assert_allclose(np.asarray(levels[1].depth), [[3.0, 2.0], [1.0, 1.0]], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(sanitize_depth(d, 10.0))[0, :2], [1.0, 4.5])
    # a different cut
    levels = build_pyramid(np.zeros((4, 4), np.float32), d, 1, max_depth=1.5)
    np.testing.assert_allclose(np.asarray(levels[0].depth)[:2], [[1.0, 0, 0, 0], [0, 0, 0, 0]])


def test_shapes_640x480_four_levels_down_to_80x60():
    assert num_levels_for(640, 480) == 4
    assert num_levels_for(320, 240) == 3
    assert num_levels_for(160, 120) == 2
    assert num_levels_for(80, 60) == 1
    assert num_levels_for(1280, 960) == 5
    assert num_levels_for(100, 100) == 1
    img = np.zeros((480, 640), np.float32)
    levels = build_pyramid(img, np.ones_like(img), num_levels_for(640, 480))
    assert [lev.intensity.shape for lev in levels] == [(480, 640), (240, 320), (120, 160), (60, 80)]
    for lev in levels:
        assert lev.depth.shape == lev.intensity.shape
        assert lev.igrad.shape == lev.intensity.shape + (3,)
        assert lev.intensity.dtype == jnp.float32 and lev.depth.dtype == jnp.float32


def test_gradients_of_linear_ramp_are_exact_everywhere():
    v, u = np.mgrid[0:30, 0:40].astype(np.float32)
    img = 3.0 * u - 2.0 * v + 7.0
    gu, gv = gradients(jnp.asarray(img))
    np.testing.assert_allclose(np.asarray(gu), 3.0, atol=1e-4)
    np.testing.assert_allclose(np.asarray(gv), -2.0, atol=1e-4)


def test_gradients_central_difference_values():
    img = np.array([[0.0, 1.0, 4.0, 9.0]], np.float32).repeat(3, 0)
    gu, gv = gradients(jnp.asarray(img))
    np.testing.assert_allclose(np.asarray(gu)[0], [1.0, 2.0, 4.0, 5.0])
    np.testing.assert_allclose(np.asarray(gv), 0.0)


def test_pyramid_levels_carry_intensity_and_gradients():
    v, u = np.mgrid[0:32, 0:48].astype(np.float32)
    img = 2.0 * u + 0.5 * v
    levels = build_pyramid(img, np.ones_like(img), 3)
    for l, lev in enumerate(levels):
        g = np.asarray(lev.igrad)
        np.testing.assert_allclose(g[..., 0], np.asarray(lev.intensity))
        # a ramp stays a ramp; its slope per pixel doubles per level
        np.testing.assert_allclose(g[..., 1], 2.0 * 2 ** l, rtol=1e-5)
        np.testing.assert_allclose(g[..., 2], 0.5 * 2 ** l, rtol=1e-5)
    # level 1 of a ramp: the value at the block centre (2i + 0.5, 2j + 0.5)
    vv, uu = np.mgrid[0:16, 0:24].astype(np.float32)
    np.testing.assert_allclose(np.asarray(levels[1].intensity), 2.0 * (2 * uu + 0.5) + 0.5 * (2 * vv + 0.5),
                               rtol=1e-6)
