"""Controller laws: regressor exactness, Lyapunov decrease, tracking with Omega_d' != 0."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import so3jax as sj
from so3jax.controllers import Desired, Feedback, regressor, regressor_parameters
from so3jax.controllers.adaptive import adaptive_terms
from so3jax.core import so3
from tests.helpers import J_BODY, custom_scenario

RNG = np.random.default_rng(1)


def random_symmetric(n):
    a = RNG.normal(size=(n, 3, 3)) * 100
    return a + np.swapaxes(a, -1, -2)


def test_regressor_is_exact_for_any_symmetric_inertia():
    for J in random_symmetric(20):
        Omega, beta_dot = RNG.normal(size=(2, 3))
        Theta = np.asarray(regressor_parameters(J))
        lhs = Theta.T @ np.asarray(regressor(Omega, beta_dot))
        np.testing.assert_allclose(lhs, np.cross(Omega, J @ Omega) + J @ beta_dot, rtol=1e-12, atol=1e-9)


def test_regressor_parameters_of_identity():
    Theta = np.asarray(regressor_parameters(np.eye(3)))
    np.testing.assert_array_equal(Theta[:6], 0.0)
    np.testing.assert_array_equal(Theta[6:], np.eye(3))


def test_pd_torque_closed_form_at_rest_on_reference():
    """On the reference (R = R_d, Omega = Omega_r) the PD law is pure feedforward."""
    Rd = so3.exp(jnp.array([0.3, -0.2, 0.5]))
    Omega_d = jnp.array([0.01, -0.02, 0.03])
    desired = Desired(Rd, Omega_d, jnp.zeros(3))
    tau, _ = sj.geometric_pd().torque(sj.PAPER_PD_GAINS, (), Feedback(Rd, Omega_d), desired, 0.0)
    # Omega x Omega - (Omega x Omega_r - 0) = 0
    np.testing.assert_allclose(tau, 0.0, atol=1e-15)
    # a pure attitude error gives -k_R e_R with e_R = sin(theta) axis for a rotation about an axis
    R = so3.matmul(Rd, so3.exp(jnp.array([0.0, 0.0, 0.2])))
    tau, _ = sj.geometric_pd().torque(sj.PAPER_PD_GAINS, (), Feedback(R, jnp.zeros(3)),
                                      Desired(Rd, jnp.zeros(3), jnp.zeros(3)), 0.0)
    np.testing.assert_allclose(tau, [0.0, 0.0, -0.5714 * np.sin(0.2)], atol=1e-15)


def lyapunov(gains, J, history):
    """V = K_r |e|^2 / 2 + z^T J z / 2 + tr(dTheta^T Gamma^-1 dTheta) / 2 along a history (docs/model.md §3.2)."""
    Theta = regressor_parameters(J)

    def one(R, Omega, R_d, Omega_d, Omega_d_dot, Theta_hat):
        terms = adaptive_terms(gains, Feedback(R, Omega), Desired(R_d, Omega_d, Omega_d_dot))
        d = Theta_hat - Theta
        return (0.5 * gains.K_r * so3.dot(terms.e, terms.e) + 0.5 * terms.z @ J @ terms.z
                + 0.5 * jnp.sum(d * d / gains.Gamma[:, None]))

    rate_dot = jax.vmap(jax.jacfwd(custom_rate))(history.t)
    return np.asarray(jax.vmap(one)(history.R, history.Omega, history.R_d, history.Omega_d, rate_dot,
                                    history.controller))


def custom_rate(t):
    return 0.05 * jnp.stack([jnp.sin(0.1 * t), jnp.cos(0.07 * t), 0.5 * jnp.sin(0.05 * t + 0.3)])


def test_lyapunov_function_never_increases():
    """Constant J, smooth Omega_d with Omega_d' != 0, d = 0: V' = -K_r^2 |e|^2 - K_w |z|^2 <= 0."""
    gains = sj.AdaptiveGains(K_r=jnp.asarray(0.2), K_w=jnp.asarray(30.0), Gamma=jnp.full(9, 1e4))
    R0 = so3.exp(jnp.array([0.6, -0.4, 0.8]))
    scenario = custom_scenario(200.0, 0.01, R0=R0, Omega0=(0.05, 0.02, -0.04), rate_fn=custom_rate)
    r = sj.simulate(scenario, sj.adaptive_backstepping(), gains, 0, record_every=10)
    V = lyapunov(gains, jnp.asarray(J_BODY), r.history)
    assert np.all(np.diff(V) <= 1e-9 * V[0]), np.max(np.diff(V))
    assert V[-1] < 0.5 * V[0]
    # and V' matches its closed form -K_r^2 |e|^2 - K_w |z|^2 (midpoint differences)
    terms = jax.vmap(lambda R, Om, Rd, Omd, Omdd: adaptive_terms(gains, Feedback(R, Om), Desired(Rd, Omd, Omdd)))(
        r.history.R, r.history.Omega, r.history.R_d, r.history.Omega_d, jax.vmap(jax.jacfwd(custom_rate))(r.history.t)
    )
    Vdot = -(gains.K_r**2) * jnp.sum(terms.e**2, -1) - gains.K_w * jnp.sum(terms.z**2, -1)
    dt = float(r.history.t[1] - r.history.t[0])
    np.testing.assert_allclose(np.diff(V) / dt, 0.5 * (Vdot[1:] + Vdot[:-1]),  # trapezoid over 0.1 s
                               rtol=1e-2, atol=1e-6 * abs(Vdot).max())


@pytest.mark.parametrize(
    "controller,gains",
    [
        (sj.geometric_pd(), sj.PDGains(k_R=60.0, k_Omega=300.0)),
        (sj.adaptive_backstepping(), sj.AdaptiveGains(K_r=0.2, K_w=150.0, Gamma=jnp.full(9, 1e4))),
        (sj.adaptive_backstepping(log_derivative="paper"),
         sj.AdaptiveGains(K_r=0.2, K_w=150.0, Gamma=jnp.full(9, 1e4))),
    ],
    ids=["pd", "adaptive", "adaptive-paper-log"],
)
def test_tracks_a_reference_with_angular_acceleration(controller, gains):
    """Unknown inertia (J_hat = I, true J ~ 100 kg m^2), Omega_d' != 0, the paper's noise."""
    scenario = custom_scenario(300.0, 0.01, rate_fn=custom_rate, noise=True)
    r = sj.simulate(scenario, controller, gains, 3, record_every=100)
    h = r.history
    late = h.t > 150.0
    scale = np.sqrt(np.mean(np.sum(np.asarray(h.Omega_d) ** 2, -1)))
    rate_error = np.sqrt(np.mean(np.sum(np.asarray(h.Omega_e)[late] ** 2, -1)))
    assert not bool(r.metrics.diverged)
    assert rate_error < 0.05 * scale, (rate_error, scale)
    assert np.max(np.asarray(h.angle)[late]) < 0.02  # rad
    # the reference really accelerates
    assert np.ptp(np.asarray(h.Omega_d), axis=0).min() > 0.02


# --- the interface: controllers are values ----------------------------------------------------


def test_controllers_built_alike_are_equal_and_share_one_compilation():
    """Two controllers with the same options are equal and hash alike (an array option
    compared by value), so a second simulate reuses the first's compiled rollout."""
    import importlib

    from so3jax.controllers import registry

    rollout = importlib.import_module("so3jax.sim.rollout")  # the package re-exports a function of that name
    for name in registry.names():
        a, b = registry.get(name).factory(), registry.get(name).factory()
        assert a is not b and a == b and hash(a) == hash(b), name
    J = np.diag([600.0, 400.0, 900.0])
    a, b = sj.geometric_pd(J_hat=J), sj.geometric_pd(J_hat=J.tolist())
    assert a == b and hash(a) == hash(b) and a != sj.geometric_pd() and a != sj.sliding_mode(J_hat=J)
    assert sj.adaptive_backstepping() == sj.adaptive_backstepping(leakage="none", projection_eps=0.1)
    assert sj.adaptive_backstepping().update is None
    assert sj.adaptive_backstepping(projection_bound=1.0).update is not None
    assert sj.mrp_feedback().update is not None and sj.geometric_pd().update is None
    scenario = sj.paper_scenario(T=0.5)
    first = sj.simulate(scenario, a, sj.PAPER_PD_GAINS)
    size = rollout._simulate_jit._cache_size()
    second = sj.simulate(scenario, b, sj.PAPER_PD_GAINS)
    assert rollout._simulate_jit._cache_size() == size
    np.testing.assert_array_equal(np.asarray(first.final.Omega), np.asarray(second.final.Omega))


