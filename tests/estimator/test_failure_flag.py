"""The failure flag (MotionEstimate.valid) on a few pairs with known truth (synthetic room, 160x120).

The full measurement as a classifier is experiments/failure_flag.py (README, "The failure flag").
"""
from __future__ import annotations

import jax
import numpy as np
import pytest

from jaxvo import Config, Frame, estimate_motion, geometry
from jaxvo.camera import DEFAULT
from jaxvo.estimator import explain_validity

CAM = DEFAULT.at_level(2)
CFG = Config(method="classic")   # the rule is the same for every method; classic compiles fastest


def _step(axis=1, deg=0.0, t=(0.0, 0.0, 0.0)):
    w = np.zeros(3)
    w[axis] = np.radians(deg)
    T = np.eye(4)
    T[:3, :3] = geometry.exp_so3(w)
    T[:3, 3] = t
    return T


NEAR = _step(1, 1.0, (0.01, 0.0, 0.0))


@pytest.fixture(scope="module")
def renders():
    from jaxvo.synthetic import SensorModel, make_room, render
    scene = make_room(0)
    shot = lambda T, k: render(scene, CAM, T, sensor=SensorModel(), rng=k).frame()  # noqa: E731
    return {"ref": shot(np.eye(4), 0), "near": shot(NEAR, 1), "far": shot(_step(1, 3.0, (0.03, 0.0, 0.0)), 1),
            "turned": shot(_step(1, 90.0), 2)}


def _mirror(f):
    return Frame(np.ascontiguousarray(f.intensity[:, ::-1]), np.ascontiguousarray(f.depth[:, ::-1]))


def _flat(f):
    return Frame(np.full_like(f.intensity, 100.0), f.depth)


@pytest.mark.parametrize("cur, valid", [
    (lambda r: r["near"], True),                 # overlapping, 1 cm and 1 deg: estimated within 2 mm
    (lambda r: r["far"], False),                 # 3 cm and 3 deg: too far for classic at 160x120 (20 cm off)
    (lambda r: _mirror(r["ref"]), False),        # no rigid motion maps a frame onto its mirror image
    (lambda r: r["turned"], False),              # turned 90 deg: hardly any overlap
], ids=["overlapping", "too-far-for-classic", "mirrored", "turned-away"])
def test_flag_on_pairs_with_known_truth(renders, cur, valid):
    ref = renders["ref"]
    est = estimate_motion(ref, cur(renders), CAM, CFG, jax.random.key(0))
    assert bool(est.valid) is valid
    stats, again = explain_validity(ref, cur(renders), CAM, est, CFG)
    assert bool(again) == bool(est.valid)
    assert 0.0 <= float(stats.photometric_agreement) <= 1.0
    if valid:
        err = NEAR @ np.asarray(est.T_cur_ref, np.float64)   # inv(T_true) @ T_est
        assert np.linalg.norm(err[:3, 3]) < 0.005


def test_textureless_pair_is_invalid(renders):
    ref, cur = _flat(renders["ref"]), _flat(renders["near"])
    est = estimate_motion(ref, cur, CAM, CFG, jax.random.key(0))
    stats, _ = explain_validity(ref, cur, CAM, est, CFG)
    assert not bool(est.valid) and float(stats.textured) == 0.0



@pytest.mark.parametrize("size, method, sensor", [((16, 12), "huber", False), ((40, 30), "classic", True)],
                         ids=["16x12", "40x30"])
def test_tiny_images_are_too_few_pixels_to_trust(size, method, sensor):
    """The NEAR step rendered small: the estimate is 1 cm / 1 deg (16x12) or 2 cm (40x30) off a
    1 cm / 1 deg motion, and every fraction the flag tests agrees with it, since a pixel spans
    degrees; too few pixels is the reason it is not valid, as explain_validity says."""
    from jaxvo.camera import camera_for_size
    from jaxvo.estimator.trust import MIN_VALID_PIXELS
    from jaxvo.synthetic import SensorModel, make_room, render

    cam = camera_for_size(DEFAULT, *size)
    scene, kw = make_room(0), ({"sensor": SensorModel()} if sensor else {})
    ref, cur = (render(scene, cam, T, rng=k, **kw).frame() for k, T in enumerate((np.eye(4), NEAR)))
    cfg = Config(method=method)
    est = estimate_motion(ref, cur, cam, cfg, jax.random.key(0))
    err = NEAR @ np.asarray(est.T_cur_ref, np.float64)
    assert np.linalg.norm(err[:3, 3]) > 0.008          # wrong by about the motion itself
    stats, again = explain_validity(ref, cur, cam, est, cfg)
    assert not bool(est.valid) and not bool(again)
    assert int(stats.valid_pixels) == int(np.sum(ref.depth > 0)) < MIN_VALID_PIXELS
    # the rule without the pixel count would trust it
    assert bool(stats.finite) and float(stats.conditioning) > 1e-9
    assert float(stats.inlier_ratio) >= cfg.min_inlier_ratio and float(stats.depth_agreement) >= cfg.min_depth_agreement
    assert float(stats.photometric_agreement) >= cfg.min_photometric_agreement

