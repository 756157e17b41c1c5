"""Tests of jaxvo.frame: make_frame conversion and validation, luminance, validate_pair."""
from __future__ import annotations

import numpy as np
import pytest

from jaxvo.camera import DEFAULT, camera_for_size
from jaxvo.frame import Frame, check_frame, luminance, make_frame, suggest_depth_scale, validate_pair

H, W = 60, 80
CAM = DEFAULT.at_level(3)  # 80 x 60


def _rgb(h=H, w=W):
    rng = np.random.default_rng(0)
    return rng.integers(0, 256, size=(h, w, 3), dtype=np.uint8)


def _depth_u16(h=H, w=W, value=10000):
    return np.full((h, w), value, np.uint16)


def test_uint16_depth_is_divided_by_the_scale():
    d = _depth_u16()
    d[0, 0] = 0
    d[1, 1] = 5000
    d[2, 2] = 65535
    f = make_frame(_rgb(), d, 5000)
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
    f = make_frame(g, _depth_u16(), 5000)
    assert f.intensity.dtype == np.float32 and np.all(f.intensity == 77.0)
    f = make_frame(np.full((H, W), 123.5, np.float64), _depth_u16(), 5000)
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


def test_depth_without_a_valid_pixel_makes_a_frame_without_depth():
    """A covered sensor's depth (all zero, NaN or negative) is a frame, one without depth: the
    odometry holds it; the estimator refuses it, naming the frame."""
    from jaxvo.frame import has_depth
    for d in (np.zeros((H, W), np.uint16), np.full((H, W), np.nan, np.float32), -np.ones((H, W), np.float32)):
        f = make_frame(_rgb(), d, 5000 if d.dtype == np.uint16 else None)
        assert not has_depth(f) and f.depth.dtype == np.float32 and not f.depth.any()
        with pytest.raises(ValueError, match=r"^current frame: depth has no valid pixel"):
            validate_pair(make_frame(_rgb(), _depth_u16(), 5000), f, camera_for_size(DEFAULT, W, H))
    assert has_depth(make_frame(_rgb(), _depth_u16(), 5000))


def test_millimetres_passed_as_metres_raises_scale_error():
    mm = np.full((H, W), 1500.0, np.float32)
    _raises(r"wrong scale", _rgb(), mm)
    _raises(r"depth_scale", _rgb(), mm)
    # uint16 millimetres with depth_scale=1 (i.e. "already metres")
    _raises(r"wrong scale", _rgb(), _depth_u16(value=1500), depth_scale=1.0)


def test_source_is_named_in_the_message():
    with pytest.raises(ValueError, match=r"^depth/0001\.png: .*no depth_scale"):
        make_frame(_rgb(), _depth_u16(), source="depth/0001.png")


def test_non_finite_intensity_raises():
    img = np.full((H, W), 10.0)
    img[3, 3] = np.nan
    _raises(r"intensity contains NaN", img, _depth_u16(), 5000)


def test_a_float_image_on_0_1_raises_with_the_fix():
    """Float colour scaled to [0, 1] (skimage, OpenCV's convertTo) would put every residual under
    the 30-grey-level threshold; a dark uint8 image and float images on 0-255 pass."""
    rng = np.random.default_rng(0)
    _raises(r"values in \[0, 1\].*pass image \* 255", rng.random((H, W, 3)), _depth_u16(), 5000)
    _raises(r"values in \[0, 1\]", rng.random((H, W)).astype(np.float32), _depth_u16(), 5000)
    make_frame((rng.random((H, W)) * 255).astype(np.float32), _depth_u16(), 5000)
    make_frame(np.ones((H, W), np.uint8), _depth_u16(), 5000)          # integer: grey levels, however dark


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
    f = make_frame(np.broadcast_to(px[:, :1], (H, W, 3)).copy(), _depth_u16(), 5000)
    np.testing.assert_allclose(f.intensity, 0.299 * 255, rtol=1e-6)


def test_validate_pair():
    a = make_frame(_rgb(), _depth_u16(), 5000)
    b = make_frame(_rgb(), _depth_u16(value=7000), 5000)
    validate_pair(a, b, CAM)  # fine
    small = make_frame(_rgb(h=30, w=40), _depth_u16(h=30, w=40), 5000)
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


@pytest.mark.parametrize("depth, scale, match", [
    # integer depth needs its scale; the message names the one that puts the median indoors
    (_depth_u16(value=10000), None, r"uint16 \(sensor units\) and no depth_scale was given: pass depth_scale=5000 "
                                    r"\(value / 5000 = metres: median 2\.00 m\)"),
    (_depth_u16(value=1500), None, r"no depth_scale was given: pass depth_scale=1000 .*median 1\.50 m"),
    (np.full((H, W), 2500, np.int32), None, r"int32 \(sensor units\).*depth_scale=1000"),
    # float depth is metres: millimetres as float say which scale
    (np.full((H, W), 1500.0, np.float32), None, r"wrong scale: median 1500\.0 m .*pass depth_scale=1000, which gives 1\.50 m"),
    # the scale itself: a positive number
    (_depth_u16(), "5000", r"make_frame: depth_scale must be a number > 0, or None \(float depth in metres\), got '5000'"),
    (_depth_u16(), 0, r"depth_scale must be a number > 0"),
    (_depth_u16(), -1000.0, r"depth_scale must be a number > 0"),
    (_depth_u16(), np.array([1000.0, 5000.0]), r"depth_scale must be a number > 0"),
    (_depth_u16(), True, r"depth_scale must be a number"),
], ids=["uint16-tum", "uint16-mm", "int32-mm", "float-mm", "scale-str", "scale-0", "scale-neg", "scale-array",
        "scale-bool"])
