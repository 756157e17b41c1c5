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
