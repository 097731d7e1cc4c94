"""A mission: the scenario (inertia profile, reference, disturbance, horizon, initial
state), the loop (sensors, estimator, actuator, control period) and the controllers with
their gains and options (docs/model.md §4, §8). Parsed once from TOML tables plus ``--set``
overrides into validated plain data, then built into a :class:`~so3jax.dynamics.scenario.Scenario`,
a :class:`~so3jax.sim.loop.Loop` and controllers.

The loop's components are read through their registrations (:mod:`so3jax.components.registry`,
:mod:`so3jax.controllers.registry`): ``[sensors.NAME]`` (a table, or false to leave a
sensor out), ``[estimator] kind`` with ``[estimator.NAME]``, ``[actuator] kind`` with
``[actuator.NAME]``, ``[controller.NAME]`` (options), ``[gains.NAME]`` (a table, or
the path of a best_gains.json written by ``so3jax tune``) and ``[schedule]`` (a controller's
gains per phase or over time, :mod:`so3jax.missions.schedule`). Without a file, the flight
mission of docs/model.md §8.5 (``missions/flight.toml`` spells it out).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import warnings
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from so3jax.components import actuators
from so3jax.components import registry as components
from so3jax.components.sensors import Sensors
from so3jax.controllers import registry
from so3jax.controllers.scheduled import Scheduled
from so3jax.core import checks
from so3jax.core.params import parse_params
from so3jax.dynamics import flexible as flexible_dynamics
from so3jax.dynamics.inertia import check_inertia
from so3jax.dynamics.paper import PAPER_J0, PHASE_NAMES
from so3jax.dynamics.scenario import Scenario, check_scenario, steps_for_horizon
from so3jax.missions import build, keys
from so3jax.missions import config as cfg
from so3jax.missions import faults as fault_list
from so3jax.missions import schedule as schedules
from so3jax.results import runfolder
from so3jax.results.io import to_builtin
from so3jax.sim import memory, pointing
from so3jax.sim.loop import Loop, check_loop, check_wiring
from so3jax.sim.rollout import block_steps

# docs/model.md §8.5: the paper's mission flown with sensors, an MEKF, four wheels in a pyramid and
# thrusters dumping their momentum, on a rigid body's J0 (keys.BODY_J0).
# The mission's own keys are their declarations' defaults (so3jax.missions.keys), the
# components' values their registrations' defaults.
FLIGHT = {
    **keys.defaults(),
    "sensors": {"gyro": {}, "star_tracker": {}},
    "estimator": {"kind": "mekf"},
    "actuator": {"kind": "wheels"},
    "momentum": {"kind": "thrusters"},
    "filter": {"kind": "none"},
    "reference": {"kind": "paper"},
    "controller": {},
    "gains": {},
}

# docs/model.md §4-§5: the paper's experiment in the same schema: the controller reads the true state
# in every RK4 stage and its torque reaches the body exactly (missions/paper.toml spells it out).
PAPER = dict(FLIGHT, control={"mode": "continuous"}, sensors={}, estimator={"kind": "truth"},
             actuator={"kind": "ideal"}, momentum={"kind": "none"},
             inertia=dict(FLIGHT["inertia"], J0={"nominal": keys.matrix(PAPER_J0)}))

# [[requirements]] (so3jax.sim.pointing), [[faults]], [[appendages]] and [[slosh]] (docs/model.md §8.9)
TOP_KEYS = keys.TOP + ("requirements", "faults", "appendages", "slosh")
POINTING = {"window": keys.KEY["pointing.window"].default, "levels": tuple(keys.KEY["pointing.levels"].default)}
MISSION_TABLES = keys.TABLES + ("sensors", "estimator", "actuator", "momentum", "filter", "environment", "reference",
                                "controller", "gains", "schedule", "fdir")
DEFAULT_REFERENCE = {"kind": "paper", "paper": {}}  # described only where another is flown
DEFAULT_INERTIA = {"kind": "paper"}
ORBIT_ANGLES = ("inclination", "raan", "argument_of_latitude", "earth_angle")
DEFAULT_ORBIT = {name: keys.KEY[f"orbit.{name}"].default for name in ORBIT_ANGLES}
DEFAULT_MOMENTUM = {"kind": "none", "none": {}}  # J0, J1, J2 (or J) and tau_J: the Mission's own fields
DEFAULT_FILTER = {"kind": "none", "none": {}}
UNIT_TOLERANCE = 1e-9  # a unit vector's departure allowed ([[appendages]], [[slosh]])
PAPER_PHASES = {"names": tuple(PHASE_NAMES), "start": tuple(keys.KEY["phases.start"].default)}


@dataclasses.dataclass(frozen=True, eq=False)
class Mission:
    """A validated mission: plain numbers, strings and NumPy arrays (nothing compiled).

    sensors: {name: values} of the sensors flown; estimator, actuator: {"kind": name,
    name: values}; options: {controller: factory keywords}; gains: {controller: gains}.
    schedule: {controller: {"by": "phase"}, {"by": "time", "at": breakpoints [s]} or {"by": "inertia",
    "at": breakpoints [kg m^2], "of": moment}} of the
    scheduled laws (:mod:`so3jax.missions.schedule`), whose gains have a leading axis of
    one entry per phase or breakpoint.
    constant_inertia: J(t) = J0 throughout (``[inertia] J``), else the paper's profile
    (where ``inertia`` is of kind ``paper``; another kind: :mod:`so3jax.components.inertias`).
    initial: {"attitude": rotation vector of R(0) [rad], "rate": Omega(0) [rad/s]}.
    """

    T: float
    dt: float
    seed: int
    controllers: tuple
    record_every: int
    period_steps: int | None  # None: continuous-time controller (the paper's mode)
    J0: np.ndarray
    J1: np.ndarray
    J2: np.ndarray
    J1_scale: float | None  # J1 = J1_scale J0 when the mission gives the deployment's growth, else None
    constant_inertia: bool
    tau_J: float
    n: float
    disturbance: dict  # amplitude, frequency, noise_std
    initial: dict
    sensors: dict
    estimator: dict
    actuator: dict
    options: dict
    gains: dict
    pointing: dict = dataclasses.field(default_factory=lambda: dict(POINTING))  # window [s], levels
    requirements: tuple = ()  # so3jax.sim.pointing.Requirement, checked by fly
    reference: dict = dataclasses.field(default_factory=lambda: dict(DEFAULT_REFERENCE))  # {"kind": name, name: values}
    phases: dict = dataclasses.field(default_factory=lambda: dict(PAPER_PHASES))  # names, start [s]
    inertia: dict = dataclasses.field(default_factory=lambda: dict(DEFAULT_INERTIA))  # {"kind": name, name: values}
    orbit: dict = dataclasses.field(default_factory=lambda: dict(DEFAULT_ORBIT))  # the angles of [orbit] [deg]
    environment: dict = dataclasses.field(default_factory=dict)  # {torque model: values} of [environment]
    momentum: dict = dataclasses.field(default_factory=lambda: dict(DEFAULT_MOMENTUM))  # {"kind": name, name: values}
    schedule: dict = dataclasses.field(default_factory=dict)  # {controller: {"by": ..., ["at": (...), "of": ...]}}
    faults: tuple = ()  # [[faults]] as plain dicts (so3jax.missions.faults), docs/model.md §8.7
    fdir: dict = dataclasses.field(default_factory=lambda: dict(fault_list.NO_FDIR))  # what the loop knows of them
    filter: dict = dataclasses.field(default_factory=lambda: dict(DEFAULT_FILTER))  # {"kind": name, name: values}
    hub_mass: float | None = None  # [hub] mass [kg], with appendages or slosh
    appendages: tuple = ()  # [[appendages]] as plain dicts (keys.APPENDAGE_KEYS), docs/model.md §8.9
    slosh: tuple = ()  # [[slosh]] as plain dicts (keys.SLOSH_KEYS)

    @property
    def flexible(self) -> bool:
        """Whether the hub carries hinged panels or slosh particles (docs/model.md §8.9)."""
        return bool(self.appendages or self.slosh)

    @property
    def phase_names(self) -> tuple:
        return tuple(self.phases["names"])

    @property
    def period(self) -> float | None:
        return None if self.period_steps is None else self.period_steps * self.dt

    @property
    def recording(self) -> tuple[float, str]:
        """(the interval between recorded samples [s], what sets it): ``record_every`` steps,
        rounded up to whole control periods, at most the horizon (:func:`so3jax.sim.rollout.block_steps`)."""
        n_steps = steps_for_horizon(self.T, self.dt)
        steps = block_steps(n_steps, self.record_every, self.period_steps)
        how = f"record_every = {self.record_every} step{'s' * (self.record_every != 1)} of dt = {self.dt:g} s"
        if steps != min(self.record_every, n_steps):
            how += f", rounded up to whole control periods of {self.period_steps} steps"
        elif steps < self.record_every:
            how += f", at most the horizon T = {self.T:g} s"
        return steps * self.dt, how

    @property
    def no_estimate(self) -> str | None:
        """Why the mission's runs have no attitude estimate that can be wrong (its estimator
        reads the true state: e_K = 0), None where they have one."""
        kind = self.estimator["kind"]
        if not components.get("estimator", kind).truth:
            return None
        others = [n for n in components.names("estimator") if not components.get("estimator", n).truth]
        return (f"the mission's estimator (estimator.kind = {kind!r}) reads the true state (an estimator that "
                f"estimates: {', '.join(others)})")

    def scenario(self, dtype=None) -> Scenario:
        """The mission's scenario (:func:`so3jax.missions.build.scenario`)."""
        return build.scenario(self, dtype=dtype)

    def loop(self, dtype=None) -> Loop:
        dtype = jnp.result_type(float) if dtype is None else jnp.dtype(dtype)
        return build_loop(self, lambda x: jnp.asarray(x, dtype))

    def controller(self, name: str):
        """(Controller, gains) of a registered controller with the mission's options
        ([controller.NAME]); gains None where the mission does not fly it. A scheduled law
        is :class:`~so3jax.controllers.scheduled.Scheduled` over its knots, its gains with
        their leading axis. Equal options give equal controllers (a static jit argument)."""
        law = registry.get(name).factory(**self.options.get(name, {}))
        if name in self.schedule:
            entry = self.schedule[name]
            law = Scheduled(law, entry["by"], schedules.knots(entry, self.phases), schedules.variable(entry, self))
        return law, self.gains.get(name)

    def __eq__(self, other) -> bool:
        return isinstance(other, Mission) and self.fingerprint == other.fingerprint

    def __hash__(self) -> int:
        return hash(self.fingerprint)

    @functools.cached_property
    def fingerprint(self) -> str:
        """The fingerprint of :meth:`describe` (:func:`so3jax.results.runfolder.fingerprint`): equal
        missions, and only they, share it, so a mission can be a static argument of jit."""
        return runfolder.fingerprint(self.describe())

    def describe(self) -> dict:
        """The mission as JSON-ready plain data (the ``config`` of results)."""
        d = dataclasses.asdict(self)
        # options fix results only for the laws flown and where given: a law registered
        # or left at its defaults elsewhere does not change what a mission is
        d["options"] = {name: values for name, values in d["options"].items()
                        if name in self.controllers
                        or to_builtin(values) != to_builtin(registry.parse_options(name, {}))}
        d["gains"] = {k: {f: np.asarray(v).tolist() for f, v in g._asdict().items()} for k, g in self.gains.items()}
        # what fly reports and checks, not what is flown: described where given
        if to_builtin(self.pointing) == to_builtin(POINTING):
            del d["pointing"]
        if not self.requirements:
            del d["requirements"]
        for r in d.get("requirements", ()):  # a period of its own where given ("after fault")
            if r["after"] is None:
                del r["after"]
        wheels = d["actuator"].get("wheels")
        if wheels is not None and not np.any(wheels["coulomb_friction"]) and not np.any(wheels["viscous_friction"]):
            for key in actuators.FRICTION_KEYS:  # frictionless wheels: no friction described (friction_speed acts
                del wheels[key]  # only with friction)
        if to_builtin(self.reference) == to_builtin(DEFAULT_REFERENCE):
            del d["reference"]
        if to_builtin(self.phases) == to_builtin(PAPER_PHASES):
            del d["phases"]
        for name, default in (("inertia", DEFAULT_INERTIA), ("orbit", DEFAULT_ORBIT), ("environment", {}),
                              ("momentum", DEFAULT_MOMENTUM), ("schedule", {}), ("faults", ()),
                              ("fdir", fault_list.NO_FDIR), ("filter", DEFAULT_FILTER), ("hub_mass", None),
                              ("appendages", ()), ("slosh", ())):
            if to_builtin(getattr(self, name)) == to_builtin(default):
                del d[name]
        return to_builtin(d)


