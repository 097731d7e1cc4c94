"""sliding_mode against an independent NumPy transcription of the law (scipy's rotations),
the kinematics e_R' = E(R_e) Omega_e by finite differences, the Lyapunov function
V = 1/2 s^T J s along a closed-loop rollout, the registration (its derivatives in the flight
loop, at zero rotation error, against central differences: tests/test_entry_points.py)."""

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import so3jax as sj
from so3jax.controllers import Desired, Feedback, registry
from so3jax.controllers.gains import check_gains
from so3jax.controllers.sliding import SlidingModeGains, attitude_error_rate_matrix, sliding_mode
from tests.helpers import J_BODY, custom_scenario

RNG = np.random.default_rng(11)
J_HAT = np.array([[900.0, 10.0, -5.0], [10.0, 700.0, 20.0], [-5.0, 20.0, 1200.0]])


def vee(m):
    return np.array([m[2, 1], m[0, 2], m[1, 0]])


def e_R_np(R, R_d):
    """1/2 (R_d^T R - R^T R_d)^vee."""
    R_e = R_d.T @ R
    return 0.5 * vee(R_e - R_e.T)


def numpy_torque(gains, R, Omega, R_d, Omega_d, Omega_d_dot, J_hat, boundary):
    """The law written out in NumPy for one state (gains: floats)."""
    lam, k_s, eta, phi = gains
    J = np.eye(3) if J_hat is None else J_hat
    R_e = R_d.T @ R
    Omega_r = R.T @ R_d @ Omega_d
    Omega_e = Omega - Omega_r
    s = Omega_e + lam * e_R_np(R, R_d)
    E = 0.5 * (np.trace(R_e.T) * np.eye(3) - R_e.T)
    sat = np.tanh(s / phi) if boundary == "tanh" else np.clip(s / phi, -1.0, 1.0)
    feedforward = J @ (np.cross(Omega, Omega_r) - R.T @ R_d @ Omega_d_dot + lam * E @ Omega_e)
    return np.cross(Omega, J @ Omega) - feedforward - k_s * s - eta * sat, s


def random_states(n):
    """R, Omega, R_d, Omega_d, Omega_d_dot, each with a leading axis of n."""
    R, R_d = Rotation.random(n, random_state=RNG).as_matrix(), Rotation.random(n, random_state=RNG).as_matrix()
    Omega, Omega_d, Omega_d_dot = (RNG.normal(size=(n, 3)) * scale for scale in (0.05, 0.02, 1e-3))
    return R, Omega, R_d, Omega_d, Omega_d_dot


GAINS = (0.3, 40.0, 0.2, 0.03)  # phi such that some components of s lie in the layer, some outside


@pytest.mark.parametrize("boundary", ["tanh", "sat"])
@pytest.mark.parametrize("J_hat", [None, J_HAT], ids=["identity", "J_hat"])
def test_torque_matches_numpy(boundary, J_hat):
    """Single states, then the same states as one batch (trailing axis) with per-column
    gains k_s and eta; the layer's inside and outside both reached."""
    n = 6
    states = random_states(n)
    controller = sliding_mode(J_hat=None if J_hat is None else jnp.asarray(J_hat), boundary=boundary)
    gains = SlidingModeGains(*map(jnp.asarray, GAINS))
    t = jnp.asarray(0.0)
    inside = outside = 0
    for R, Omega, R_d, Omega_d, Omega_d_dot in zip(*states):
        feedback = Feedback(jnp.asarray(R), jnp.asarray(Omega))
        desired = Desired(*map(jnp.asarray, (R_d, Omega_d, Omega_d_dot)))
        tau, state = controller.torque(gains, controller.init(gains), feedback, desired, t)
        expected, s = numpy_torque(GAINS, R, Omega, R_d, Omega_d, Omega_d_dot, J_hat, boundary)
        np.testing.assert_allclose(tau, expected, rtol=1e-12, atol=1e-15)
        assert state == ()
        inside, outside = inside + np.sum(np.abs(s) < GAINS[3]), outside + np.sum(np.abs(s) > GAINS[3])
    assert inside > 0 and outside > 0

    k_s, eta = RNG.uniform(10.0, 50.0, n), RNG.uniform(0.05, 0.5, n)
    batch_gains = SlidingModeGains(jnp.asarray(GAINS[0]), jnp.asarray(k_s), jnp.asarray(eta), jnp.asarray(GAINS[3]))
    R, Omega, R_d, Omega_d, Omega_d_dot = (jnp.asarray(np.moveaxis(x, 0, -1)) for x in states)
    tau, _ = controller.torque(batch_gains, (), Feedback(R, Omega), Desired(R_d, Omega_d, Omega_d_dot), t)
    assert tau.shape == (3, n)
    for j in range(n):
        column = (GAINS[0], k_s[j], eta[j], GAINS[3])
        expected, _ = numpy_torque(column, *(x[j] for x in states), J_hat, boundary)
        np.testing.assert_allclose(tau[:, j], expected, rtol=1e-12, atol=1e-15)


