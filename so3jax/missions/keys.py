"""The mission's own keys (docs/model.md §4, §8.5), declared as
:class:`~so3jax.core.params.Param` like the components' parameters: the horizon, step,
seed, controllers and history stride, and the ``[control]``, ``[inertia]``,
``[deployment]``, ``[orbit]``, ``[disturbance]``, ``[initial]``, ``[phases]`` and ``[pointing]`` tables
(the mission's ``[[requirements]]``: :func:`so3jax.sim.pointing.parse_requirements`), and
the entries of ``[[appendages]]`` and ``[[slosh]]`` (:data:`APPENDAGE_KEYS`, :data:`SLOSH_KEYS`,
with ``[hub] mass``: docs/model.md §8.9). Their
defaults are the flight mission's (:data:`so3jax.missions.mission.FLIGHT`); the parser
(:func:`so3jax.missions.mission.from_dict`) reads every value through :func:`parse`, and
the documentation's key table reads the declarations.
"""

from __future__ import annotations

import dataclasses

from so3jax.controllers import registry
from so3jax.core import checks
from so3jax.core.params import Param
from so3jax.dynamics.orbit import MAX_MEAN_MOTION, MIN_ALTITUDE, check_mean_motion
from so3jax.dynamics.paper import PAPER_DEPLOY_TIME, PAPER_DOCK_TIME, PAPER_J2, PHASE_NAMES

CONTROL_MODES = ("sampled", "continuous")
# The flight mission's inertia at capture [kg m^2]: the paper's J0 with J_zz = 900, a rigid
# body's (the paper's J_zz = 1000 exceeds J_xx + J_yy = 975, the triangle inequality).
BODY_J0 = ((625.0, 5.5, 3.0), (5.5, 350.0, 4.0), (3.0, 4.0, 900.0))


@dataclasses.dataclass(frozen=True)
class ControllerNames(Param):
    """A list of registered controllers' names (the registry is read when a value is parsed)."""

    def parse(self, value, where: str):
        return checks.names(value, where, registry.names())

    def domain(self) -> str:
        return "names among " + ", ".join(f"`{name}`" for name in registry.names())


@dataclasses.dataclass(frozen=True)
class Names(Param):
    """A list of distinct, non-empty names."""

    def parse(self, value, where: str):
        if not isinstance(value, (list, tuple)) or not value or not all(isinstance(v, str) and v for v in value):
            raise ValueError(f"{where} must be a list of non-empty names, got {checks.short(value)}")
        if len(set(value)) != len(value):
            raise ValueError(f"{where}: each name once, got {checks.short(list(value))}")
        return tuple(value)

    def domain(self) -> str:
        return "distinct names"


@dataclasses.dataclass(frozen=True)
class MeanMotion(Param):
    """The mean motion of a circular orbit: 0 (no orbital motion) or that of an orbit at
    least MIN_ALTITUDE above the Earth's equatorial radius (so3jax.dynamics.orbit)."""

    def parse(self, value, where: str):
        n = checks.number(value, f"{where} [{self.unit}]", low=self.low)
        return check_mean_motion(n, where)

    def domain(self) -> str:
        return (f"number, in [0, {MAX_MEAN_MOTION:.6g}]: an orbit at least {MIN_ALTITUDE / 1e3:g} km above the "
                "Earth's equatorial radius")


def matrix(J) -> list:
    """A 3x3 matrix as TOML data (a list of rows)."""
    return [list(row) for row in J]