def default_tree() -> dict:
    """The flight mission as TOML tables with every registered component's and
    controller's parameters at their defaults (None defaults left out): the whole schema."""
    def values(params):
        return {p.name: p.default for p in params if p.default is not None}

    tree = {k: v for k, v in FLIGHT.items()}
    tree["sensors"] = {n: values(components.get("sensor", n).params) for n in components.names("sensor")}
    for kind in ("estimator", "actuator", "momentum", "filter", "reference"):
        tree[kind] = dict(FLIGHT[kind], **{n: values(components.get(kind, n).params) for n in components.names(kind)})
    tree["inertia"] = dict(FLIGHT["inertia"], kind="paper",
                           **{n: values(components.get("inertia", n).params) for n in components.names("inertia")
                              if n != "paper"})
    tree["controller"] = {n: values(registry.get(n).options) for n in registry.names()}
    tree["gains"] = {n: {f: np.asarray(v).tolist() for f, v in registry.get(n).defaults._asdict().items()}
                     for n in registry.names()}
    return tree


def build_loop(m: Mission, as_array, noise_of: Mission | None = None) -> Loop:
    """The loop's components built from their registrations; an estimator assumes the
    noise levels of the sensors of ``noise_of`` (default: m's own)."""
    noise = {}
    for name, values in (m if noise_of is None else noise_of).sensors.items():
        spec = components.get("sensor", name)
        noise.update(spec.noise(values) if spec.noise else {})
    ctx = components.BuildContext(as_array, noise, m.dt if m.period_steps is None else m.period_steps * m.dt)
    slots = {}
    for name, values in m.sensors.items():
        slots[components.get("sensor", name).provides] = components.get("sensor", name).build(values, ctx)
    estimator = components.get("estimator", m.estimator["kind"]).build(m.estimator[m.estimator["kind"]], ctx)
    actuator = components.get("actuator", m.actuator["kind"]).build(m.actuator[m.actuator["kind"]], ctx)
    momentum = components.get("momentum", m.momentum["kind"]).build(m.momentum[m.momentum["kind"]], ctx)
    structural = components.get("filter", m.filter["kind"]).build(m.filter[m.filter["kind"]], ctx)
    return Loop(Sensors(**slots), estimator, actuator, m.period_steps, momentum,
                fault_list.model(m.faults, m.fdir, as_array), structural)


