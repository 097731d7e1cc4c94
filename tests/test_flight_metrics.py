"""Flight metrics over a horizon that is not a whole number of control periods: what a
tick holds over its period (time at a limit, efforts) counts only the part of the period
inside the horizon."""

import jax.numpy as jnp
import numpy as np
import pytest

import so3jax as sj

DT = 0.05


@pytest.mark.parametrize("n_steps, period_steps", [(5, 2), (1, 4), (4, 2)])
def test_time_at_a_limit_counts_only_the_horizon(n_steps, period_steps):
    """A torque limit (1e-9 N m) that binds at every tick: time at the limit = T exactly,
    also when the last period overruns the horizon, or the period is longer than it."""
    scenario = sj.paper_scenario(T=n_steps * DT, dt=DT)
    loop = sj.Loop(actuator=sj.Saturated(jnp.asarray(1e-9)), period_steps=period_steps)
    r = sj.simulate(scenario, sj.geometric_pd(), sj.PAPER_PD_GAINS, seed=0, loop=loop, record_every=period_steps)
    assert scenario.n_steps == n_steps
    np.testing.assert_allclose(float(r.flight.time_at_torque_limit), n_steps * DT, rtol=1e-12)
    # the held torque is at the limit throughout: actuator effort = |u|^2 T for |u| = sqrt(3) 1e-9
    np.testing.assert_allclose(float(r.flight.actuator_effort), 3e-18 * n_steps * DT, rtol=1e-9)
