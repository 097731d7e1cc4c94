"""so3jax.core._trig: the vectorizable float64 sine and cosine against NumPy's."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from so3jax.core import _trig

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


def test_near_zero_within_two_ulp_of_numpy_within_and_beyond_a_quarter_turn():
    """The kernels alone where every element is within +-0.78 rad, sincos where one is not."""
    near = jax.jit(_trig.sincos_near_zero)
    rng = np.random.default_rng(2)
    within = np.concatenate([rng.uniform(-0.78, 0.78, 5000), [0.0, -0.0, 0.7799999999999999, 5e-324, 1e-300]])
    for x in (within, np.concatenate([within, [0.8, -3.0, 1e6, 8e5]])):
        s, c = near(jnp.asarray(x))
        assert _ulps(s, np.sin(x)).max() <= 2.0 and _ulps(c, np.cos(x)).max() <= 2.0
        assert np.mean(np.asarray(s) == np.sin(x)) > 0.5


@pytest.mark.parametrize("dtype", [jnp.float32])
def test_other_dtypes_are_the_library_functions(dtype):
    x = jnp.linspace(-3.0, 3.0, 7, dtype=dtype)
    s, c = _trig.sincos(x)
    assert s.dtype == dtype
    np.testing.assert_array_equal(s, jnp.sin(x))
    np.testing.assert_array_equal(c, jnp.cos(x))


def test_atan2_within_two_ulp_of_numpy():
    rng = np.random.default_rng(1)
    y = np.concatenate([np.abs(rng.standard_normal(40000)) * 10.0 ** rng.uniform(-8, 8, 40000),
                        [0.0, 0.0, 0.0, 1.0, 1.0]])
    x = np.concatenate([rng.standard_normal(40000) * 10.0 ** rng.uniform(-8, 8, 40000), [1.0, -1.0, 0.0, 0.0, -0.0]])
    boundaries = np.array([7, 11, 19, 39]) / 16.0  # fdlibm's argument ranges, and either side
    y = np.concatenate([y, boundaries, np.nextafter(boundaries, 0), np.nextafter(boundaries, 9)])
    x = np.concatenate([x, np.ones(12)])
    got = jax.jit(_trig.atan2)(jnp.asarray(y), jnp.asarray(x))
    assert _ulps(got, np.arctan2(y, x)).max() <= 2.0


def test_atan2_derivatives():
    y, x = jnp.linspace(0.1, 3.0, 50), jnp.linspace(-2.0, 2.0, 50)
    dy, dx = jax.vmap(jax.grad(_trig.atan2, argnums=(0, 1)))(y, x)
    r2 = y * y + x * x
    np.testing.assert_allclose(dy, x / r2, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(dx, -y / r2, rtol=1e-14, atol=1e-15)
