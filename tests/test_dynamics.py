"""The plant and the integrator against solve_ivp, convergence order, SO(3) drift."""

import dataclasses
import warnings

import jax.numpy as jnp
import numpy as np
from scipy.integrate import solve_ivp

import so3jax as sj
from so3jax.core import so3
from tests.helpers import J_BODY, custom_scenario, zero_torque


def free_body_ivp(J, Omega0, T):
    def rhs(t, y):
        R, Omega = y[:9].reshape(3, 3), y[9:]
        dR = R @ np.array(so3.hat(Omega))
        dOmega = np.linalg.solve(J, -np.cross(Omega, J @ Omega))
        return np.concatenate([dR.ravel(), dOmega])

    y0 = np.concatenate([np.eye(3).ravel(), Omega0])
    sol = solve_ivp(rhs, (0.0, T), y0, method="DOP853", rtol=1e-12, atol=1e-12)
    return sol.y[:9, -1].reshape(3, 3), sol.y[9:, -1]


def test_torque_free_body_matches_solve_ivp():
    Omega0 = np.array([0.05, -0.2, 0.1])
    T = 600.0
    scenario = custom_scenario(T, 0.01, Omega0=Omega0, rate_fn=lambda t: jnp.zeros(3) * t)
    result = sj.simulate(scenario, zero_torque(), (), 0)
    R_ref, Omega_ref = free_body_ivp(J_BODY, Omega0, T)
    np.testing.assert_allclose(result.final.R, R_ref, atol=1e-9)
    np.testing.assert_allclose(result.final.Omega, Omega_ref, atol=1e-10)
    # conserved: kinetic energy and the inertial angular momentum R J Omega
    h0, h1 = J_BODY @ Omega0, np.asarray(result.final.R) @ J_BODY @ np.asarray(result.final.Omega)
    np.testing.assert_allclose(h1, h0, rtol=1e-11)


def _final_state(dt, T=24.0):
    scenario = custom_scenario(T, dt, Omega0=(0.3, -0.2, 0.25))
    gains = sj.AdaptiveGains(K_r=0.4, K_w=60.0, Gamma=jnp.full(9, 200.0))
    r = sj.simulate(scenario, sj.adaptive_backstepping(), gains, 0)
    f = r.final
    return np.concatenate([np.ravel(f.R), np.ravel(f.Omega), np.ravel(f.controller) / 100.0, np.ravel(f.R_d)])


def test_observed_order_is_four():
    """Closed loop (adaptive, integrated R_d, smooth reference, no noise): error ~ dt^4."""
    dts = [0.1, 0.05]
    reference = _final_state(0.005)
    errors = [np.linalg.norm(_final_state(dt) - reference) for dt in dts]
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(orders >= 3.9), (errors, orders)


def test_the_mission_through_every_phase_stays_on_so3():
    scenario = sj.paper_scenario(T=2700.0)  # capture, deployment, and 100 s docked
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sj.InertiaWarning)
        r = sj.simulate(scenario, sj.adaptive_backstepping(), sj.PAPER_ADAPTIVE_GAINS, 0, record_every=4000)
    assert float(r.metrics.orthogonality_error) < 1e-12
    assert not bool(r.metrics.diverged)
    R = np.asarray(r.final.R)
    assert abs(np.linalg.det(R) - 1) < 1e-12


def test_variable_inertia_term_changes_the_motion_as_modelled():
    """With J(t) = J0 (1 + t/T) and no torque, d/dt (J Omega) = -Omega x J Omega holds only with -J' Omega."""
    J0 = J_BODY
    T = 50.0
    grow = lambda t: jnp.asarray(J0) * (1.0 + t / T)
    Omega0 = np.array([0.02, -0.03, 0.05])
    base = custom_scenario(T, 0.01, Omega0=Omega0, rate_fn=lambda t: jnp.zeros(3) * t)
    with_term = dataclasses.replace(base, inertia=sj.InertiaFunction(grow), variable_inertia_term=True)
    without = dataclasses.replace(base, inertia=sj.InertiaFunction(grow), variable_inertia_term=False)
    r_with = sj.simulate(with_term, zero_torque(), (), 0)
    r_without = sj.simulate(without, zero_torque(), (), 0)
    # with the term the inertial angular momentum R J Omega is conserved; without, it is not
    h = lambda r, t: np.asarray(r.final.R) @ np.asarray(grow(t)) @ np.asarray(r.final.Omega)
    np.testing.assert_allclose(h(r_with, T), J0 @ Omega0, rtol=1e-10)
    assert np.linalg.norm(h(r_without, T) - J0 @ Omega0) > 1e-3 * np.linalg.norm(J0 @ Omega0)
