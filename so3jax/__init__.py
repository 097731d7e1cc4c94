"""so3jax: differentiable spacecraft attitude simulation on SO(3) in JAX."""

from importlib import import_module as _import_module
from importlib import metadata as _metadata
from typing import TYPE_CHECKING

try:
    __version__ = _metadata.version("so3jax")
except _metadata.PackageNotFoundError:  # a source tree that is not installed
    __version__ = "0+unknown"

from so3jax.components.actuators import Ideal, Saturated, Wheels, pyramid_axes
from so3jax.components.base import (
    Actuator,
    Estimate,
    Estimator,
    Filter,
    Measurements,
    MomentumManager,
    Sensor,
    StoredMomentum,
)
from so3jax.components.environment import Aerodynamic, GravityGradient, ResidualDipole, SolarPressure
from so3jax.components.estimators import MEKF, Raw, Truth
from so3jax.components.filters import SecondOrder
from so3jax.components.momentum import Magnetorquers, MomentumWarning, Thrusters
from so3jax.components.navigation import NavAttitude, NavRate
from so3jax.components.registry import BuildContext, ComponentSpec
from so3jax.components.registry import get as get_component
from so3jax.components.registry import names as component_names
from so3jax.components.registry import register as register_component
from so3jax.components.registry import unregister as unregister_component
from so3jax.components.sensors import Gyro, IntegratingGyro, Sensors, StarTracker
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
    tracking_error,
)
from so3jax.controllers.registry import get as get_controller
from so3jax.controllers.registry import names as controller_names
from so3jax.controllers.registry import register as register_controller
from so3jax.controllers.registry import unregister as unregister_controller
from so3jax.core import so3
from so3jax.core.params import Param
from so3jax.core.pytree import pytree_dataclass, static_field
from so3jax.dynamics.attitude_profiles import EigenaxisSlews, Tabulated
from so3jax.dynamics.disturbance import SinusoidPlusNoise, no_disturbance
from so3jax.dynamics.environment import CircularOrbit, circular_orbit
from so3jax.dynamics.inertia import InertiaWarning
from so3jax.dynamics.inertia_timelines import InertiaEvents, InertiaTable
from so3jax.dynamics.orbit import orbital_rate
from so3jax.dynamics.paper import PAPER_J0, PAPER_J2
from so3jax.dynamics.plant import ConstantInertia, InertiaFunction, PaperInertia
from so3jax.dynamics.reference import PiecewiseConstantRate, RateFunction, piecewise_constant_rate
from so3jax.dynamics.scenario import Scenario, paper_scenario, steps_for_horizon
from so3jax.dynamics.space import Environment, EnvironmentTorque
from so3jax.missions.distributions import Fixed, LogNormal, Normal, Uniform
from so3jax.missions.draw import Dispersions, InertiaDispersion, Samples, draw_samples
from so3jax.missions.mission import Mission
from so3jax.missions.mission import load as load_mission
from so3jax.parallel import devices
from so3jax.parallel.xla_flags import configure_xla
from so3jax.sim.gradients import checkpoint_steps, value_and_grad
from so3jax.sim.loop import PAPER_LOOP, Loop
from so3jax.sim.metrics import Metrics
from so3jax.sim.pointing import Evaluation, Requirement, Signals, Statistic
from so3jax.sim.rollout import History, Result, State, rollout, rollout_batch, simulate
from so3jax.viz.styles import register as register_style

# imported at first use, as ``import so3jax`` leaves SciPy (the margins, the identification) unloaded
_LAZY = {
    "so3jax.jobs.api": ("fly", "identify", "margins", "pointing_errors", "sweep", "tune"),
    "so3jax.jobs.fly": ("Flight",),
    "so3jax.jobs.identify.telemetry": ("Telemetry",),
    "so3jax.jobs.margins": ("Margins",),
    "so3jax.sim.margins": ("AxisMargins", "Disk", "DiskMargins", "Linearization", "LoopMargins", "disk_margin",
                           "linearize", "loop_at_a_time", "nominal_state", "tick_index"),
}
_LAZY_MODULE = {name: module for module, names in _LAZY.items() for name in names}

