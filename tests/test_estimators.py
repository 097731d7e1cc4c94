"""Estimators (docs/model.md §8.3): truth, raw and the MEKF.

The MEKF is checked for statistical consistency by Monte Carlo on a case with a closed
form truth (a constant body rate, R(t) = R0 exp(hat(Omega t))): its sensors (Sensors.measure
with the docs/model.md §8.2 gyro and star tracker) and the filter run in one jitted scan over the
ticks for a batch of keys, and the normalized estimation error squared (NEES)
e^T P^-1 e, e = (log(R_hat^T R)^vee, b - b_hat), averaged over the runs, must follow
chi^2(6 N) / N. The filter's model matches the simulated truth up to terms ~1e-6 of the
noise (its Q's sigma_u^2 Delta_c^3 / 3 and cross terms, for a bias that the simulation
steps at the tick), so a wrong noise scaling, gain, Jacobian or sign shows as a NEES
outside its bounds. All keys are fixed: the tests are deterministic.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats
from scipy.spatial.transform import Rotation

from so3jax.components.base import Estimate, Estimator, Measurements
from so3jax.components.estimators import MEKF, Covariance, MEKFState, Raw, Truth
from so3jax.components.sensors import Gyro, Sensors, StarTracker
from so3jax.core import so3

F64 = jnp.float64

# --- the Monte Carlo case ---------------------------------------------------------------

THETA_R0 = np.array([0.3, -0.2, 0.1])  # R0 = exp(hat(.)) [rad]
OMEGA = np.array([0.01, -0.02, 0.005])  # constant body rate [rad/s]
PERIOD = 0.1  # Delta_c [s]
ARW, RRW, SIGMA_ST = 1e-5, 1e-7, 1e-4  # rad/sqrt(s), rad/s^(3/2), rad
BIAS0 = np.array([1e-4, -2e-4, 5e-5])  # rad/s
SIGMA_THETA0, SIGMA_B0 = 1e-3, 1e-3  # rad, rad/s
THETA0 = np.array([5e-4, -3e-4, 2e-4])  # initial attitude error of the filter [rad]
N_RUNS, N_TICKS, SKIP = 200, 300, 10


def f64(x):
    return jnp.asarray(x, F64)


def keys(n, offset=0):
    return jax.vmap(jax.random.key)(jnp.arange(offset, offset + n))


def mission_sensors(sigma_st=SIGMA_ST, every=1):
    return Sensors(Gyro(f64(ARW), f64(RRW), f64(BIAS0)), StarTracker(f64(sigma_st), every=every))


def mission_mekf(sigma_st=SIGMA_ST, theta0=THETA0):
    return MEKF(f64(SIGMA_THETA0), f64(SIGMA_B0), f64(theta0), f64(ARW), f64(RRW), f64(sigma_st))


def true_attitude(j):
    """R(t_j) = R0 exp(hat(Omega t_j)) (3, 3)."""
    t = jnp.asarray(j).astype(F64) * PERIOD
    return so3.matmul(so3.exp(f64(THETA_R0)), so3.exp(f64(OMEGA) * t))


def batched(x, n):
    return jnp.broadcast_to(x[..., None], x.shape + (n,))


def nees(P, e):
    """e^T P^-1 e for P (6, 6, n) (or (3, 3, n)), e (6, n)."""
    Pn = jnp.moveaxis(P, -1, 0)
    en = jnp.moveaxis(e, -1, 0)
    return jnp.einsum("ni,ni->n", en, jnp.linalg.solve(Pn, en[..., None])[..., 0])


@jax.jit
def monte_carlo(ks):
    """For every tick (leading axis) and run (last axis): the prior's and the posterior's
    NEES (6 dof, and the attitude / bias marginals, 3 dof each), the posterior errors, the
    filter's posterior std, and the true and estimated bias."""
    n = ks.shape[0]
    sensors, mekf = mission_sensors(), mission_mekf()
    Omega = batched(f64(OMEGA), n)
    dc = f64(PERIOD)

    def errors(state, R, b):
        return jnp.concatenate([so3.log(so3.rmatmul(state.R_hat, R)), b - state.bias_hat])

    def stats_of(state, R, b):
        e = errors(state, R, b)
        P = state.P.matrix()
        return nees(P, e), nees(state.P.A, e[:3]), nees(state.P.C, e[3:])

    def tick(carry, j):
        sensed, prior = carry
        bias = sensors.true_bias(sensed, Omega)
        R = batched(true_attitude(j), n)
        new_bias, measured = sensors.measure(sensed, R, Omega, ks, j, dc)
        nxt, estimate = mekf.update(prior, measured, dc)
        # the posterior at t_j with its whole covariance: the update propagated over 0 s
        posterior, _ = mekf.update(prior, measured, f64(0.0))
        out = dict(
            prior=stats_of(prior, R, bias),
            posterior=stats_of(posterior, R, bias),
            error=errors(posterior, R, bias),
            estimate_error=jnp.concatenate([so3.log(so3.rmatmul(estimate.R_hat, R)), bias - estimate.bias_hat]),
            std=estimate.std,
            posterior_std=jnp.sqrt(jnp.diagonal(posterior.P.matrix()).T),
            bias=bias,
            omega_error=estimate.Omega_hat - (measured.omega_m - estimate.bias_hat),
        )
        return (new_bias, nxt), out

    carry = (sensors.init((n,), F64), mekf.init(so3.exp(f64(THETA_R0)), (n,), F64))
    return jax.lax.scan(tick, carry, jnp.arange(N_TICKS))[1]


