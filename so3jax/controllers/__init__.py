"""Attitude controllers behind one interface (see :mod:`so3jax.controllers.base`), each
registered by name in :mod:`so3jax.controllers.registry`."""

from so3jax.controllers import pd, adaptive, open_loop, mrp_feedback, sliding_mode  # noqa: I001 (registration order)

from so3jax.controllers.adaptive import (
    PAPER_ADAPTIVE_GAINS,
    AdaptiveGains,
    adaptive_backstepping,
    regressor,
    regressor_parameters,
)
from so3jax.controllers.base import Controller, Desired, Measured, TrackingError, tracking_error
from so3jax.controllers.open_loop import NoGains, open_loop
from so3jax.controllers.pd import PAPER_PD_GAINS, PDGains, geometric_pd
from so3jax.controllers.registry import ControllerSpec, get, names, register
from so3jax.controllers.sliding_mode import SlidingModeGains, sliding_mode

__all__ = [
    "PAPER_ADAPTIVE_GAINS",
    "PAPER_PD_GAINS",
    "AdaptiveGains",
    "Controller",
    "ControllerSpec",
    "Desired",
    "Measured",
    "NoGains",
    "PDGains",
    "SlidingModeGains",
    "TrackingError",
    "adaptive_backstepping",
    "geometric_pd",
    "get",
    "names",
    "open_loop",
    "register",
    "regressor",
    "regressor_parameters",
    "sliding_mode",
    "tracking_error",
]