def merge_tables(base: dict, over: dict) -> dict:
    """base updated by over, table by table (over's keys win)."""
    out = dict(base)
    for k, v in over.items():
        out[k] = merge_tables(base[k], v) if isinstance(v, dict) and isinstance(base.get(k), dict) else v
    return out


def _inertia_form(table) -> str | None:
    """Which form an ``[inertia]`` table gives: "constant" (J), "paper" (J0, J1, J2 or
    kind = "paper"), "kind" (another kind, by kind or its one subtable); None: none."""
    if not isinstance(table, dict):
        return None
    if "J" in table:
        return "constant"
    if table.get("kind", "paper") != "paper" or any(isinstance(table.get(k), dict) for k in components.names("inertia")
                                                    if k != "paper"):
        return "kind"
    return "paper" if "kind" in table or set(table) & set(keys.allowed("inertia")) else None


def layered(lower: dict, upper: dict) -> dict:
    """``upper`` over ``lower`` (a file over another, ``--set`` over a file) by one rule, as
    a file over the defaults: table by table, except that an ``[inertia]`` of another form
    (a constant J, the paper's J0, J1, J2, or another kind) replaces the lower one's."""
    lower_form, upper_form = _inertia_form(lower.get("inertia")), _inertia_form(upper.get("inertia"))
    if upper_form is not None and lower_form is not None and upper_form != lower_form:
        lower = {k: v for k, v in lower.items() if k != "inertia"}
    return merge_tables(lower, upper)