@pytest.fixture(scope="module")
def mc():
    return jax.tree.map(np.asarray, monte_carlo(keys(N_RUNS, offset=1000)))


def nees_bounds(dof, n_runs=N_RUNS, p=0.99):
    """Two-sided p bounds on the average over n_runs of a chi^2(dof) NEES."""
    return stats.chi2.ppf([(1 - p) / 2, (1 + p) / 2], dof * n_runs) / n_runs


@pytest.mark.parametrize("which", ["prior", "posterior"])
def test_mekf_nees_is_consistent(mc, which):
    """The run-averaged NEES of the prior (the state passed into update at tick j) and of
    the posterior at t_j lies within the two-sided 99 % chi^2(6 N)/N bounds at >= 95 % of the
    ticks after the first 10; so do the attitude and the bias marginals (chi^2(3 N)/N)."""
    for part, dof in zip(mc[which], (6, 3, 3)):
        lo, hi = nees_bounds(dof)
        avg = part[SKIP:].mean(axis=1)
        inside = (avg >= lo) & (avg <= hi)
        assert inside.mean() >= 0.95, (
            f"{which} NEES ({dof} dof): {inside.mean():.1%} of ticks in [{lo:.3f}, {hi:.3f}]; "
            f"mean {avg.mean():.3f}, range [{avg.min():.3f}, {avg.max():.3f}]")
        # and on the whole, an average over the ticks near the dof (not a chi^2 bound:
        # the ticks are correlated; a factor-of-two error in a variance moves it by ~50 %)
        assert abs(avg.mean() / dof - 1.0) < 0.15, (which, dof, avg.mean())


def test_mekf_std_matches_the_empirical_error(mc):
    """Estimate.std (sqrt(diag P) after the update) against the RMS over the runs of the
    posterior error, per axis: within 20 % at >= 95 % of the ticks after the first 10, and
    in the mean over those ticks within 10 %."""
    err, std = mc["estimate_error"][SKIP:], mc["std"][SKIP:]
    rms = np.sqrt(np.mean(err**2, axis=-1))  # (ticks, 6)
    filt = std.mean(axis=-1)
    # the filter's covariance hardly depends on the run (only through Omega_hat in Phi)
    np.testing.assert_allclose(std, np.broadcast_to(filt[..., None], std.shape), rtol=1e-3)
    ratio = rms / filt
    for axis in range(6):
        inside = np.abs(ratio[:, axis] - 1.0) <= 0.2
        assert inside.mean() >= 0.95, (axis, inside.mean(), ratio[:, axis].min(), ratio[:, axis].max())
        assert abs(np.sqrt(np.mean(rms[:, axis] ** 2) / np.mean(filt[:, axis] ** 2)) - 1.0) < 0.1, axis


def test_mekf_estimate_is_the_posterior(mc):
    """The Estimate at tick j is the posterior: its errors and std are those of the state
    that update returns for a zero period; Omega_hat = omega_m - b_hat."""
    np.testing.assert_allclose(mc["estimate_error"], mc["error"], rtol=0, atol=1e-15)
    np.testing.assert_allclose(mc["std"], mc["posterior_std"], rtol=1e-12)
    np.testing.assert_array_equal(mc["omega_error"], 0.0)