KEYS = (
    Param("T", 4000.0, "s", doc="horizon: a whole number of steps dt (and of control periods)"),
    Param("dt", 0.01, "s", doc="plant integration step (RK4 on SO(3))"),
    Param("seed", 0, low=0, high=2**31 - 1, integer=True, doc="disturbance and sensor-noise seed"),
    ControllerNames("controllers", ["pd", "adaptive"], shapes=((None,),), doc="the controllers flown, in turn"),
    Param("record_every", 100, low=1, integer=True,
          doc="trajectory sampling [steps], rounded up to whole control periods"),
    Param("control.mode", "sampled", choices=CONTROL_MODES,
          doc="sampled: the controller ticks every control.period through the sensors, estimator and actuator; "
              "continuous: the paper's idealized loop (the true state in every RK4 stage)"),
    Param("control.period", 0.1, "s", low=0.0, doc="control period (sampled mode), a whole number of steps dt"),
    Param("inertia.J", None, "kg m^2", shapes=((3, 3),),
          doc="a constant inertia J(t) = J throughout (excludes inertia.J0, J1, J2)"),
    Param("inertia.J0.nominal", matrix(BODY_J0), "kg m^2", shapes=((3, 3),),
          doc="inertia at capture (the paper's J0 with J_zz = 900, a rigid body's)"),
    Param("inertia.J1.scale", 2.0, low=0.0, doc="deployed inertia J1 = scale J0"),
    Param("inertia.J1.nominal", None, "kg m^2", shapes=((3, 3),), doc="deployed inertia J1 (instead of a scale of J0)"),
    Param("inertia.J2.nominal", matrix(PAPER_J2), "kg m^2", shapes=((3, 3),), doc="inertia once docked"),
    Param("deployment.tau_J", 300.0, "s", doc="deployment time constant (positive)"),
    MeanMotion("orbit.n", 0.0011067834463349404, "rad/s", low=0.0, high=MAX_MEAN_MOTION,
               doc="orbital rate (the default: orbital_rate(), a 500 km circular orbit); the radius follows from it; "
                   "0: no orbital motion (refused with an [environment] or a momentum manager that reads the "
                   "geomagnetic field)"),
    Param("orbit.inclination", 0.0, "deg", low=0.0, high=180.0, doc="the orbit's inclination"),
    Param("orbit.raan", 0.0, "deg", doc="right ascension of the ascending node"),
    Param("orbit.argument_of_latitude", 0.0, "deg", doc="the argument of latitude at t = 0"),
    Param("orbit.earth_angle", 0.0, "deg", doc="the Greenwich sidereal angle at t = 0 (the geomagnetic field's)"),
    Param("disturbance.amplitude", 0.1, "N m", doc="d = amplitude sin(frequency t) [1, 1, 1] + noise_std eta"),
    Param("disturbance.frequency", 1e-3, "rad/s", doc="the sinusoid's frequency"),
    Param("disturbance.noise_std", 0.025, "N m", low=0.0, doc="the white noise's standard deviation"),
    Param("initial.attitude", [0.0, 0.0, 0.0], "rad", shapes=((3,),),
          doc="R(0) = exp(hat(attitude)), a rotation vector (R_d(0) = I: the initial attitude error)"),
    Param("initial.quaternion", None, shapes=((4,),),
          doc="R(0) as a unit quaternion [w, x, y, z] (instead of attitude)"),
    Param("initial.rate", [0.0, 0.0, 0.0], "rad/s", shapes=((3,),), doc="Omega(0), body frame"),
    Names("phases.names", list(PHASE_NAMES), shapes=((None,),),
          doc="the mission's phases, named in every per-phase metric, table and figure"),
    Param("phases.start", [0.0, PAPER_DEPLOY_TIME, PAPER_DOCK_TIME], "s", shapes=((None,),), low=0.0,
          doc="each phase's start time: 0 first, increasing, whole steps dt (one at or after T is not reached); "
              "the paper's inertia profile and reference switch at the paper's"),
    Param("hub.mass", None, "kg", low=0.0, low_excluded=True,
          doc="the hub's mass, with [[appendages]] or [[slosh]] (needed then): the rigid body whose inertia about "
              "its centre of mass, the body origin B, is the mission's J(t) ([inertia]), wheels included"),
    Param("pointing.window", 60.0, "s", low=0.0,
          doc="window of the relative errors (RPE, RKE) in fly's pointing report (ECSS-E-ST-60-10C)"),
    Param("pointing.levels", [0.95, 0.9973], shapes=((None,),), low=0.0, high=1.0,
          doc="confidence levels P_C of fly's pointing report, each in (0, 1)"),
)

