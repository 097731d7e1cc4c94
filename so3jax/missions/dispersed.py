"""A mission's ``[dispersions]`` table: which of the mission's own leaves vary from
sample to sample, and each sample's scenario and loop.

Keys are the mission's leaves (``deployment.tau_J``, ``sensors.gyro.arw``,
``actuator.wheels.max_torque``, ...), values a number (fixed) or a distribution
(:func:`so3jax.missions.dispersions.parse_distribution`). A few leaves take structured
distributions and keep :mod:`so3jax.missions.dispersions`' variate layout:

* ``inertia.J0``, ``inertia.J1``, ``inertia.J2``: ``{scale, axis_scale, rotation_deg,
  products}``, or ``{scale, second_moments, rotation_deg}`` (a rigid body by construction)
  (:class:`~so3jax.missions.dispersions.InertiaDispersion`; J1's is applied to the
  sample's J0 when the mission gives J1 as a scale of J0);
* ``initial.attitude``: ``{max_angle_deg}``, R(0) = R_mission(0) exp(hat(v)), v uniform
  on SO(3) up to that angle; ``initial.rate``: ``{norm}``, |Omega(0)| drawn from the
  distribution ``norm`` [rad/s], its direction uniform on the sphere;
* ``seed``: ``"random"``, a disturbance and sensor-noise seed per sample, or ``"mission"``
  (the default), the mission's seed for every sample.

Every other leaf is a parameter of a flown sensor, estimator or actuator, or of the
mission's reference or inertia kind (:data:`SCENARIO_LEAVES`: slew times and attitudes,
inertia-event times, ...; an inertia matrix by an inertia.J0-style table, each matrix from
11 variates of its own): each element of its value is drawn independently from its own
variates, ``fold_in(fold_in(key(seed), k), crc32(leaf))``, so adding or removing a
dispersion moves no other; a distribution with ``relative = "offset"`` (``"scale"``) draws
what is added to (multiplies) the mission's value. Each sample's reference and inertia are
built from its values (:func:`scenario_values`); a sample whose values the kind's checks
refuse (slews that overlap) is rejected. A sample with a
value outside the parameter's declared domain is rejected (never simulated), and so is
one that breaks a bound a component's own check sets between two of its parameters
(:data:`MAGNITUDE_LIMITS`: a wheel's initial speed within its speed limit, as ``fly``
checks it): a sample's mission passes the checks of a flown one. A distribution that
cannot keep within such a bound, by :func:`~so3jax.missions.dispersions.check_domain`'s
rule against the least limit drawn (:func:`~so3jax.missions.dispersions.least`), is
refused before anything is drawn; its tails are rejected sample by sample. The
estimator keeps the noise levels the mission's nominal sensors report: the hardware is
dispersed, not what the filter assumes. A fault's values (``faults.I.time``, ``.end``,
``.factor``, ``.wheel``, ``.step``, I the 0-based ``[[faults]]`` entry: :data:`FAULT_LEAVES`)
are leaves of each sample's loop as a component's parameters are; a sample whose
star-tracker outage ends at or before its time is rejected, and so is one whose wheels
failed off leave the others spanning less than 3-D where the loop drops them.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import zlib

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.components import registry as components
from so3jax.core import checks, so3
from so3jax.dynamics import attitude_profiles as profiles
from so3jax.dynamics.orbit import MAX_MEAN_MOTION, MIN_ALTITUDE
from so3jax.dynamics.reference import PiecewiseConstantRate
from so3jax.missions import build
from so3jax.missions import dispersions as disp
from so3jax.missions import faults as fault_list
from so3jax.missions.mission import Mission, build_loop
from so3jax.sim import memory
from so3jax.sim.pointing import AFTER_FAULT
from so3jax.sim.rollout import rollout_batch

STRUCTURED = {
    ("deployment", "tau_J"): "tau_J",
    ("orbit", "n"): "n",
    ("disturbance", "amplitude"): "amplitude",
    ("disturbance", "frequency"): "frequency",
    ("disturbance", "noise_std"): "noise_std",
}
INERTIA_KEYS = ("scale", "axis_scale", "rotation_deg", "products", "second_moments")
LOOP_TABLES = ("sensors", "estimator", "actuator", "momentum")
_SCENARIO_TABLES = ("reference", "inertia")
# A component parameter whose magnitude its component's check bounds by another of its
# parameters, element by element: {parameter: limit} (Wheels.check: |Omega_w(0)| <= Omega_max).
MAGNITUDE_LIMITS = {"actuator.wheels.initial_speed": "actuator.wheels.max_speed"}
INERTIA = "inertia"  # an inertia matrix [kg m^2], dispersed as inertia.J0 is (an InertiaDispersion)
# The scenario's dispersible parameters, by reference and inertia kind: {(table, kind):
# {parameter: (low, strict) or INERTIA}}. Each sample's reference or inertia is built from its values
# (:func:`scenario_values`); one its kind's checks refuse is rejected (:func:`draw_leaves`).
SCENARIO_LEAVES = {
    ("reference", "inertial"): {"attitude": (-math.inf, False)},
    ("reference", "lvlh"): {"offset": (-math.inf, False)},
    ("reference", "table"): {"times": (-math.inf, False)},
    ("reference", "slews"): {"start": (-math.inf, False), "attitudes": (-math.inf, False), "times": (0.0, False),
                             "max_rate": (0.0, True), "max_acceleration": (0.0, True)},
    ("inertia", "events"): {"initial": INERTIA, "times": (0.0, False), "time_constants": (0.0, False),
                            "targets": (0.0, True)},
    ("inertia", "linear"): {"start": INERTIA, "end": INERTIA, "times": (0.0, False)},
    ("inertia", "table"): {"inertias": INERTIA, "times": (-math.inf, False)},
}
# A fault's dispersible values ([[faults]] entry i: faults.i.PARAMETER), by its target:
# {target: {parameter: (low, high, high excluded)}}; a wheel's factor is a degraded one's.
FAULT_LEAVES = {"wheel": {"time": (0.0, math.inf, False), "factor": (0.0, 1.0, True), "wheel": (1.0, math.inf, False)},
                "star_tracker": {"time": (0.0, math.inf, False), "end": (0.0, math.inf, False)},
                "gyro": {"time": (0.0, math.inf, False), "step": (-math.inf, math.inf, False)},
                "thruster": {"time": (0.0, math.inf, False)}}
FAULT_UNITS = {"time": "s", "end": "s", "factor": "-", "step": "rad/s", "wheel": "-"}  # samples.csv's units
# Why a sample is rejected (never simulated), in the order its checks are read: {check: reason}.
REJECTED = {
    "draws": "no positive definite inertia and positive tau_J within sweep.max_draws draws",
    "orbit": f"an orbit below the least altitude ({MIN_ALTITUDE / 1e3:g} km: orbit.n above "
             f"{MAX_MEAN_MOTION:.6g} rad/s) or no orbit (orbit.n < 0, or 0 where the mission flies on its orbit)",
    "domain": "a dispersed value outside its parameter's domain",
    "bound": "a dispersed value beyond its limit (|actuator.wheels.initial_speed| > max_speed)",
    "outage": "a star-tracker outage that ends at or before its time (faults: [time, end))",
    "wheels": "wheels failed off that leave the others spanning less than 3-D, with detection on (fdir)",
    "overlap": "slews that overlap (reference.slews: a slew ends after the next starts)",
    "order": "times that do not increase (reference or inertia table, inertia events)",
    "inertia_table": "an inertia of the inertia kind (events, linear, table) not positive definite",
}
# A distribution's ``relative`` key: "offset", the mission's value plus the draw; "scale", times it.
RELATIVE = ("offset", "scale")
INERTIA_VARIATES = 11  # per inertia matrix drawn (disp.InertiaDispersion.apply)


@dataclasses.dataclass(frozen=True)
class Leaf:
    """A dispersed component or scenario parameter: its dotted key, distribution (of the value,
    or of its offset from or scale of the mission's value, element by element), the shape of
    the mission's value, and the parameter's domain [low, high]. bound: (parameter, its
    mission value, limit, its mission value), flattened, of a :data:`MAGNITUDE_LIMITS`
    pair this leaf is either side of (each sample's |parameter| <= limit, element by
    element, the dispersed side's drawn values in place of the mission's)."""

    key: str
    dist: disp.Distribution
    shape: tuple
    low: float
    high: float
    bound: tuple | None = None
    order: tuple | None = None  # (time key, its mission value, end key, its value): end > time (an outage's)
    relative: str | None = None  # "offset" or "scale" of the mission's value (:data:`RELATIVE`)
    nominal: tuple = ()  # the mission's value, flattened (a relative leaf's)
    inertia: disp.InertiaDispersion | None = None  # inertia matrices (..., 3, 3) drawn as inertia.J0 is


def _flatten(table: dict, prefix: str = "") -> dict:
    """{dotted key: value} down to numbers, strings and distribution tables (with 'dist',
    or an inertia / initial-state table)."""
    out = {}
    for key, value in table.items():
        path = f"{prefix}{key}"
        structured = (path in ("inertia.J0", "inertia.J1", "inertia.J2", "initial.attitude", "initial.rate")
                      or path.split(".")[0] in ("reference", "inertia") and path.count(".") == 2)
        if isinstance(value, dict) and "dist" not in value and not structured:
            out.update(_flatten(value, path + "."))
        else:
            out[path] = value
    return out


def parse(table: dict, mission: Mission) -> tuple[disp.Dispersions, tuple[Leaf, ...]]:
    """(structured dispersions, component leaves) of a ``[dispersions]`` table on ``mission``;
    one-line ValueErrors naming the key."""
    if not isinstance(table, dict):
        raise ValueError(f"[dispersions] must be a table, got {checks.short(table)}")  # noqa: TRY004 (bad input)
    fields = {
        "J0": disp.InertiaDispersion(nominal=_matrix(mission.J0)),
        "J1": disp.InertiaDispersion(nominal=None if mission.J1_scale is not None else _matrix(mission.J1),
                                     scale=disp.Fixed(1.0 if mission.J1_scale is None else mission.J1_scale)),
        "J2": disp.InertiaDispersion(nominal=_matrix(mission.J2)),
        "tau_J": disp.Fixed(mission.tau_J),
        "n": disp.Fixed(mission.n),
        **{name: disp.Fixed(mission.disturbance[name]) for name in ("amplitude", "frequency", "noise_std")},
        "disturbance_seed": mission.seed,
    }
    leaves = []
    for key, value in _flatten(table).items():
        path = tuple(key.split("."))
        where = f"dispersions.{key}"
        if key == "seed":
            choice = checks.choice(value, f"{where} (random: a seed per sample; mission: the mission's seed for all)",
                                ("random", "mission"))
            fields["disturbance_seed"] = None if choice == "random" else mission.seed
        elif path[0] == "inertia" and len(path) == 2 and path[1] in ("J0", "J1", "J2"):
            if mission.inertia["kind"] != "paper":
                raise ValueError(f"{where}: the mission's inertia is of kind {mission.inertia['kind']!r}; "
                                 "inertia.J0/J1/J2 disperse the paper's profile (inertia.kind = \"paper\")")
            if mission.constant_inertia and path[1] != "J0":
                raise ValueError(f"{where}: a constant inertia ([inertia] J) is dispersed as inertia.J0")
            fields[path[1]] = _inertia(value, where, fields[path[1]])
        elif key == "initial.attitude":
            t = checks.table({"": value}, "", ("max_angle_deg",), where)
            fields["initial_angle_deg"] = checks.number(t.get("max_angle_deg", 0.0), f"{where}.max_angle_deg",
                                                        0.0, 180.0)
        elif key == "initial.rate":
            t = checks.table({"": value}, "", ("norm",), where)
            fields["initial_rate"] = _distribution(t.get("norm", 0.0), f"{where}.norm")
        elif path in STRUCTURED:
            fields[STRUCTURED[path]] = _distribution(value, where)
        elif path[0] in LOOP_TABLES:
            leaves.append(_leaf(path, value, where, mission))
        elif path[0] in ("reference", "inertia") and len(path) == 3:
            leaves.append(_scenario_leaf(path, value, where, mission))
        elif path[0] == "faults":
            leaves.append(_fault_leaf(path, value, where, mission))
        else:
            raise ValueError(f"{where} cannot be dispersed: dispersible are inertia.J0/J1/J2, deployment.tau_J, "
                             f"orbit.n, {_scenario_parameters(mission)}, disturbance.amplitude/frequency/noise_std, "
                             "initial.attitude/rate, seed, the numeric parameters of the mission's sensors, "
                             "estimator, actuator and momentum management, and its faults' "
                             "(faults.I.time/end/factor/wheel/step, I the 0-based [[faults]] entry)")
    if mission.constant_inertia:  # J(t) = J0 throughout; J1, J2 follow it undispersed
        fields["J1"] = disp.InertiaDispersion(nominal=None, scale=disp.Fixed(1.0))
        fields["J2"] = disp.InertiaDispersion(nominal=_matrix(mission.J0))
    dispersions = disp.Dispersions(**fields)
    disp.check_orbit(dispersions.n, "dispersions.orbit.n")
    disp.check(dispersions, warn=False)
    users = build.orbit_users(mission)
    if users:  # no orbit (n = 0) is refused, n > 0 drawn: the mission flies on its orbit
        disp.check_domain(dispersions.n, f"dispersions.orbit.n ({', '.join(users)} fly on the orbit)", 0.0, strict=True)
    timed = [leaf.key for leaf in leaves if leaf.key.startswith("faults.") and leaf.key.endswith(".time")]
    if timed and any(r.after is not None for r in mission.requirements):
        raise ValueError(f"requirements: phase = {AFTER_FAULT!r} starts at the mission's first fault, and "
                         f"{', '.join(timed)} is dispersed: each sample's starts elsewhere (a sweep's fault cases "
                         "give each sample's APE and RPE after its own fault)")
    return dispersions, _ordered(_bounded(tuple(leaves), mission), mission)


def _bounded(leaves: tuple, mission: Mission) -> tuple:
    """The leaves, each side of a :data:`MAGNITUDE_LIMITS` pair given its bound; ValueError
    where a distribution cannot keep within it (against the least limit drawn)."""
    by_key = {leaf.key: leaf for leaf in leaves}
    for key, limit_key in MAGNITUDE_LIMITS.items():
        value, limit = by_key.get(key), by_key.get(limit_key)
        if value is None and limit is None:
            continue
        nominal, nominal_limit = _flown(mission, key), _flown(mission, limit_key)
        if value is not None:
            least = disp.least(limit.dist) if limit is not None else float(np.min(nominal_limit))
            disp.check_magnitude(value.dist, f"dispersions.{key}", least,
                                 f"the least {limit_key}{' drawn' if limit is not None else ''}")
        else:
            disp.check_domain(limit.dist, f"dispersions.{limit_key} (the limit of {key})",
                              float(np.max(np.abs(nominal))), strict=False)
        bound = (key, _flat(nominal), limit_key, _flat(nominal_limit))
        for leaf in (value, limit):
            if leaf is not None:
                by_key[leaf.key] = dataclasses.replace(leaf, bound=bound)
    return tuple(by_key[leaf.key] for leaf in leaves)


def _ordered(leaves: tuple, mission: Mission) -> tuple:
    """The leaves, each side of a dispersed star-tracker outage given its order (end > time,
    per sample: the mission's value of the side not dispersed)."""
    by_key = {leaf.key: leaf for leaf in leaves}
    for i, fault in enumerate(mission.faults):
        time, end = f"faults.{i}.time", f"faults.{i}.end"
        if "star_tracker" not in fault or (time not in by_key and end not in by_key):
            continue
        order = (time, (float(fault["time"]),), end, (float(fault["end"]),))
        for key in (time, end):
            if key in by_key:
                by_key[key] = dataclasses.replace(by_key[key], order=order)
    return tuple(by_key[leaf.key] for leaf in leaves)


def _fault_leaf(path: tuple, value, where: str, mission: Mission) -> Leaf:
    """A numeric value of one of the mission's ``[[faults]]`` (:data:`FAULT_LEAVES`):
    ``faults.I.PARAMETER``, I the entry's 0-based index."""
    if len(path) != 3:
        raise ValueError(f"{where} must name a fault's value, e.g. dispersions.faults.0.time "
                         "(the 0-based [[faults]] entry)")
    n = len(mission.faults)
    if not path[1].isdigit() or int(path[1]) >= n:
        raise ValueError(f"{where}: the mission has no fault {path[1]!r} "
                         + (f"(its [[faults]] entries are 0 to {n - 1})" if n else "(it states no [[faults]])"))
    fault, param = mission.faults[int(path[1])], path[2]
    target = next(t for t in FAULT_LEAVES if t in fault)
    if param not in FAULT_LEAVES[target]:
        raise ValueError(f"{where}: a {target.replace('_', ' ')} fault disperses "
                         f"{', '.join(FAULT_LEAVES[target])}, not {param!r}")
    if param == "factor" and fault["mode"] != "degraded":
        raise ValueError(f"{where}: wheel {fault['wheel']} fails off (no factor); a degraded wheel's factor is "
                         "dispersed")
    low, high, high_excluded = FAULT_LEAVES[target][param]
    if param == "wheel":  # which wheel fails: one of the mission's, 1-based
        high = float(len(mission.actuator["wheels"]["axes"]))
        dist = _distribution(value, where)
        drawn = dist.values if isinstance(dist, disp.Choice) else (dist.value,) if isinstance(dist, disp.Fixed) else ()
        if not drawn or not all(v == int(v) and low <= v <= high for v in drawn):
            raise ValueError(f"{where} draws a wheel's index, 1 to {high:g} (the mission's wheels): a number or "
                             f"{{dist = \"choice\", values = [...]}} of those, got {checks.short(value)}")
    leaf = _checked_leaf(f"faults.{int(path[1])}.{param}", value, where, np.asarray(fault[param], np.float64),
                         low, high, strict=False)
    return dataclasses.replace(leaf, high=float(np.nextafter(high, -np.inf))) if high_excluded else leaf


def _flown(mission: Mission, key: str):
    """The mission's value of a flown component's parameter (a dotted key)."""
    table, name, param = key.split(".")
    return (mission.sensors if table == "sensors" else getattr(mission, table))[name][param]


def _flat(x) -> tuple:
    return tuple(np.asarray(x, float).ravel().tolist())


def _matrix(J) -> tuple:
    return tuple(map(tuple, np.asarray(J, float).tolist()))


def _distribution(value, where: str) -> disp.Distribution:
    if isinstance(value, dict) and "dist" in value and not isinstance(value["dist"], str):
        checks.choice(value["dist"], f"{where}.dist", tuple(disp.DISTRIBUTIONS))
    return disp.parse_distribution(value, where)


def _inertia(value, where: str, default: disp.InertiaDispersion) -> disp.InertiaDispersion:
    t = checks.table({"": value}, "", INERTIA_KEYS, where)
    changes = {name: _distribution(t[name], f"{where}.{name}")
               for name in ("scale", "axis_scale", "products", "second_moments") if name in t}
    if "rotation_deg" in t:
        changes["rotation_deg"] = checks.number(t["rotation_deg"], f"{where}.rotation_deg", low=0.0, high=180.0)
    return dataclasses.replace(default, **changes)


def _leaf(path: tuple, value, where: str, mission: Mission) -> Leaf:
    """A component parameter of the mission: flown, numeric, not an integer."""
    table, name, param = path[0], path[1] if len(path) > 1 else "", path[2] if len(path) > 2 else ""
    if len(path) != 3:
        raise ValueError(f"{where} must name a component parameter, e.g. dispersions.{table}.NAME.PARAMETER")
    if table == "sensors":
        flown = mission.sensors
    else:
        chosen = getattr(mission, table)  # {"kind": name, name: values}
        flown = {chosen["kind"]: chosen[chosen["kind"]]}
    if name not in flown:
        raise ValueError(f"{where}: the mission flies no {table} {name!r} (flown: {', '.join(flown) or 'none'})")
    kind = "sensor" if table == "sensors" else table
    spec = next((p for p in components.get(kind, name).params if p.name == param), None)
    if spec is None:
        raise ValueError(f"{where}: {table} {name!r} has no parameter {param!r}")
    current = flown[name][param]
    if spec.integer or spec.boolean or spec.choices or current is None:
        raise ValueError(f"{where}: only real-valued parameters are dispersed ({param} is "
                         f"{'not set in the mission' if current is None else 'not a real number'})")
    return _checked_leaf(".".join(path), value, where, current, spec.low, spec.high, strict=spec.low_excluded)


def _checked_leaf(key: str, value, where: str, current, low: float, high: float, strict: bool) -> Leaf:
    """A leaf of the mission's value ``current`` in [low, high] (low excluded where strict): a
    distribution of the value or, with ``relative = "offset"`` ("scale") in its table, of
    what is added to (multiplies) the mission's value, element by element; ValueError where
    it cannot draw into the domain (an offset: for no element; the elements drawn outside it
    reject their samples)."""
    relative = None
    if isinstance(value, dict) and "relative" in value:
        relative = checks.choice(value["relative"], f"{where}.relative", RELATIVE)
        value = {k: v for k, v in value.items() if k != "relative"}
    dist = _distribution(value, where)
    nominal = np.asarray(current, np.float64)
    if relative == "offset" and math.isfinite(low) and isinstance(dist, (disp.Fixed, disp.Uniform)):
        largest = float(nominal.max()) + (dist.value if isinstance(dist, disp.Fixed) else dist.high)
        if not largest > low:
            raise ValueError(f"{where}: the mission's value plus {disp.describe(dist)} never exceeds {low:g}")
    elif relative == "scale" and low >= 0.0:
        disp.check_domain(dist, f"{where} (a scale)", 0.0, strict)
    elif relative is None:
        disp.check_domain(dist, where, low, strict)
    low = float(np.nextafter(low, np.inf)) if strict else low
    return Leaf(key, dist, np.shape(current), low, high, relative=relative,
                nominal=_flat(nominal) if relative else ())


def _scenario_keys(mission: Mission, table: str | None = None) -> list[str]:
    """The dispersible parameters of the mission's reference and inertia kinds (``table``'s
    alone where given), as a dispersions table names them: "reference.slews.times", ..."""
    return [f"{t}.{kind}.{param}" for (t, kind), params in SCENARIO_LEAVES.items()
            if (table is None or t == table) and getattr(mission, t)["kind"] == kind for param in params]


def _scenario_parameters(mission: Mission) -> str:
    """The dispersible parameters of the mission's reference and inertia kinds, in words."""
    keys = _scenario_keys(mission)
    if keys:
        return f"the parameters of the mission's reference and inertia kinds ({', '.join(keys)})"
    kinds = " and ".join(f"{table}.kind = {getattr(mission, table)['kind']!r}" for table in _SCENARIO_TABLES)
    return f"the parameters of the reference and inertia kinds (the mission's, {kinds}, have none)"


def _scenario_leaf(path: tuple, value, where: str, mission: Mission) -> Leaf:
    """A parameter of the mission's reference or inertia kind (:data:`SCENARIO_LEAVES`); an
    inertia event's targets when every one is a scale of the inertia at its event."""
    table, kind, param = path
    flown = getattr(mission, table)["kind"]
    if kind != flown:
        raise ValueError(f"{where}: the mission's {table} is of kind {flown!r}, not {kind!r}")
    params = SCENARIO_LEAVES.get((table, kind))
    if params is None or param not in params:
        keys = _scenario_keys(mission, table)
        raise ValueError(f"{where} cannot be dispersed: "
                         + (f"dispersible are {', '.join(keys)}" if keys else
                            f"{table}.kind = {kind!r} has no dispersible parameter"))
    values = getattr(mission, table)[kind]
    current, domain = values[param], params[param]
    if (kind, param) == ("events", "targets"):
        scales = values["scales"] > 0
        if scales.any() and not scales.all():
            raise ValueError(f"{where}: the targets are dispersed where all are scales of the inertia at their "
                             "event, or all inertias")
        current, domain = (values["scales"], domain) if scales.all() else (values["matrices"], INERTIA)
    if domain == INERTIA:
        matrices = np.asarray(current, np.float64)
        inertia = _inertia(value, where, disp.InertiaDispersion(nominal=None))
        for J in matrices.reshape(-1, 3, 3):
            disp.check_inertia_dispersion(dataclasses.replace(inertia, nominal=_matrix(J)), where, warn=False)
        return Leaf(".".join(path), disp.Fixed(0.0), matrices.shape, -math.inf, math.inf, inertia=inertia,
                    nominal=_flat(matrices))
    low, strict = domain
    return _checked_leaf(".".join(path), value, where, current, low, math.inf, strict)


def scenario_values(mission: Mission, values: dict) -> Mission:
    """The mission with its reference's and inertia's dispersed parameters {key: value}
    replaced (traceable: only :func:`so3jax.missions.build.scenario` reads the result); the
    mission itself without any."""
    if not values:
        return mission
    tables = {}
    for key, value in values.items():
        table, kind, param = key.split(".")
        chosen = tables.setdefault(table, {**getattr(mission, table), kind: dict(getattr(mission, table)[kind])})
        if (kind, param) == ("events", "targets"):
            param = "scales" if jnp.ndim(value) == 1 else "matrices"
        chosen[kind][param] = value
    return dataclasses.replace(mission, **tables)


def split(values: dict) -> tuple[dict, dict]:
    """({reference and inertia leaf: value}, {component leaf: value}) of a sample's dispersed
    values: the first for :func:`scenario_values`, the second for :func:`loop`."""
    own = {k: v for k, v in values.items() if k.split(".")[0] in _SCENARIO_TABLES}
    return own, {k: v for k, v in values.items() if k not in own}


def _scenario_checks(mission: Mission, values: dict, n_samples: int) -> dict:
    """{reason: (N,) whether each sample passes} of the checks a mission file's reference and
    inertia pass (:data:`REJECTED`): slews that do not overlap, times that increase,
    inertias positive definite (the other dispersible parameters' domains are their leaves')."""
    passed = {}
    if any(k.startswith("reference.slews.") for k in values):
        given = mission.reference["slews"]
        drawn = {name: values.get(f"reference.slews.{name}", np.asarray(given[name], np.float64))
                 for name in ("start", "attitudes", "times", "max_rate", "max_acceleration")}
        times = np.broadcast_to(drawn["times"], (n_samples, len(given["times"])))
        passed[REJECTED["overlap"]] = ~profiles.overlapping(
            disp.rotation_matrix(drawn["start"]), disp.rotation_matrix(drawn["attitudes"]), times, drawn["max_rate"],
            drawn["max_acceleration"])
    order = np.ones(n_samples, bool)
    for key in ("inertia.events.times", "inertia.linear.times", "inertia.table.times", "reference.table.times"):
        if key in values:
            order &= np.all(np.diff(values[key], axis=1) > 0, axis=1)
    definite = np.ones(n_samples, bool)
    for key, x in values.items():
        if key.startswith("inertia.") and np.shape(x)[-2:] == (3, 3):
            definite &= np.all(disp.is_positive_definite(x), axis=tuple(range(1, np.ndim(x) - 2)))
    return {**passed, REJECTED["order"]: order, REJECTED["inertia_table"]: definite}


def _wheels_span(mission: Mission, values: dict, n_samples: int) -> np.ndarray:
    """(N,) whether each sample's wheels left after those failed off (``values``' drawn
    wheels, the mission's where not drawn) span 3-D, or the loop never drops them (fdir
    detection "never", which flies the sample unaware, as ``fly`` does)."""
    if mission.fdir["detection"] == "never":
        return np.ones(n_samples, bool)
    axes = np.asarray(mission.actuator["wheels"]["axes"], float)
    off = np.zeros((n_samples, len(axes)), bool)
    for i, fault in enumerate(mission.faults):
        if fault.get("mode") == "off":
            wheel = np.broadcast_to(values.get(f"faults.{i}.wheel", fault["wheel"]), (n_samples,)).astype(int)
            off[np.arange(n_samples), wheel - 1] = True
    return fault_list.spanning(axes, off)


# --- drawing ---------------------------------------------------------------------------------


@functools.partial(jax.jit, static_argnames="n_words")
def _leaf_words(seed, indices, salt, n_words: int):
    base = jax.random.key(seed)
    draw = lambda k: jax.random.bits(jax.random.fold_in(jax.random.fold_in(base, k), salt), (n_words,), jnp.uint32)
    return jax.vmap(draw)(indices)


def draw_leaves(leaves: tuple, seed: int, n_samples: int, first: int = 0) -> tuple[dict, np.ndarray]:
    """({key: values (N, *shape)}, valid (N,)): each leaf's values for samples first ..
    first + N - 1, in float64, and whether every value lies in its parameter's domain and
    within its bound."""
    values, passed = _drawn_leaves(leaves, seed, n_samples, first)
    return values, np.logical_and.reduce(list(passed.values()))


def _drawn_leaves(leaves: tuple, seed: int, n_samples: int, first: int) -> tuple[dict, dict]:
    """(:func:`draw_leaves`' values, {reason: (N,) whether each sample passes}: every value in
    its parameter's domain, every bound kept, every dispersed outage ending after its time
    (:data:`REJECTED`))."""
    values, domain, bound = {}, np.ones(n_samples, bool), np.ones(n_samples, bool)
    order = np.ones(n_samples, bool)
    for leaf in leaves:
        size = int(np.prod(leaf.shape))
        n_words = 2 * INERTIA_VARIATES * (size // 9) if leaf.inertia is not None else 2 * max(size, 1)
        words = np.asarray(_leaf_words(np.uint32(seed), np.arange(first, first + n_samples, dtype=np.uint32),
                                       np.uint32(zlib.crc32(leaf.key.encode())), n_words))
        if leaf.inertia is not None:  # each matrix from its own 11 variates, as inertia.J0's
            nominal = np.reshape(leaf.nominal, (-1, 3, 3))
            variates = disp.draw_variates(words.reshape(n_samples, len(nominal), 2 * INERTIA_VARIATES))
            values[leaf.key] = leaf.inertia.apply(variates, nominal)[0].reshape((n_samples, *leaf.shape))
            continue
        v = disp.draw_variates(words)
        u, z = v.take(max(size, 1))
        x = leaf.dist.sample(u, z)[:, :size].reshape((n_samples, *leaf.shape))
        if leaf.relative is not None:
            nominal = np.reshape(leaf.nominal, leaf.shape)
            x = nominal + x if leaf.relative == "offset" else nominal * x
        values[leaf.key] = x
        domain &= np.all((x >= leaf.low) & (x <= leaf.high), axis=tuple(range(1, x.ndim)))
    for leaf in leaves:
        if leaf.bound is not None:
            bound &= within_bound(leaf.bound, values, n_samples)
        if leaf.order is not None:
            time, nominal_time, end, nominal_end = leaf.order
            order &= (values[end] if end in values else nominal_end[0]) > (
                values[time] if time in values else nominal_time[0])
    return values, {REJECTED["domain"]: domain, REJECTED["bound"]: bound, REJECTED["outage"]: order}


def within_bound(bound: tuple, values: dict, n_samples: int) -> np.ndarray:
    """(N,) whether each sample keeps |parameter| <= limit, element by element (a leaf's
    bound; ``values``: the drawn leaves, the mission's value of the side not drawn)."""
    key, nominal, limit_key, nominal_limit = bound
    x = np.reshape(values[key], (n_samples, -1)) if key in values else np.asarray(nominal)
    limit = np.reshape(values[limit_key], (n_samples, -1)) if limit_key in values else np.asarray(nominal_limit)
    return np.all(np.reshape(np.abs(x) <= limit, (n_samples, -1)), axis=1)


def draw(dispersions: disp.Dispersions, leaves: tuple, seed: int, n_samples: int, max_draws: int,
         first: int = 0, mission: Mission | None = None) -> disp.Samples:
    """Samples first .. first + n_samples - 1 with their dispersed component and scenario
    values (``leaves``); valid: a positive definite inertia within max_draws, an orbit at
    least MIN_ALTITUDE high (:func:`~so3jax.missions.dispersions.in_orbit_domain`), every value in
    its domain and, with dispersed reference or inertia parameters, the sample's reference
    and inertia passing their kind's checks (``mission``: the mission the leaves disperse);
    outside: the samples rejected for a component or scenario value alone; reason: why each
    sample is rejected, the first of :data:`REJECTED` in order it fails ("" where valid)."""
    samples = disp.draw_samples(dispersions, seed, n_samples, max_draws, first)
    values, passed = _drawn_leaves(leaves, seed, n_samples, first)
    strict = mission is not None and bool(build.orbit_users(mission))
    passed = {REJECTED["orbit"]: disp.in_orbit_domain(samples.params.n, strict), **passed}
    if any(leaf.key.split(".")[0] in _SCENARIO_TABLES for leaf in leaves):
        if mission is None:
            raise TypeError("draw: dispersed reference or inertia parameters need the mission (mission=)")
        passed.update(_scenario_checks(mission, values, n_samples))
    if any(leaf.key.startswith("faults.") and leaf.key.endswith(".wheel") for leaf in leaves):
        if mission is None:
            raise TypeError("draw: a dispersed failed wheel needs the mission (mission=)")
        passed[REJECTED["wheels"]] = _wheels_span(mission, values, n_samples)
    reason = np.where(samples.valid, "", REJECTED["draws"]).astype(object)
    for why, ok in passed.items():
        reason[(reason == "") & ~ok] = why
    in_domain = np.logical_and.reduce([np.ones(n_samples, bool), *passed.values()])
    return samples._replace(valid=samples.valid & in_domain, leaves=values, outside=samples.valid & ~in_domain,
                            reason=reason)


def rejections(samples: disp.Samples) -> dict:
    """{reason: samples rejected for it} of the rejected samples (:func:`draw`'s ``reason``;
    without one, their draws), in :data:`REJECTED`'s order."""
    reason = samples.reason if samples.reason is not None else np.where(samples.valid, "", REJECTED["draws"])
    return {why: int(np.sum(reason == why)) for why in REJECTED.values() if np.any(reason == why)}


def inputs(samples: disp.Samples, dtype) -> tuple:
    """(RolloutParams, {leaf: values}) of the samples, reals in dtype: :func:`sample_metrics`' inputs."""
    as_dtype = lambda x: x.astype(dtype) if x.dtype.kind == "f" else x
    return jax.tree.map(as_dtype, samples.params), {k: as_dtype(v) for k, v in samples.leaves.items()}


def input_shapes(leaves: tuple, n_samples: int, dtype) -> tuple:
    """The shapes and dtypes (``jax.ShapeDtypeStruct``) of :func:`inputs` of n_samples
    samples, from the leaves alone: nothing drawn or compiled."""
    def struct(shape, dtype):
        return jax.ShapeDtypeStruct((n_samples, *shape), dtype)

    params = disp.RolloutParams(*(struct(shape, np.int32 if name == "seed" else dtype)
                                  for name, shape in zip(disp.RolloutParams._fields, disp.PARAM_SHAPES)))
    return params, {leaf.key: struct(leaf.shape, dtype) for leaf in leaves}


def samples_bytes(leaves: tuple, n_samples: int, dtype) -> int:
    """Bytes n_samples drawn samples hold: their values in float64 (:func:`draw`) and as
    a run's inputs in ``dtype`` (:func:`inputs`)."""
    return sum(memory.nbytes(input_shapes(leaves, n_samples, d)) for d in (np.float64, dtype))


# --- a sample's scenario and loop ------------------------------------------------------------


def sample_metrics(inputs, gains, *, controller, mission: Mission, record_every: int | None = None,
                   estimator=None, pointing: bool = False) -> dict:
    """{metric: values} of a batch of samples of ``mission`` (hashable by its fingerprint: a
    static argument of jit) flown by ``controller`` at ``gains``: the docs/model.md §6 metrics, and the
    flight metrics of a sampled loop. inputs = (RolloutParams, {dispersed component
    parameter: values}), leading batch axis. The samples share the mission's loop and run
    natively batched (:func:`so3jax.sim.rollout.rollout_batch`, the values of a vmap of
    rollouts); with dispersed component parameters, each sample flies its own loop (the
    components' parameters with a batch axis). record_every: the rollouts' checkpoint blocks [steps] (reverse-mode
    memory; the horizon's steps: none). estimator: {parameter: value} of the mission's
    estimator that every sample shares (the noise levels the filter assumes, tuned).
    pointing: also the attitude errors at the start of every block of ``record_every``
    steps, ``pointing_performance`` e_P and, where the loop estimates the attitude,
    ``pointing_knowledge`` e_K ((batch, M, 3) rad, :func:`pointing_errors`).
    Pure: jit, grad and :func:`so3jax.parallel.devices.split` compose with it."""
    params, leaves = inputs
    m, dtype = mission, params.J0.dtype
    shared = {f"estimator.{m.estimator['kind']}.{k}": v for k, v in (estimator or {}).items()}
    own, leaves = split(leaves)
    scenarios = jax.vmap(lambda p, v: build.scenario(scenario_values(m, v), p))(params, own)  # own: its own
    dispersed_tables = {k.split(".")[0] for k in own}
    shared_parts = [name for name, shared_part in (
        ("reference", "reference" not in dispersed_tables  # a constant rate depends on the sample's orbit rate
         and not isinstance(scenarios.reference, PiecewiseConstantRate)),
        ("inertia", "inertia" not in dispersed_tables and m.inertia["kind"] != "paper"),  # the paper's: per sample
    ) if shared_part]
    axes = 0
    if shared_parts:  # one for the batch: the mission's own
        nominal = build.scenario(m, dtype=dtype)
        scenarios = dataclasses.replace(scenarios, **{name: getattr(nominal, name) for name in shared_parts})
        axes = dataclasses.replace(jax.tree.map(lambda _: 0, scenarios), **dict.fromkeys(shared_parts))
    if leaves:  # each sample's loop: its components' parameters with a batch axis
        loops, loop_axes = jax.vmap(lambda values: loop(m, {**shared, **values}, dtype))(leaves), 0
    else:
        loops, loop_axes = (loop(m, shared, dtype) if shared else m.loop(dtype)), None
    return _results(rollout_batch(scenarios, controller, gains, params.seed, scenario_axes=axes, loop=loops,
                                  loop_axes=loop_axes, record_every=record_every), pointing)


def _results(result, pointing: bool = False) -> dict:
    """A rollout's docs/model.md §6 metrics and, in the sampled wiring, its flight metrics, by
    name; with ``pointing``, its recorded attitude errors (:func:`pointing_errors`)."""
    flight = {} if result.flight is None else result.flight._asdict()
    return {**result.metrics._asdict(), **flight, **(pointing_errors(result.history) if pointing else {})}


def pointing_errors(history) -> dict:
    """{"pointing_performance": e_P, "pointing_knowledge": e_K (where the history holds an
    estimate)}: log(R_ref^T R)^vee [rad] of the recorded attitudes R (M, 3, 3) against R_d and
    R_hat, (..., M, 3) of records (..., M, 3, 3), in the run's precision (the signals of
    :mod:`so3jax.sim.pointing`)."""
    def error(R_ref):
        R_e = jnp.einsum("...mji,...mjk->ik...m", R_ref, history.R)  # R_ref^T R, (3, 3, ..., M)
        return jnp.moveaxis(so3.log(R_e, select=True), 0, -1)

    out = {"pointing_performance": error(history.R_d)}
    if history.R_hat is not None:
        out["pointing_knowledge"] = error(history.R_hat)
    return out


def loop(mission: Mission, values: dict, dtype):
    """The mission's loop with component and fault leaves {key: value} replaced (traceable);
    the estimator assumes the nominal sensors' noise levels."""
    faults = [dict(f) for f in mission.faults]
    tables = {"sensors": {k: dict(v) for k, v in mission.sensors.items()},
              **{table: {k: (dict(v) if isinstance(v, dict) else v) for k, v in getattr(mission, table).items()}
                 for table in ("estimator", "actuator", "momentum")}}
    for key, value in values.items():
        table, name, param = key.split(".")
        if table == "faults":
            faults[int(name)][param] = value
        else:
            tables[table][name][param] = value
    changed = dataclasses.replace(mission, **tables, faults=tuple(faults))
    return build_loop(changed, lambda x: jnp.asarray(x, dtype), noise_of=mission)