def test_mekf_bias_estimate_converges(mc):
    """At the last tick the mean over the runs of |b_hat - b| is < 10 % of |b_0| (and
    within 3x the filter's predicted sqrt(trace C))."""
    final_error = mc["estimate_error"][-1, 3:]  # b - b_hat (3, runs)
    mean_norm = np.linalg.norm(final_error, axis=0).mean()
    assert mean_norm < 0.1 * np.linalg.norm(BIAS0), mean_norm
    predicted = np.sqrt(np.sum(mc["std"][-1, 3:] ** 2, axis=0)).mean()
    assert mean_norm < 3 * predicted, (mean_norm, predicted)
    # the start: the filter began at b_hat = 0, an error of |b_0|
    np.testing.assert_allclose(mc["bias"][0], np.broadcast_to(BIAS0[:, None], (3, N_RUNS)))


# --- truth, raw ---------------------------------------------------------------------------


def random_rotations(n, seed=0):
    return jax.jit(so3.exp)(f64(np.random.default_rng(seed).normal(size=(3, n))))


def test_truth_returns_the_truth():
    n = 4
    R = random_rotations(n)
    Omega = f64(np.random.default_rng(1).normal(size=(3, n)))
    measured = Measurements(Omega + 1.0, so3.matmul(R, random_rotations(n, seed=5)), jnp.asarray(True))
    est = Truth()
    state = est.init(R, (n,), F64)
    assert state == ()
    state, out = jax.jit(est.update)(state, measured, f64(PERIOD), (R, Omega))
    assert isinstance(out, Estimate) and state == ()
    np.testing.assert_array_equal(np.asarray(out.R_hat), np.asarray(R))
    np.testing.assert_array_equal(np.asarray(out.Omega_hat), np.asarray(Omega))
    np.testing.assert_array_equal(np.asarray(out.bias_hat), 0.0)
    assert out.std.shape == (6, n)
    np.testing.assert_array_equal(np.asarray(out.std), 0.0)
    Truth().check()


