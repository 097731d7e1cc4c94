"""A mission file (TOML): the paper's quantities (SPEC 4, under the names of ``so3jax
sweep``'s config) plus the flight loop's control period, sensors, estimator, actuator
and controllers (SPEC 8). Parsed into validated plain data, then built into a
:class:`~so3jax.scenario.Scenario`, a :class:`~so3jax.loop.Loop` and controllers.

Without a file, the flight mission of SPEC 8.5 (``missions/flight.toml`` spells it out).
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from so3jax import config as cfg
from so3jax.actuators import Ideal, Saturated, Wheels
from so3jax.controllers import registry
from so3jax.controllers.adaptive import LOG_DERIVATIVES
from so3jax.estimators import MEKF, Raw, Truth
from so3jax.io import to_builtin
from so3jax.loop import Loop, check_loop
from so3jax.scenario import (
    PAPER_J0,
    PAPER_J2,
    Scenario,
    check_inertia,
    check_scenario,
    paper_scenario,
    steps_for_horizon,
)
from so3jax.sensors import Gyro, Sensors, StarTracker

ESTIMATORS = ("truth", "raw", "mekf")
ACTUATORS = ("ideal", "saturated", "wheels")
CONTROL_MODES = ("sampled", "continuous")

# SPEC 8.5: the paper's mission flown with sensors, an MEKF and four wheels in a pyramid.
FLIGHT = {
    "T": 4000.0,
    "dt": 0.01,
    "seed": 0,
    "controllers": ["pd", "adaptive"],
    "record_every": 100,
    "control": {"mode": "sampled", "period": 0.1},
    "inertia": {"J0": {"nominal": [list(r) for r in PAPER_J0]}, "J1": {"scale": 2.0},
                "J2": {"nominal": [list(r) for r in PAPER_J2]}},
    "deployment": {"tau_J": 300.0},
    "orbit": {"n": 0.0011067834463349404},  # orbital_rate(): 500 km circular
    "disturbance": {"amplitude": 0.1, "frequency": 1e-3, "noise_std": 0.025},
    "sensors": {
        "gyro": {"arw": 1e-6, "rrw": 1e-9, "bias0": [1e-4, 1e-4, 1e-4]},
        "star_tracker": {"sigma": 3e-5, "every": 1},
    },
    "estimator": {"kind": "mekf", "sigma_theta0": 1e-3, "sigma_b0": 1e-3, "theta0": [0.0, 0.0, 0.0]},
    "actuator": {
        "kind": "wheels",
        "max_torque": [0.25, 0.25, 0.25],
        "wheels": {
            "axes": [[0.8165408118857462, 0.0, 0.5772877120855479], [0.0, 0.8165408118857462, 0.5772877120855479],
                     [-0.8165408118857462, 0.0, 0.5772877120855479], [0.0, -0.8165408118857462, 0.5772877120855479]],
            "spin_inertia": 0.16,
            "max_torque": 0.25,
            "max_speed": 628.0,
            "initial_speed": 0.0,
            "momentum_compensation": True,
        },
    },
    "controller": {"open_loop": {"torque": [0.0, 0.0, 0.0]}, "adaptive": {"log_derivative": "exact"}},
    "gains": {},
}

_TOP = ("T", "dt", "seed", "controllers", "record_every")
_TABLES = ("control", "inertia", "deployment", "orbit", "disturbance", "sensors", "estimator", "actuator",
           "controller", "gains")
_WHEEL_KEYS = ("axes", "spin_inertia", "max_torque", "max_speed", "initial_speed", "momentum_compensation")


@dataclasses.dataclass(frozen=True)
class Mission:
    """A validated mission: plain numbers and NumPy arrays (nothing compiled)."""

    T: float
    dt: float
    seed: int
    controllers: tuple
    record_every: int
    period_steps: int | None  # None: continuous-time controller (the paper's mode)
    J0: np.ndarray
    J1: np.ndarray
    J2: np.ndarray
    tau_J: float
    n: float
    disturbance: dict  # amplitude, frequency, noise_std
    gyro: dict | None
    star_tracker: dict | None
    estimator: dict
    actuator: dict
    options: dict  # controller name -> factory keyword options
    gains: dict  # controller name -> gains NamedTuple

    @property
    def period(self) -> float | None:
        return None if self.period_steps is None else self.period_steps * self.dt

    def scenario(self, dtype=None) -> Scenario:
        return paper_scenario(self.T, self.dt, tau_J=self.tau_J, n=self.n, J0=self.J0, J1=self.J1, J2=self.J2,
                              disturbance_amplitude=self.disturbance["amplitude"],
                              disturbance_frequency=self.disturbance["frequency"],
                              noise_std=self.disturbance["noise_std"], dtype=dtype)

    def loop(self, dtype=None) -> Loop:
        dtype = jnp.result_type(float) if dtype is None else jnp.dtype(dtype)
        return _build_loop(self, lambda x: jnp.asarray(x, dtype))

    def controller(self, name: str):
        """(Controller, gains) of a controller named in the mission."""
        spec = registry.get(name)
        return spec.factory(**self.options.get(name, {})), self.gains[name]

    def describe(self) -> dict:
        """The mission as JSON-ready plain data (the ``config`` of results)."""
        d = dataclasses.asdict(self)
        d["gains"] = {k: {f: np.asarray(v).tolist() for f, v in g._asdict().items()} for k, g in self.gains.items()}
        return to_builtin(d)


def _build_loop(m: Mission, as_array) -> Loop:
    sensors = Sensors(
        Gyro(as_array(m.gyro["arw"]), as_array(m.gyro["rrw"]), as_array(m.gyro["bias0"])) if m.gyro else None,
        StarTracker(as_array(m.star_tracker["sigma"]), m.star_tracker["every"]) if m.star_tracker else None,
    )
    e = m.estimator
    if e["kind"] == "mekf":
        if not (m.gyro and m.star_tracker):
            raise ValueError("estimator 'mekf' needs [sensors.gyro] and [sensors.star_tracker]")
        estimator = MEKF(as_array(e["sigma_theta0"]), as_array(e["sigma_b0"]), as_array(e["theta0"]),
                         as_array(m.gyro["arw"]), as_array(m.gyro["rrw"]), as_array(m.star_tracker["sigma"]))
    else:
        estimator = Truth() if e["kind"] == "truth" else Raw()
    a = m.actuator
    if a["kind"] == "ideal":
        actuator = Ideal()
    elif a["kind"] == "saturated":
        actuator = Saturated(as_array(a["max_torque"]))
    else:
        w = a["wheels"]
        actuator = Wheels(as_array(np.asarray(w["axes"]).T), as_array(w["spin_inertia"]), as_array(w["max_torque"]),
                          as_array(w["max_speed"]), as_array(w["initial_speed"]), bool(w["momentum_compensation"]))
    return Loop(sensors, estimator, actuator, m.period_steps)


def _merge(base: dict, over: dict) -> dict:
    """base updated by over, table by table (over's keys win)."""
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(base[k], v) if isinstance(v, dict) and isinstance(base.get(k), dict) else v
    return out


def from_dict(d: dict) -> Mission:
    """A Mission from the TOML tables (missing entries: the flight mission's); ValueError on bad input."""
    if not isinstance(d, dict):
        raise ValueError(f"a mission must be a table, got {cfg.short(d)}")  # noqa: TRY004 (bad input)
    unknown = set(d) - set(_TOP) - set(_TABLES)
    if unknown:
        raise ValueError(f"unknown mission key(s): {', '.join(sorted(unknown))}; allowed: {', '.join(_TOP + _TABLES)}")
    for t in _TABLES:
        if t in d and not isinstance(d[t], dict):
            raise ValueError(f"[{t}] must be a table")
    full = _merge(FLIGHT, d)
    # each sensor is its own entry: a table merged with its defaults, or false for none
    sensors_given = cfg.table(d, "sensors", tuple(FLIGHT["sensors"]))
    full["sensors"] = {}
    for name, default in FLIGHT["sensors"].items():
        given = sensors_given.get(name, {})
        if given is False:
            continue
        if not isinstance(given, dict):
            raise ValueError(f"sensors.{name} must be a table, or false for no {name}, got {cfg.short(given)}")
        full["sensors"][name] = _merge(default, given)

    T = cfg.number(full["T"], "T", low=0.0)
    dt = cfg.number(full["dt"], "dt", low=0.0)
    steps_for_horizon(T, dt)
    seed = cfg.number(full["seed"], "seed", low=0, high=2**31 - 1, integer=True)
    record_every = cfg.number(full["record_every"], "record_every", low=1, integer=True)
    controllers = cfg.names(full["controllers"], "controllers", registry.names())

    control = cfg.table(full, "control", ("mode", "period"))
    mode = cfg.choice(control.get("mode", "sampled"), "control.mode", CONTROL_MODES)
    period_steps = None
    if mode == "sampled":
        period = cfg.number(control.get("period"), "control.period [s]", low=0.0)
        ratio = period / dt
        if period <= 0 or abs(ratio - round(ratio)) > 1e-9 * max(ratio, 1.0) or round(ratio) < 1:
            raise ValueError(f"control.period = {period} s is not a whole number (>= 1) of steps dt = {dt} s")
        period_steps = int(round(ratio))
        n_steps = steps_for_horizon(T, dt)
        if period_steps > n_steps:
            raise ValueError(f"control.period = {period} s is longer than the horizon T = {T} s")
        if n_steps % period_steps:
            raise ValueError(f"T (horizon) = {T} s is not a whole number of control periods "
                             f"control.period = {period} s")

    inertia = cfg.table(full, "inertia", ("J0", "J1", "J2"))
    J0 = cfg.array(cfg.table(inertia, "J0", ("nominal",), "inertia.")["nominal"], "inertia.J0.nominal", (3, 3))
    J1_table = cfg.table(inertia, "J1", ("scale", "nominal"), "inertia.")
    J1 = (cfg.array(J1_table["nominal"], "inertia.J1.nominal", (3, 3)) if "nominal" in J1_table
          else cfg.number(J1_table.get("scale", 2.0), "inertia.J1.scale", low=0.0) * J0)
    J2 = cfg.array(cfg.table(inertia, "J2", ("nominal",), "inertia.")["nominal"], "inertia.J2.nominal", (3, 3))
    tau_J = cfg.number(cfg.table(full, "deployment", ("tau_J",))["tau_J"], "deployment.tau_J [s]", low=0.0)
    if tau_J <= 0:
        raise ValueError(f"deployment.tau_J [s] must be positive, got {tau_J}")
    n = cfg.number(cfg.table(full, "orbit", ("n",))["n"], "orbit.n [rad/s]", low=0.0)
    dist = cfg.table(full, "disturbance", ("amplitude", "frequency", "noise_std"))
    disturbance = {
        "amplitude": cfg.number(dist["amplitude"], "disturbance.amplitude [N m]"),
        "frequency": cfg.number(dist["frequency"], "disturbance.frequency [rad/s]"),
        "noise_std": cfg.number(dist["noise_std"], "disturbance.noise_std [N m]", low=0.0),
    }

    sensors = full["sensors"]
    gyro = star = None
    if "gyro" in sensors:
        g = cfg.table(sensors, "gyro", ("arw", "rrw", "bias0"), "sensors.")
        gyro = {"arw": cfg.number(g["arw"], "sensors.gyro.arw [rad/sqrt(s)]", low=0.0),
                "rrw": cfg.number(g["rrw"], "sensors.gyro.rrw [rad/s^(3/2)]", low=0.0),
                "bias0": cfg.array(g["bias0"], "sensors.gyro.bias0 [rad/s]", (3,))}
    if "star_tracker" in sensors:
        s = cfg.table(sensors, "star_tracker", ("sigma", "every"), "sensors.")
        star = {"sigma": cfg.number(s["sigma"], "sensors.star_tracker.sigma [rad]", low=0.0),
                "every": cfg.number(s.get("every", 1), "sensors.star_tracker.every [ticks]", low=1, integer=True)}

    e = cfg.table(full, "estimator", ("kind", "sigma_theta0", "sigma_b0", "theta0"))
    estimator = {"kind": cfg.choice(e["kind"], "estimator.kind", ESTIMATORS),
                 "sigma_theta0": cfg.number(e["sigma_theta0"], "estimator.sigma_theta0 [rad]", low=0.0),
                 "sigma_b0": cfg.number(e["sigma_b0"], "estimator.sigma_b0 [rad/s]", low=0.0),
                 "theta0": cfg.array(e["theta0"], "estimator.theta0 [rad]", (3,))}
    if e["kind"] == "raw" and star is None:
        raise ValueError("estimator 'raw' needs [sensors.star_tracker]")

    a = cfg.table(full, "actuator", ("kind", "max_torque", "wheels"))
    actuator = {"kind": cfg.choice(a["kind"], "actuator.kind", ACTUATORS),
                "max_torque": np.broadcast_to(cfg.array(a["max_torque"], "actuator.max_torque [N m]",
                                                        (3,) if np.ndim(a["max_torque"]) else (), low=0.0), (3,))}
    w = cfg.table(a, "wheels", _WHEEL_KEYS, "actuator.")
    axes = cfg.array(w["axes"], "actuator.wheels.axes (one unit spin axis per wheel)", (None, 3))
    count = axes.shape[0]
    per_wheel = lambda key, low: np.broadcast_to(
        cfg.array(w[key], f"actuator.wheels.{key}", (count,) if np.ndim(w[key]) else (), low=low), (count,)).copy()
    cfg.boolean(w["momentum_compensation"], "actuator.wheels.momentum_compensation")
    actuator["wheels"] = {"axes": axes, "spin_inertia": per_wheel("spin_inertia", 0.0),
                          "max_torque": per_wheel("max_torque", 0.0), "max_speed": per_wheel("max_speed", 0.0),
                          "initial_speed": per_wheel("initial_speed", -math.inf),
                          "momentum_compensation": w["momentum_compensation"]}
    over = np.abs(actuator["wheels"]["initial_speed"]) > actuator["wheels"]["max_speed"]
    if np.any(over):
        raise ValueError("actuator.wheels.initial_speed [rad/s] must not exceed actuator.wheels.max_speed in magnitude "
                         f"(wheel {int(np.argmax(over)) + 1}: {actuator['wheels']['initial_speed'][over][0]:g} against "
                         f"{actuator['wheels']['max_speed'][over][0]:g})")

    options_table = cfg.table(full, "controller", registry.names())
    options = {}
    for name, t in options_table.items():
        if name == "open_loop":
            t = cfg.table(options_table, name, ("torque",), "controller.")
            options[name] = {"torque": tuple(cfg.array(t["torque"], "controller.open_loop.torque [N m]", (3,)).tolist())}
        elif name == "adaptive":
            t = cfg.table(options_table, name, ("log_derivative",), "controller.")
            if "log_derivative" in t:
                cfg.choice(t["log_derivative"], "controller.adaptive.log_derivative", LOG_DERIVATIVES)
            options[name] = dict(t)
        else:
            options[name] = dict(cfg.table(options_table, name, (), "controller."))
    gains_table = cfg.table(full, "gains", registry.names())
    gains = {}
    for name in registry.names():  # every table given is checked, also of a controller not flown
        spec = registry.get(name)
        g = cfg.gains(gains_table.get(name, {}), spec.defaults, spec.gain_shapes(), f"gains.{name}")
        try:
            spec.check(g)
        except (TypeError, ValueError) as err:
            raise ValueError(f"[gains.{name}]: {err}") from None
        if name in controllers:
            gains[name] = g

    mission = Mission(T, dt, seed, controllers, record_every, period_steps, J0, J1, J2, tau_J, n, disturbance, gyro,
                      star, estimator, actuator, options, gains)
    for name in controllers:
        try:
            mission.controller(name)
        except TypeError as err:
            raise ValueError(f"[controller.{name}]: {err}") from None
    inertias = {"J0": J0, "J1": J1, "J2": J2}
    for name, J in inertias.items():
        check_inertia(f"{name} (inertia.{name})", J, warn=False)
    check_scenario(mission.scenario())  # J(t) over every phase; the triangle inequality's warning
    check_loop(_build_loop(mission, np.asarray), inertias)
    return mission


def load(path=None, overrides=()) -> Mission:
    """The mission of a TOML file (or the flight mission of SPEC 8.5), with KEY=VALUE overrides."""
    return from_dict(cfg.load(path, overrides))
