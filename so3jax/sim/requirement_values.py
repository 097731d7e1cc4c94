"""A pointing requirement's value (:mod:`so3jax.sim.pointing`) on traced signals, differentiable:
a tuner's goal or constraint on the attitude errors of a batch of rollouts (docs/model.md §18.4).

:func:`plan` fixes with NumPy everything about one requirement on one time grid that does not
depend on the signal: the samples of the evaluation period, each whole window's samples, the
drift's separation in windows, the quantile's rank. :func:`value` then reads the signal
e (S, M, 3) [rad] with ``jax.numpy`` only: the same index (18.2), magnitudes and statistic as
``pointing.evaluate(requirement, t, e, phase_bounds, diverged_worst=True).value`` [arcsec].

Derivatives (almost everywhere, (18.3)): the empirical quantile x_(k) is an order statistic,
taken by sorting, and passes its selected sample's derivative; the maximum over runs
(temporal), over times (ensemble) and over x, y, z (axis "each") passes the maximizing
element's. The angle is a safe norm (a zero gradient at v = 0). A sample that is not finite
(a diverged run) counts as +inf and passes no derivative.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.core import so3
from so3jax.sim import pointing


@dataclass(frozen=True)
class Plan:
    """The static part of one requirement on one time grid (hashable: a static argument of jax.jit).

    The index's vector samples are taken from e[:, start:stop] where those are contiguous
    (``take`` None), else from e[:, take]; windows: ``length`` samples each, contiguous and in
    order, where ``segments`` is None, else sample i in window segments[i], window j holding
    counts[j] samples."""

    kind: str  # "A" absolute, "M" mean, "R" relative, "D" drift
    columns: tuple  # of (x, y, z, angle): the axis's, (0, 1, 2) for "each"
    interpretation: str
    level: float  # P_C
    records: int  # M, the time grid's length
    samples: int  # n per run: samples (A, R), windows (M), window pairs (D)
    runs: int | None  # S where given to plan (then value checks it)
    start: int
    stop: int
    take: tuple | None
    windows: int  # J, whole windows (0 for A)
    length: int  # samples per window where contiguous equal blocks, else 0
    segments: tuple | None
    counts: tuple | None
    shift: int  # s, the drift's separation in windows (0 otherwise)


def _positions(mask: np.ndarray):
    """(start, stop, take): the positions of mask's True entries, a slice where contiguous."""
    idx = np.flatnonzero(mask)
    if idx.size == 0 or np.array_equal(idx, np.arange(idx[0], idx[0] + idx.size)):
        start = int(idx[0]) if idx.size else 0
        return start, start + int(idx.size), None
    return 0, 0, tuple(int(i) for i in idx)


def plan(requirement: pointing.Requirement, t, phase_bounds, runs: int | None = None) -> Plan:
    """The :class:`Plan` of ``requirement`` on the record times t (M,) [s]; phase_bounds:
    (t_start, t_end) [s] per phase, as :func:`pointing.evaluate` takes them. runs: S, where
    known (needed by :func:`resolved` for the ensemble and mixed interpretations). A one-line
    ValueError where the period holds no sample or no whole window (or pair of windows)."""
    r = requirement
    if r.index not in pointing.INDICES:
        raise ValueError(f"unknown index {r.index!r} (one of {', '.join(pointing.INDICES)})")
    if r.axis not in pointing.AXES:
        raise ValueError(f"unknown axis {r.axis!r} (one of {', '.join(pointing.AXES)})")
    if r.interpretation not in pointing.INTERPRETATIONS:
        raise ValueError(f"unknown interpretation {r.interpretation!r} "
                         f"(one of {', '.join(pointing.INTERPRETATIONS)})")
    t = np.asarray(t, np.float64)
    bounds = pointing.requirement_period(r, phase_bounds)
    kind = "D" if r.index in pointing.DRIFT else r.index[0]
    columns = (0, 1, 2) if r.axis == "each" else (pointing.COLUMNS.index(r.axis),)
    common = dict(kind=kind, columns=columns, interpretation=r.interpretation, level=float(r.level),
                  records=int(t.shape[0]), runs=None if runs is None else int(runs))
    if kind == "A":
        start, stop, take = _positions(pointing.in_period(t, bounds))
        n = stop - start if take is None else len(take)
        if n == 0:
            raise ValueError(f"the evaluation period [{bounds[0]:g}, {bounds[1]:g}) s holds no sample")
        return Plan(samples=n, start=start, stop=stop, take=take, windows=0, length=0, segments=None, counts=None,
                    shift=0, **common)
    if r.window is None:
        raise ValueError(f"{r.index} needs a window [s]")
    shift = 0
    if kind == "D":
        if r.separation is None:
            raise ValueError(f"{r.index} needs a separation [s]")
        shift = pointing.windows_in(r.separation, r.window)
        pointing.check_window(bounds, r.window, r.separation)
    pointing.check_window(bounds, r.window)
    j = pointing.window_of(t, bounds, r.window)
    keep = j >= 0
    n_windows = pointing.whole_windows(bounds, r.window)
    counts = np.bincount(j[keep], minlength=n_windows)
    if np.any(counts == 0):
        raise ValueError(f"window {r.window:g} s holds no sample somewhere: it is shorter than the sampling interval")
    start, stop, take = _positions(keep)
    kept = j[keep]
    length = int(counts[0])
    blocks = take is None and np.all(counts == length) and np.array_equal(kept, np.repeat(np.arange(n_windows), length))
    segments = None if blocks else tuple(int(i) for i in kept)
    n = {"M": n_windows, "R": int(kept.size), "D": n_windows - shift}[kind]
    return Plan(samples=n, start=start, stop=stop, take=take, windows=n_windows, length=length if blocks else 0,
                segments=segments, counts=None if blocks else tuple(int(c) for c in counts), shift=shift, **common)