def _components(kind: str, table: str, given, default) -> dict:
    """{name: values} of a set of registered components, each in its own ``[table.NAME]``: the
    base mission's (``default``), each merged with its given table, plus any other given a
    table; false leaves one out."""
    given = checks.table({table: given}, table, components.names(kind))
    out = {}
    for name in components.names(kind):
        values = given.get(name, {} if name in default else False)
        if values is False:
            continue
        if not isinstance(values, dict):
            raise ValueError(f"{table}.{name} must be a table, or false to leave it out, got {checks.short(values)}")
        out[name] = components.get(kind, name).parse(values, f"{table}.{name}")
    return out


def _sensors(given: dict, default: dict) -> dict:
    """{name: values} of the sensors flown (:func:`_components`), at most one per measured quantity."""
    out = _components("sensor", "sensors", given, default)
    providers = {}
    for name in out:
        quantity = components.get("sensor", name).provides
        if quantity in providers:
            raise ValueError(f"sensors.{providers[quantity]} and sensors.{name} both measure the {quantity}: "
                             f"leave one out (sensors.{providers[quantity]}=false)")
        providers[quantity] = name
    return out


def _given_kind(given, table: str, kinds: tuple, base: str, paper_keys: tuple = ()) -> str | None:
    """``[table] kind`` as the user's tables give it: ``kind`` itself, else the one kind whose
    ``[table.NAME]`` is given, if not the base mission's kind ``base`` (None: neither); a
    one-line ValueError naming ``{table}.kind`` where tables of two kinds are given without
    it. paper_keys: the paper profile's keys given in [inertia] (its kind ``paper``'s)."""
    given = given if isinstance(given, dict) else {}
    if "kind" in given:
        return given["kind"]
    named = [name for name in kinds if isinstance(given.get(name), dict)] + (["paper"] if paper_keys else [])
    if len(named) > 1:
        settings = [f"the paper profile's {', '.join(paper_keys)}" if name == "paper" else f"[{table}.{name}]"
                    for name in named]
        raise ValueError(f"{' and '.join(settings)} given without {table}.kind: set {table}.kind to the one flown")
    return named[0] if named and named[0] != base else None


def _chosen(d: dict, kind: str, table: str, base: dict, given=None) -> dict:
    """{"kind": name, name: values} of ``[table] kind`` and its ``[table.NAME]`` subtable
    (every other registered name's subtable is checked too, so a typo is never ignored);
    without ``kind`` in the user's table ``given``, the kind whose subtable alone it gives
    (:func:`_given_kind`), else the merged tables' ``d``."""
    t = checks.table(d, table, ("kind",) + components.names(kind))
    inferred = _given_kind(given, table, components.names(kind), base[table]["kind"])
    name = checks.choice(inferred or t.get("kind", base[table]["kind"]), f"{table}.kind", components.names(kind))
    out = {"kind": name}
    for other in components.names(kind):
        if other in t or other == name:
            values = components.get(kind, other).parse(t.get(other, {}), f"{table}.{other}")
            if other == name:
                out[name] = values
    return out


