"""The mission's inertia kinds (``[inertia] kind``, docs/model.md §4): registrations of the
inertia profiles J(t) [kg m^2], each with its parameters.

* ``paper``: the paper's profile (``[inertia]`` J0, J1, J2 and ``[deployment] tau_J``, switching
  at the paper's phases), or a constant inertia (``[inertia] J``);
* ``events``: from an initial inertia, events at given times, each a step or a first-order
  blend to a new inertia or to a scale of the inertia at the event
  (:func:`so3jax.dynamics.inertia_timelines.events`): the paper's deployment and docking
  are two;
* ``linear``: a linear change between two times (fuel use), held before and after;
* ``table``: a tabulated history (times and inertias, inline or from a file), linear
  between samples (:func:`so3jax.dynamics.inertia_timelines.table`).

Every kind runs in the natively batched loop; ``events`` and ``linear`` switch on time, not on
the mission's phases.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.components import registry as components
from so3jax.core import checks
from so3jax.core.params import Param
from so3jax.dynamics import inertia_timelines as timelines
from so3jax.dynamics.inertia import check_inertia
from so3jax.dynamics.plant import PaperInertia


class InertiaContext(NamedTuple):
    """What an inertia's builder may read: as_array(x) casts to the run's dtype; the
    profile of the mission's ``[inertia]`` J0, J1, J2 (or J) keys."""

    as_array: Callable[[Any], Any]
    paper: Any


@dataclasses.dataclass(frozen=True)
class Targets(Param):
    """A list whose entries are each a (3, 3) matrix [kg m^2] or a positive number (a scale)."""

    def parse(self, value, where: str):
        if not isinstance(value, (list, tuple)) or not value:
            raise ValueError(f"{where} must be a list of inertias [kg m^2] or scales, got {checks.short(value)}")
        out = tuple(checks.number(v, f"{where}[{i}] (a scale)") if not isinstance(v, (list, tuple))
                    else checks.array(v, f"{where}[{i}] [kg m^2]", (3, 3)) for i, v in enumerate(value))
        bad = [i for i, v in enumerate(out) if np.ndim(v) == 0 and not v > 0]
        if bad:
            raise ValueError(f"{where}[{bad[0]}]: a scale must be positive, got {out[bad[0]]}")
        return out

    def domain(self) -> str:
        return "each a (3, 3) matrix or a scale > 0"


def _events_values(values: dict) -> dict:
    """The events given, as many times, targets and time constants; adds ``scales`` (K,)
    and ``matrices`` (K, 3, 3) (a scale's entry 0, a matrix's scale 0)."""
    missing = [name for name in ("initial", "times", "targets") if values.get(name) is None]
    if missing:
        raise ValueError(f"inertia.events: give {missing[0]} (initial, times, targets; time_constants: 0 = steps)")
    times, targets = np.asarray(values["times"], np.float64), values["targets"]
    taus = np.zeros_like(times) if values.get("time_constants") is None else values["time_constants"]
    if not (len(times) == len(targets) == len(taus)):
        raise ValueError(f"inertia.events: {len(times)} times, {len(targets)} targets and {len(taus)} time "
                         "constants: one of each per event")
    if np.any(np.diff(times) <= 0):
        raise ValueError(f"inertia.events.times [s] must increase, got {times.tolist()}")
    check_inertia("inertia.events.initial", values["initial"], warn=False)
    for i, target in enumerate(targets):
        if np.ndim(target):
            check_inertia(f"inertia.events.targets[{i}]", target, warn=False)
    scales = np.array([0.0 if np.ndim(t) else float(t) for t in targets])
    matrices = np.stack([np.asarray(t, np.float64) if np.ndim(t) else np.zeros((3, 3)) for t in targets])
    return {**values, "time_constants": np.asarray(taus, np.float64), "scales": scales, "matrices": matrices}


def _events(values: dict, ctx: InertiaContext):
    a = ctx.as_array
    return timelines.events(a(values["initial"]), a(values["times"]), a(values["matrices"]), a(values["scales"]),
                            a(values["time_constants"]))


