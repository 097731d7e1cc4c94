"""Sensors (docs/model.md §8.2): the noise recipe bit for bit, the Farrenkopf gyro and the star
tracker by their statistics over many keys, the perfect (absent) sensors, the checks.

The statistical tests use fixed keys, so they are deterministic; their bounds are the
two-sided 99.9 % quantiles of the sampling distributions (chi-square for a variance,
normal for a mean), narrow enough (a few % at 20 000 keys) that a wrong scaling of a
noise level (sqrt(period) on the wrong side, a variance for a sigma, a missing term) fails.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from so3jax.components.base import Measurements
from so3jax.components.sensors import (
    GYRO_BIAS_WALK,
    GYRO_WHITE,
    STAR_TRACKER,
    Gyro,
    IntegratingGyro,
    Sensors,
    StarTracker,
    sensor_noise,
)
from so3jax.core import so3
from so3jax.dynamics.disturbance import noise as disturbance_noise

F64 = jnp.float64
N_KEYS = 20_000
PERIOD = 0.1  # Delta_c [s]
P_TWO_SIDED = 0.999


def keys(n, offset=0):
    """n keys, batch axis last (a (n,) key array)."""
    return jax.vmap(jax.random.key)(jnp.arange(offset, offset + n))


def reference_noise(key, stream, j, dtype=F64):
    """docs/model.md §8.2's recipe as written: normal(fold_in(fold_in(K_sens, s), j), (3,), dtype) with
    K_sens = fold_in(key, 2^32 - 1)."""
    k_sens = jax.random.fold_in(key, np.uint32(4294967295))
    return jax.random.normal(jax.random.fold_in(jax.random.fold_in(k_sens, stream), j), (3,), dtype)


def variance_bounds(n, sigma2, p=P_TWO_SIDED):
    """Two-sided p bounds on the sample variance (ddof = 1) of n draws of N(mu, sigma2)."""
    lo, hi = stats.chi2.ppf([(1 - p) / 2, (1 + p) / 2], n - 1)
    return sigma2 * lo / (n - 1), sigma2 * hi / (n - 1)


def mean_bound(n, sigma2, p=P_TWO_SIDED):
    """Two-sided p bound on |sample mean| of n draws of N(0, sigma2)."""
    return stats.norm.ppf((1 + p) / 2) * np.sqrt(sigma2 / n)


def assert_normal_sample(x, sigma2, label):
    """x (n,): sample variance within its chi-square bounds, sample mean within its bound."""
    x = np.asarray(x)
    n = x.size
    lo, hi = variance_bounds(n, sigma2)
    var = x.var(ddof=1)
    assert lo <= var <= hi, f"{label}: variance {var:.6e} outside [{lo:.6e}, {hi:.6e}] (expected {sigma2:.6e})"
    bound = mean_bound(n, sigma2)
    assert abs(x.mean()) <= bound, f"{label}: mean {x.mean():.3e} beyond +-{bound:.3e}"


# --- the noise recipe -------------------------------------------------------------


def test_stream_numbers_are_the_spec():
    assert (GYRO_WHITE, GYRO_BIAS_WALK, STAR_TRACKER) == (1, 2, 3)


@pytest.mark.parametrize("stream", [1, 2, 3])
@pytest.mark.parametrize("j", [0, 1, 17, 1234])
def test_sensor_noise_single_key_is_the_recipe_exactly(stream, j):
    key = jax.random.key(42)
    got = sensor_noise(key, stream, j, F64)
    assert got.shape == (3,) and got.dtype == F64
    np.testing.assert_array_equal(np.asarray(got), np.asarray(reference_noise(key, stream, j)))
    # a traced tick (as inside a scan) draws the same numbers
    traced = jax.jit(lambda jj: sensor_noise(key, stream, jj, F64))(jnp.asarray(j))
    np.testing.assert_array_equal(np.asarray(traced), np.asarray(got))


def test_sensor_noise_batch_of_keys_is_the_recipe():
    """A batch of keys (3, *b), batch axes last: the recipe's numbers within a few ulp
    (the batched float64 draw uses so3jax's own erf_inv, <= 3 ulp from XLA's)."""
    ks = keys(2000, offset=100)
    draw = jax.jit(sensor_noise, static_argnums=3)  # stream and tick traced
    recipe = jax.jit(lambda ks, s, j: jax.vmap(lambda k: reference_noise(k, s, j))(ks).T, static_argnums=1)
    for stream in (1, 2, 3):
        for j in (0, 29):
            want = recipe(ks, stream, j)  # (3, n)
            got = draw(ks, jnp.asarray(stream), jnp.asarray(j), F64)
            assert got.shape == (3, 2000) and got.dtype == F64
            np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-15, atol=0)
    # two batch axes: (3, 40, 50), each key's draw in its place
    got2 = draw(ks.reshape(40, 50), jnp.asarray(3), jnp.asarray(29), F64)
    assert got2.shape == (3, 40, 50)
    np.testing.assert_allclose(np.asarray(got2), np.asarray(want).reshape(3, 40, 50), rtol=1e-15, atol=0)
    # float32: bit for bit
    got32 = draw(ks, jnp.asarray(3), jnp.asarray(29), jnp.float32)
    want32 = jax.vmap(lambda k: reference_noise(k, 3, 29, jnp.float32))(ks).T
    assert got32.dtype == jnp.float32
    np.testing.assert_array_equal(np.asarray(got32), np.asarray(want32))


def test_sensor_streams_differ_from_each_other_and_from_the_disturbance():
    ks = keys(500)
    sensor = jax.jit(lambda ks, s, j: sensor_noise(ks, s, j, F64))
    disturbance = jax.jit(lambda ks, k: disturbance_noise(ks, k, F64))
    for j in (0, 1, 2, 3, 7):
        draws = {s: np.asarray(sensor(ks, s, j)) for s in (1, 2, 3)}
        # the disturbance's step-k draws, for every k a sensor stream could be confused with
        for k in (j, 1, 2, 3):
            d = np.asarray(disturbance(ks, k))
            for s, x in draws.items():
                assert not np.any(np.isclose(x, d, rtol=1e-12, atol=0)), (s, j, k)
        for s in (1, 2, 3):
            for t in (1, 2, 3):
                if s < t:
                    assert not np.any(np.isclose(draws[s], draws[t], rtol=1e-12, atol=0)), (s, t, j)
        # and the same stream at another tick
        nxt = np.asarray(sensor(ks, 1, j + 1))
        assert not np.any(np.isclose(draws[1], nxt, rtol=1e-12, atol=0))


# --- the gyro ---------------------------------------------------------------------

OMEGA = np.array([0.03, -0.01, 0.02])  # rad/s
BIAS0 = np.array([1e-3, -2e-3, 5e-4])  # rad/s
GYRO_TICKS = 6


@jax.jit
def _gyro_scan(gyro, ks, period):
    n = ks.shape[0]
    sensors = Sensors(rate=gyro)
    Omega = jnp.broadcast_to(jnp.asarray(OMEGA, F64)[:, None], (3, n))
    R = so3.eye_like(Omega)

    def step(state, j):
        new, m = sensors.measure(state, R, Omega, ks, j, period)
        return new, (m.omega_m - Omega, sensors.true_bias(state, Omega), m.R_m - R)

    last, (err, biases, R_m_error) = jax.lax.scan(step, sensors.init((n,), F64), jnp.arange(GYRO_TICKS))
    return err, jnp.concatenate([biases, sensors.true_bias(last, Omega)[None]]), R_m_error


def run_gyro(gyro, period=PERIOD):
    """omega_m - Omega (ticks, 3, n) and the bias b_j before each tick's measurement
    (ticks + 1, 3, n), through Sensors.measure in a jitted scan over GYRO_TICKS ticks."""
    err, biases, R_m_error = _gyro_scan(gyro, keys(N_KEYS, offset=7), jnp.asarray(period, F64))
    np.testing.assert_array_equal(np.asarray(R_m_error), 0.0)  # no star tracker: R_m = R
    return np.asarray(err), np.asarray(biases)


def gyro(arw, rrw):
    return Gyro(jnp.asarray(arw, F64), jnp.asarray(rrw, F64), jnp.asarray(BIAS0, F64))


def test_gyro_white_noise_statistics():
    """rrw = 0: omega_m - Omega - b_0 ~ N(0, arw^2 / period) per axis, at every tick."""
    arw = 2e-4
    err, biases = run_gyro(gyro(arw, 0.0))
    np.testing.assert_array_equal(biases, np.broadcast_to(BIAS0[None, :, None], biases.shape))  # no walk
    white = err - BIAS0[None, :, None]
    sigma2 = arw**2 / PERIOD
    for j in range(white.shape[0]):
        for axis in range(3):
            assert_normal_sample(white[j, axis], sigma2, f"tick {j} axis {axis}")
    # the axes are uncorrelated
    c = np.corrcoef(white.transpose(1, 0, 2).reshape(3, -1))
    assert np.max(np.abs(c - np.eye(3))) < 4 / np.sqrt(white[:, 0].size)


def test_gyro_white_noise_scales_with_period():
    """The same keys at another period: the white noise is arw / sqrt(period) eta (to the
    round-off of omega_m = Omega + b + white, ~1e-18 rad/s, on a noise of ~6e-4 rad/s)."""
    arw = 2e-4
    a, _ = run_gyro(gyro(arw, 0.0), period=0.1)
    b, _ = run_gyro(gyro(arw, 0.0), period=0.4)
    np.testing.assert_allclose(b - BIAS0[None, :, None], 0.5 * (a - BIAS0[None, :, None]), rtol=0, atol=1e-16)


def test_gyro_bias_walk_statistics():
    """b_n - b_0 ~ N(0, rrw^2 n period) per axis; increments of different ticks, the white
    noise and the walk, and different axes are all uncorrelated; omega_m = Omega + b_j + white
    with b_j the bias before the tick's measurement."""
    arw, rrw, n_ticks = 2e-4, 3e-4, GYRO_TICKS
    err, biases = run_gyro(gyro(arw, rrw))
    np.testing.assert_array_equal(biases[0], np.broadcast_to(BIAS0[:, None], biases[0].shape))
    for n in range(1, n_ticks + 1):
        drift = biases[n] - biases[0]
        for axis in range(3):
            assert_normal_sample(drift[axis], rrw**2 * n * PERIOD, f"b_{n} - b_0 axis {axis}")
    white = err - biases[:-1]  # omega_m - Omega - b_j
    for j in range(n_ticks):
        for axis in range(3):
            assert_normal_sample(white[j, axis], arw**2 / PERIOD, f"white tick {j} axis {axis}")
    increments = np.diff(biases, axis=0)  # (ticks, 3, n)
    for j in range(n_ticks):
        for axis in range(3):
            assert_normal_sample(increments[j, axis], rrw**2 * PERIOD, f"increment {j} axis {axis}")
    # all 2 x ticks x 3 variables pairwise uncorrelated
    variables = np.concatenate([increments.reshape(-1, N_KEYS), white.reshape(-1, N_KEYS)])
    c = np.corrcoef(variables)
    off = c - np.eye(c.shape[0])
    assert np.max(np.abs(off)) < 4 / np.sqrt(N_KEYS), np.unravel_index(np.argmax(np.abs(off)), off.shape)