def test_depth_units_must_be_said(depth, scale, match):
    with pytest.raises(ValueError, match=match):
        make_frame(_rgb(), depth, scale)


def test_float_metres_and_integer_depth_with_its_scale_pass():
    assert make_frame(_rgb(), np.full((H, W), 2.0, np.float32)).depth[0, 0] == 2.0
    for dtype in (np.uint16, np.int32, np.uint8):
        f = make_frame(_rgb(), np.full((H, W), 200, dtype), depth_scale=100)
        assert f.depth[0, 0] == pytest.approx(2.0)


@pytest.mark.parametrize("raw, exclude, want", [
    (10000.0, None, 5000.0), (1500.0, None, 1000.0), (2.0, None, 1.0), (3000.0, 5000.0, 1000.0),
    (1e9, None, 5e8),   # no common scale fits: the one that gives 2 m
])
def test_suggest_depth_scale(raw, exclude, want):
    assert suggest_depth_scale(raw, exclude) == want


def test_bgr_image_via_from_cv2_equals_the_rgb_path():
    rgb = _rgb()
    bgr = np.ascontiguousarray(rgb[..., ::-1])    # what cv2.imread returns for the same file
    d = _depth_u16()
    want = make_frame(rgb, d, 5000)
    for got in (Frame.from_cv2(bgr, d, 5000), make_frame(bgr, d, 5000, color_order="bgr")):
        np.testing.assert_array_equal(got.intensity, want.intensity)
        np.testing.assert_array_equal(got.depth, want.depth)
    # read as RGB, a BGR image has other intensities (red and blue weigh differently)
    assert np.abs(make_frame(bgr, d, 5000).intensity - want.intensity).max() > 10
    # from_cv2 passes the other arguments on
    m = Frame.from_cv2(bgr, d, 5000, mask=np.ones((H, W), np.uint8)).mask
    assert m.dtype == bool and m.all()
    with pytest.raises(ValueError, match=r"^frame\.png: .*wrong scale"):
        Frame.from_cv2(bgr, d, 1.0, source="frame.png")


@pytest.mark.parametrize("order", ["BGR", "gbr", "", None, 1])
def test_unknown_colour_order_raises(order):
    with pytest.raises(ValueError, match=r"color_order must be one of 'rgb', 'bgr'"):
        make_frame(_rgb(), _depth_u16(), 5000, color_order=order)
    with pytest.raises(ValueError, match=r"luminance: color_order must be one of"):
        luminance(_rgb(), order)


@pytest.mark.parametrize("value, match", [
    ((0.0, Frame(np.zeros((2, 2), np.float32), np.ones((2, 2), np.float32))),
     r"got tuple; iterating a sequence yields \(timestamp, Frame\) pairs: pass the frames, e\.g\. \(f for _, f in seq\)"),
    ((np.zeros((2, 2)), np.ones((2, 2))), r"must be a jaxvo\.Frame .*got tuple$"),
    (None, r"got NoneType$"),
    (np.zeros((2, 2)), r"got ndarray$"),
])
def test_check_frame_names_what_was_passed(value, match):
    with pytest.raises(ValueError, match=r"^frame must be a jaxvo\.Frame"):
        check_frame(value)
    with pytest.raises(ValueError, match=match):
        check_frame(value)
    check_frame(Frame(np.zeros((2, 2), np.float32), np.ones((2, 2), np.float32)))   # a Frame passes


def test_depth_in_millimetres_is_refused_by_the_estimator_with_the_fix():
    """A Frame built directly (not by make_frame) with depth in millimetres: every pixel beyond any
    sensor's range. Refused, naming the unit, where it would otherwise give invalid estimates in
    silence; depth farther than Config.max_depth but in metres is not refused (a far view)."""
    from jaxvo.frame import validate_frame
    rng = np.random.default_rng(0)
    img = (rng.random((H, W)) * 255).astype(np.float32)
    cam = camera_for_size(DEFAULT, W, H)
    with pytest.raises(ValueError, match=r"reference frame: depth has no pixel within 0-100 m \(median 1500\).*depth_scale=1000"):
        validate_pair(Frame(img, np.full((H, W), 1500.0, np.float32)), Frame(img, np.ones((H, W), np.float32)), cam)
    validate_frame(Frame(img, np.full((H, W), 30.0, np.float32)), cam)
    with pytest.raises(ValueError, match="no valid pixel"):
        validate_frame(Frame(img, np.full((H, W), -1.0, np.float32)), cam)
