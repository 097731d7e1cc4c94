"""The recorded history ends with the final state: its last record is at t = T and holds the
rollout's final state, in the continuous and the sampled wiring, whether or not the
record stride divides the step count; fly's trajectory arrays end there too."""

import jax
import jax.numpy as jnp
import numpy as np

import so3jax as sj
from so3jax.components.actuators import Wheels, pyramid_axes
from so3jax.components.estimators import MEKF
from so3jax.components.sensors import Gyro, Sensors, StarTracker
from so3jax.sim.loop import Loop
from tests.helpers import custom_scenario

DT = 0.01
SCENARIO = custom_scenario(2.0, DT, noise=True, Omega0=(0.01, 0.0, -0.01))  # N = 200 steps
LONGER = custom_scenario(2.5, DT, noise=True, Omega0=(0.01, 0.0, -0.01))  # the same flight, 0.5 s more


def _flight_loop(m: int) -> Loop:
    """Gyro, star tracker, MEKF and four wheels, a tick every m steps."""
    gyro = Gyro(jnp.asarray(1e-6), jnp.asarray(1e-9), jnp.full(3, 1e-4))
    star = StarTracker(jnp.asarray(3e-5), 1)
    mekf = MEKF(jnp.asarray(1e-3), jnp.asarray(1e-3), jnp.zeros(3), gyro.arw, gyro.rrw, star.sigma)
    wheels = Wheels(jnp.asarray(pyramid_axes(4), float), jnp.full(4, 0.16), jnp.full(4, 0.6), jnp.full(4, 628.0),
                    jnp.zeros(4))
    return Loop(period_steps=m, sensors=Sensors(gyro, star), estimator=mekf, actuator=wheels)


def _run(scenario, loop, record_every, seed=3):
    result = sj.simulate(scenario, sj.geometric_pd(), sj.PAPER_PD_GAINS, seed, loop=loop, record_every=record_every)
    return jax.tree.map(np.asarray, result)


def _assert_last_is_final(result, T):
    """The last record: t = T [s], the true state the rollout ends in."""
    h, final = result.history, result.final
    assert h.t[-1] == np.float64(round(T / DT)) * DT
    np.testing.assert_array_equal(h.R[-1], final.R)
    np.testing.assert_array_equal(h.Omega[-1], final.Omega)
    for got, want in zip(jax.tree.leaves(h.controller), jax.tree.leaves(final.controller)):
        np.testing.assert_array_equal(got[-1], want)
    if h.actuator is not None:
        np.testing.assert_array_equal(h.actuator[-1], final.actuator)


def _assert_same_records(a, b, at):
    """History a equals history b's records at indices ``at``, field by field."""
    for name, x, y in zip(a._fields, a, b):
        for u, v in zip(jax.tree.leaves(x), jax.tree.leaves(y)):
            np.testing.assert_allclose(u, v[at], rtol=1e-12, atol=1e-15, err_msg=name)


def test_continuous_history_ends_with_the_final_state():
    """Records every 50 steps: t = 0, 0.5, ..., 2 s, each the state a record every step holds
    there, the last the final state; the record at T evaluates the law as a block
    start would."""
    every_50, every_step = (_run(SCENARIO, sj.PAPER_LOOP, r) for r in (50, 1))
    np.testing.assert_allclose(every_50.history.t, [0.0, 0.5, 1.0, 1.5, 2.0], rtol=0, atol=1e-12)
    assert every_step.history.t.shape == (201,)
    for r in (every_50, every_step):
        _assert_last_is_final(r, 2.0)
    _assert_same_records(every_50.history, every_step.history, np.arange(0, 201, 50))


def test_continuous_history_ends_at_T_when_the_stride_does_not_divide_N():
    """Records every 30 steps of 200: steps 0, 30, ..., 180, then 200."""
    r = _run(SCENARIO, sj.PAPER_LOOP, 30)
    np.testing.assert_allclose(r.history.t, np.r_[np.arange(0, 200, 30), 200] * DT, rtol=0, atol=1e-12)
    _assert_last_is_final(r, 2.0)


def test_sampled_history_ends_with_a_tick_at_T():
    """Records every 5 ticks of 5 steps: the last at T holds the final state, and the tick
    there is the one a longer flight takes at T (estimate, covariance, command, torque)."""
    loop = _flight_loop(5)
    r, longer = _run(SCENARIO, loop, 25), _run(LONGER, loop, 25)
    np.testing.assert_allclose(r.history.t, np.arange(0, 201, 25) * DT, rtol=0, atol=1e-12)
    _assert_last_is_final(r, 2.0)
    _assert_same_records(r.history, longer.history, np.arange(9))


def test_sampled_history_ends_at_T_between_ticks():
    """A tick every 7 steps of 200 (blocks of 35): T is no tick, so its record holds the
    final state, the held input's torque, and NaN for what only a tick computes."""
    loop = _flight_loop(7)
    r = _run(SCENARIO, loop, 30)
    h = r.history
    np.testing.assert_allclose(h.t, np.r_[np.arange(0, 200, 35), 200] * DT, rtol=0, atol=1e-12)
    _assert_last_is_final(r, 2.0)
    for name in ("R_hat", "Omega_hat", "bias", "bias_hat", "std", "covariance", "tau_cmd"):
        assert np.all(np.isnan(getattr(h, name)[-1])) and np.all(np.isfinite(getattr(h, name)[:-1])), name
    final = jax.tree.map(jnp.asarray, r.final)
    held = loop.actuator.delivered(final.actuator, final.held, final.Omega)
    np.testing.assert_array_equal(h.tau[-1], np.asarray(held))


def test_batched_history_ends_with_each_final_state():
    r = jax.tree.map(np.asarray, sj.simulate(SCENARIO, sj.geometric_pd(), sj.PAPER_PD_GAINS, jnp.asarray([3, 4]),
                                             loop=_flight_loop(5), record_every=25))
    assert r.history.t.shape == (2, 9)
    for i in range(2):
        _assert_last_is_final(jax.tree.map(lambda x, i=i: x[i], r), 2.0)


def test_fly_trajectory_ends_at_T():
    """trajectory.npz's arrays: the last t is T, with the final attitude and wheel speeds."""
    from so3jax.jobs import fly
    from so3jax.missions import mission as missions

    m = missions.load(None, ["T=1.0", "controllers=pd", "record_every=30"])
    result = fly.fly(m)[0]["pd"]
    arrays = fly.trajectory_arrays({"pd": result})
    assert arrays["pd/t"][-1] == np.float64(m.scenario().n_steps) * m.dt
    np.testing.assert_array_equal(arrays["pd/R"][-1], result.final.R)
    np.testing.assert_array_equal(arrays["pd/wheel_speed"][-1], result.final.actuator)