def from_dict(d: dict, base: dict = FLIGHT) -> Mission:
    """A Mission from the TOML tables (missing entries: ``base``'s, the flight mission or
    :data:`PAPER`); ValueError on bad input."""
    if not isinstance(d, dict):
        raise ValueError(f"a mission must be a table, got {checks.short(d)}")  # noqa: TRY004 (bad input)
    unknown = set(d) - set(TOP_KEYS) - set(MISSION_TABLES)
    if unknown:
        raise ValueError(f"unknown mission key(s): {', '.join(sorted(unknown))}; "
                         f"allowed: {', '.join(TOP_KEYS + MISSION_TABLES)}")
    for t in MISSION_TABLES:
        if t in d and not isinstance(d[t], dict):
            raise ValueError(f"[{t}] must be a table, got {checks.short(d[t])}")
    full = merge_tables({k: v for k, v in base.items() if k != "sensors"},
                        {k: v for k, v in d.items() if k != "sensors"})

    T = keys.parse("T", full["T"])  # a number here; positive and a multiple of dt below
    dt = keys.parse("dt", full["dt"])
    n_steps = memory.check_steps(steps_for_horizon(T, dt), f"T = {T:g} s at dt = {dt:g} s", "shorten T")
    seed = keys.parse("seed", full["seed"])
    record_every = keys.parse("record_every", full["record_every"])
    controllers = keys.parse("controllers", full["controllers"])
    period_steps = _period_steps(checks.table(full, "control", keys.allowed("control")), T, dt, n_steps)

    inertia = _inertia_kind(d.get("inertia", {}))
    J0, J1, J2, J1_scale, constant = _inertias(*(_paper_keys(t) for t in (d.get("inertia", {}), full["inertia"])))
    tau_J = keys.parse("deployment.tau_J", checks.table(full, "deployment", keys.allowed("deployment"))["tau_J"])
    if tau_J <= 0:
        raise ValueError(f"deployment.tau_J [s] must be positive, got {tau_J}")
    orbit_table = checks.table(full, "orbit", keys.allowed("orbit"))
    n = keys.parse("orbit.n", orbit_table["n"])
    orbit = {name: float(keys.parse(f"orbit.{name}", orbit_table[name])) for name in ORBIT_ANGLES}
    dist = checks.table(full, "disturbance", keys.allowed("disturbance"))
    disturbance = {name: keys.parse(f"disturbance.{name}", dist[name]) for name in keys.allowed("disturbance")}
    initial = _initial(d.get("initial", {}), full["initial"])

    sensors = _sensors(d.get("sensors", {}), base["sensors"])
    estimator = _chosen(full, "estimator", "estimator", base, d.get("estimator"))
    actuator = _chosen(full, "actuator", "actuator", base, d.get("actuator"))
    momentum_kind = _given_kind(d.get("momentum"), "momentum", components.names("momentum"), base["momentum"]["kind"])
    if momentum_kind is None and actuator["kind"] != base["actuator"]["kind"]:
        full["momentum"] = {"kind": "none"}  # the base's momentum management comes with the base's actuator
    momentum = _chosen(full, "momentum", "momentum", base, d.get("momentum"))
    environment = _components("environment", "environment", d.get("environment", {}), {})  # none by default
    reference = _chosen(full, "reference", "reference", base, d.get("reference"))
    structural = _chosen(full, "filter", "filter", base, d.get("filter"))
    phases = _phases(full["phases"], dt, inertia["kind"] == "paper" and not constant, reference["kind"])
    _filter_phases(structural, phases["names"])
    _check_wiring(period_steps, sensors, estimator["kind"])
    schedule = schedules.parse(full.get("schedule", {}), controllers)
    fdir = fault_list.parse_fdir(d.get("fdir"))
    wheels = actuator["wheels"] if actuator["kind"] == "wheels" else None
    faults = fault_list.parse(d.get("faults", []), wheels=wheels, sensors=tuple(sensors), momentum=momentum["kind"],
                              sampled=period_steps is not None, fdir=fdir)
    if wheels is not None:
        _check_friction_step(wheels, dt, faults)

    hub_mass, appendages, slosh = _flexible(d, full, phases["names"])

    options_table = checks.table(full, "controller", registry.names())
    options = {name: registry.parse_options(name, options_table.get(name, {})) for name in registry.names()}
    gains_table = checks.table(full, "gains", registry.names())
    gains = {}
    for name in registry.names():  # every table or file given is checked, also of a controller not flown
        given = gains_table.get(name, {})
        scheduled = {"schedule": schedule[name], "phases": phases} if name in schedule else {}
        if isinstance(given, str):
            try:
                g = gains_file(given, name, **scheduled)
            except ValueError as err:
                raise ValueError(f"gains.{name}: {err}") from None
        else:
            g = _gains(name, given, f"gains.{name}", **scheduled)
        if name in controllers:
            gains[name] = g

    mission = Mission(T, dt, seed, controllers, record_every, period_steps, J0, J1, J2, J1_scale, constant, tau_J, n,
                      disturbance, initial, sensors, estimator, actuator, options, gains,
                      _pointing(checks.table(full, "pointing", keys.allowed("pointing"))), reference=reference,
                      phases=phases, inertia=inertia, orbit=orbit, environment=environment, momentum=momentum,
                      schedule=schedule, faults=faults, fdir=fdir, filter=structural, hub_mass=hub_mass,
                      appendages=appendages, slosh=slosh)
    if isinstance(d.get("pointing"), dict) and "window" in d["pointing"]:  # a default window is reported, not refused
        pointing.check_recorded(mission.pointing["window"], "pointing.window", mission.recording)
    for name in controllers:
        try:
            mission.controller(name)
        except (TypeError, ValueError) as err:
            raise ValueError(f"[controller.{name}]: {err}") from None
    inertias = {"J0": J0} if constant else {"J0": J0, "J1": J1, "J2": J2}
    for name, J in inertias.items():
        check_inertia(f"{name} (inertia.{name})" if not constant else "inertia.J", J, warn=False)
    scenario = mission.scenario()
    check_scenario(scenario)  # J(t) over every phase; the triangle inequality's warning
    if inertia["kind"] != "paper":
        inertias = {f"inertia.{inertia['kind']}.{name}": J for name, J in scenario.inertia.matrices().items()}
    check_loop(build_loop(mission, np.asarray), inertias)
    bounds = pointing.phase_bounds_of(scenario)
    first_fault = min((f["time"] for f in mission.faults), default=None)
    requirements = pointing.parse_requirements(d.get("requirements", []), mission.phase_names, bounds,
                                               mission.recording, mission.no_estimate, first_fault)
    return dataclasses.replace(mission, requirements=requirements)


def _phases(table, dt: float, paper_inertia: bool, reference: str) -> dict:
    """[phases]: names and start times [s], 0 first, increasing, on whole steps dt (a phase
    starting at or after T is not reached: a shortened horizon flies the first phases); the
    paper's inertia profile and reference switch at the paper's phases, so they need those."""
    table = checks.table({"phases": table}, "phases", keys.allowed("phases"))
    names = keys.parse("phases.names", table["names"])
    start = tuple(float(t) for t in keys.parse("phases.start", table["start"]))
    if len(start) != len(names):
        raise ValueError(f"phases.start: one start time per name ({len(names)}), got {len(start)}")
    if start[0] != 0.0 or any(b <= a for a, b in zip(start[:-1], start[1:])):
        raise ValueError(f"phases.start [s] must begin at 0 and increase, got {list(start)}")
    off = [t for t in start if abs(t / dt - round(t / dt)) > 1e-9 * max(1.0, t / dt)]
    if off:
        raise ValueError(f"phases.start: {off[0]:g} s is not a whole number of steps dt = {dt:g} s")
    paper = tuple(keys.KEY["phases.start"].default)
    if len(start) != len(paper) or any(abs(a - b) > 1e-9 for a, b in zip(start, paper)):
        needs = [what for what, uses in (("the paper's inertia profile (inertia.J0, J1, J2; a constant one: "
                                          "inertia.J; or another inertia.kind)", paper_inertia),
                                         ("the paper's reference (reference.kind = \"paper\")", reference == "paper"))
                 if uses]
        if needs:
            raise ValueError(f"phases.start: {' and '.join(needs)} switch at the paper's phases {list(paper)} s; "
                             "other phases need another")
    return {"names": names, "start": start}


