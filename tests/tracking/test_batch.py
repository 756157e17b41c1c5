"""Many sequences as one batch (jaxvo.tracking.batch): the same poses as each sequence alone, one compile.

Frames are rendered by jaxvo.synthetic at 640x480 and block-averaged to 160x120 so that the
programs compile fast; the second sequence's camera has other intrinsics (vmapped) and the
sequences differ in length (a finished sequence's slot is padding).
"""
from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest

from jaxvo import geometry
from jaxvo.tracking.batch import batch_size, estimate_batch, track_batch
from jaxvo.camera import DEFAULT
from jaxvo.frame import Frame
from jaxvo.config import Config, TrackConfig
from jaxvo.estimator import estimate_motion, trace_count
from jaxvo.tracking.odometry import Odometry, track
from jaxvo.estimator.pyramid import downsample
from jaxvo.synthetic import make_room, render

CAM = DEFAULT.at_level(2)                      # 160 x 120
MOTION = geometry.exp(np.array([np.radians(1.0), np.radians(-1.5), 0.5 * np.radians(1.0), 0.02, -0.01, 0.02]))


def _small(frame):
    i, d = np.asarray(frame.intensity), np.asarray(frame.depth)
    for _ in range(2):
        i, d = downsample(i, d)
    return Frame(np.asarray(i, np.float32), np.asarray(d, np.float32))


@pytest.fixture(scope="module")
def frames():
    scene = make_room(0)
    T = np.eye(4)
    out = []
    for k in range(5):
        out.append(_small(render(scene, DEFAULT, T).frame()))
        T = T @ np.linalg.inv(MOTION if k % 2 == 0 else geometry.exp(0.5 * geometry.log(MOTION)))
    return out


def test_batch_equals_each_sequence_alone_and_compiles_once(frames):
    cfg = Config(method="classic")
    cams = [CAM, dataclasses.replace(CAM, fx=CAM.fx * 1.02, cy=CAM.cy + 0.5)]
    seqs = [frames, frames[::-1][:4]]
    keys = [jax.random.key(3), jax.random.key(4)]
    policy = TrackConfig(max_gap=3, lag=1)
    alone = [track(s, c, cfg, k, policy=policy) for s, c, k in zip(seqs, cams, keys)]
    steps = [[], []]
    before = trace_count()
    batched = track_batch(seqs, cams, cfg, keys, policy, callbacks=[steps[0].append, steps[1].append])
    assert trace_count() - before <= 1          # the batched estimate traced once, not per frame
    for a, b, st in zip(alone, batched, steps):
        assert b.poses.shape == a.poses.shape
        np.testing.assert_allclose(b.poses, a.poses, atol=1e-4)   # 0.1 mm: float rounding of the batch
        assert b.reference.tolist() == a.reference.tolist() and b.valid.tolist() == a.valid.tolist()
        assert [s.frame for s in st] == list(range(1, len(a.poses)))
    # a second batch of the same shapes reuses the compiled program
    before = trace_count()
    track_batch(seqs, cams, cfg, keys, policy)
    assert trace_count() == before


def test_calm_estimates_are_their_own_batched_call(frames, monkeypatch):
    """With the segmentation and RANSAC (the default policy), the estimates without static weights
    (the calm mode's: this room is static) run as their own batched call at the level of
    TrackConfig.calm_min_width (80 here: level 1), the weighted ones at the config's finest level, each program
    traced once (the comparison with each sequence alone is the classic test above: RANSAC
    programs are slow to compile)."""
    from jaxvo.tracking import batch
    calls = []
    real = batch.estimate_batch

    def spy(pairs, cameras, config, size=None):
        calls.append((tuple(p.weights is None for p in pairs), config.finest_level))
        return real(pairs, cameras, config, size)

    monkeypatch.setattr(batch, "estimate_batch", spy)
    seqs, keys = [frames, frames[:3]], [jax.random.key(1), jax.random.key(2)]
    before = trace_count()
    long, short = track_batch(seqs, [CAM] * 2, Config(), keys, TrackConfig(calm_min_width=80))
    assert trace_count() - before <= 2
    assert all(len(set(calm)) == 1 and level == (1 if calm[0] else 0) for calm, level in calls), calls
    assert {level for _, level in calls} == {0, 1}, calls
    assert long.valid.all() and short.valid.all() and long.reference.tolist() == [0, 1, 2, 3]
    # the same first frames with other keys: the same poses to RANSAC's scatter
    np.testing.assert_allclose(short.poses, long.poses[:3], atol=5e-3)


def test_estimate_batch_matches_estimate_motion(frames):
    """Segmented default policy's inputs (weights) and RANSAC: each batched estimate is the
    estimate of its pair alone within a few mm: the batched program rounds differently (e.g. its
    sums), and the robust steps are discontinuous in the residuals (the MAD's histogram bins,
    inlier thresholds), so a rounding difference can move the pose by more than the rounding
    itself (measured: <= 1.6 mm, 0.05 deg on these pairs; classic above agrees to ~2e-5)."""
    cfg = Config(method="ransac", num_levels=1)  # one level: a small program, compiled twice here
    odo = Odometry(CAM, cfg, jax.random.key(0))
    odo.add(frames[0])
    pair = odo.prepare(frames[1])
    other = pair._replace(cur=frames[2], key=jax.random.key(9))
    ests = estimate_batch([pair, other], [CAM, CAM], cfg)
    for p, est in zip([pair, other], ests):
        one = estimate_motion(p.ref, p.cur, CAM, cfg, p.key, init=p.init, weights=p.weights)
        np.testing.assert_allclose(np.asarray(est.T_cur_ref), np.asarray(one.T_cur_ref), atol=4e-3)
        assert np.asarray(est.inlier_mask).shape == np.asarray(one.inlier_mask).shape
        assert abs(float(est.inlier_ratio) - float(one.inlier_ratio)) < 0.03
        assert np.asarray(est.hypotheses).tolist() == np.asarray(one.hypotheses).tolist()


