"""Many sequences as one batch: the estimates of several :class:`jaxvo.tracking.odometry.Odometry` runs
in lockstep, one ``jax.vmap``'d call per frame index, spread over the available devices.

Each sequence keeps its own host-side policy (reference choice, segmentation, held poses:
:meth:`Odometry.prepare` / :meth:`Odometry.finish`); only the estimates are batched. The
batch has a fixed size for the whole run (the number of sequences rounded up to a multiple of
the device count; a finished sequence's slot repeats another slot's inputs and its result is
dropped), so each batched program compiles once: one per Config of the estimates (with
``TrackConfig.calm_min_width`` set, the calm mode's estimates have their own:
:meth:`Odometry.config_for`). Sequences must share the image size; the cameras may differ
(their intrinsics are vmapped). Each sequence gets exactly the keys of
:func:`jaxvo.tracking.odometry.track`, so its result equals the sequence run alone up to the
floating-point differences of the batched program (tests/test_batch.py).
"""
from __future__ import annotations

from typing import Callable, Iterable, List, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxvo.camera import Camera
from jaxvo.config import Config, TrackConfig
from jaxvo.estimator import EstimateArgs, MotionEstimate, estimate_args, estimate_arrays
from jaxvo.tracking.odometry import Odometry, PairInputs, Track
from jaxvo.estimator.solvers import jit

__all__ = ["batch_size", "estimate_batch", "track_batch"]

# the estimate vmapped over (frames, camera, key, initial pose, weights); the config is shared
_IN_AXES = tuple(EstimateArgs(ref_intensity=0, ref_depth=0, cur_intensity=0, cur_depth=0, camera=0, config=None,
                              key=0, T_init=0, ref_weight=0))
_BATCHED = jit(jax.vmap(estimate_arrays, in_axes=_IN_AXES))


def _sharding():
    """NamedSharding that splits a leading batch axis over jax.devices() (its size a multiple of their count)."""
    devices = jax.devices()
    return NamedSharding(Mesh(np.asarray(devices), ("seq",)), PartitionSpec("seq"))


def batch_size(n: int) -> int:
    """The batch that holds ``n`` sequences: n rounded up to a multiple of the device count."""
    d = len(jax.devices())
    return -(-n // d) * d


def estimate_batch(pairs: Sequence[PairInputs], cameras: Sequence[Camera], config: Config,
                   size: Optional[int] = None) -> List[MotionEstimate]:
    """The estimates of ``pairs`` (one per sequence, with its camera) as one batched call.

    ``size``: the batch size to run (>= len(pairs), a multiple of the device count; default
    :func:`batch_size`); missing slots repeat the first pair and are dropped. Inputs are checked
    as :func:`jaxvo.estimator.motion.estimate_motion` checks them (ValueError naming the problem).
    Returns one :class:`MotionEstimate` per pair.
    """
    if not pairs:
        return []
    size = batch_size(len(pairs)) if size is None else size
    if size < len(pairs) or size % len(jax.devices()):
        raise ValueError(f"batch size {size} must hold {len(pairs)} pairs and be a multiple of "
                         f"{len(jax.devices())} devices")
    args = [estimate_args(p.ref, p.cur, c, config, p.key, p.init, p.weights) for p, c in zip(pairs, cameras)]
    args += [args[0]] * (size - len(args))
    if len({a.ref_intensity.shape for a in args}) != 1:
        raise ValueError("sequences in one batch must have the same image size, got "
                         + ", ".join(sorted({f"{a.ref_intensity.shape[1]}x{a.ref_intensity.shape[0]}" for a in args})))
    config = args[0].config
    cols = EstimateArgs(*zip(*args))   # each field: its values over the batch
    stacked = [jnp.stack(c) for c in (cols.ref_intensity, cols.ref_depth, cols.cur_intensity, cols.cur_depth, cols.key,
                                      cols.T_init, cols.ref_weight)]
    cam = jax.tree.map(lambda *x: jnp.asarray(x, jnp.float32), *cols.camera)
    sharding = _sharding()
    ri, rd, ci, cd, keys, T0, wt = jax.device_put(stacked, sharding)
    cam = jax.device_put(cam, sharding)
    out = _BATCHED(ri, rd, ci, cd, cam, config, keys, T0, wt)
    return [jax.tree.map(lambda x, i=i: x[i], out) for i in range(len(pairs))]


def track_batch(sequences: Sequence[Iterable], cameras: Sequence[Camera], config: Optional[Config] = None,
                keys=None, policy: Optional[TrackConfig] = None,
                callbacks: Optional[Sequence[Optional[Callable]]] = None) -> List[Track]:
    """:func:`jaxvo.tracking.odometry.track` of several sequences at once, their estimates batched.

    sequences: iterables of :class:`jaxvo.frame.Frame` (lazy is fine), all of one image size;
    cameras: one per sequence; keys: one ``jax.random`` key per sequence (default
    ``jax.random.key(0)`` each); ``policy``: the :class:`TrackConfig` of every sequence;
    ``callbacks[s](step)`` is called with each :class:`jaxvo.tracking.odometry.TrackStep` of sequence s
    (frames >= 1). Returns one :class:`Track` per sequence.
    """
    n = len(sequences)
    keys = [jax.random.key(0)] * n if keys is None else list(keys)
    callbacks = [None] * n if callbacks is None else list(callbacks)
    if not (len(cameras) == len(keys) == len(callbacks) == n):
        raise ValueError("track_batch needs one camera, key and callback per sequence")
    odos = [Odometry(c, config, k, policy) for c, k in zip(cameras, keys)]
    iters = [iter(s) for s in sequences]
    active = list(range(n))
    size = batch_size(n)
    while active:
        pairs = {}
        for s in list(active):
            frame = next(iters[s], None)
            if frame is None:
                active.remove(s)
                continue
            pair = odos[s].prepare(frame)
            if pair is not None and not pair.depth:   # a frame without depth: nothing to estimate
                step = odos[s].finish(pair, None)
                if callbacks[s] is not None:
                    callbacks[s](step)
            elif pair is not None:
                pairs[s] = pair
        if not pairs:
            continue
        # one batched call per Config: the estimates with static weights and those without (the
        # calm mode's, at TrackConfig.calm_min_width's level where it is set: Odometry.config_for);
        # all sequences share config and policy, so the first sequence's configs stand for all
        groups = {}
        for s, p in pairs.items():
            cfg = odos[0].config_for("track", p.weights)
            groups.setdefault(id(cfg), (cfg, []))[1].append(s)
        ests = {}
        for cfg, group in groups.values():
            ests.update(zip(group, estimate_batch([pairs[s] for s in group], [cameras[s] for s in group], cfg, size)))
        for s, pair in pairs.items():
            est = ests[s]
            step = odos[s].finish(pair, est)
            if callbacks[s] is not None:
                callbacks[s](step)
    for s, odo in enumerate(odos):
        if not odo.poses:
            raise ValueError(f"sequence {s}: track_batch needs at least one frame per sequence")
    return [odo.result() for odo in odos]