if TYPE_CHECKING:
    from so3jax.jobs.api import fly, identify, margins, pointing_errors, sweep, tune
    from so3jax.jobs.fly import Flight
    from so3jax.jobs.identify.telemetry import Telemetry
    from so3jax.jobs.margins import Margins
    from so3jax.sim.margins import (
        AxisMargins,
        Disk,
        DiskMargins,
        Linearization,
        LoopMargins,
        disk_margin,
        linearize,
        loop_at_a_time,
        nominal_state,
        tick_index,
    )


def __getattr__(name: str):
    if name in _LAZY_MODULE:
        value = getattr(_import_module(_LAZY_MODULE[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'so3jax' has no attribute {name!r}")


def __dir__() -> list:
    return sorted(set(globals()) | set(_LAZY_MODULE))


__all__ = [
    "DEFAULT_MRP_FEEDBACK_GAINS",
    "DEFAULT_SLIDING_MODE_GAINS",
    "MEKF",
    "PAPER_ADAPTIVE_GAINS",
    "PAPER_J0",
    "PAPER_J2",
    "PAPER_LOOP",
    "PAPER_PD_GAINS",
    "Actuator",
    "AdaptiveBackstepping",
    "AdaptiveGains",
    "Aerodynamic",
    "AxisMargins",
    "BuildContext",
    "CircularOrbit",
    "ComponentSpec",
    "ConstantInertia",
    "Controller",
    "ControllerSpec",
    "Desired",
    "Disk",
    "DiskMargins",
    "Dispersions",
    "EigenaxisSlews",
    "Environment",
    "EnvironmentTorque",
    "Estimate",
    "Estimator",
    "Evaluation",
    "Feedback",
    "Filter",
    "Fixed",
    "Flight",
    "GeometricPD",
    "GravityGradient",
    "Gyro",
    "History",
    "Ideal",
    "InertiaDispersion",
    "InertiaEvents",
    "InertiaFunction",
    "InertiaTable",
    "InertiaWarning",
    "IntegratingGyro",
    "Linearization",
    "LogNormal",
    "Loop",
    "LoopMargins",
    "MRPFeedback",
    "MRPFeedbackGains",
    "Magnetorquers",
    "Margins",
    "Measurements",
    "Metrics",
    "Mission",
    "MomentumManager",
    "MomentumWarning",
    "NavAttitude",
    "NavRate",
    "NoGains",
    "Normal",
    "OpenLoop",
    "PDGains",
    "PaperInertia",
    "Param",
    "PiecewiseConstantRate",
    "RateFunction",
    "Raw",
    "Requirement",
    "ResidualDipole",
    "Result",
    "Samples",
    "Saturated",
    "Scenario",
    "Scheduled",
    "SecondOrder",
    "Sensor",
    "Sensors",
    "Signals",
    "SinusoidPlusNoise",
    "SlidingMode",
    "SlidingModeGains",
    "SolarPressure",
    "StarTracker",
    "State",
    "Statistic",
    "StoredMomentum",
    "Tabulated",
    "Telemetry",
    "Thrusters",
    "Truth",
    "Uniform",
    "Wheels",
    "__version__",
    "adaptive_backstepping",
    "checkpoint_steps",
    "circular_orbit",
    "component_names",
    "configure_xla",
    "controller_names",
    "devices",
    "disk_margin",
    "draw_samples",
    "fly",
    "from_functions",
    "geometric_pd",
    "get_component",
    "get_controller",
    "identify",
    "linearize",
    "load_mission",
    "loop_at_a_time",
    "margins",
    "mrp_feedback",
    "no_disturbance",
    "nominal_state",
    "open_loop",
    "orbital_rate",
    "paper_scenario",
    "piecewise_constant_rate",
    "pointing_errors",
    "pyramid_axes",
    "pytree_dataclass",
    "register_component",
    "register_controller",
    "register_style",
    "rollout",
    "rollout_batch",
    "simulate",
    "sliding_mode",
    "so3",
    "static_field",
    "steps_for_horizon",
    "sweep",
    "tick_index",
    "tracking_error",
    "tune",
    "unregister_component",
    "unregister_controller",
    "value_and_grad",
]
