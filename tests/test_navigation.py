"""Navigation errors as Basilisk's simpleNav draws them (so3jax.components.navigation): the
MRP rotation against SciPy, each walk against a NumPy replay of its own draws, the unbounded
walk's variance (j + 1) sigma^2 within chi-square bounds, the bound held, and the sensors as
a mission reads them. No rollout is compiled."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats
from scipy.spatial.transform import Rotation

from so3jax.components.navigation import NAV_ATTITUDE, NAV_RATE, NavAttitude, NavRate, mrp_rotation
from so3jax.components.sensors import sensor_noise
from so3jax.missions import mission as missions

SIGMA = 1e-3
TICKS = 40


def test_mrp_rotation_is_scipy_s_rotation_of_the_mrp():
    s = np.random.default_rng(0).normal(scale=0.4, size=(3, 50))
    ours = np.moveaxis(np.asarray(mrp_rotation(jnp.asarray(s))), -1, 0)
    np.testing.assert_allclose(ours, Rotation.from_mrp(s.T).as_matrix(), rtol=0, atol=1e-14)


@jax.jit
def _walks(keys, sigma, bound):
    """e_j (TICKS, 3, B) of each key's rate walk, as the sensor steps it tick by tick."""
    sensor = NavRate(sigma, bound)

    def tick(e, j):
        e, omega_m = jax.vmap(lambda e, key: sensor.measure(e, None, jnp.zeros(3), key, j, 0.1),
                              in_axes=(-1, 0), out_axes=-1)(e, keys)
        return e, omega_m

    return jax.lax.scan(tick, jnp.zeros((3, keys.shape[0])), jnp.arange(TICKS, dtype=jnp.uint32))[1]


KEYS = jax.random.split(jax.random.key(11), 4000)


@pytest.mark.parametrize("bound", [0.0, 2.5 * SIGMA])
def test_each_walk_is_the_clipped_sum_of_its_own_draws(bound):
    """A NumPy replay: e_j = clip(e_{j-1} + sigma eta_j, +-bound), the draws of
    sensor_noise's stream 5, the step before it is applied (tick 0 already off)."""
    walks = np.asarray(_walks(KEYS, SIGMA, bound))[:, :, :8]
    draw = jax.vmap(lambda key, j: sensor_noise(key, NAV_RATE, j, jnp.float64), in_axes=(None, 0))
    draws = np.asarray(jax.jit(jax.vmap(draw, in_axes=(0, None)))(KEYS[:8], jnp.arange(TICKS, dtype=jnp.uint32)))
    e = np.zeros((8, 3))
    for j in range(TICKS):
        e = e + SIGMA * draws[:, j]
        e = np.clip(e, -bound, bound) if bound > 0 else e
        np.testing.assert_allclose(walks[j].T, e, rtol=1e-13, atol=1e-18)
    if bound:
        assert np.abs(walks).max() == pytest.approx(bound) and np.mean(np.abs(walks) == bound) > 0.2


def test_the_unbounded_walk_s_variance_grows_as_j_plus_one_sigma_squared():
    """Over 4 000 walks x 3 axes, the sample variance at ticks 0, 9 and 39 within the
    chi-square interval (two-sided 1e-6) of (j + 1) sigma^2; the mean within 5 standard errors of 0."""
    walks = np.asarray(_walks(KEYS, SIGMA, 0.0))
    n = walks.shape[1] * walks.shape[2]
    for j in (0, 9, 39):
        x = walks[j].ravel()
        expected = (j + 1) * SIGMA**2
        low, high = (stats.chi2.ppf(q, n) / n * expected for q in (5e-7, 1 - 5e-7))
        assert low < np.mean(x**2) < high, (j, np.mean(x**2) / expected)
        assert abs(x.mean()) < 5 * np.sqrt(expected / n)


def test_the_attitude_sensor_composes_its_mrp_error_after_the_truth():
    """R_m = R C(s)^T with s the stream-4 walk: the MRP of R_m^T... taken back by SciPy is s."""
    key = jax.random.key(3)
    R = jnp.asarray(Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix())
    sensor = NavAttitude(jnp.asarray(0.01), jnp.asarray(0.0))
    s, (R_m, valid) = sensor.measure(jnp.zeros(3), R, jnp.zeros(3), key, jnp.uint32(0), 0.1)
    np.testing.assert_allclose(s, 0.01 * np.asarray(sensor_noise(key, NAV_ATTITUDE, jnp.uint32(0), jnp.float64)))
    np.testing.assert_allclose(Rotation.from_matrix(np.asarray(R).T @ np.asarray(R_m)).as_mrp(), s, rtol=1e-12)
    assert bool(valid)


def test_a_mission_reads_the_sensors_and_their_values():
    m = missions.load(None, ['estimator.kind="raw"', "sensors.gyro=false", "sensors.star_tracker=false",
                             "sensors.nav_attitude={sigma=1e-5, bound=3e-5}", "sensors.nav_rate={sigma=1e-6}"])
    sensors = m.loop().sensors
    assert isinstance(sensors.attitude, NavAttitude) and isinstance(sensors.rate, NavRate)
    assert float(sensors.attitude.bound) == 3e-5 and float(sensors.rate.bound) == 0.0
    with pytest.raises(ValueError, match="both measure the attitude"):
        missions.load(None, ["sensors.nav_attitude={sigma=1e-5}"])  # beside the flight mission's star tracker
    with pytest.raises(ValueError, match="sensors.nav_rate.sigma"):
        missions.load(None, ["sensors.gyro=false", "sensors.nav_rate={sigma=-1.0}"])
