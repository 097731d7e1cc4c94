"""The component interfaces beyond reaction wheels: an actuator defined here, outside the
library, flies in both wirings; a stateful actuator reports the same effort in both as the
control period shrinks; the plant with wheels matches an independent integration in the
closed loop; a controller's discrete update runs at the ticks."""

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import so3jax as sj
from so3jax.components.actuators import Wheels, pyramid_axes
from so3jax.components.base import Actuator
from so3jax.controllers import Controller, from_functions
from so3jax.core.pytree import pytree_dataclass
from so3jax.sim.loop import Loop
from tests.helpers import J_BODY, custom_scenario

PD = jax.tree.map(jnp.asarray, sj.PAPER_PD_GAINS)
T, DT = 3.0, 0.01
OMEGA0 = (0.02, -0.01, 0.03)  # rad/s


@pytree_dataclass
class FirstOrderLag(Actuator):
    """tau_a' = (tau_c - tau_a) / T_lag: the body receives tau_a, the actuator's state; no
    stored momentum, no limits (the base's defaults: so3jax.components.base.Actuator)."""

    time_constant: jax.Array  # T_lag, s

    def init(self, batch_shape, dtype):
        return jnp.zeros((3, *batch_shape), dtype)

    def command(self, state, tau_c, Omega_hat):
        return tau_c

    def body_torque(self, state, held, Omega):
        return state

    def derivative(self, state, held, Omega, Omega_dot):
        return (held - state) / self.time_constant


LAG = FirstOrderLag(jnp.asarray(0.3))


def _fly(period_steps, actuator=LAG, controller=None, gains=PD, T=T, **kwargs):
    scenario = custom_scenario(T, DT, Omega0=OMEGA0)
    return sj.simulate(scenario, controller or sj.geometric_pd(), gains, loop=Loop(actuator=actuator,
                       period_steps=period_steps), **kwargs)


@pytest.fixture(scope="module")
def lag_runs():
    """The lag flown continuously and at Delta_c = 4, 2, 1 dt (one compiled program each)."""
    return _fly(None), {m: _fly(m) for m in (4, 2, 1)}


def test_a_first_order_lag_flies_in_both_wirings(lag_runs):
    """The torque on the body is the lag's state: it starts at 0 and follows the command
    with T_lag (so the delivered torque trails the commanded one), in both wirings."""
    continuous, sampled = lag_runs
    for r in (continuous, *sampled.values()):
        h = r.history
        assert np.all(np.isfinite(r.final.Omega)) and not bool(r.metrics.diverged)
        assert np.all(h.tau[0] == 0.0) and np.abs(h.tau_cmd[0]).max() > 1e-2  # tau_a(0) = 0, the command is not
        np.testing.assert_array_equal(h.actuator, h.tau)  # delivered = the state
        assert np.abs(h.tau - h.tau_cmd).max() > 0.1 * np.abs(h.tau_cmd).max()  # the lag matters
        assert r.final.actuator.shape == (3,)
    np.testing.assert_allclose(continuous.final.Omega, sampled[1].final.Omega, rtol=0, atol=1e-4)


def test_lag_effort_agrees_between_wirings_to_first_order_in_the_period(lag_runs):
    """The effort of docs/model.md §6 counts the delivered torque at every step start, read from the
    actuator's state in both wirings: the sampled wiring's effort tends to the continuous
    one's as O(Delta_c), while the command's effort stays apart (the lag delays it)."""
    continuous, sampled = lag_runs
    effort = float(continuous.metrics.effort)
    gaps = np.array([abs(float(sampled[m].metrics.effort) - effort) for m in (4, 2, 1)])
    ratios = gaps[:-1] / gaps[1:]
    assert gaps[-1] < 5e-3 * effort
    np.testing.assert_allclose(ratios, 2.0, rtol=0.25)
    command = float(sampled[1].flight.command_effort)
    assert abs(command - effort) > 20 * gaps[-1]  # the reported effort is the lag's, not the command's


