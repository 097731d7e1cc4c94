"""A mission's gain schedules (docs/model.md §10.5): the ``[schedule]`` table, one entry per
scheduled controller, ``NAME = { by = "phase" }`` (one set of gains per phase of
``[phases]``) or ``NAME = { by = "time", at = [t_0, ..., t_{n-1}] }`` (breakpoints [s], the
gains interpolated linearly between them); and a scheduled law's ``[gains.NAME]``, each gain
a list of one value per phase or breakpoint, or a single number for all of them."""

from __future__ import annotations

import numpy as np

from so3jax.controllers import registry
from so3jax.controllers.scheduled import BY, check_scheduled_gains, checked_knots, schedule_gains
from so3jax.core import checks


def parse(table, controllers: tuple) -> dict:
    """{controller: {"by": "phase"} or {"by": "time", "at": breakpoints [s]}} of the
    ``[schedule]`` table (a phase schedule switches at the mission's [phases] start times).
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
    entry = checks.table({name: entry}, name, ("by", "at"), "schedule.")
    by = checks.choice(entry.get("by"), f"{where}.by", BY)
    if by == "time":
        if "at" not in entry:
            raise ValueError(f"{where}.at: a schedule by \"time\" needs its breakpoints [s]")
        return {"by": by, "at": checked_knots(entry["at"], f"{where}.at")}
    if "at" in entry:
        raise ValueError(f"{where}.at: a schedule by \"phase\" switches at the phases' start times "
                         "(phases.start); breakpoints need by = \"time\"")
    return {"by": by}


def knots(entry: dict, phases: dict) -> tuple:
    """The schedule's knots [s]: the phases' start times (by phase) or its breakpoints."""
    return tuple(phases["start"]) if entry["by"] == "phase" else tuple(entry["at"])


def labels(entry: dict, phases: dict) -> tuple:
    """A name per knot for messages: the phases' names, or "t = T s" per breakpoint."""
    return tuple(phases["names"]) if entry["by"] == "phase" else tuple(f"t = {t:g} s" for t in entry["at"])


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
