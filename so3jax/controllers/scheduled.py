"""Gain schedules (docs/model.md §10.5): any law's gains, one set per phase of the mission or
interpolated linearly between breakpoints of a scheduling variable: the time, or a moment of
the inertia the mission declares at that time.

:class:`Scheduled` wraps a law: its gains are the law's gains NamedTuple with a leading axis
of one entry per knot (k_R (n,), a diagonal Gamma (n, 9)), and at time t it hands the law
the gains of that time:

* ``by="phase"``: knots t_0 < ... < t_{n-1} are the phases' start times [s]; the gains of
  phase i = #{j : t_j <= t} - 1 (0 before t_0), selected by indexing;
* ``by="time"``: knots are breakpoint times [s]; each gain interpolated linearly in t between
  them and held at the first (last) value before (after) them, as ``jnp.interp``;
* ``by="inertia"``: the same over x = ``variable(t)`` [kg m^2], knots breakpoints of x
  (``variable``: a hashable callable, e.g. the declared inertia's mean principal moment,
  :class:`so3jax.missions.schedule.DeclaredInertia`).

Equal gains in every phase give the unscheduled law's values bit for bit in both modes.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.controllers import registry
from so3jax.controllers.base import Controller

BY = ("phase", "time", "inertia")


@dataclasses.dataclass(frozen=True)
class Scheduled(Controller):
    """``inner``'s gains scheduled ``by`` "phase", "time" or "inertia" over ``knots`` (phase
    start times or breakpoints [s], or breakpoints of ``variable(t)``, increasing): module
    docstring. Hashable and equal by value."""

    inner: Controller
    by: str
    knots: tuple
    variable: object = None  # by "inertia": t [s] -> the scheduling variable (hashable, equal by value)

    gain_axes = 1  # the schedule's axis, before each gain's own

    def __post_init__(self):
        if not isinstance(self.inner, Controller):
            raise TypeError(f"Scheduled wraps a so3jax Controller, got {type(self.inner).__name__}")
        if self.by not in BY:
            raise ValueError(f"a schedule is by {', '.join(BY)}, got {self.by!r}")
        if (self.by == "inertia") != (self.variable is not None):
            raise ValueError("a schedule by \"inertia\", and only it, needs its variable")
        object.__setattr__(self, "knots", checked_knots(self.knots, "knots", "kg m^2" if self.variable else "s"))

    @property
    def gains_type(self):
        return self.inner.gains_type

    @property
    def update(self):
        """The inner law's tick update at the gains of the tick's time; None where it has none."""
        return None if self.inner.update is None else self.scheduled_update

    def at(self, gains, t):
        """The inner law's gains at time t [s] (a scalar): each field without its leading axis."""
        t = jnp.asarray(t)
        x = t if self.variable is None else self.variable(t)
        knots = jnp.asarray(self.knots, jnp.result_type(x, float))
        count = jnp.sum(knots <= x)
        if self.by == "phase" or len(self.knots) == 1:
            i = jnp.maximum(count - 1, 0)
            return jax.tree.map(lambda g: jnp.asarray(g)[i], gains)
        i = jnp.clip(count - 1, 0, len(self.knots) - 2)
        w = jnp.clip((x - knots[i]) / (knots[i + 1] - knots[i]), 0.0, 1.0)

        def interpolated(g):
            g = jnp.asarray(g)
            low, high = g[i], g[i + 1]
            return low + w.astype(g.dtype) * (high - low)

        return jax.tree.map(interpolated, gains)

    def init(self, gains):
        return self.inner.init(self.at(gains, 0.0))

    def torque(self, gains, state, feedback, desired, t):
        return self.inner.torque(self.at(gains, t), state, feedback, desired, t)

    def scheduled_update(self, gains, state, feedback, desired, t, period):
        return self.inner.update(self.at(gains, t), state, feedback, desired, t, period)


def checked_knots(knots, where: str, unit: str = "s") -> tuple:
    """knots [unit] as a tuple of floats: at least one, finite, strictly increasing; a one-line
    ValueError naming ``where`` otherwise."""
    try:
        values = tuple(float(k) for k in np.asarray(knots, dtype=float).reshape(-1))
        flat = np.ndim(knots) == 1
    except (TypeError, ValueError):
        values, flat = (), False
    if not flat or not values:
        raise ValueError(f"{where} [{unit}] must be a non-empty list of numbers, got {knots!r}")
    if not all(math.isfinite(k) for k in values) or any(b <= a for a, b in zip(values[:-1], values[1:])):
        raise ValueError(f"{where} [{unit}] must be finite and increasing, got {list(values)}")
    return values


def schedule_gains(gains, n: int):
    """gains with every field broadcast to a leading axis of n (the same gains in every
    phase or at every breakpoint)."""
    return jax.tree.map(lambda g: jnp.broadcast_to(jnp.asarray(g), (n,) + jnp.shape(g)), gains)


def gains_slice(gains, i: int):
    """The gains of phase or breakpoint i of scheduled gains."""
    return jax.tree.map(lambda g: g[i], gains)


def check_scheduled_gains(controller: str, gains, n: int, labels=None) -> None:
    """Scheduled gains of registered ``controller``: every field a leading axis of n and,
    after it, a shape its registration allows; each slice passes its registered check.
    labels: a name per slice for the messages (phase names, breakpoint times)."""
    spec = registry.get(controller)
    labels = tuple(labels) if labels is not None else tuple(str(i) for i in range(n))
    allowed = spec.gain_shapes()
    for field, value in gains._asdict().items():
        shape = np.shape(value)
        if not shape or shape[0] != n or tuple(shape[1:]) not in {tuple(s) for s in allowed[field]}:
            kinds = " or ".join(str((n, *s)) for s in allowed[field])
            raise ValueError(f"scheduled gain {field} must have shape {kinds} (one value per each of {n}), "
                             f"got {shape}")
    for i in range(n):
        try:
            spec.check(gains_slice(gains, i))
        except (TypeError, ValueError) as err:
            raise ValueError(f"{labels[i]}: {err}") from None