def _hat(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def test_wheels_in_the_loop_match_an_independent_integration():
    """Wheels flown in the sampled loop (truth estimator, momentum compensation) against
    docs/model.md §8.4 integrated by DOP853 over each control period from the recorded tick state,
    with the motor torques the tick held (recomputed from the recorded command)."""
    G = pyramid_axes(4)
    spin, m = np.array([0.16, 0.12, 0.2, 0.16]), 10
    wheels = Wheels(jnp.asarray(G), jnp.asarray(spin), jnp.full(4, 0.25), jnp.full(4, 628.0),
                    jnp.asarray([40.0, -25.0, 15.0, 60.0]))
    r = _fly(m, wheels, T=2.0, record_every=m)
    h = jax.tree.map(np.asarray, r.history)
    J = np.asarray(J_BODY)
    J_B = J - G @ np.diag(spin) @ G.T

    def rhs(u):
        def f(t, y):
            R, Omega, speed = y[:9].reshape(3, 3), y[9:12], y[12:]
            Omega_dot = np.linalg.solve(J_B, -np.cross(Omega, J @ Omega + G @ (spin * speed)) - G @ u)
            return np.concatenate([(R @ _hat(Omega)).ravel(), Omega_dot, u / spin - G.T @ Omega_dot])
        return f

    for j in range(len(h.t) - 1):
        held = wheels.command(jnp.asarray(h.actuator[j]), jnp.asarray(h.tau_cmd[j]), jnp.asarray(h.Omega[j]))
        y0 = np.concatenate([h.R[j].ravel(), h.Omega[j], h.actuator[j]])
        y = solve_ivp(rhs(np.asarray(held.u)), (0.0, m * DT), y0, method="DOP853", rtol=1e-12, atol=1e-13).y[:, -1]
        np.testing.assert_allclose(h.R[j + 1], y[:9].reshape(3, 3), rtol=0, atol=1e-12)
        np.testing.assert_allclose(h.Omega[j + 1], y[9:12], rtol=0, atol=1e-13)
        np.testing.assert_allclose(h.actuator[j + 1], y[12:], rtol=0, atol=1e-10)
        np.testing.assert_allclose(h.tau[j], np.asarray(wheels.delivered(h.actuator[j], held, h.Omega[j])), rtol=1e-13,
                                   atol=1e-15)
    assert np.ptp(h.actuator, axis=0).max() > 1.0  # the wheels did the work


class Count(NamedTuple):
    ticks: jax.Array  # updates so far
    last_t: jax.Array  # s, the time the last update was given
    elapsed: jax.Array  # s, the sum of the periods it was given


def counting_controller() -> Controller:
    """PD torque; a state that only the discrete update moves (its rate, 1e3 per second,
    is what forward Euler would add instead)."""
    pd = sj.geometric_pd()

    def torque(gains, state, feedback, desired, t):
        tau, _ = pd.torque(gains, (), feedback, desired, t)
        return tau, Count(*(jnp.full_like(x, 1e3) for x in state))

    def update(gains, state, feedback, desired, t, period):
        return Count(state.ticks + 1.0, t + 0.0 * state.last_t, state.elapsed + period)

    init = lambda gains: Count(*(jnp.zeros((), jnp.asarray(gains.k_R).dtype) for _ in range(3)))  # noqa: E731
    return from_functions(init, torque, sj.PDGains, update)


def test_a_controller_update_runs_at_the_ticks():
    """Controller.update replaces forward Euler at the sampled wiring's ticks: after T
    the state has counted every tick, holds the last tick's time and the periods' sum; the
    history (one sample per tick) shows one update per tick. Without an update the same law
    advances by Euler (1e3 per second)."""
    m = 5
    counting = counting_controller()
    r = _fly(m, sj.Ideal(), counting, record_every=m)
    ticks = round(T / (m * DT))
    np.testing.assert_array_equal(np.asarray(r.history.controller.ticks), np.arange(ticks))
    np.testing.assert_allclose(float(r.final.controller.ticks), ticks)
    np.testing.assert_allclose(float(r.final.controller.last_t), (ticks - 1) * m * DT, rtol=1e-12)
    np.testing.assert_allclose(float(r.final.controller.elapsed), T, rtol=1e-12)
    euler = _fly(m, sj.Ideal(), dataclasses.replace(counting, update=None), record_every=m)
    np.testing.assert_allclose(float(euler.final.controller.ticks), 1e3 * T, rtol=1e-12)
    np.testing.assert_array_equal(euler.final.Omega, r.final.Omega)  # the torque never read the state
