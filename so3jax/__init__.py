"""so3jax: differentiable spacecraft attitude simulation on SO(3) in JAX."""

from so3jax.core import so3
from so3jax.parallel.xla_flags import configure_xla
from so3jax.controllers import (
    PAPER_ADAPTIVE_GAINS,
    PAPER_PD_GAINS,
    AdaptiveGains,
    Controller,
    Desired,
    Measured,
    PDGains,
    adaptive_backstepping,
    geometric_pd,
)
from so3jax.dynamics.disturbance import SinusoidPlusNoise, no_disturbance
from so3jax.sim.metrics import Metrics
from so3jax.dynamics.plant import ConstantInertia, InertiaFunction, PaperInertia
from so3jax.dynamics.reference import PiecewiseConstantRate, RateFunction, piecewise_constant_rate
from so3jax.components.actuators import Ideal, Saturated, Wheels, pyramid_axes
from so3jax.components.estimators import MEKF, Raw, Truth
from so3jax.sim.loop import PAPER_LOOP, Loop
from so3jax.missions.mission import Mission
from so3jax.missions.mission import load as load_mission
from so3jax.components.sensors import Gyro, Sensors, StarTracker
from so3jax.sim.rollout import History, Result, State, rollout, rollout_batch, simulate
from so3jax.dynamics.scenario import InertiaWarning, Scenario, paper_scenario, steps_for_horizon

__all__ = [
    "MEKF",
    "PAPER_ADAPTIVE_GAINS",
    "PAPER_LOOP",
    "PAPER_PD_GAINS",
    "AdaptiveGains",
    "ConstantInertia",
    "Controller",
    "Desired",
    "Gyro",
    "History",
    "Ideal",
    "InertiaFunction",
    "InertiaWarning",
    "Loop",
    "Measured",
    "Metrics",
    "Mission",
    "PDGains",
    "PaperInertia",
    "PiecewiseConstantRate",
    "RateFunction",
    "Raw",
    "Result",
    "Saturated",
    "Scenario",
    "Sensors",
    "SinusoidPlusNoise",
    "StarTracker",
    "State",
    "Truth",
    "Wheels",
    "adaptive_backstepping",
    "configure_xla",
    "geometric_pd",
    "load_mission",
    "no_disturbance",
    "paper_scenario",
    "piecewise_constant_rate",
    "pyramid_axes",
    "rollout",
    "rollout_batch",
    "simulate",
    "so3",
    "steps_for_horizon",
]