def test_the_controller_base_needs_init_and_torque():
    with pytest.raises(TypeError, match="abstract"):
        sj.Controller()
    zero = sj.from_functions(lambda gains: (), lambda gains, state, feedback, desired, t: (0.0 * feedback.Omega, ()))
    assert isinstance(zero, sj.Controller) and zero.gains_type is None and zero.update is None


def test_public_api_exports_every_law_and_its_gains():
    from so3jax.controllers import mrp_feedback, open_loop, sliding_mode

    assert callable(mrp_feedback) and callable(open_loop) and callable(sliding_mode)  # the functions, not modules
    for factory, gains in ((sj.geometric_pd, sj.PDGains), (sj.adaptive_backstepping, sj.AdaptiveGains),
                           (sj.sliding_mode, sj.SlidingModeGains), (sj.mrp_feedback, sj.MRPFeedbackGains),
                           (sj.open_loop, sj.NoGains)):
        assert factory().gains_type is gains
    assert "pd" in sj.controller_names() and sj.get_controller("pd").factory is sj.geometric_pd
    assert isinstance(sj.__version__, str) and sj.__version__


def test_gain_rules_are_declared_on_the_gains_types():
    from so3jax.controllers.gains import Nonnegative, PositiveDefinite, check_gains, gain_domain

    assert gain_domain(sj.MRPFeedbackGains, "K_i") == Nonnegative(1e-4)
    assert gain_domain(sj.AdaptiveGains, "Gamma") == PositiveDefinite(9)
    assert gain_domain(sj.PDGains, "k_R").shapes is None
    check_gains(sj.PAPER_ADAPTIVE_GAINS._replace(Gamma=np.eye(9)))
    with pytest.raises(ValueError, match="gain Gamma is not positive definite"):
        check_gains(sj.PAPER_ADAPTIVE_GAINS._replace(Gamma=-np.eye(9)))
    with pytest.raises(ValueError, match="gain Gamma must be positive"):
        check_gains(sj.PAPER_ADAPTIVE_GAINS._replace(Gamma=np.zeros(9)))
    with pytest.raises(ValueError, match="gain k_R must be positive"):
        check_gains(sj.PAPER_PD_GAINS._replace(k_R=0.0))


def test_controller_styles_live_in_viz():
    from so3jax.viz import styles

    assert styles.style("pd")["color"] == "tab:red"
    assert styles.style("sliding_mode")["label"] == "sliding mode"
    assert styles.style("no_such_controller") == {"label": "no_such_controller"}
    try:
        assert styles.register("my_law", color="tab:olive") == {"label": "my_law", "color": "tab:olive"}
        assert styles.style("my_law")["color"] == "tab:olive"
    finally:
        styles.STYLES.pop("my_law", None)
