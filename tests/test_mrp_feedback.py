"""mrp_feedback against an independent NumPy transcription of Basilisk's mrpFeedback
Update (its steps in order, scipy's MRPs), the Lyapunov function of Schaub & Junkins
Example 8.14, the wheels' momentum and the loop's ticks (its derivatives, K_i = 0 among
them, against central differences: tests/test_entry_points.py)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import so3jax as sj
from so3jax.components.actuators import Wheels, pyramid_axes
from so3jax.controllers import Desired, Feedback, registry
from so3jax.controllers.gains import check_gains
from so3jax.controllers.mrp import MRPFeedbackGains, mrp, mrp_feedback
from so3jax.sim.loop import Loop
from tests.helpers import J_BODY, custom_scenario

RNG = np.random.default_rng(8)
I_HAT = np.array([[900.0, 10.0, -5.0], [10.0, 700.0, 20.0], [-5.0, 20.0, 1200.0]])
G_S = pyramid_axes(4)
J_S = np.array([0.16, 0.12, 0.2, 0.16])


class BasiliskMRPFeedback:
    """The module's Update as its C source orders it, in NumPy: dt from the stored prior
    call time (0 when it is 0: 'no previous call', so a first call at t = 0 makes the
    second's dt 0 too), the integral advanced by K dt sigma before the torque, clipped per
    component, the integral term only for K_i > 0, the wheels' momentum from speeds and
    G_s, J_s, the known torque added to L_r."""

    def __init__(self, K, P, K_i, limit, inertia, law_type, known=(0.0, 0.0, 0.0)):
        self.K, self.P, self.K_i, self.limit, self.I, self.law_type = K, P, K_i, limit, inertia, law_type
        self.known = np.asarray(known)
        self.int_sigma, self.prior_time = np.zeros(3), 0.0

    def update(self, t, sigma, omega_BR, omega_RN, domega_RN, wheel_speeds=None):
        dt = 0.0 if self.prior_time == 0 else t - self.prior_time
        self.prior_time = t
        omega = omega_BR + omega_RN
        z = np.zeros(3)
        if self.K_i > 0:
            self.int_sigma = self.int_sigma + self.K * dt * sigma
            for i in range(3):
                if abs(self.int_sigma[i]) > self.limit:
                    self.int_sigma[i] *= self.limit / abs(self.int_sigma[i])
            z = self.int_sigma + self.I @ omega_BR
        L = self.K * sigma + self.P * omega_BR + self.P * self.K_i * z
        H = self.I @ omega
        if wheel_speeds is not None:
            for i in range(G_S.shape[1]):
                H = H + J_S[i] * (G_S[:, i] @ omega + wheel_speeds[i]) * G_S[:, i]
        v = omega_RN + self.K_i * z if self.law_type == 0 else omega
        L = L - np.cross(v, H) + self.I @ (np.cross(omega, omega_RN) - domega_RN) + self.known
        return -L


def guidance(R, Omega, R_d, Omega_d, Omega_d_dot):
    """The module's inputs (sigma_BR, omega_BR_B, omega_RN_B, domega_RN_B) from ours, with scipy."""
    R_e = R_d.T @ R
    omega_RN = R_e.T @ Omega_d
    return Rotation.from_matrix(R_e).as_mrp(), Omega - omega_RN, omega_RN, R_e.T @ Omega_d_dot


def random_state(scale=1.0):
    R, R_d = Rotation.random(2, random_state=RNG).as_matrix()
    Omega, Omega_d, Omega_d_dot = RNG.normal(size=(3, 3)) * np.array([[0.05], [0.02], [0.001]]) * scale
    return R, Omega, R_d, Omega_d, Omega_d_dot


def test_mrp_is_scipys_short_set():
    angles = [0.0, 1e-9, 1e-3, 0.05, 0.5, 2.0, np.pi - 1e-6, np.pi]
    axes = Rotation.random(len(angles), random_state=RNG).as_rotvec()
    vecs = [a * ax / np.linalg.norm(ax) for a, ax in zip(angles, axes)]
    mats = Rotation.from_rotvec(vecs).as_matrix()
    ours = np.asarray(jax.vmap(mrp)(jnp.asarray(mats)))
    theirs = Rotation.from_matrix(mats).as_mrp()
    assert np.all(np.linalg.norm(ours, axis=1) <= 1.0 + 1e-15)
    for o, t, a in zip(ours, theirs, angles):
        if a == np.pi:  # sigma and its shadow -sigma are the same rotation at a half turn, both of norm 1
            np.testing.assert_allclose(np.abs(o), np.abs(t), atol=1e-12)
        else:
            np.testing.assert_allclose(o, t, rtol=1e-12, atol=1e-15)
    grads = jax.vmap(jax.jacfwd(lambda R: mrp(R)))(jnp.asarray(mats[:6]))
    assert np.all(np.isfinite(grads))


@pytest.mark.parametrize("law_type", [0, 1])
@pytest.mark.parametrize("K_i", [0.0, 2e-4])
@pytest.mark.parametrize("wheels", [False, True])
@pytest.mark.parametrize("t0", [0.0, 0.3])
def test_ticks_follow_the_modules_update(law_type, K_i, wheels, t0):
    """Ten ticks of torque-then-update from t0 against the module's Update, the integral
    limit binding (K_i > 0) on some ticks; dt = 0 at the first tick, and at the second
    where the first is at t = 0 (the module's prior time 0 reads as 'no previous call')."""
    gains = MRPFeedbackGains(*map(jnp.asarray, (2.0, 30.0, K_i, 0.02)))
    known = (0.01, -0.02, 0.005) if wheels else None
    controller = mrp_feedback(J_hat=jnp.asarray(I_HAT), law_type=law_type, known_torque=known)
    module = BasiliskMRPFeedback(2.0, 30.0, K_i, 0.02, I_HAT, law_type, known or (0.0, 0.0, 0.0))
    state = controller.init(gains)
    period, clipped = 0.5, 0
    for j in range(10):
        t = t0 + j * period
        R, Omega, R_d, Omega_d, Omega_d_dot = random_state()
        speeds = RNG.normal(size=4) * 50 if wheels else None
        h_w = None
        if wheels:
            h_w = jnp.asarray(sum(J_S[i] * (G_S[:, i] @ Omega + speeds[i]) * G_S[:, i] for i in range(4)))
        feedback = Feedback(jnp.asarray(R), jnp.asarray(Omega), h_w)
        desired = Desired(*map(jnp.asarray, (R_d, Omega_d, Omega_d_dot)))
        tau, _ = controller.torque(gains, state, feedback, desired, jnp.asarray(t))
        expected = module.update(t, *guidance(R, Omega, R_d, Omega_d, Omega_d_dot), speeds)
        np.testing.assert_allclose(tau, expected, rtol=1e-11, atol=1e-13)
        state = controller.update(gains, state, feedback, desired, jnp.asarray(t), jnp.asarray(period))
        if K_i > 0:
            np.testing.assert_allclose(state.integral, module.int_sigma, rtol=1e-12, atol=1e-16)
            clipped += int(np.any(np.abs(module.int_sigma) >= 0.02 - 1e-15))
            if j == 1 and t0 == 0:
                assert np.all(module.int_sigma == 0)  # the first two ticks add nothing
    assert K_i == 0 or clipped > 0


@pytest.fixture(scope="module")
def lyapunov_run():
    """The continuous wiring on a constant, known inertia (J_hat = J), no disturbance, a
    moving reference and a 60 degree initial error; law type 0 and 1 side by side."""
    R0 = Rotation.from_rotvec([0.6, -0.7, 0.5]).as_matrix()
    scenario = custom_scenario(60.0, 0.01, R0=R0, Omega0=(0.01, -0.02, 0.015))
    gains = MRPFeedbackGains(*map(jnp.asarray, (200.0, 300.0, 0.0, 1.0)))
    runs = [sj.simulate(scenario, mrp_feedback(J_hat=jnp.asarray(J_BODY), law_type=k), gains, record_every=10)
            for k in (0, 1)]
    return gains, runs


def test_lyapunov_function_decreases(lyapunov_run):
    """V = 1/2 dw^T I dw + 2 K ln(1 + |sigma|^2) has V' = -P |dw|^2 with K_i = 0 (Schaub &
    Junkins Example 8.14) for both law types: V never grows, and falls by the work P |dw|^2."""
    gains, runs = lyapunov_run
    for result in runs:
        h = result.history
        R_e = np.einsum("mji,mjk->mik", np.asarray(h.R_d), np.asarray(h.R))
        sigma = Rotation.from_matrix(R_e).as_mrp()
        dw = np.asarray(h.Omega_e)
        V = 0.5 * np.einsum("mi,ij,mj->m", dw, J_BODY, dw) + 2 * 200.0 * np.log1p(np.sum(sigma**2, axis=1))
        assert np.all(np.diff(V) <= 1e-9 * V[0]), np.max(np.diff(V))
        assert V[-1] < 1e-3 * V[0]
        work = 300.0 * np.sum(dw**2, axis=1)
        t = np.asarray(h.t)
        np.testing.assert_allclose(V[0] - V[-1], np.trapezoid(work, t), rtol=1e-3)


def test_sampled_ticks_carry_dt_and_the_limit():
    """In the sampled wiring the state's dt is 0 until the second tick (the first is at
    t = 0), then the period; the integral stays within its limit."""
    scenario = custom_scenario(5.0, 0.01, R0=Rotation.from_rotvec([0.3, 0.2, -0.1]).as_matrix())
    gains = MRPFeedbackGains(*map(jnp.asarray, (2.0, 30.0, 1e-3, 0.05)))
    result = sj.simulate(scenario, mrp_feedback(), gains, loop=Loop(period_steps=10), record_every=10)
    dt, integral = np.asarray(result.history.controller.dt), np.asarray(result.history.controller.integral)
    assert np.all(dt[:2] == 0.0) and np.all(dt[2:] == 0.1)
    assert np.all(np.abs(integral) <= 0.05) and np.any(np.abs(integral) == 0.05)


def test_wheel_momentum_in_the_law_equals_the_actuators_compensation():
    """With law type 1, the law's omega x h_w (compensation off, h_w from the loop) and the
    actuator's Omega_hat x h_w_hat (compensation on) are one term: the same trajectory."""
    scenario = custom_scenario(20.0, 0.01, J=np.diag([900.0, 700.0, 1200.0]), Omega0=(0.02, -0.01, 0.03))
    gains = registry.get("mrp_feedback").defaults
    gains = jax.tree.map(jnp.asarray, gains)
    controller = mrp_feedback(law_type=1)

    def fly(compensation):
        wheels = Wheels(jnp.asarray(G_S), jnp.asarray(J_S), jnp.full(4, 0.2), jnp.full(4, 600.0),
                        jnp.asarray([40.0, -25.0, 15.0, 60.0]), compensation)
        return sj.simulate(scenario, controller, gains, loop=Loop(actuator=wheels, period_steps=10),
                           record_every=10).history

    on, off = fly(True), fly(False)
    np.testing.assert_allclose(off.Omega, on.Omega, rtol=0, atol=1e-13)
    np.testing.assert_allclose(off.actuator, on.actuator, rtol=1e-12, atol=1e-10)
    assert np.max(np.abs(on.actuator[-1] - on.actuator[0])) > 1.0  # rad/s: the wheels did work


def test_registration_and_gain_domains():
    spec = registry.get("mrp_feedback")
    assert "mrp_feedback" in registry.names(tunable=True)
    check_gains(spec.defaults)  # K_i = 0 is in its domain
    with pytest.raises(ValueError, match=r"K_i must be >= 0, got -1.0 \(.*K_i = -1, use 0\)$"):
        check_gains(spec.defaults._replace(K_i=-1.0))
    with pytest.raises(ValueError, match="K must be positive"):
        check_gains(spec.defaults._replace(K=0.0))
    with pytest.raises(ValueError, match="law_type"):
        mrp_feedback(law_type=2)


def test_tuner_parameterizes_a_nonnegative_gain_by_projection():
    """K_i's parameter is K_i / scale, kept >= 0 after each optimizer step: a step that
    would take K_i below 0 stops it at 0, one the other way moves it off 0; the positive
    gains stay log-gains."""
    import optax

    from so3jax.jobs import tune
    from so3jax.jobs.tune.optimizers import GradientState, optax_step

    gains = jax.tree.map(jnp.asarray, registry.get("mrp_feedback").defaults)
    params = tune.to_params(gains)
    np.testing.assert_allclose(params.K, np.log(gains.K), rtol=1e-15)
    assert params.K_i == 0.0
    back = tune.to_gains(params)
    assert all(np.allclose(a, b, rtol=1e-15) for a, b in zip(back, gains))
    tx = optax.sgd(0.5)
    state = GradientState(params, tx.init(params))
    for sign in (1.0, -1.0):
        grad = jax.tree.map(jnp.zeros_like, params)._replace(K_i=jnp.asarray(sign))
        new = optax_step(tx, state, grad, jnp.asarray(0.0))
        assert float(new.params.K_i) == (0.0 if sign > 0 else 0.5)
        assert float(tune.to_gains(new.params).K_i) == (0.0 if sign > 0 else 0.5e-4)
