"""A mission's gain schedules (docs/model.md §10.5): the ``[schedule]`` table, one entry per
scheduled controller, ``NAME = { by = "phase" }`` (one set of gains per phase of
``[phases]``), ``NAME = { by = "time", at = [t_0, ..., t_{n-1}] }`` (breakpoints [s], the
gains interpolated linearly between them) or ``NAME = { by = "inertia", at = [...], of =
"mean" }`` (breakpoints [kg m^2] of a moment of the inertia the mission declares at t:
:class:`DeclaredInertia`); and a scheduled law's ``[gains.NAME]``, each gain a list of one
value per phase or breakpoint, or a single number for all of them."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.controllers import registry
from so3jax.controllers.scheduled import BY, check_scheduled_gains, checked_knots, schedule_gains
from so3jax.core import checks
from so3jax.dynamics.plant import stage_inertia

ENTRY_KEYS = ("by", "at", "of")  # the keys of a [schedule] entry
MOMENTS = ("mean", "Jxx", "Jyy", "Jzz")  # an inertia schedule's variable: tr(J) / 3 or a diagonal entry [kg m^2]


@dataclasses.dataclass(frozen=True)
class DeclaredInertia:
    """x(t) [kg m^2]: the moment ``of`` (:data:`MOMENTS`) of the inertia J(t) the mission
    declares (its nominal profile, what flight software is told: a dispersed sample's true
    inertia does not enter), as the loop's records show it (the step's first stage, phase
    of its midpoint). The profile is held as plain numbers: hashable, equal by value."""

    leaves: tuple  # the profile's leaves, each (shape, values)
    treedef: object
    phase_times: tuple  # the phases after the first [s]
    dt: float
    of: str

    @classmethod
    def of_mission(cls, mission, of: str):
        scenario = mission.scenario()
        leaves, treedef = jax.tree.flatten(scenario.inertia)
        held = tuple((np.shape(x), tuple(np.asarray(x, float).ravel().tolist())) for x in leaves)
        return cls(held, treedef, tuple(scenario.phase_times), float(scenario.dt), of)

    def __call__(self, t):
        dtype = jnp.result_type(t, float)
        profile = jax.tree.unflatten(self.treedef, [jnp.asarray(v, dtype).reshape(shape) for shape, v in self.leaves])
        midpoint = t + 0.5 * jnp.asarray(self.dt, dtype)
        phase = sum((midpoint >= T).astype(jnp.int32) for T in self.phase_times) if self.phase_times else 0
        J = stage_inertia(profile, t, phase, midpoint)
        return jnp.trace(J) / 3.0 if self.of == "mean" else J[(MOMENTS.index(self.of) - 1,) * 2]


def parse(table, controllers: tuple) -> dict:
    """{controller: {"by": "phase"}, {"by": "time", "at": breakpoints [s]} or {"by":
    "inertia", "at": breakpoints [kg m^2], "of": moment}} of the ``[schedule]`` table (a
    phase schedule switches at the mission's [phases] start times).
    One-line ValueError naming the key on bad input."""
    if not isinstance(table, dict):
        raise ValueError(f"[schedule] must be a table, got {checks.short(table)}")  # noqa: TRY004 (bad input)
    return {name: _entry(name, entry, controllers) for name, entry in table.items()}


def _entry(name: str, entry, controllers: tuple) -> dict:
    where = f"schedule.{name}"
    if name not in controllers:
        raise ValueError(f"{where}: the mission flies no {name!r} controller (controllers: {', '.join(controllers)})")
    if not registry.get(name).tunable:
        raise ValueError(f"{where}: the {name} law has no gains to schedule")
    entry = checks.table({name: entry}, name, ENTRY_KEYS, "schedule.")
    by = checks.choice(entry.get("by"), f"{where}.by", BY)
    if "of" in entry and by != "inertia":
        raise ValueError(f"{where}.of: names the moment of a schedule by \"inertia\"; this one is by {by!r}")
    if by in ("time", "inertia"):
        unit = "s" if by == "time" else "kg m^2"
        if "at" not in entry:
            raise ValueError(f"{where}.at: a schedule by \"{by}\" needs its breakpoints [{unit}]")
        out = {"by": by, "at": checked_knots(entry["at"], f"{where}.at", unit)}
        if by == "inertia":
            if out["at"][0] <= 0:
                raise ValueError(f"{where}.at: breakpoints of an inertia [kg m^2] are > 0, got {list(out['at'])}")
            out["of"] = checks.choice(entry.get("of", "mean"), f"{where}.of", MOMENTS)
        return out
    if "at" in entry:
        raise ValueError(f"{where}.at: a schedule by \"phase\" switches at the phases' start times "
                         "(phases.start); breakpoints need by = \"time\"")
    return {"by": by}


def knots(entry: dict, phases: dict) -> tuple:
    """The schedule's knots [s]: the phases' start times (by phase) or its breakpoints."""
    return tuple(phases["start"]) if entry["by"] == "phase" else tuple(entry["at"])


def variable(entry: dict, mission):
    """The schedule's variable t -> x: a :class:`DeclaredInertia` by inertia, else None (t)."""
    return DeclaredInertia.of_mission(mission, entry["of"]) if entry["by"] == "inertia" else None


def labels(entry: dict, phases: dict) -> tuple:
    """A name per knot for messages: the phases' names, or "t = T s" (J = x kg m^2) per breakpoint."""
    if entry["by"] == "phase":
        return tuple(phases["names"])
    if entry["by"] == "inertia":
        return tuple(f"{entry['of']} J = {x:g} kg m^2" for x in entry["at"])
    return tuple(f"t = {t:g} s" for t in entry["at"])


def scheduled_gains(controller: str, given, entry: dict, phases: dict, where: str):
    """The gains of ``controller`` scheduled by ``entry`` (:func:`parse`; phases: the
    mission's), each field with a leading axis of one entry per knot: its defaults at every
    knot, with the entries of the table ``given``, each a list of one value per phase (per
    breakpoint) or a single number for all. One-line ValueError naming ``where``'s key."""
    spec = registry.get(controller)
    names = labels(entry, phases)
    n = len(names)
    if not isinstance(given, dict):
        raise ValueError(f"[{where}] must be a table, got {checks.short(given)}")  # noqa: TRY004 (bad input)
    each = "phase" if entry["by"] == "phase" else "breakpoint"
    for field, value in given.items():
        if isinstance(value, (list, tuple, np.ndarray)) and len(value) != n:
            raise ValueError(f"{where}.{field}: one value per {each} ({n}: {', '.join(names)}) or a single "
                             f"number for all, got {len(value)} values")
    allowed = spec.gain_shapes()
    shapes = {f: ((),) * (() in allowed[f]) + tuple((n, *s) for s in allowed[f]) for f in allowed}
    defaults = spec.gains_type(*(np.asarray(g, dtype=float) for g in schedule_gains(spec.defaults, n)))
    g = checks.gains(given, defaults, shapes, where)
    g = type(g)(*(_per_knot(value, n) for value in g))
    try:
        check_scheduled_gains(controller, g, n, names)
    except (TypeError, ValueError) as err:
        raise ValueError(f"[{where}]: {err}") from None
    return g


def _per_knot(value, n: int) -> np.ndarray:
    """A gain as a float array with the schedule's leading axis (a number: the same at every knot)."""
    a = np.asarray(value, dtype=float)
    return np.array(np.broadcast_to(a, (n,))) if a.ndim == 0 else a