# --- the rate-integrating gyro ---------------------------------------------------------


def integrating_gyro(arw, rrw, bias0=BIAS0):
    return IntegratingGyro(jnp.asarray(arw, F64), jnp.asarray(rrw, F64), jnp.asarray(bias0, F64))


def run_integrating(sensor, attitudes, n_keys=N_KEYS, period=PERIOD):
    """The readings omega_m,j (ticks, 3, n) and the true biases b_j (ticks, 3, n) over the
    attitudes R_j (ticks, 3, 3), shared by n keys, ticks j = 0, 1, ..."""
    ks = keys(n_keys)

    def step(state, x):
        R, j = x
        bias = sensor.bias(state, None)
        R = jnp.broadcast_to(R[..., None], (3, 3, n_keys))
        state, omega_m = sensor.measure(state, R, jnp.zeros((3, n_keys), F64), ks, j, period)
        return state, (omega_m, bias)

    ticks = jnp.arange(attitudes.shape[0])
    _, (omega_m, biases) = jax.jit(lambda Rs: jax.lax.scan(step, sensor.init((n_keys,), F64), (Rs, ticks)))(attitudes)
    return np.asarray(omega_m), np.asarray(biases)


def test_integrating_gyro_reads_the_mean_rate_of_a_varying_rotation():
    """Noise-free, about a fixed axis with theta(t) = a t + c t^2 / 2 (the rate changes within
    every period): omega_m,j = (theta(t_j) - theta(t_{j-1})) / Delta_c n + b_0, the closed form
    of the mean rate; omega_m,0 = 0 (no period has elapsed)."""
    n = np.array([1.0, -2.0, 2.0]) / 3.0
    t = PERIOD * np.arange(12)
    theta = 0.4 * t + 0.5 * 0.9 * t**2  # rad, past pi within the run
    Rs = jax.vmap(so3.exp)(jnp.asarray(theta[:, None] * n, F64))
    omega_m, biases = run_integrating(integrating_gyro(0.0, 0.0), Rs, n_keys=2)
    expected = np.diff(theta)[:, None] / PERIOD * n + BIAS0
    np.testing.assert_allclose(omega_m[1:, :, 0], expected, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(omega_m[0], 0.0)
    np.testing.assert_array_equal(biases, np.broadcast_to(BIAS0[None, :, None], biases.shape))


def test_integrating_gyro_noise_is_the_integrated_farrenkopf_model():
    """A still body: omega_m,j - (b_{j-1} + b_j) / 2 ~ N(0, arw^2 / Delta_c + rrw^2 Delta_c / 12)
    per axis (docs/model.md (8.2)), b_j - b_{j-1} ~ N(0, rrw^2 Delta_c), all uncorrelated."""
    arw, rrw, n_ticks = 2e-4, 3e-3, GYRO_TICKS
    Rs = jnp.broadcast_to(jnp.eye(3, dtype=F64), (n_ticks + 1, 3, 3))
    omega_m, biases = run_integrating(integrating_gyro(arw, rrw), Rs)
    white = omega_m[1:] - 0.5 * (biases[:-1] + biases[1:])
    for j in range(n_ticks):
        for axis in range(3):
            assert_normal_sample(white[j, axis], arw**2 / PERIOD + rrw**2 * PERIOD / 12, f"tick {j + 1} axis {axis}")
    increments = np.diff(biases, axis=0)
    for j in range(1, n_ticks):
        for axis in range(3):
            assert_normal_sample(increments[j, axis], rrw**2 * PERIOD, f"bias increment {j} axis {axis}")
    variables = np.concatenate([increments[1:].reshape(-1, N_KEYS), white.reshape(-1, N_KEYS)])
    off = np.corrcoef(variables) - np.eye(variables.shape[0])
    assert np.max(np.abs(off)) < 4 / np.sqrt(N_KEYS)


# --- the star tracker -----------------------------------------------------------------


def random_rotations(n, seed=3):
    v = np.random.default_rng(seed).normal(size=(3, n))
    v *= (np.random.default_rng(seed + 1).uniform(0.0, 3.0, n) / np.linalg.norm(v, axis=0))  # angles up to 3 rad
    return jax.jit(so3.exp)(jnp.asarray(v, F64))


def test_star_tracker_error_statistics_in_the_body_frame():
    """log(R^T R_m)^vee = sigma eta_3,j (right multiplication: a body-frame error), so per
    axis ~ N(0, sigma^2) for true attitudes anywhere on SO(3)."""
    sigma, n_ticks = 1e-3, 3
    st = StarTracker(jnp.asarray(sigma, F64), every=1)
    sensors = Sensors(attitude=st)
    ks = keys(N_KEYS, offset=11)
    R = random_rotations(N_KEYS)
    Omega = jnp.zeros((3, N_KEYS), F64)

    @jax.jit
    def run(ks):
        def step(state, j):
            new, m = sensors.measure(state, R, Omega, ks, j, jnp.asarray(PERIOD, F64))
            return new, (so3.log(so3.rmatmul(R, m.R_m)), m.omega_m, m.star_valid)

        return jax.lax.scan(step, sensors.init((N_KEYS,), F64), jnp.arange(n_ticks))[1]

    err, omega_m, valid = (np.asarray(x) for x in run(ks))
    eta = jax.jit(lambda ks: jnp.stack([sensor_noise(ks, STAR_TRACKER, j, F64) for j in range(n_ticks)]))(ks)
    np.testing.assert_array_equal(omega_m, 0.0)  # no gyro: the true rate
    assert valid.all()
    for j in range(n_ticks):
        # the error is the recipe's draw, sigma eta_{3,j}
        np.testing.assert_allclose(err[j], sigma * np.asarray(eta[j]),
                                   rtol=0, atol=1e-12 * sigma)
        for axis in range(3):
            assert_normal_sample(err[j, axis], sigma**2, f"star tracker tick {j} axis {axis}")
    c = np.corrcoef(err.transpose(1, 0, 2).reshape(3, -1))
    assert np.max(np.abs(c - np.eye(3))) < 4 / np.sqrt(N_KEYS * n_ticks)


@pytest.mark.parametrize("every", [1, 3, 7])
def test_star_tracker_valid_exactly_at_multiples_of_every(every):
    st = StarTracker(jnp.asarray(1e-4, F64), every=every)
    R = jnp.eye(3, dtype=F64)
    key = jax.random.key(0)
    ticks = jnp.arange(30)
    traced = jax.jit(lambda: jax.lax.scan(lambda c, j: (c, st.measure((), R, R[0], key, j, 0.1)[1][1]), 0, ticks)[1])()
    want = np.arange(30) % every == 0
    np.testing.assert_array_equal(np.asarray(traced), want)
    for j in (0, 1, every, every + 1, 2 * every):  # concrete ticks
        R_m, valid = st.measure((), R, R[0], key, j, 0.1)[1]
        assert bool(valid) == (j % every == 0)
        assert float(so3.orthogonality_error(R_m)) < 1e-14  # a rotation, sampled or not


# --- perfect sensors, checks ---------------------------------------------------------


def test_sensors_without_parts_read_the_truth():
    n = 5
    ks = keys(n)
    R = random_rotations(n)
    Omega = jnp.asarray(np.random.default_rng(0).normal(size=(3, n)), F64)
    dc = jnp.asarray(PERIOD, F64)
    measure = jax.jit(lambda sensors, state: sensors.measure(state, R, Omega, ks, 3, dc))

    none = Sensors()
    assert none.init((n,), F64) == ((), ())
    state, m = measure(none, ((), ()))
    assert isinstance(m, Measurements) and state == ((), ())
    np.testing.assert_array_equal(np.asarray(m.omega_m), np.asarray(Omega))
    np.testing.assert_array_equal(np.asarray(m.R_m), np.asarray(R))
    assert bool(m.star_valid)
    np.testing.assert_array_equal(np.asarray(none.true_bias(((), ()), Omega)), 0.0)

    gyro_only = Sensors(rate=gyro(1e-3, 1e-4))
    s0 = gyro_only.init((n,), F64)
    b0 = s0[0]
    assert b0.shape == (3, n) and b0.dtype == F64 and s0[1] == ()
    state, m = measure(gyro_only, s0)
    np.testing.assert_array_equal(np.asarray(m.R_m), np.asarray(R))
    assert bool(m.star_valid)
    assert not np.allclose(np.asarray(m.omega_m), np.asarray(Omega))
    np.testing.assert_array_equal(np.asarray(gyro_only.true_bias(s0, Omega)), np.asarray(b0))

    st_only = Sensors(attitude=StarTracker(jnp.asarray(1e-3, F64), every=2))
    state, m = measure(st_only, ((), ()))
    assert state == ((), ())
    np.testing.assert_array_equal(np.asarray(m.omega_m), np.asarray(Omega))
    assert not bool(m.star_valid)
    assert not np.allclose(np.asarray(m.R_m), np.asarray(R))


def good_gyro(**kw):
    args = dict(arw=1e-6, rrw=1e-9, bias0=np.array([1e-4, 1e-4, 1e-4]))
    args.update(kw)
    return Gyro(**args)


def test_valid_parts_pass_their_checks():
    good_gyro().check()
    good_gyro(arw=0.0, rrw=0.0, bias0=np.zeros(3)).check()
    StarTracker(3e-5, every=1).check()
    StarTracker(0.0, every=10).check()
    Sensors(good_gyro(), StarTracker(3e-5)).check()
    Sensors().check()


@pytest.mark.parametrize("kw", [
    dict(arw=-1e-6), dict(arw=np.nan), dict(arw=np.inf), dict(arw=np.array([1e-6, 1e-6])),
    dict(rrw=-1e-9), dict(rrw=np.nan), dict(rrw=-np.inf),
    dict(bias0=np.zeros(2)), dict(bias0=np.zeros((3, 1))), dict(bias0=1e-4), dict(bias0=np.array([0.0, np.nan, 0.0])),
    dict(bias0=np.array([0.0, np.inf, 0.0])),
])
def test_gyro_check_rejects(kw):
    with pytest.raises(ValueError):
        good_gyro(**kw).check()
    with pytest.raises(ValueError):
        Sensors(rate=good_gyro(**kw)).check()


@pytest.mark.parametrize("kw", [
    dict(sigma=-1e-5), dict(sigma=np.nan), dict(sigma=np.inf), dict(sigma=np.array([1e-5, 1e-5, 1e-5])),
    dict(every=0), dict(every=-2), dict(every=1.5), dict(every=True), dict(every=2.0),
])
def test_star_tracker_check_rejects(kw):
    args = dict(sigma=3e-5, every=1)
    args.update(kw)
    with pytest.raises(ValueError):
        StarTracker(**args).check()
    with pytest.raises(ValueError):
        Sensors(attitude=StarTracker(**args)).check()