def count(p: Plan, runs: int | None = None) -> int:
    """How many samples the quantile is over: n (temporal), S (ensemble) or S n (mixed);
    S: ``runs``, else the plan's."""
    if p.interpretation == "temporal":
        return p.samples
    runs = p.runs if runs is None else runs
    if runs is None:
        raise ValueError(f"the {p.interpretation} interpretation's sample count needs the number of runs S")
    return runs if p.interpretation == "ensemble" else runs * p.samples


def rank(p: Plan, runs: int | None = None) -> int:
    """k = ceil(P_C count), the quantile's rank (:func:`count`)."""
    return pointing.rank(p.level, count(p, runs))


def resolved(p: Plan, runs: int | None = None) -> bool:
    """:func:`pointing.resolved` for the plan's sample count (:func:`count`): k < count."""
    return pointing.resolved(p.level, count(p, runs))


def vectors(p: Plan, e) -> jax.Array:
    """The index's vector samples (S, n, 3) [rad] of e (S, M, 3) [rad] (18.2)."""
    kept = e[:, p.start:p.stop] if p.take is None else e[:, np.asarray(p.take)]
    if p.kind == "A":
        return kept
    S = e.shape[0]
    if p.segments is None:  # contiguous blocks of equal length
        blocks = kept.reshape(S, p.windows, p.length, 3)
        means = jnp.sum(blocks, axis=2) / p.length  # (S, J, 3)
        if p.kind == "R":
            return (blocks - means[:, :, None, :]).reshape(S, p.windows * p.length, 3)
    else:
        segments = np.asarray(p.segments)
        ordered = bool(np.all(np.diff(segments) >= 0))
        sums = jax.ops.segment_sum(jnp.moveaxis(kept, 1, 0), segments, num_segments=p.windows,
                                   indices_are_sorted=ordered)  # (J, S, 3)
        means = jnp.moveaxis(sums / jnp.asarray(p.counts, e.dtype)[:, None, None], 0, 1)
        if p.kind == "R":
            return kept - means[:, segments]
    if p.kind == "M":
        return means
    return means[:, p.shift:] - means[:, :-p.shift]


def magnitudes(p: Plan, v) -> jax.Array:
    """(len(columns), S, n) [rad]: the plan's columns of |v_x|, |v_y|, |v_z|, |v| of v (S, n, 3);
    +inf where a component is not finite (diverged), with no derivative there."""
    bad = ~jnp.all(jnp.isfinite(v), axis=-1)
    safe = jnp.where(bad[..., None], 0.0, v)
    columns = [so3.safe_norm(jnp.moveaxis(safe, -1, 0)) if c == 3 else jnp.abs(safe[..., c]) for c in p.columns]
    return jnp.where(bad, jnp.inf, jnp.stack(columns))


def order_statistic(x, k: int) -> jax.Array:
    """x_(k), the k-th smallest along the last axis (1 <= k <= n), by a sort: the derivative is
    the selected sample's."""
    return jnp.sort(x, axis=-1)[..., k - 1]


def value(p: Plan, e) -> jax.Array:
    """The requirement's value [arcsec], a scalar: the interpretation's statistic (18.2) of the
    magnitudes of e (S, M, 3) or (M, 3) [rad] (the signal ``requirement.signal`` reads), the
    worst of x, y, z for axis "each"; +inf where the statistic selects a diverged sample."""
    e = jnp.asarray(e)
    e = e[None] if e.ndim == 2 else e
    if e.ndim != 3 or e.shape[1:] != (p.records, 3):
        raise ValueError(f"signal of shape {e.shape}: expected (S, {p.records}, 3) on the plan's time grid")
    S = e.shape[0]
    if p.runs is not None and S != p.runs:
        raise ValueError(f"signal of {S} runs: the plan is for {p.runs}")
    x = magnitudes(p, vectors(p, e))  # (C, S, n)
    k = rank(p, S)
    if p.interpretation == "temporal":  # each run's quantile over time, the worst run's
        q = jnp.max(order_statistic(x, k), axis=-1)
    elif p.interpretation == "ensemble":  # each time's quantile over the runs, the worst time's
        q = jnp.max(order_statistic(jnp.swapaxes(x, 1, 2), k), axis=-1)
    else:  # pooled
        q = order_statistic(x.reshape(x.shape[0], -1), k)
    return jnp.max(q) * pointing.ARCSEC
