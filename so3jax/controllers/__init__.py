"""Attitude controllers behind one interface (:class:`so3jax.controllers.base.Controller`),
each registered by name in :mod:`so3jax.controllers.registry`, its gains' rules declared on
its gains type (:mod:`so3jax.controllers.gains`).

One module per law: ``pd`` (:func:`geometric_pd`), ``adaptive``
(:func:`adaptive_backstepping`), ``commanded`` (:func:`open_loop`), ``mrp``
(:func:`mrp_feedback`), ``sliding`` (:func:`sliding_mode`); ``scheduled`` wraps any of them
(:class:`Scheduled`: gains per phase or over time); the module names differ from
the functions', so ``from so3jax.controllers import mrp_feedback`` is the function."""

from so3jax.controllers import pd, adaptive, commanded, mrp, sliding  # noqa: F401, I001 (registration order)

from so3jax.controllers.adaptive import (
    PAPER_ADAPTIVE_GAINS,
    AdaptiveBackstepping,
    AdaptiveGains,
    adaptive_backstepping,
    regressor,
    regressor_parameters,
)
from so3jax.controllers.base import (
    Controller,
    Desired,
    Feedback,
    FunctionController,
    TrackingError,
    from_functions,
    tracking_error,
)
from so3jax.controllers.commanded import NoGains, OpenLoop, open_loop
from so3jax.controllers.gains import POSITIVE, Nonnegative, Positive, PositiveDefinite, check_gains, gain_domain
from so3jax.controllers.mrp import DEFAULT_GAINS as DEFAULT_MRP_FEEDBACK_GAINS
from so3jax.controllers.mrp import MRPFeedback, MRPFeedbackGains, mrp_feedback
from so3jax.controllers.pd import PAPER_PD_GAINS, GeometricPD, PDGains, geometric_pd
from so3jax.controllers.registry import ControllerSpec, get, names, register, unregister
from so3jax.controllers.scheduled import Scheduled, check_scheduled_gains, schedule_gains
from so3jax.controllers.sliding import DEFAULT_GAINS as DEFAULT_SLIDING_MODE_GAINS
from so3jax.controllers.sliding import SlidingMode, SlidingModeGains, sliding_mode

__all__ = [
    "DEFAULT_MRP_FEEDBACK_GAINS",
    "DEFAULT_SLIDING_MODE_GAINS",
    "PAPER_ADAPTIVE_GAINS",
    "PAPER_PD_GAINS",
    "POSITIVE",
    "AdaptiveBackstepping",
    "AdaptiveGains",
    "Controller",
    "ControllerSpec",
    "Desired",
    "Feedback",
    "FunctionController",
    "GeometricPD",
    "MRPFeedback",
    "MRPFeedbackGains",
    "NoGains",
    "Nonnegative",
    "OpenLoop",
    "PDGains",
    "Positive",
    "PositiveDefinite",
    "Scheduled",
    "SlidingMode",
    "SlidingModeGains",
    "TrackingError",
    "adaptive_backstepping",
    "check_gains",
    "check_scheduled_gains",
    "from_functions",
    "gain_domain",
    "geometric_pd",
    "get",
    "mrp_feedback",
    "names",
    "open_loop",
    "register",
    "regressor",
    "regressor_parameters",
    "schedule_gains",
    "sliding_mode",
    "tracking_error",
    "unregister",
]