def test_attitude_error_kinematics_by_finite_differences():
    """d/dt e_R = E(R_e) Omega_e along R(t) = R exp(hat(Omega) t), R_d(t) = R_d exp(hat(Omega_d) t),
    against a central difference; random attitudes, R = R_d and a near half turn; E evaluated
    on the whole set as one batch (trailing axis)."""
    R, Omega, R_d, Omega_d, _ = random_states(8)
    Omega, Omega_d = Omega * 20.0, Omega_d * 20.0  # ~1 rad/s, ~0.4 rad/s
    R[0] = R_d[0]
    R[1] = R_d[1] @ Rotation.from_rotvec([0.0, (np.pi - 1e-3), 0.0]).as_matrix()
    h = 1e-5

    def e_R_at(j, t):
        return e_R_np(R[j] @ Rotation.from_rotvec(Omega[j] * t).as_matrix(),
                      R_d[j] @ Rotation.from_rotvec(Omega_d[j] * t).as_matrix())

    R_e = np.einsum("nji,njk->nik", R_d, R)
    E = np.moveaxis(np.asarray(attitude_error_rate_matrix(jnp.asarray(np.moveaxis(R_e, 0, -1)))), -1, 0)
    for j in range(len(R)):
        Omega_e = Omega[j] - R_e[j].T @ Omega_d[j]
        difference = (e_R_at(j, h) - e_R_at(j, -h)) / (2 * h)
        np.testing.assert_allclose(E[j] @ Omega_e, difference, rtol=1e-7, atol=1e-9)


@pytest.fixture(scope="module")
def lyapunov_run():
    """The continuous wiring on the constant inertia J_BODY, known (J_hat = J), no
    disturbance, the sinusoidal reference (Omega_d' != 0) and a 60 degree initial error."""
    R0 = Rotation.from_rotvec([0.6, -0.7, 0.5]).as_matrix()
    scenario = custom_scenario(15.0, 0.01, R0=R0, Omega0=(0.01, -0.02, 0.015))
    gains = SlidingModeGains(*map(jnp.asarray, (0.2, 100.0, 0.5, 0.01)))
    result = sj.simulate(scenario, sliding_mode(J_hat=jnp.asarray(J_BODY)), gains, record_every=2)
    h = result.history
    R, Omega, R_d, Omega_d = (np.asarray(x) for x in (h.R, h.Omega, h.R_d, h.Omega_d))
    e_R = np.stack([e_R_np(a, b) for a, b in zip(R, R_d)])
    s = Omega - np.einsum("mji,mjk,mk->mi", R, R_d, Omega_d) + 0.2 * e_R
    return gains, np.asarray(h.t), s, np.asarray(h.angle)


def test_lyapunov_function_decreases(lyapunov_run):
    """V = 1/2 s^T J s never grows, falls by the work k_s |s|^2 + eta s . tanh(s / phi)
    (J s' = -k_s s - eta tanh(s / phi)), and s and the attitude error decay."""
    gains, t, s, angle = lyapunov_run
    V = 0.5 * np.einsum("mi,ij,mj->m", s, J_BODY, s)
    assert np.all(np.diff(V) <= 1e-9 * V[0]), np.max(np.diff(V))
    work = 100.0 * np.sum(s**2, axis=1) + 0.5 * np.sum(s * np.tanh(s / 0.01), axis=1)
    np.testing.assert_allclose(V[0] - V[-1], np.trapezoid(work, t), rtol=1e-3)
    assert np.max(np.abs(s[-1])) < 1e-6 * np.max(np.abs(s[0]))
    assert angle[0] > 0.9 and angle[-1] < 0.1 * angle[0]




def test_registration():
    spec = registry.get("sliding_mode")
    assert spec.name in registry.names(tunable=True)
    assert spec.gains_type is SlidingModeGains and spec.label == "sliding mode"
    check_gains(spec.defaults)
    for name in SlidingModeGains._fields:
        for bad in (0.0, -1.0):
            with pytest.raises(ValueError, match=f"{name} must be positive"):
                spec.check(spec.defaults._replace(**{name: bad}))
    options = registry.parse_options("sliding_mode", {"boundary": "sat", "J_hat": J_HAT.tolist()})
    controller = spec.factory(**options)
    assert controller.gains_type is SlidingModeGains and controller.init(spec.defaults) == ()
    assert registry.parse_options("sliding_mode", {}) == {"boundary": "tanh"}
    with pytest.raises(ValueError, match="boundary"):
        registry.parse_options("sliding_mode", {"boundary": "sign"})
    with pytest.raises(ValueError, match="boundary"):
        sliding_mode(boundary="sign")