def _entries(entries, name: str, params: tuple) -> tuple:
    """The entries of an array of tables ``[[name]]``, each checked against ``params`` (every key
    with a None default required), as plain dicts; one-line ValueError naming ``name[i]``."""
    if not isinstance(entries, (list, tuple)):
        raise ValueError(f"{name} must be a list of tables ([[{name}]]), got {checks.short(entries)}")
    out = []
    for i, entry in enumerate(entries):
        where = f"{name}[{i}]"
        if not isinstance(entry, dict):
            raise ValueError(f"{where} must be a table, got {checks.short(entry)}")
        values = parse_params(params, entry, where)
        missing = [p for p in params if values[p.name] is None]
        if missing:
            p = missing[0]
            raise ValueError(f"{where}.{p.name}{f' [{p.unit}]' if p.unit else ''} is required ({p.doc})")
        out.append(values)
    return tuple(out)


def _unit(v, where: str) -> None:
    if abs(np.linalg.norm(v) - 1.0) > UNIT_TOLERANCE:
        raise ValueError(f"{where} must be a unit vector, got {checks.short(np.asarray(v).tolist())} "
                         f"(norm {np.linalg.norm(v):.12g})")


def _flexible(d: dict, full: dict, phase_names: tuple = ()):
    """(hub mass [kg] or None, [[appendages]], [[slosh]]) (docs/model.md §8.9), checked: unit axes and
    directions, a panel's direction perpendicular to its axis, positive definite inertias, the
    hub's mass given where they are (and only there), a k or c given as a list one value per
    phase (``phase_names``); one-line ValueErrors naming the key."""
    appendages = _entries(d.get("appendages", []), "appendages", keys.APPENDAGE_KEYS)
    slosh = _entries(d.get("slosh", []), "slosh", keys.SLOSH_KEYS)
    for name, entries in (("appendages", appendages), ("slosh", slosh)):
        for i, entry in enumerate(entries):
            for field in ("k", "c"):
                n = np.size(entry[field]) if np.ndim(entry[field]) else None
                if n is not None and n != len(phase_names):
                    raise ValueError(f"{name}[{i}].{field} has {n} value{'s' * (n != 1)}: give one number, or one "
                                     f"per phase ({len(phase_names)}: {', '.join(phase_names)})")
    hub = checks.table(full, "hub", keys.allowed("hub"))
    mass = keys.parse("hub.mass", hub["mass"]) if "mass" in hub else None
    if not (appendages or slosh):
        if mass is not None:
            raise ValueError("hub.mass [kg] is read only with [[appendages]] or [[slosh]] (a rigid body's mass does "
                             "not turn it): give them or leave hub.mass out")
        return None, (), ()
    if mass is None:
        raise ValueError("[[appendages]] and [[slosh]] need the hub's mass: give hub.mass [kg] (the rigid body whose "
                         "inertia about B is the mission's J(t))")
    for i, a in enumerate(appendages):
        where = f"appendages[{i}]"
        _unit(a["axis"], f"{where}.axis")
        _unit(a["direction"], f"{where}.direction")
        if abs(float(np.dot(a["axis"], a["direction"]))) > UNIT_TOLERANCE:
            raise ValueError(f"{where}.direction must be perpendicular to {where}.axis, got axis . direction = "
                             f"{float(np.dot(a['axis'], a['direction'])):.6g}")
        check_inertia(f"{where}.inertia", a["inertia"], warn=False)
    for j, p in enumerate(slosh):
        _unit(p["direction"], f"slosh[{j}].direction")
    # the rest (finite values, non-negative distances and springs) as the model reads them
    flexible_dynamics.check(build.flexible_body(mass, appendages, slosh, np.eye(3), phases=len(phase_names)))
    return mass, appendages, slosh


def _filter_phases(structural: dict, phase_names: tuple) -> None:
    """[filter.NAME]: a parameter given as a list has one value per phase (docs/model.md §8.8)."""
    values = structural.get(structural["kind"]) or {}
    for name, value in values.items():
        n = np.size(value) if np.ndim(value) and not isinstance(value, str) else None
        if n is not None and n != len(phase_names):
            raise ValueError(f"filter.{structural['kind']}.{name} has {n} value{'s' * (n != 1)}: give one number, or "
                             f"one per phase ({len(phase_names)}: {', '.join(phase_names)})")


def _pointing(table: dict) -> dict:
    """[pointing]: the report's RPE window [s] (positive) and confidence levels (each in (0, 1))."""
    window = keys.parse("pointing.window", table["window"])
    levels = keys.parse("pointing.levels", table["levels"])
    if not window > 0:
        raise ValueError(f"pointing.window [s] must be positive, got {window}")
    if len(levels) == 0 or np.any((levels <= 0) | (levels >= 1)):
        raise ValueError(f"pointing.levels must be confidence levels in (0, 1), got {checks.short(levels.tolist())}")
    return {"window": float(window), "levels": tuple(float(x) for x in levels)}


def _gains(name: str, table, where: str, schedule: dict | None = None, phases: dict | None = None) -> tuple:
    """The gains of controller ``name``: its defaults with the entries of ``table``, checked
    against their shapes and by the registration; one-line ValueError naming ``where``.
    schedule: the law's [schedule] entry (with the mission's phases): each gain one value
    per phase or breakpoint (:func:`so3jax.missions.schedule.scheduled_gains`)."""
    if schedule is not None:
        return schedules.scheduled_gains(name, table, schedule, phases, where)
    spec = registry.get(name)
    g = checks.gains(table, spec.defaults, spec.gain_shapes(), where)
    try:
        spec.check(g)
    except (TypeError, ValueError) as err:
        raise ValueError(f"[{where}]: {err}") from None
    return g