_TWO_DEVICES = """
import sys
import jax
import numpy as np
from jaxvo.tracking.batch import batch_size, estimate_batch, track_batch
from jaxvo.camera import DEFAULT
from jaxvo.frame import Frame
from jaxvo.config import Config, TrackConfig
from jaxvo.tracking.odometry import track

import jaxvo.tracking.batch

# the batched program's outputs, to check where the batch ran
shardings, batched_call = [], jaxvo.tracking.batch._BATCHED


def recorded(*args):
    out = batched_call(*args)
    shardings.append(out.T_cur_ref.sharding)
    return out


jaxvo.tracking.batch._BATCHED = recorded
data = np.load(sys.argv[1])
frames = [Frame(i, d) for i, d in zip(data["intensity"], data["depth"])]
cam = DEFAULT.at_level(2)
assert len(jax.devices()) == 2 and batch_size(3) == 4, jax.devices()
cfg, policy = Config(method="classic"), TrackConfig(max_gap=3, lag=1)
seqs = [frames, frames[::-1], frames[1:]]
keys = [jax.random.key(k) for k in range(3)]
batched = track_batch(seqs, [cam] * 3, cfg, keys, policy)
for s, k, b in zip(seqs, keys, batched):
    a = track(s, cam, cfg, k, policy=policy)
    np.testing.assert_allclose(b.poses, a.poses, atol=1e-4)
assert shardings and all(len(x.device_set) == 2 and not x.is_fully_replicated for x in shardings), shardings
print("same poses on", len(jax.devices()), "devices")
"""


def test_batch_spreads_over_several_devices(frames, tmp_path):
    """With two devices (here two host CPU devices, the path a node with several GPUs takes) three
    sequences run as one batch of four split over both, and each gets the poses it gets alone."""
    import os
    import subprocess
    import sys

    npz = tmp_path / "frames.npz"
    np.savez(npz, intensity=np.stack([f.intensity for f in frames]), depth=np.stack([f.depth for f in frames]))
    # XLA_FLAGS of its own: flags inherited from the test process could end XLA's parsing early
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    r = subprocess.run([sys.executable, "-c", _TWO_DEVICES, str(npz)], env=env, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "same poses on 2 devices" in r.stdout


def test_batch_size_and_bad_inputs(frames):
    n = len(jax.devices())
    assert batch_size(1) == n and batch_size(n + 1) == 2 * n
    odo = Odometry(CAM, Config(method="classic"), jax.random.key(0))
    odo.add(frames[0])
    pair = odo.prepare(frames[1])
    big = Frame(np.ones((240, 320), np.float32), np.ones((240, 320), np.float32))
    with pytest.raises(ValueError, match="same image size"):
        estimate_batch([pair, pair._replace(ref=big, cur=big, weights=None)], [CAM, CAM.with_size(320, 240)],
                       odo.config)
    with pytest.raises(ValueError, match="one camera, key and callback per sequence"):
        track_batch([frames], [CAM, CAM])


def _poses(path):
    return np.loadtxt(path, comments="#")[:, 1:]


def test_cli_runs_a_folder_of_sequences_as_one_batch(tmp_path):
    """`jaxvo run FOLDER` with two sequence folders inside: one trajectory and one summary line per
    sequence, the poses of each sequence run alone."""
    from click.testing import CliRunner

    from jaxvo.cli.main import main

    def invoke(*args):
        r = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)
        assert r.exit_code == 0, r.output
        return r.output
    for seed in (3, 4):
        invoke("synth", "seq1", tmp_path / "seqs" / f"s{seed}", "--frames", 5, "--seed", seed, "--size", "160x120",
               "--no-progress")
    out = invoke("run", tmp_path / "seqs", "--method", "classic", "--out-dir", tmp_path / "out", "--no-progress")
    assert "2 sequences in 1 batch(es)" in out
    for seed in (3, 4):
        assert f"s{seed}: 5 frames" in out
        invoke("run", tmp_path / "seqs" / f"s{seed}", "--method", "classic", "--out", tmp_path / f"alone{seed}.txt",
               "--no-progress")
        np.testing.assert_allclose(_poses(tmp_path / "out" / f"s{seed}.txt"), _poses(tmp_path / f"alone{seed}.txt"),
                                   atol=1e-4)
    r = CliRunner().invoke(main, ["run", str(tmp_path / "seqs" / "s3"), str(tmp_path / "seqs" / "s4"),
                                  "--out", str(tmp_path / "x.txt")])
    assert r.exit_code == 2 and "use --out-dir" in r.output
