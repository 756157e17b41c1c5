"""Tests of jaxvo.frame: make_frame conversion and validation, luminance, validate_pair."""
from __future__ import annotations

import numpy as np
import pytest

from jaxvo.camera import DEFAULT
from jaxvo.frame import Frame, luminance, make_frame, validate_pair

H, W = 60, 80
CAM = DEFAULT.at_level(3)  # 80 x 60


def _rgb(h=H, w=W):
    rng = np.random.default_rng(0)
    return rng.integers(0, 256, size=(h, w, 3), dtype=np.uint8)


def _depth_u16(h=H, w=W, value=10000):
    return np.full((h, w), value, np.uint16)


def test_uint16_depth_is_divided_by_5000():
    d = _depth_u16()
    d[0, 0] = 0
    d[1, 1] = 5000
    d[2, 2] = 65535
    f = make_frame(_rgb(), d)
    assert f.depth.dtype == np.float32 and f.intensity.dtype == np.float32
    assert f.depth.shape == (H, W) and f.intensity.shape == (H, W)
    assert f.depth[0, 0] == 0.0
    assert f.depth[1, 1] == pytest.approx(1.0)
    assert f.depth[3, 3] == pytest.approx(2.0)
    assert f.depth[2, 2] == pytest.approx(65535 / 5000)
    # an explicit scale for integer depth (millimetres)
    f = make_frame(_rgb(), _depth_u16(value=1500), depth_scale=1000)
    assert f.depth[5, 5] == pytest.approx(1.5)


def test_float_depth_is_metres_and_bad_values_become_invalid():
    d = np.full((H, W), 1.25, np.float32)
    d[0, :4] = [np.nan, -1.0, np.inf, -np.inf]
    d[1, 0] = 0.0
    f = make_frame(_rgb(), d)
    np.testing.assert_array_equal(f.depth[0, :4], 0.0)
    assert f.depth[1, 0] == 0.0
    assert f.depth[5, 5] == pytest.approx(1.25)
    assert np.isfinite(f.depth).all()
    # float64 metres are converted to float32
    f = make_frame(_rgb(), np.full((H, W), 2.0))
    assert f.depth.dtype == np.float32 and f.depth[0, 0] == 2.0
    # float depth with a scale
    f = make_frame(_rgb(), np.full((H, W), 1500.0), depth_scale=1000.0)
    assert f.depth[0, 0] == pytest.approx(1.5)


def test_grey_and_float_images():
    g = np.full((H, W), 77, np.uint8)
    f = make_frame(g, _depth_u16())
    assert f.intensity.dtype == np.float32 and np.all(f.intensity == 77.0)
    f = make_frame(np.full((H, W), 123.5, np.float64), _depth_u16())
    assert np.all(f.intensity == np.float32(123.5))
    assert isinstance(f, Frame) and f.shape == (H, W)


def _raises(match, *args, **kw):
    with pytest.raises(ValueError, match=match):
        make_frame(*args, **kw)


def test_mismatched_sizes_raise():
    _raises(r"does not match", _rgb(), _depth_u16(h=H + 2))
    _raises(r"80x60.*80x62|does not match", _rgb(), _depth_u16(h=62))
    _raises(r"does not match", _rgb(w=W + 1), _depth_u16())


def test_wrong_ndim_raises():
    _raises(r"depth must be a 2-D", _rgb(), np.ones((H, W, 1), np.float32))
    _raises(r"depth must be a 2-D", _rgb(), np.ones(W, np.float32))
    _raises(r"image must be", np.ones((2, H, W, 3), np.uint8), _depth_u16())
    _raises(r"image must be", np.ones(W, np.uint8), _depth_u16())
    # 3-D image with a wrong channel count
    _raises(r"\(H, W, 3\)", np.ones((H, W, 2), np.uint8), _depth_u16())


def test_non_numeric_raises():
    _raises(r"numeric", np.full((H, W), "a"), _depth_u16())
    _raises(r"numeric", _rgb(), np.empty((H, W), dtype=object))


def test_no_valid_depth_raises():
    _raises(r"no valid", _rgb(), np.zeros((H, W), np.uint16))
    _raises(r"no valid", _rgb(), np.full((H, W), np.nan, np.float32))
    _raises(r"no valid", _rgb(), -np.ones((H, W), np.float32))


