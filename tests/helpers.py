"""Small scenarios shared by the tests."""

import jax.numpy as jnp
import numpy as np

import so3jax as sj
from so3jax.controllers import Controller, from_functions

J_BODY = np.array([[120.0, 3.0, -2.0], [3.0, 100.0, 4.0], [-2.0, 4.0, 80.0]])  # a physical rigid body


def zero_torque() -> Controller:
    """A third controller in a few lines: no torque at all (free rigid body)."""
    return from_functions(init=lambda gains: (),
                          torque=lambda gains, state, feedback, desired, t: (0.0 * feedback.Omega, ()))


def sinusoidal_rate(t):
    """A smooth reference with Omega_d' != 0 [rad/s]."""
    return 0.05 * jnp.stack([jnp.sin(0.1 * t), jnp.cos(0.07 * t), 0.5 * jnp.sin(0.05 * t + 0.3)])


def custom_scenario(T, dt, *, J=J_BODY, rate_fn=sinusoidal_rate, Omega0=(0.0, 0.0, 0.0), R0=None, noise=False):
    """Constant inertia, a user rate profile (R_d integrated), optionally the paper's disturbance."""
    disturbance = (sj.SinusoidPlusNoise(jnp.asarray(0.1), jnp.asarray(1e-3), jnp.asarray(0.025)) if noise
                   else sj.no_disturbance())
    return sj.Scenario(
        inertia=sj.ConstantInertia(jnp.asarray(J)),
        reference=sj.RateFunction(rate_fn),
        disturbance=disturbance,
        R0=jnp.eye(3) if R0 is None else jnp.asarray(R0),
        Omega0=jnp.asarray(Omega0, dtype=float),
        dt=dt,
        n_steps=sj.steps_for_horizon(T, dt),
    )