def gains_file(path, controller: str, schedule: dict | None = None, phases: dict | None = None) -> tuple:
    """The gains of a best_gains.json (``so3jax tune``'s, :mod:`so3jax.jobs.tune.storage`)
    tuned for ``controller``: every gain given, checked as a ``[gains.NAME]`` table is
    (scheduled by ``schedule`` over ``phases``: lists of one value per phase or breakpoint). A
    one-line ValueError naming the file for a missing, unreadable or malformed file, or one
    tuned for another law; a warning where the run that wrote it did not finish."""
    path = Path(path)
    try:
        saved = json.loads(path.read_text(encoding="utf-8-sig"))
    except FileNotFoundError:
        raise ValueError(f"gains file {path} does not exist") from None
    except OSError as err:
        raise ValueError(f"gains file {path} cannot be read: {err.strerror or err}") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"gains file {path} is not JSON: {err}") from None
    held = saved.get("controller") if isinstance(saved, dict) else None
    if not isinstance(held, str) or not isinstance(saved.get("gains"), dict):
        raise ValueError(f"gains file {path} is not a best_gains.json of so3jax tune "
                         "(a 'controller' name and a 'gains' table)")
    if held != controller:
        raise ValueError(f"gains file {path} holds gains tuned for the {held!r} controller, not {controller!r}")
    missing = [f for f in registry.get(controller).gains_type._fields if f not in saved["gains"]]
    if missing:
        raise ValueError(f"gains file {path} misses the {controller} gain {missing[0]!r}")
    if runfolder.incomplete(path.parent):
        warnings.warn(f"gains file {path} is from a so3jax run that did not finish (its manifest says incomplete)")
    try:
        return _gains(controller, saved["gains"], "gains", schedule, phases)
    except ValueError as err:
        raise ValueError(f"gains file {path}: {err}") from None


def _gain_files_in(tables: dict, folder) -> dict:
    """The tables of a file in ``folder`` with the gains files its [gains] table names and its
    reference and inertia tables' files made absolute, relative to that folder (the file's own, like a
    job's mission path)."""
    given = tables.get("gains")
    if isinstance(given, dict):
        paths = {name: str((Path(folder) / v).resolve()) for name, v in given.items() if isinstance(v, str)}
        tables = {**tables, "gains": {**given, **paths}}
    for kind in ("reference", "inertia"):  # reference.table.file, inertia.table.file
        table = tables.get(kind, {}).get("table") if isinstance(tables.get(kind), dict) else None
        if isinstance(table, dict) and isinstance(table.get("file"), str):
            path = str((Path(folder) / table["file"]).resolve())
            tables = {**tables, kind: {**tables[kind], "table": {**table, "file": path}}}
    return tables


def _period_steps(control: dict, T: float, dt: float, n_steps: int) -> int | None:
    """m = control.period / dt, a whole number >= 1 dividing the horizon; None: continuous."""
    mode = keys.parse("control.mode", control.get("mode", "sampled"))
    if mode == "continuous":
        return None
    period = keys.parse("control.period", control.get("period"))
    ratio = period / dt
    if period <= 0 or abs(ratio - round(ratio)) > 1e-9 * max(ratio, 1.0) or round(ratio) < 1:
        raise ValueError(f"control.period = {period} s is not a whole number (>= 1) of steps dt = {dt} s")
    m = int(round(ratio))
    if m > n_steps:
        raise ValueError(f"control.period = {period} s is longer than the horizon T = {T} s")
    if n_steps % m:
        raise ValueError(f"T (horizon) = {T} s is not a whole number of control periods control.period = {period} s")
    return m


def _inertia_kind(given) -> dict:
    """{"kind": name, name: values} of ``[inertia] kind`` (:mod:`so3jax.components.inertias`) and
    its ``[inertia.NAME]`` subtable; the default, ``paper``, is read from the ``[inertia]``
    keys J0, J1, J2 (or J) by :func:`_inertias`, which another kind excludes."""
    given = given if isinstance(given, dict) else {}
    kinds = components.names("inertia")
    paper = tuple(sorted(set(given) & set(keys.allowed("inertia"))))
    kind = _given_kind(given, "inertia", tuple(k for k in kinds if k != "paper"), "paper", paper)
    name = checks.choice(kind or "paper", "inertia.kind", kinds)
    out = {"kind": name}
    for other in kinds:
        if other != "paper" and (other in given or other == name):
            values = components.get("inertia", other).parse(given.get(other, {}), f"inertia.{other}")
            if other == name:
                out[name] = values
    if name != "paper" and paper:
        raise ValueError(f"[inertia] kind = {name!r} excludes the paper profile's key(s) {', '.join(paper)}: "
                         f"give its inertias in [inertia.{name}]")
    return out


def _paper_keys(table) -> dict:
    """The ``[inertia]`` table without its kind and the registered kinds' subtables."""
    kinds = ("kind",) + tuple(k for k in components.names("inertia") if k != "paper")
    return {k: v for k, v in table.items() if k not in kinds} if isinstance(table, dict) else table