def _linear_values(values: dict) -> dict:
    missing = [name for name in ("start", "end", "times") if values.get(name) is None]
    if missing:
        raise ValueError(f"inertia.linear: give {missing[0]} (start and end inertias, times [t_start, t_end])")
    if not values["times"][1] > values["times"][0]:
        raise ValueError("inertia.linear.times [s]: the change must end after it starts, "
                         f"got {values['times'].tolist()}")
    return values


def _table(times, inertias, as_array):
    """An inertia table: checked where concrete (:func:`~so3jax.dynamics.inertia_timelines.table`),
    built as it is where traced (a sweep's samples, checked where they are drawn)."""
    if any(isinstance(x, jax.core.Tracer) for x in (times, inertias)):
        return timelines.InertiaTable(as_array(times), as_array(inertias))
    return timelines.table(as_array(times), as_array(inertias))


def _linear(values: dict, as_array):
    """The linear change's table of two samples."""
    ends = (values["start"], values["end"])
    stack = jnp.stack if any(isinstance(x, jax.core.Tracer) for x in ends) else np.stack
    return _table(values["times"], stack(ends), as_array)


def _table_values(values: dict) -> dict:
    """The table's samples: from ``file`` or inline ``times`` and ``inertias``, one of the two."""
    inline = values.get("times") is not None or values.get("inertias") is not None
    if (values.get("file") is not None) == inline:
        raise ValueError("inertia.table: give file, or times and inertias, one of the two")
    try:
        if values.get("file") is not None:
            times, inertias = timelines.read_inertia_table(values["file"])
        else:
            times, inertias = values.get("times"), values.get("inertias")
            if times is None or inertias is None:
                raise ValueError("give both times and inertias")
        timelines.table(times, inertias)
    except ValueError as error:
        raise ValueError(f"inertia.table: {error}") from None
    return {**values, "times": np.asarray(times, np.float64), "inertias": np.asarray(inertias, np.float64)}


components.register(components.ComponentSpec(
    kind="inertia", name="paper", component=PaperInertia, params=(),
    build=lambda v, ctx: ctx.paper,
    doc="the paper's J0 -> J1 -> J2 of [inertia] J0, J1, J2 and [deployment] tau_J at the paper's phases "
        "(docs/model.md §4), or [inertia] J throughout",
))
components.register(components.ComponentSpec(
    kind="inertia", name="events", component=timelines.InertiaEvents,
    params=(
        Param("initial", None, "kg m^2", shapes=((3, 3),), doc="J before the first event"),
        Param("times", None, "s", shapes=((None,),), low=0.0, doc="each event's time, increasing"),
        Targets("targets", None, "kg m^2", shapes=((None,),),
                doc="each event's inertia, or a number: a scale of the inertia at the event"),
        Param("time_constants", None, "s", shapes=((None,),), low=0.0,
              doc="each event's first-order time constant; 0: a step (the default)"),
    ),
    complete=_events_values,
    build=_events,
    doc="events at given times: J blends toward each event's inertia with its time constant (0: a step)",
))
components.register(components.ComponentSpec(
    kind="inertia", name="linear", component=timelines.InertiaTable,
    params=(
        Param("start", None, "kg m^2", shapes=((3, 3),), doc="J until times[0]"),
        Param("end", None, "kg m^2", shapes=((3, 3),), doc="J from times[1]"),
        Param("times", None, "s", shapes=((2,),), doc="the change's start and end"),
    ),
    complete=_linear_values,
    build=lambda v, ctx: _linear(v, ctx.as_array),
    doc="a linear change from start to end between two times (e.g. fuel use), held outside",
))
components.register(components.ComponentSpec(
    kind="inertia", name="table", component=timelines.InertiaTable,
    params=(
        Param("file", None, text=True, doc="a CSV (header t, Jxx, Jyy, Jzz, Jxy, Jxz, Jyz) or .npz (t, J), "
                                           "relative to the mission file"),
        Param("times", None, "s", shapes=((None,),), doc="the samples' times, increasing (instead of file)"),
        Param("inertias", None, "kg m^2", shapes=((None, 3, 3),), doc="the samples' inertias"),
    ),
    complete=_table_values,
    build=lambda v, ctx: _table(v["times"], v["inertias"], ctx.as_array),
    doc="a tabulated inertia history, linear between samples, held outside",
))
