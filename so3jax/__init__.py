"""so3jax: differentiable spacecraft attitude simulation on SO(3) in JAX."""

from so3jax import so3
from so3jax._xla_flags import configure_xla
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
from so3jax.disturbance import SinusoidPlusNoise, no_disturbance
from so3jax.metrics import Metrics
from so3jax.plant import ConstantInertia, InertiaFunction, PaperInertia
from so3jax.reference import PiecewiseConstantRate, RateFunction, piecewise_constant_rate
from so3jax.loop import PAPER_LOOP, Loop
from so3jax.rollout import FlightHistory, History, Result, State, rollout, rollout_batch, simulate
from so3jax.scenario import InertiaWarning, Scenario, paper_scenario, steps_for_horizon

__all__ = [
    "PAPER_ADAPTIVE_GAINS",
    "PAPER_LOOP",
    "PAPER_PD_GAINS",
    "AdaptiveGains",
    "ConstantInertia",
    "Controller",
    "FlightHistory",
    "Desired",
    "History",
    "InertiaFunction",
    "InertiaWarning",
    "Loop",
    "Measured",
    "Metrics",
    "PDGains",
    "PaperInertia",
    "PiecewiseConstantRate",
    "RateFunction",
    "Result",
    "Scenario",
    "SinusoidPlusNoise",
    "State",
    "adaptive_backstepping",
    "configure_xla",
    "geometric_pd",
    "no_disturbance",
    "paper_scenario",
    "piecewise_constant_rate",
    "rollout",
    "rollout_batch",
    "simulate",
    "so3",
    "steps_for_horizon",
]