def test_raw_holds_the_last_star_sample_and_uses_the_gyro():
    n, every, n_ticks = 3, 3, 10
    sensors = mission_sensors(sigma_st=1e-3, every=every)
    est = Raw()
    R0 = so3.exp(f64(THETA_R0))
    Omega = batched(f64(OMEGA), n)
    ks = keys(n)
    state0 = est.init(R0, (n,), F64)
    assert state0.shape == (3, 3, n)
    np.testing.assert_array_equal(np.asarray(state0), np.broadcast_to(np.asarray(R0)[..., None], (3, 3, n)))

    @jax.jit
    def run(ks):
        def tick(carry, j):
            bias, state = carry
            R = batched(true_attitude(j), n)
            bias, measured = sensors.measure(bias, R, Omega, ks, j, f64(PERIOD))
            state, out = est.update(state, measured, f64(PERIOD))
            return (bias, state), (measured, out)

        return jax.lax.scan(tick, (sensors.init((n,), F64), state0), jnp.arange(n_ticks))[1]

    measured, out = jax.tree.map(np.asarray, run(ks))
    np.testing.assert_array_equal(measured.star_valid, np.arange(n_ticks) % every == 0)
    for j in range(n_ticks):
        last = every * (j // every)
        np.testing.assert_array_equal(out.R_hat[j], measured.R_m[last], err_msg=f"tick {j}")
        np.testing.assert_array_equal(out.Omega_hat[j], measured.omega_m[j])
        if j != last:  # between samples: not the (unused) sample of this tick
            assert not np.allclose(out.R_hat[j], measured.R_m[j])
    np.testing.assert_array_equal(out.bias_hat, 0.0)
    np.testing.assert_array_equal(out.std, 0.0)
    # the gyro's reading is not the truth (bias and noise), and raw passes it through
    assert np.all(np.abs(out.Omega_hat - OMEGA[None, :, None]) > 0)
    Raw().check()


# --- MEKF: init, checks, gradients --------------------------------------------------------


def test_mekf_init():
    theta0 = np.array([0.02, -0.03, 0.01])
    mekf = MEKF(f64(2e-3), f64(5e-4), f64(theta0), f64(ARW), f64(RRW), f64(SIGMA_ST))
    R0 = Rotation.from_rotvec(THETA_R0).as_matrix()
    want = R0 @ Rotation.from_rotvec(theta0).as_matrix()
    state = mekf.init(f64(R0), (2, 5), F64)
    assert isinstance(state, MEKFState) and isinstance(state.P, Covariance)
    assert state.R_hat.shape == (3, 3, 2, 5) and state.R_hat.dtype == F64
    np.testing.assert_allclose(np.asarray(state.R_hat), np.broadcast_to(want[..., None, None], (3, 3, 2, 5)),
                               rtol=0, atol=1e-15)
    np.testing.assert_array_equal(np.asarray(state.bias_hat), np.zeros((3, 2, 5)))
    P = np.asarray(state.P.matrix())
    assert P.shape == (6, 6, 2, 5)
    P0 = np.diag([2e-3**2] * 3 + [5e-4**2] * 3)
    np.testing.assert_allclose(P, np.broadcast_to(P0[..., None, None], P.shape), rtol=1e-15, atol=0)
    # no batch: one estimate
    single = mekf.init(f64(R0), (), F64)
    assert single.R_hat.shape == (3, 3) and single.P.matrix().shape == (6, 6)
    np.testing.assert_allclose(np.asarray(single.R_hat), want, rtol=0, atol=1e-15)


def test_mekf_single_update_is_the_spec():
    """One update and propagation against docs/model.md §8.3's formulas written with 6 x 6 matrices
    (numpy, Joseph form), from a correlated prior P."""
    rng = np.random.default_rng(4)
    L = rng.normal(size=(6, 6)) * np.array([1e-3] * 3 + [1e-4] * 3)[:, None]
    P = L @ L.T + 1e-9 * np.eye(6)
    R_hat = Rotation.from_rotvec([0.1, 0.2, -0.3]).as_matrix()
    b_hat = np.array([1e-4, 2e-4, -3e-4])
    R_m = R_hat @ Rotation.from_rotvec([1e-3, -2e-3, 5e-4]).as_matrix()
    omega_m = np.array([0.02, -0.01, 0.03])
    sigma, arw, rrw, dc = 2e-4, 3e-5, 4e-7, 0.25
    mekf = MEKF(f64(1e-3), f64(1e-3), f64(np.zeros(3)), f64(arw), f64(rrw), f64(sigma))
    prior = MEKFState(f64(R_hat), f64(b_hat), Covariance(f64(P[:3, :3]), f64(P[:3, 3:]), f64(P[3:, 3:])))
    measured = Measurements(f64(omega_m), f64(R_m), jnp.asarray(True))
    nxt, est = jax.jit(mekf.update)(prior, measured, f64(dc))
    # the spec
    H = np.hstack([np.eye(3), np.zeros((3, 3))])
    r = Rotation.from_matrix(R_hat.T @ R_m).as_rotvec()
    S = H @ P @ H.T + sigma**2 * np.eye(3)
    K = P @ H.T @ np.linalg.inv(S)
    dx = K @ r
    I_KH = np.eye(6) - K @ H
    P_u = I_KH @ P @ I_KH.T + sigma**2 * K @ K.T
    R_u = R_hat @ Rotation.from_rotvec(dx[:3]).as_matrix()
    b_u = b_hat + dx[3:]
    w = omega_m - b_u
    Phi = np.block([[Rotation.from_rotvec(-w * dc).as_matrix(), -dc * np.eye(3)], [np.zeros((3, 3)), np.eye(3)]])
    Q = np.block([[(arw**2 * dc + rrw**2 * dc**3 / 3) * np.eye(3), -(rrw**2 * dc**2 / 2) * np.eye(3)],
                  [-(rrw**2 * dc**2 / 2) * np.eye(3), rrw**2 * dc * np.eye(3)]])
    P_next = Phi @ P_u @ Phi.T + Q
    R_next = R_u @ Rotation.from_rotvec(w * dc).as_matrix()
    np.testing.assert_allclose(np.asarray(est.R_hat), R_u, rtol=0, atol=1e-14)
    np.testing.assert_allclose(np.asarray(est.bias_hat), b_u, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(est.Omega_hat), w, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(est.std), np.sqrt(np.diag(P_u)), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(nxt.R_hat), R_next, rtol=0, atol=1e-14)
    np.testing.assert_allclose(np.asarray(nxt.bias_hat), b_u, rtol=1e-12)
    scale = np.sqrt(np.outer(np.diag(P_next), np.diag(P_next)))
    np.testing.assert_allclose(np.asarray(nxt.P.matrix()) / scale, P_next / scale, rtol=0, atol=1e-12)
    # without a star sample: no update, only the propagation
    measured = measured._replace(star_valid=jnp.asarray(False))
    nxt, est = jax.jit(mekf.update)(prior, measured, f64(dc))
    np.testing.assert_array_equal(np.asarray(est.R_hat), R_hat)
    np.testing.assert_array_equal(np.asarray(est.bias_hat), b_hat)
    w = omega_m - b_hat
    Phi = np.block([[Rotation.from_rotvec(-w * dc).as_matrix(), -dc * np.eye(3)], [np.zeros((3, 3)), np.eye(3)]])
    P_next = Phi @ P @ Phi.T + Q
    scale = np.sqrt(np.outer(np.diag(P_next), np.diag(P_next)))
    np.testing.assert_allclose(np.asarray(nxt.P.matrix()) / scale, P_next / scale, rtol=0, atol=1e-12)


def test_mekf_valid_parameters_pass_check():
    mission_mekf().check()
    MEKF(0.0, 0.0, np.zeros(3), 0.0, 0.0, 1e-5).check()
    from so3jax.components import registry as components

    assert components.names("estimator") == ("truth", "raw", "mekf")
    assert Truth.reads_truth and not Raw.reads_truth and not MEKF.reads_truth
    assert (Truth.needs, Raw.needs, MEKF.needs) == ((), ("attitude",), ("rate", "attitude"))
    assert all(issubclass(c, Estimator) for c in (Truth, Raw, MEKF))
    # the registration reads what the class declares: one declaration per fact
    assert [(components.get("estimator", n).truth, components.get("estimator", n).needs) for n in ("truth", "mekf")] \
        == [(True, ()), (False, ("rate", "attitude"))]


@pytest.mark.parametrize("field,value", [
    ("sigma_theta0", -1e-3), ("sigma_b0", -1e-3), ("arw", -1e-6), ("rrw", -1e-9), ("sigma_st", -3e-5),
    ("sigma_theta0", np.nan), ("arw", np.inf), ("sigma_st", np.nan), ("sigma_b0", np.array([1e-3, 1e-3])),
    ("sigma_st", 0.0),
    ("theta0", np.zeros(2)), ("theta0", np.zeros((3, 1))), ("theta0", 0.0), ("theta0", np.array([0.0, np.nan, 0.0])),
    ("theta0", np.array([np.inf, 0.0, 0.0])),
])
def test_mekf_check_rejects(field, value):
    args = dict(sigma_theta0=1e-3, sigma_b0=1e-3, theta0=np.zeros(3), arw=1e-6, rrw=1e-9, sigma_st=3e-5)
    args[field] = value
    with pytest.raises(ValueError):
        MEKF(**args).check()


GRAD_RUNS = 4


def final_attitude_error(sigma_st, ks):
    """A short MEKF run, one tick: sensors at t_0, the update, the propagation to t_1.
    Sum over the runs of |log(R_hat^T R)^vee|^2 at t_1, with sigma_st the star tracker's
    sigma and the filter's. (One tick, not a scan: a gradient through so3's exp / log
    compiles in ~8 s per tick on this CPU, ~100 s as a scan body with so3jax's XLA flags.)"""
    n = ks.shape[0]
    sensors, mekf = mission_sensors(sigma_st), mission_mekf(sigma_st)
    Omega = batched(f64(OMEGA), n)
    R = batched(true_attitude(0), n)
    _, measured = sensors.measure(sensors.init((n,), F64), R, Omega, ks, 0, f64(PERIOD))
    state, _ = mekf.update(mekf.init(so3.exp(f64(THETA_R0)), (n,), F64), measured, f64(PERIOD))
    e = so3.log(so3.rmatmul(state.R_hat, batched(true_attitude(1), n)))
    return so3.dot(e, e).sum()


def test_mekf_gradient_through_sensor_and_filter_sigma():
    """jit(grad) of the final attitude error with respect to the star tracker's sigma
    (the sensor's and the filter's) is finite, nonzero and matches central differences."""
    ks = keys(GRAD_RUNS, offset=77)
    value_and_grad = jax.jit(jax.value_and_grad(final_attitude_error))
    value, grad = value_and_grad(f64(SIGMA_ST), ks)
    assert np.isfinite(value) and value > 0
    assert np.isfinite(grad) and grad != 0
    h = 1e-4 * SIGMA_ST
    fd = (value_and_grad(f64(SIGMA_ST + h), ks)[0] - value_and_grad(f64(SIGMA_ST - h), ks)[0]) / (2 * h)
    np.testing.assert_allclose(float(grad), float(fd), rtol=1e-5)
