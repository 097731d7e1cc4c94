"""Inertia timelines J(t) [kg m^2] beyond the paper's profile (docs/model.md §4): a sequence
of events, each a step or a first-order blend to a new inertia, and a table interpolated
linearly between its samples (a linear change, e.g. fuel use, is a table of two).

Both are :class:`~so3jax.dynamics.plant.InertiaProfile` pytrees that ignore ``phase``: they
switch on time, so an event's time (traced in a sweep) needs no phase of its own. Every
J(t) lies on a segment between two matrices the profile lists in :meth:`matrices` (a blend
between an event's start and its target, a table's two neighbouring samples): symmetric
positive definite matrices, and those meeting the triangle inequality, form convex sets,
so checking the listed matrices checks every J(t) (``convex_phases``). As every profile's,
:meth:`matrices` are the profile's matrix fields by name: J(t) is linear in them (a profile
scaled by s is them scaled by s, :func:`so3jax.sim.gradients.scale_inertia`). J' is the
forward-mode derivative of J(t) (:func:`so3jax.dynamics.plant.inertia_rate`): exact,
0 across a step.
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.core import tables
from so3jax.core.pytree import pytree_dataclass
from so3jax.dynamics.inertia import check_inertia
from so3jax.dynamics.plant import InertiaProfile

TABLE_COLUMNS = ("t", "Jxx", "Jyy", "Jzz", "Jxy", "Jxz", "Jyz")  # a CSV inertia table's columns


@pytree_dataclass
class InertiaEvents(InertiaProfile):
    """J(t) = initial before times[0]; from times[k] (until the next event),

        J(t) = targets[k] - (targets[k] - starts[k]) exp(-(t - times[k]) / time_constants[k]),

    starts[k] = J(times[k]) just before the event (a blend need not have finished), and
    J(t) = targets[k] from times[k] for a step (time_constant 0). Build with :func:`events`.
    Leaves may carry a trailing batch axis (a natively batched rollout)."""

    initial: jax.Array  # (3, 3)
    times: jax.Array  # (K,) s, increasing
    targets: jax.Array  # (K, 3, 3)
    starts: jax.Array  # (K, 3, 3)
    time_constants: jax.Array  # (K,) s, 0: a step
    convex_phases = True

    def __call__(self, t, phase):
        return self.in_step(t, phase, t)

    def in_step(self, t, phase, midpoint):
        """J at time t [s] within the integration step whose midpoint is ``midpoint`` [s]
        (:func:`~so3jax.dynamics.plant.stage_inertia`): a step from that step on when its
        time is at most the midpoint, a blend from its time on."""
        J = self.initial
        for k in range(self.times.shape[0]):
            switch = jnp.where(self.time_constants[k] <= 0, midpoint, t)
            J = jnp.where(switch >= self.times[k], self._event(k, t), J)
        return J

    def _event(self, k, t):
        tau = self.time_constants[k]
        step = tau <= 0
        since = jnp.where(t >= self.times[k], t - self.times[k], 0.0)  # J' from the event's time on
        decay = jnp.exp(-since / jnp.where(step, 1.0, tau))
        return self.targets[k] - (self.targets[k] - self.starts[k]) * jnp.where(step, 0.0, decay)

    def check(self):
        """Times finite and increasing, time constants finite and >= 0 (ValueError), where concrete."""
        if any(isinstance(x, jax.core.Tracer) for x in (self.times, self.time_constants)):
            return
        times, taus = np.asarray(self.times, np.float64), np.asarray(self.time_constants, np.float64)
        if not np.all(np.isfinite(times)) or np.any(np.diff(times, axis=0) <= 0):
            raise ValueError(f"inertia events: times [s] must be finite and increasing, got {times.tolist()}")
        if not np.all(np.isfinite(taus) & (taus >= 0)):
            raise ValueError(f"inertia events: time constants [s] must be finite and >= 0, got {taus.tolist()}")

    def matrices(self):
        return {"initial": self.initial, "targets": self.targets, "starts": self.starts}


def events(initial, times, targets, scales, time_constants) -> InertiaEvents:
    """The events' profile: at times[k] [s], J blends toward targets[k] [kg m^2], or where
    scales[k] > 0 toward scales[k] J(times[k]) (a scale of the inertia at the event), with
    time constant time_constants[k] [s] (0: a step). targets (K, 3, 3) (ignored where
    scales[k] > 0), scales (K,). Traceable (a sweep's sample times and inertias)."""
    initial, times, targets, scales, taus = (jnp.asarray(x) for x in (initial, times, targets, scales, time_constants))
    profile = InertiaEvents(initial, times[:0], targets[:0], targets[:0], taus[:0])
    starts, goals = [], []
    for k in range(times.shape[0]):
        start = profile(times[k], 0) if k else initial
        goals.append(jnp.where(scales[k] > 0, scales[k] * start, targets[k]))
        starts.append(start)
        profile = InertiaEvents(initial, times[:k + 1], jnp.stack(goals), jnp.stack(starts), taus[:k + 1])
    return profile


@pytree_dataclass
class InertiaTable(InertiaProfile):
    """J(t) interpolated linearly between samples (times[i], inertias[i]), held at the first
    before times[0] and at the last after times[-1]; J' piecewise constant. Build with
    :func:`table`. Leaves may carry a trailing batch axis (a sweep's samples' own tables,
    evaluated lane by lane)."""

    times: jax.Array  # (K,) s, increasing, K >= 2
    inertias: jax.Array  # (K, 3, 3)
    convex_phases = True

    def __call__(self, t, phase):
        if jnp.ndim(self.times) > 1 or jnp.ndim(self.inertias) > 3:  # per trajectory: batch axis last
            axes = InertiaTable(-1 if jnp.ndim(self.times) > 1 else None, -1 if jnp.ndim(self.inertias) > 3 else None)
            return jax.vmap(lambda table: table(t, phase), in_axes=(axes,), out_axes=-1)(self)
        t = jnp.asarray(t, self.times.dtype)
        i = jnp.clip(jnp.searchsorted(self.times, t, side="right") - 1, 0, self.times.shape[0] - 2)
        t0, t1 = self.times[i], self.times[i + 1]
        fraction = jnp.where(t < t0, 0.0, jnp.where(t >= t1, 1.0, (t - t0) / (t1 - t0)))  # J' from t on
        return self.inertias[i] + (self.inertias[i + 1] - self.inertias[i]) * fraction

    def matrices(self):
        return {"inertias": self.inertias}


def table(times, inertias) -> InertiaTable:
    """The table's profile; one-line ValueError unless times (K,) [s] are finite and
    increasing (K >= 2) and inertias (K, 3, 3) [kg m^2] are finite."""
    t, J = np.asarray(times, np.float64), np.asarray(inertias, np.float64)
    if t.ndim != 1 or t.shape[0] < 2 or J.shape != (t.shape[0], 3, 3):
        raise ValueError(f"an inertia table needs times (K,) and inertias (K, 3, 3), K >= 2; "
                         f"got shapes {t.shape} and {J.shape}")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        bad = int(np.flatnonzero(~np.isfinite(t) | np.append(np.diff(t) <= 0, False))[0])
        raise ValueError(f"inertia table: times [s] must be finite and increasing, row {bad + 1} "
                         f"(t = {t[bad]:g} s) is not before the next")
    if not np.all(np.isfinite(J)):
        raise ValueError("inertia table: non-finite inertia entries")
    try:
        check_inertia("table", J, warn=False)
    except ValueError:
        for i, (ti, Ji) in enumerate(zip(t, J)):
            check_inertia(f"table row {i + 1} (t = {ti:g} s)", Ji, warn=False)
    return InertiaTable(jnp.asarray(times), jnp.asarray(inertias))


def read_inertia_table(path) -> tuple[np.ndarray, np.ndarray]:
    """(times (K,) [s], inertias (K, 3, 3) [kg m^2]), float64, from a CSV file (a header line
    naming the columns of :data:`TABLE_COLUMNS`, in any order) or a .npz file (arrays t (K,)
    and J (K, 3, 3))."""
    path = Path(path)
    if path.suffix == ".npz":
        return tables.read_npz_arrays(path, {"t": "(K,)", "J": "(K, 3, 3)"})
    columns = tables.read_csv_columns(path, TABLE_COLUMNS)
    xx, yy, zz, xy, xz, yz = (columns[name] for name in TABLE_COLUMNS[1:])
    J = np.stack([np.stack([xx, xy, xz], -1), np.stack([xy, yy, yz], -1), np.stack([xz, yz, zz], -1)], -2)
    return columns["t"], J
