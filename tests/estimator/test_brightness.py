"""jaxvo.estimator.brightness: the median the exposure offset is fitted with, against NumPy's."""
import jax
import numpy as np

from jaxvo.estimator.brightness import masked_median


def test_masked_median_is_numpys_median_of_the_masked_values():
    """Odd and even counts, ties (rounded values), a single value, values masked out that would
    move the median, and an empty mask (NaN, as jnp.nanmedian): bitwise NumPy's median (the mean
    of the two middle values for an even count), jitted as the estimator runs it. The values sit
    in arrays of two fixed lengths (odd and even), the rest masked out, so that the median is
    compiled twice rather than once per count."""
    rng = np.random.default_rng(0)
    med = jax.jit(masked_median)

    def padded(values, mask, t):
        size = 2047 + t % 2
        x, m = np.full(size, 1e4, np.float32), np.zeros(size, bool)
        x[:len(values)], m[:len(mask)] = values, mask
        return x, m

    for t in range(60):
        n = int(rng.integers(1, 2000))
        x = np.clip(rng.normal(rng.uniform(-60, 60), rng.uniform(0.01, 80), n), -255, 255).astype(np.float32)
        if t % 3 == 0:
            x = np.round(x)
        mask = rng.random(n) < rng.uniform(0.05, 1.0)
        mask[rng.integers(n)] = True
        x[~mask] = 1e4                     # far outside: a median that counted them would move
        assert float(med(*padded(x, mask, t))) == np.float32(np.median(x[mask])), (t, n, int(mask.sum()))
    assert float(med(*padded(np.float32([7.5]), np.bool_([True]), 0))) == 7.5
    assert float(med(*padded(np.float32([1.0, 2.0, 4.0, 8.0]), np.ones(4, bool), 1))) == 3.0
    assert np.isnan(float(med(*padded(np.ones(5, np.float32), np.zeros(5, bool), 0))))