KEY = {p.name: p for p in KEYS}

# the labels of the values in error messages, where they say more than the key
LABELS = {"T": "T (horizon)", "dt": "dt (step)", "initial.attitude": "initial.attitude (rotation vector of R(0))",
          "initial.rate": "initial.rate (Omega(0))", "initial.quaternion": "initial.quaternion [w, x, y, z]"}

TOP = tuple(p.name for p in KEYS if "." not in p.name)  # the keys outside tables
TABLES = tuple(dict.fromkeys(p.name.split(".")[0] for p in KEYS if "." in p.name))  # the tables declared here


def parse(name: str, value):
    """The value of the declared key ``name`` checked against its declaration; one-line
    ValueError naming the key otherwise."""
    return KEY[name].parse(value, LABELS.get(name, name))


def allowed(table: str) -> tuple:
    """The keys (or subtables) declared in ``table`` (dotted), in declaration order."""
    prefix = table + "."
    return tuple(dict.fromkeys(p.name[len(prefix):].split(".")[0] for p in KEYS if p.name.startswith(prefix)))


def defaults() -> dict:
    """The declared defaults as nested tables (None defaults left out)."""
    tree = {}
    for p in KEYS:
        if p.default is None:
            continue
        *tables, last = p.name.split(".")
        node = tree
        for t in tables:
            node = node.setdefault(t, {})
        node[last] = p.default
    return tree


# docs/model.md §8.9: a [[appendages]] entry, a hinged rigid panel (so3jax.dynamics.flexible.HingedPanel)
APPENDAGE_KEYS = (
    Param("mass", None, "kg", low=0.0, low_excluded=True, doc="the panel's mass"),
    Param("inertia", None, "kg m^2", shapes=((3, 3),),
          doc="the panel's inertia about its centre of mass, in the panel frame (s1 = -direction, s2 = axis, "
              "s3 = s1 x s2 at theta = 0)"),
    Param("hinge", None, "m", shapes=((3,),), doc="the hinge point from the body origin B, body frame"),
    Param("axis", None, shapes=((3,),), doc="the hinge axis (unit, body frame): theta turns the panel about it"),
    Param("direction", None, shapes=((3,),),
          doc="unit vector from the hinge towards the panel's centre of mass at theta = 0, perpendicular to axis"),
    Param("distance", None, "m", low=0.0, doc="the panel's centre of mass from the hinge (along direction)"),
    Param("k", None, "N m/rad", shapes=((), (None,)), low=0.0,
          doc="the hinge's torsional spring (about theta = 0): one value, or one per phase ([phases])"),
    Param("c", 0.0, "N m s/rad", shapes=((), (None,)), low=0.0,
          doc="the hinge's damper: one value, or one per phase ([phases])"),
    Param("angle", 0.0, "rad", doc="the hinge angle theta(0) (its rate 0)"),
)

# docs/model.md §8.9: a [[slosh]] entry, a spring-mass-damper particle (so3jax.dynamics.flexible.SloshParticle)
SLOSH_KEYS = (
    Param("mass", None, "kg", low=0.0, low_excluded=True, doc="the particle's mass"),
    Param("location", None, "m", shapes=((3,),), doc="its rest location from the body origin B, body frame"),
    Param("direction", None, shapes=((3,),), doc="the unit direction it moves along, body frame"),
    Param("k", None, "N/m", shapes=((), (None,)), low=0.0,
          doc="the spring (about rest): one value, or one per phase ([phases])"),
    Param("c", 0.0, "N s/m", shapes=((), (None,)), low=0.0, doc="the damper: one value, or one per phase ([phases])"),
    Param("displacement", 0.0, "m", doc="its displacement rho(0) along direction (its rate 0)"),
)
