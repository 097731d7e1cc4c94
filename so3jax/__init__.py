"""so3jax: differentiable spacecraft attitude simulation on SO(3) in JAX."""

from importlib import metadata as _metadata

try:
    __version__ = _metadata.version("so3jax")
except _metadata.PackageNotFoundError:  # a source tree that is not installed
    __version__ = "0+unknown"

from so3jax.components.actuators import Ideal, Saturated, Wheels, pyramid_axes
from so3jax.components.base import Actuator, Estimate, Estimator, Measurements, Sensor, StoredMomentum
from so3jax.components.estimators import MEKF, Raw, Truth
from so3jax.components.registry import BuildContext, ComponentSpec
from so3jax.components.registry import get as get_component
from so3jax.components.registry import names as component_names
from so3jax.components.registry import register as register_component
from so3jax.components.registry import unregister as unregister_component
from so3jax.components.sensors import Gyro, Sensors, StarTracker
from so3jax.controllers import (
    DEFAULT_MRP_FEEDBACK_GAINS,
    DEFAULT_SLIDING_MODE_GAINS,
    PAPER_ADAPTIVE_GAINS,
    PAPER_PD_GAINS,
    AdaptiveBackstepping,
    AdaptiveGains,
    Controller,
    ControllerSpec,
    Desired,
    Feedback,
    GeometricPD,
    MRPFeedback,
    MRPFeedbackGains,
    NoGains,
    OpenLoop,
    PDGains,
    Scheduled,
    SlidingMode,
    SlidingModeGains,
    adaptive_backstepping,
    from_functions,
    geometric_pd,
    mrp_feedback,
    open_loop,
    sliding_mode,
)
from so3jax.controllers.registry import get as get_controller
from so3jax.controllers.registry import names as controller_names
from so3jax.controllers.registry import register as register_controller
from so3jax.controllers.registry import unregister as unregister_controller
from so3jax.core import so3
from so3jax.core.params import Param
from so3jax.core.pytree import pytree_dataclass, static_field
from so3jax.dynamics.disturbance import SinusoidPlusNoise, no_disturbance
from so3jax.dynamics.inertia import InertiaWarning
from so3jax.dynamics.plant import ConstantInertia, InertiaFunction, PaperInertia
from so3jax.dynamics.reference import PiecewiseConstantRate, RateFunction, piecewise_constant_rate
from so3jax.dynamics.scenario import Scenario, paper_scenario, steps_for_horizon
from so3jax.missions.mission import Mission
from so3jax.missions.mission import load as load_mission
from so3jax.parallel.xla_flags import configure_xla
from so3jax.sim.loop import PAPER_LOOP, Loop
from so3jax.sim.metrics import Metrics
from so3jax.sim.rollout import History, Result, State, rollout, rollout_batch, simulate

__all__ = [
    "DEFAULT_MRP_FEEDBACK_GAINS",
    "DEFAULT_SLIDING_MODE_GAINS",
    "MEKF",
    "PAPER_ADAPTIVE_GAINS",
    "PAPER_LOOP",
    "PAPER_PD_GAINS",
    "Actuator",
    "AdaptiveBackstepping",
    "AdaptiveGains",
    "BuildContext",
    "ComponentSpec",
    "ConstantInertia",
    "Controller",
    "ControllerSpec",
    "Desired",
    "Estimate",
    "Estimator",
    "Feedback",
    "GeometricPD",
    "Gyro",
    "History",
    "Ideal",
    "InertiaFunction",
    "InertiaWarning",
    "Loop",
    "MRPFeedback",
    "MRPFeedbackGains",
    "Measurements",
    "Metrics",
    "Mission",
    "NoGains",
    "OpenLoop",
    "PDGains",
    "Scheduled",
    "PaperInertia",
    "Param",
    "PiecewiseConstantRate",
    "RateFunction",
    "Raw",
    "Result",
    "Saturated",
    "Scenario",
    "Sensor",
    "Sensors",
    "SinusoidPlusNoise",
    "SlidingMode",
    "SlidingModeGains",
    "StarTracker",
    "State",
    "StoredMomentum",
    "Truth",
    "Wheels",
    "__version__",
    "adaptive_backstepping",
    "component_names",
    "configure_xla",
    "controller_names",
    "from_functions",
    "geometric_pd",
    "get_component",
    "get_controller",
    "load_mission",
    "mrp_feedback",
    "no_disturbance",
    "open_loop",
    "paper_scenario",
    "piecewise_constant_rate",
    "pyramid_axes",
    "pytree_dataclass",
    "register_component",
    "register_controller",
    "rollout",
    "rollout_batch",
    "simulate",
    "sliding_mode",
    "so3",
    "static_field",
    "steps_for_horizon",
    "unregister_component",
    "unregister_controller",
]
