"""The estimator's inputs, checked: what :func:`jaxvo.estimator.motion.estimate_motion` passes to
the compiled estimate (:class:`EstimateArgs`), and the checks and conversions it is made with.

These are the estimator's internal API for the tracking package (which batches estimates and
checks its own config and key as the estimator does); a user calls ``estimate_motion``.
"""
from __future__ import annotations

from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from jaxvo import geometry
from jaxvo.camera import Camera
from jaxvo.config import Config
from jaxvo.estimator.pyramid import num_levels_for
from jaxvo.frame import Frame, validate_pair

__all__ = ["EstimateArgs", "as_float32", "checked_config", "checked_key", "estimate_args", "num_levels"]


def num_levels(config: Config, width: int, height: int) -> int:
    """Pyramid levels of the estimate of (height, width) images: ``config.num_levels``, or by default
    :func:`jaxvo.estimator.pyramid.num_levels_for` the size."""
    return config.num_levels if config.num_levels is not None else num_levels_for(width, height)


def checked_config(config: Optional[Config], camera: Camera) -> Config:
    """The config (default ``Config()``) after checking it and the camera (ValueError naming the field)."""
    config = Config() if config is None else config
    if not isinstance(config, Config):
        raise ValueError(f"config must be a jaxvo.Config, got {type(config).__name__}")
    if not isinstance(camera, Camera):
        raise ValueError(f"camera must be a jaxvo.Camera, got {type(camera).__name__} "
                         f"(e.g. jaxvo.camera.PRESETS['fr2'])")
    # the checks cost a fraction of a millisecond at every estimate (docs/decisions/cpu-kernels.md):
    # a (config, camera) pair that passed once is not checked again (equal values pass equally;
    # configs holding arrays are not hashable: checked)
    try:
        known = (config, camera) in _CHECKED
    except TypeError:
        known = None
    if not known:
        config.validate()
        camera.validate()
        if known is not None:
            if len(_CHECKED) > 256:
                _CHECKED.clear()
            _CHECKED.add((config, camera))
    return config


_CHECKED: set = set()


def checked_key(key):
    """``key`` (default ``jax.random.key(0)``) if it is a jax.random key, else ValueError with a hint."""
    if key is None:
        return jax.random.key(0)
    dtype = getattr(key, "dtype", None)
    if dtype is not None and (jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key)
                              or (dtype == jnp.uint32 and tuple(key.shape) == (2,))):
        return key
    shown = repr(key) if isinstance(key, (int, float, str)) else type(key).__name__
    raise ValueError(f"key must be a jax.random key, got {shown}; pass jax.random.key(seed), "
                     f"e.g. jax.random.key({key if isinstance(key, int) else 0})")


class EstimateArgs(NamedTuple):
    """The arguments of the compiled estimate (:func:`jaxvo.estimator.levels.estimate_arrays`), in its order.

    ref_intensity, ref_depth, cur_intensity, cur_depth: (H, W) float32 images (0-255; metres,
      0 = invalid), NumPy or JAX arrays.
    camera: the :class:`Camera` of (H, W) images; config: the checked :class:`Config` (static).
    key: ``jax.random`` key. T_init: (4, 4) float32 initial T_cur_ref.
    ref_weight: (H, W) float32 trust in each reference pixel (the weights times ``ref.mask``).
    """
    ref_intensity: jnp.ndarray
    ref_depth: jnp.ndarray
    cur_intensity: jnp.ndarray
    cur_depth: jnp.ndarray
    camera: Camera
    config: Config
    key: jnp.ndarray
    T_init: jnp.ndarray
    ref_weight: jnp.ndarray


def estimate_args(ref: Frame, cur: Frame, camera: Camera, config: Optional[Config], key, init,
                  weights) -> EstimateArgs:
    """The checked :class:`EstimateArgs` of the compiled estimate for the inputs of
    :func:`jaxvo.estimator.motion.estimate_motion` (same arguments, same checks: ValueError
    naming the problem)."""
    config = checked_config(config, camera)
    validate_pair(ref, cur, camera)
    h, w = ref.intensity.shape
    L = num_levels(config, w, h)
    if config.finest_level >= L:
        raise ValueError(f"config.finest_level={config.finest_level} but the pyramid has only {L} levels")
    if (w >> (L - 1)) < 8 or (h >> (L - 1)) < 8:
        raise ValueError(f"{L} pyramid levels are too many for {w}x{h} images")
    key = checked_key(key)
    if init is None:
        T0 = _IDENTITY
    else:
        if not isinstance(init, jax.core.Tracer):   # a traced guess (inside a caller's jit) has no values yet
            geometry.checked_transform(init, "init (the initial T_cur_ref)")
        T0 = as_float32(init)
    return EstimateArgs(as_float32(ref.intensity), as_float32(ref.depth), as_float32(cur.intensity),
                        as_float32(cur.depth), camera, config, key, T0, _reference_weights(ref, weights))


_IDENTITY = np.eye(4, dtype=np.float32)
_IDENTITY.flags.writeable = False
_ONES: dict = {}   # (h, w) -> read-only float32 ones: the weights when none are given


def as_float32(x):
    """``x`` as float32 without a dispatch per array: NumPy (and lists) stay on the host, as NumPy,
    and travel with the compiled call (one transfer, not one ``jnp.asarray`` dispatch per array
    and estimate; docs/decisions/cpu-kernels.md); JAX arrays (and tracers) stay where they are."""
    if isinstance(x, jax.Array):
        return x if x.dtype == jnp.float32 else x.astype(jnp.float32)
    return np.asarray(x, np.float32)


def _check_weight_values(wt: np.ndarray) -> None:
    """ValueError unless every weight lies in [0, 1] (NaN fails both bounds). Host weights only: a
    device array (the tracking's static weights, in [0, 1] by construction) is not read back, as
    that would wait for it at every estimate."""
    ok = (wt >= 0.0) & (wt <= 1.0)
    if not np.all(ok):
        bad = wt[~ok]
        nan = np.isnan(bad)
        values = bad[~nan]
        found = (["NaN"] if nan.any() else []) + \
            ([f"values from {float(values.min()):g} to {float(values.max()):g}"] if values.size else [])
        hint = " (a 0-255 mask? divide it by 255)" if values.size and values.max() > 1.0 else ""
        raise ValueError(f"weights must lie in [0, 1] (trust per reference pixel; 0 = ignore), got "
                         f"{' and '.join(found)}{hint}")


def _reference_weights(ref: Frame, weights=None):
    """(H, W) float32 trust of the reference pixels: ``weights`` (default 1) times ``ref.mask``."""
    h, w = ref.intensity.shape
    if weights is None:
        if (h, w) not in _ONES:
            _ONES[(h, w)] = np.ones((h, w), np.float32)
            _ONES[(h, w)].flags.writeable = False
        wt = _ONES[(h, w)]
    else:
        wt = as_float32(weights)
    if wt.shape != (h, w):
        raise ValueError(f"weights must have the images' shape {(h, w)}, got {wt.shape}")
    if weights is not None and not isinstance(wt, jax.Array):
        _check_weight_values(wt)
    if getattr(ref, "mask", None) is not None:
        m = ref.mask if isinstance(ref.mask, jax.Array) else np.asarray(ref.mask)
        if m.shape != (h, w):
            raise ValueError(f"reference frame: mask must have the images' shape {(h, w)}, got {m.shape}")
        wt = wt * (m != 0)
    return wt
