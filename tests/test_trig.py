"""so3jax._trig: the vectorizable float64 sine and cosine against NumPy's."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from so3jax import _trig

_sincos = jax.jit(_trig.sincos)


def _ulps(got, ref):
    """|got - ref| in units of the last place of max(|ref|, 2^-52)."""
    return np.abs(np.asarray(got) - ref) / np.spacing(np.maximum(np.abs(ref), 2.0**-52))


def test_within_two_ulp_of_numpy():
    rng = np.random.default_rng(0)
    x = np.concatenate([
        rng.uniform(-10.0, 10.0, 20000),
        rng.uniform(-8e5, 8e5, 20000),
        rng.uniform(-1e-3, 1e-3, 2000),
        np.arange(-2000, 2001) * (np.pi / 4),  # quadrant boundaries and zeros of sin, cos
        [0.0, -0.0, 5e-324, 1e-300],
    ])
    s, c = _sincos(jnp.asarray(x))
    assert _ulps(s, np.sin(x)).max() <= 2.0
    assert _ulps(c, np.cos(x)).max() <= 2.0
    assert np.mean(np.asarray(s) == np.sin(x)) > 0.5  # mostly the same double


def test_out_of_range_and_non_finite_take_the_library_function():
    x = jnp.asarray([0.5, 1e6, -3e12, np.inf, np.nan])
    s, c = _sincos(x)
    assert _ulps(np.asarray(s)[:3], np.sin(np.asarray(x)[:3])).max() <= 2.0
    assert _ulps(np.asarray(c)[:3], np.cos(np.asarray(x)[:3])).max() <= 2.0
    assert np.all(np.isnan(np.asarray(s)[3:])) and np.all(np.isnan(np.asarray(c)[3:]))


def test_derivatives_are_cosine_and_minus_sine():
    x = jnp.linspace(-7.0, 7.0, 101)
    ds = jax.vmap(jax.grad(_trig.sin))(x)
    dc = jax.vmap(jax.grad(lambda y: _trig.sincos(y)[1]))(x)
    np.testing.assert_allclose(ds, np.cos(x), rtol=0, atol=1e-15)
    np.testing.assert_allclose(dc, -np.sin(x), rtol=0, atol=1e-15)


@pytest.mark.parametrize("dtype", [jnp.float32])
def test_other_dtypes_are_the_library_functions(dtype):
    x = jnp.linspace(-3.0, 3.0, 7, dtype=dtype)
    s, c = _trig.sincos(x)
    assert s.dtype == dtype
    np.testing.assert_array_equal(s, jnp.sin(x))
    np.testing.assert_array_equal(c, jnp.cos(x))
