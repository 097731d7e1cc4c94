"""Attitude controllers behind one interface (see :mod:`so3jax.controllers.base`)."""

from so3jax.controllers.adaptive import (
    PAPER_ADAPTIVE_GAINS,
    AdaptiveGains,
    adaptive_backstepping,
    regressor,
    regressor_parameters,
)
from so3jax.controllers.base import Controller, Desired, Measured, TrackingError, tracking_error
from so3jax.controllers.pd import PAPER_PD_GAINS, PDGains, geometric_pd

__all__ = [
    "PAPER_ADAPTIVE_GAINS",
    "PAPER_PD_GAINS",
    "AdaptiveGains",
    "Controller",
    "Desired",
    "Measured",
    "PDGains",
    "TrackingError",
    "adaptive_backstepping",
    "geometric_pd",
    "regressor",
    "regressor_parameters",
    "tracking_error",
]