def _inertias(given: dict, full: dict):
    """(J0, J1, J2, J1's scale or None, constant): ``[inertia] J`` for a constant inertia,
    else the paper's J0 (capture), J1 = scale J0 or a nominal (deployed), J2 (docked) [kg m^2]."""
    if isinstance(given, dict) and "J" in given:
        extra = sorted(set(given) - {"J"})
        if extra:
            raise ValueError(f"[inertia] J (a constant inertia) excludes {', '.join(extra)}")
        J = keys.parse("inertia.J", given["J"])
        return J, J, J, None, True
    inertia = checks.table({"inertia": full}, "inertia", keys.allowed("inertia"))
    J0 = keys.parse("inertia.J0.nominal",
                    checks.table(inertia, "J0", keys.allowed("inertia.J0"), "inertia.")["nominal"])
    J1_table = checks.table(inertia, "J1", keys.allowed("inertia.J1"), "inertia.")
    scale_default = keys.KEY["inertia.J1.scale"].default
    scale = None if "nominal" in J1_table else keys.parse("inertia.J1.scale", J1_table.get("scale", scale_default))
    J1 = keys.parse("inertia.J1.nominal", J1_table["nominal"]) if scale is None else scale * J0
    J2 = keys.parse("inertia.J2.nominal",
                    checks.table(inertia, "J2", keys.allowed("inertia.J2"), "inertia.")["nominal"])
    return J0, J1, J2, scale, False


def _initial(given: dict, full: dict) -> dict:
    """{"attitude": rotation vector of R(0) [rad], "rate": Omega(0) [rad/s]}; R(0) given as
    ``attitude`` (a rotation vector) or ``quaternion`` [w, x, y, z] (scalar first, unit)."""
    init = checks.table({"initial": full}, "initial", keys.allowed("initial"))
    rate = keys.parse("initial.rate", init["rate"])
    if not (isinstance(given, dict) and "quaternion" in given):
        return {"attitude": keys.parse("initial.attitude", init["attitude"]), "rate": rate}
    if "attitude" in given:
        raise ValueError("initial.attitude and initial.quaternion both give R(0): give one")
    q = keys.parse("initial.quaternion", given["quaternion"])
    if abs(np.linalg.norm(q) - 1.0) > 1e-9:
        raise ValueError("initial.quaternion [w, x, y, z] must be a unit quaternion, "
                         f"got norm {np.linalg.norm(q):.12g}")
    w, v = q[0], q[1:]
    sin_half = np.linalg.norm(v)
    angle = 2.0 * np.arctan2(sin_half, w)
    return {"attitude": v * (angle / sin_half) if sin_half > 0 else np.zeros(3), "rate": rate}


def _check_friction_step(wheels: dict, dt: float, faults: tuple) -> None:
    """ValueError where the wheels' bearing friction, scaled by the largest friction fault's
    factor, decays a wheel's speed too fast for the plant's RK4 step (docs/model.md (8.13a))."""
    factor = max([1.0] + [f["factor"] for f in faults if f.get("mode") == "friction"])
    rate = actuators.friction_rate(wheels, factor)
    if dt * rate > actuators.MAX_FRICTION_STEP:
        raise ValueError(f"actuator.wheels: the bearing friction's slope at rest (f_c / friction_speed + c_v"
                         f"{f', times the friction fault factor {factor:g}' if factor != 1.0 else ''}) over J_s is "
                         f"{rate:.4g} 1/s, too steep for dt = {dt:g} s (dt times it at most "
                         f"{actuators.MAX_FRICTION_STEP:g}): raise friction_speed or lower dt")


def _check_wiring(period_steps, sensors: dict, estimator: str) -> None:
    """The loop's wiring check (:func:`so3jax.sim.loop.check_wiring`) of the sensors flown and
    the estimator chosen, before they are built: a sensor left out measures nothing."""
    measured = tuple(components.get("sensor", name).provides for name in sensors)
    check_wiring(period_steps is None, measured, measured, components.get("estimator", estimator).component, estimator)


def load_job(d: dict, base_dir, job_tables: tuple, base: dict = FLIGHT) -> tuple[Mission, dict]:
    """(the mission, {table: value}) of a job file (a sweep, a tuning campaign): its
    ``mission`` entry names a mission file (relative to ``base_dir``), its other mission
    keys and tables override that file's entries, and ``job_tables`` are the job's own
    tables. A mission file means what ``so3jax fly`` flies (the entries it leaves out the
    flight mission's, :data:`FLIGHT`); a job without one starts from ``base``. A gains file
    is relative to the folder of the file naming it: the mission file's, or ``base_dir`` for
    the job's own entries."""
    d = dict(d)
    jobs = {k: d.pop(k) for k in job_tables if k in d}
    path = d.pop("mission", None)
    if path is not None and not isinstance(path, str):
        raise ValueError(f"mission must be the path of a mission file, got {checks.short(path)}")
    unknown = set(d) - set(TOP_KEYS) - set(MISSION_TABLES)
    if unknown:
        allowed = ("mission",) + job_tables + TOP_KEYS + MISSION_TABLES
        raise ValueError(f"unknown config key(s): {', '.join(sorted(unknown))}; allowed: {', '.join(allowed)}")
    tables = {}
    if path is not None:
        tables = _gain_files_in(cfg.read_toml(Path(base_dir) / path), (Path(base_dir) / path).parent)
        base = FLIGHT
    return from_dict(layered(tables, _gain_files_in(d, base_dir)), base), jobs


def load(path=None, overrides=(), base: dict = FLIGHT) -> Mission:
    """The mission of a TOML file (or ``base``: the flight mission of docs/model.md §8.5), with
    KEY=VALUE overrides. A gains file named in the file is relative to the file's folder, one
    named in an override to the current directory."""
    tables = _gain_files_in(cfg.read_toml(path), Path(path).parent) if path is not None else {}
    return from_dict(layered(tables, cfg.override({}, overrides)), base)