def test_millimetres_passed_as_metres_raises_scale_error():
    mm = np.full((H, W), 1500.0, np.float32)
    _raises(r"wrong scale", _rgb(), mm)
    _raises(r"depth_scale", _rgb(), mm)
    # uint16 millimetres with depth_scale=1 (i.e. "already metres")
    _raises(r"wrong scale", _rgb(), _depth_u16(value=1500), depth_scale=1.0)


def test_source_is_named_in_the_message():
    with pytest.raises(ValueError, match=r"^depth/0001\.png: .*no valid"):
        make_frame(_rgb(), np.zeros((H, W), np.uint16), source="depth/0001.png")


def test_non_finite_intensity_raises():
    img = np.full((H, W), 10.0)
    img[3, 3] = np.nan
    _raises(r"intensity contains NaN", img, _depth_u16())


def test_luminance_weights():
    px = np.zeros((1, 4, 3), np.uint8)
    px[0, 0] = (255, 0, 0)
    px[0, 1] = (0, 255, 0)
    px[0, 2] = (0, 0, 255)
    px[0, 3] = (255, 255, 255)
    lum = luminance(px)
    assert lum.dtype == np.float32
    np.testing.assert_allclose(lum[0], [0.299 * 255, 0.587 * 255, 0.114 * 255, 255.0], rtol=1e-6)
    # BGR order (cv2.imread) swaps red and blue
    np.testing.assert_allclose(luminance(px, order="bgr")[0], [0.114 * 255, 0.587 * 255, 0.299 * 255, 255.0],
                               rtol=1e-6)
    # alpha channel ignored
    rgba = np.concatenate([px, np.full((1, 4, 1), 7, np.uint8)], -1)
    np.testing.assert_allclose(luminance(rgba), lum)
    # uint16 colour is rescaled to 0-255
    np.testing.assert_allclose(luminance(px.astype(np.uint16) * 257), lum, rtol=1e-5)
    # grey passes through as float32
    g = np.arange(12, dtype=np.uint8).reshape(3, 4)
    np.testing.assert_array_equal(luminance(g), g.astype(np.float32))
    with pytest.raises(ValueError):
        luminance(np.zeros((3, 4, 5), np.uint8))
    # make_frame with colour uses the same weights
    f = make_frame(np.broadcast_to(px[:, :1], (H, W, 3)).copy(), _depth_u16())
    np.testing.assert_allclose(f.intensity, 0.299 * 255, rtol=1e-6)


def test_validate_pair():
    a = make_frame(_rgb(), _depth_u16())
    b = make_frame(_rgb(), _depth_u16(value=7000))
    validate_pair(a, b, CAM)  # fine
    small = make_frame(_rgb(h=30, w=40), _depth_u16(h=30, w=40))
    with pytest.raises(ValueError, match="differ in size"):
        validate_pair(a, small, CAM)
    with pytest.raises(ValueError, match="intrinsics"):
        validate_pair(a, b, DEFAULT)
    with pytest.raises(ValueError, match="floating point"):
        validate_pair(a, Frame(b.intensity.astype(np.uint8), b.depth), CAM)
    with pytest.raises(ValueError, match="no valid"):
        validate_pair(a, Frame(b.intensity, np.zeros_like(b.depth)), CAM)
    with pytest.raises(ValueError, match="2-D"):
        validate_pair(a, Frame(b.intensity[None], b.depth[None]), CAM)
    with pytest.raises(ValueError, match="differ in size"):
        validate_pair(a, Frame(b.intensity, b.depth[:-1]), CAM)
    with pytest.raises(ValueError, match="jaxvo.Frame"):
        validate_pair(a, (1, 2, 3), CAM)


def test_valid_depth_check_is_the_full_test_whatever_rows_hold_the_depth():
    """validate_pair's "no valid depth" check looks at every 8th row first; it must agree with
    the plain test (a finite positive pixel anywhere) wherever the one valid pixel is."""
    from jaxvo.frame import _has_valid_depth

    def plain(d):
        return bool(np.any(np.isfinite(d) & (d > 0)))

    for fill in (0.0, -1.0, np.nan, np.inf):
        d = np.full((48, 64), fill, np.float32)
        assert _has_valid_depth(d) == plain(d) is False
        for row in (0, 3, 8, 47):
            e = d.copy()
            e[row, 5] = 1.5
            assert _has_valid_depth(e) == plain(e) is True
    d = np.zeros((48, 64), np.float32)
    d[::8] = np.inf
    d[3, 2] = np.nan
    assert _has_valid_depth(d) == plain(d) is False
