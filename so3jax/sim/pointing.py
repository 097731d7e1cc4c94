"""Pointing-error indices of ECSS-E-ST-60-10C (control performance), from recorded histories,
with their statistical interpretations at a confidence level, and requirements on them.

Signals [rad, body axes], from a :class:`so3jax.sim.rollout.History`:

* performance error e_P(t) = log(R_d(t)^T R(t))^vee, its angle |e_P| = the rotation angle
  between the desired and the true attitude;
* knowledge error e_K(t) = log(R_hat(t)^T R(t))^vee, where the estimate R_hat is recorded.

Indices, for e either signal (P: performance, K: knowledge), over an evaluation period
[t_0, t_1) (a phase, or the whole run) tiled by windows W_j = [t_0 + j Dt, t_0 + (j + 1) Dt)
of length Dt [s]; a sample belongs to the window that holds its recorded time (to a
round-off of 1e-9 of the times' scale: in a float32 run a sample within float32 round-off of
a boundary may fall on either side of it):

* APE / AKE (absolute):  e(t);
* MPE / MKE (mean):      m_j = mean of e(t) over the samples t in W_j;
* RPE / RKE (relative):  e(t) - m_j, for t in W_j;
* PDE / KDE (drift):     m_{j+s} - m_j, two windows whose starts are Dt_s = s Dt apart
  (Dt_s, the separation, a whole number s >= 1 of windows).

Each is taken per component (x, y, z: its absolute value) and as an angle: the norm of the
vector index, |m_j|, |e(t) - m_j|, |m_{j+s} - m_j| (not the mean of the angle |e|). Only
whole windows count: a tail of the period shorter than Dt holds no window and is left out
of the windowed indices (MPE, RPE, PDE).

Statistical interpretations at a confidence level P_C, of the magnitudes x (one per sample,
or per window for MPE and per window pair for PDE) of S runs on one time grid:

* temporal:  in each run, the P_C-quantile over the period's samples; the worst run's;
* ensemble:  at each sample (window), the P_C-quantile over the S runs; the worst over time;
* mixed:     the P_C-quantile of all runs' and times' samples pooled.

Quantile: the empirical one, q = x_(k), the k-th smallest of the n samples, k = ceil(P_C n)
(NumPy's ``method="inverted_cdf"``): the smallest sample value with at least P_C of the
samples at or below it, a value some sample takes (no interpolation), so exactly testable.
It is a quantile over *samples*: it is one over time only for uniform sampling, which the recorder's
is (every ``record_every`` steps). Where k = n (n < 1 / (1 - P_C): fewer than 20 samples at
0.95, 371 at 0.9973) the quantile is the sample maximum, whatever the level: the result says
so (``resolved`` False). A NaN sample (a diverged run) makes the value NaN, which fails.

Values are reported in arcsec (:data:`ARCSEC` per rad), the unit of pointing requirements.
"""

from __future__ import annotations

import functools
import math
import numbers
from dataclasses import dataclass
from typing import NamedTuple

import jax
import numpy as np

from so3jax.core import checks, so3

ARCSEC = 180.0 / math.pi * 3600.0  # arcsec per rad
INDICES = ("APE", "MPE", "RPE", "PDE", "AKE", "MKE", "RKE", "KDE")
WINDOWED = ("MPE", "RPE", "PDE", "MKE", "RKE", "KDE")
DRIFT = ("PDE", "KDE")
AXES = ("x", "y", "z", "angle", "each")
INTERPRETATIONS = ("temporal", "ensemble", "mixed")
AFTER_FAULT = "after fault"  # a requirement's phase: from the mission's first fault to the end
KEYS = ("index", "axis", "level", "limit", "window", "separation", "phase", "interpretation", "name")
REQUIRED = ("index", "axis", "level", "limit")
REPORTED = ("APE", "MPE", "RPE", "AKE", "MKE", "RKE")  # a report's, with an estimate (else the first three)
COLUMNS = ("x", "y", "z", "angle")  # the magnitudes' last axis


# --- signals ------------------------------------------------------------------------------


class Signals(NamedTuple):
    t: np.ndarray  # (M,) s
    performance: np.ndarray  # (*batch, M, 3) rad, e_P
    knowledge: np.ndarray | None  # (*batch, M, 3) rad, e_K; None without a recorded estimate


_log = jax.jit(functools.partial(so3.log, select=True))


def attitude_error(R_ref, R) -> np.ndarray:
    """log(R_ref^T R)^vee [rad] of arrays in a History's layout, (M, 3, 3, *batch) (R_ref may
    broadcast), as (*batch, M, 3): runs first. Computed in float64 (so3.log's safe branches)."""
    R_ref, R = np.asarray(R_ref, np.float64), np.asarray(R, np.float64)
    R_e = np.einsum("mji...,mjk...->mik...", R_ref, R)
    flat = np.moveaxis(R_e, (1, 2), (0, 1)).reshape(3, 3, -1)  # (3, 3, N), N = M * batch
    n = flat.shape[-1]
    size = max(64, 1 << (n - 1).bit_length())  # pad to a power of two: few compiled shapes
    padded = np.concatenate([flat, np.broadcast_to(np.eye(3)[:, :, None], (3, 3, size - n))], axis=-1)
    with jax.enable_x64(True):
        e = np.asarray(_log(padded))[:, :n]
    e = e.reshape((3,) + R_e.shape[:1] + R_e.shape[3:])  # (3, M, *batch)
    return np.moveaxis(np.moveaxis(e, 1, -1), 0, -1)


def signals(history) -> Signals:
    """e_P and e_K (None where the History has no R_hat) of a recorded History."""
    knowledge = None if history.R_hat is None else attitude_error(history.R_hat, history.R)
    return Signals(np.asarray(history.t, np.float64), attitude_error(history.R_d, history.R), knowledge)


# --- evaluation periods and windows -------------------------------------------------------


def phase_bounds_of(scenario) -> tuple:
    """((t_start, t_end) [s], ...) of a Scenario's phases: the switch times on step
    boundaries, clamped to [0, horizon], as ``Scenario.steps_per_phase`` counts them."""
    steps = (0,) + tuple(min(max(k, 0), scenario.n_steps) for k in scenario.phase_steps) + (scenario.n_steps,)
    return tuple((a * scenario.dt, b * scenario.dt) for a, b in zip(steps[:-1], steps[1:]))


def _tolerance(bounds) -> float:
    """Round-off allowed on sampled times [s] (times k dt summed in floating point)."""
    return 1e-9 * max(1.0, abs(bounds[0]), abs(bounds[1]))


def in_period(t, bounds) -> np.ndarray:
    """(M,) bool: t in [t_start, t_end)."""
    t, tol = np.asarray(t, np.float64), _tolerance(bounds)
    return (t >= bounds[0] - tol) & (t < bounds[1] - tol)


def whole_windows(bounds, window: float) -> int:
    """How many whole windows of ``window`` [s] tile the period [t_start, t_end)."""
    return max(0, math.floor((bounds[1] - bounds[0] + _tolerance(bounds)) / window))


def window_of(t, bounds, window: float) -> np.ndarray:
    """(M,) int: the whole window j each sample belongs to, -1 outside every whole window."""
    t = np.asarray(t, np.float64)
    j = np.floor((t - bounds[0] + _tolerance(bounds)) / window).astype(np.int64)
    return np.where(in_period(t, bounds) & (j < whole_windows(bounds, window)), j, -1)


def check_window(bounds, window, separation=None):
    need = window + (separation or 0.0)
    if whole_windows(bounds, need) < 1:
        what = f"window {window:g} s" + ("" if separation is None else f" + separation {separation:g} s")
        raise ValueError(f"{what} is longer than the evaluation period [{bounds[0]:g}, {bounds[1]:g}) s")


# --- indices (rad), samples along axis -2, components along axis -1 -------------------------


def absolute(t, e, bounds) -> np.ndarray:
    """APE / AKE: e(t) for t in the period, (..., n, 3)."""
    return np.asarray(e, np.float64)[..., in_period(t, bounds), :]


def _windows(t, e, bounds, window):
    """(window means (..., J, 3), the window of each kept sample (n,), the kept samples (..., n, 3))."""
    check_window(bounds, window)
    j = window_of(t, bounds, window)
    keep = j >= 0
    j, kept = j[keep], np.asarray(e, np.float64)[..., keep, :]
    n_windows = whole_windows(bounds, window)
    counts = np.bincount(j, minlength=n_windows)
    if np.any(counts == 0):
        raise ValueError(f"window {window:g} s holds no sample somewhere: it is shorter than the sampling interval")
    sums = np.zeros((n_windows,) + kept.shape[:-2] + (3,))
    np.add.at(sums, j, np.moveaxis(kept, -2, 0))
    return np.moveaxis(sums, 0, -2) / counts[:, None], j, kept


def mean(t, e, bounds, window: float) -> np.ndarray:
    """MPE / MKE: m_j, the mean of e over each whole window, (..., J, 3)."""
    return _windows(t, e, bounds, window)[0]


def relative(t, e, bounds, window: float) -> np.ndarray:
    """RPE / RKE: e(t) - m_j for t in W_j, the samples of the whole windows, (..., n, 3)."""
    means, j, kept = _windows(t, e, bounds, window)
    return kept - means[..., j, :]


def drift(t, e, bounds, window: float, separation: float) -> np.ndarray:
    """PDE / KDE: m_{j+s} - m_j, s = separation / window, (..., J - s, 3)."""
    check_window(bounds, window, separation)
    means, s = mean(t, e, bounds, window), windows_in(separation, window)
    return means[..., s:, :] - means[..., :-s, :]


def windows_in(separation, window) -> int:
    """separation / window [s / s], which must be a whole number >= 1."""
    s = round(separation / window)
    if s < 1 or abs(separation - s * window) > 1e-9 * separation:
        raise ValueError(f"separation {separation:g} s is not a whole number of windows of {window:g} s")
    return s


def magnitudes(v) -> np.ndarray:
    """(..., 4): |v_x|, |v_y|, |v_z| and the angle |v| of vector indices v (..., 3); all
    four NaN where a component is not finite (the run diverged: it fails on every axis)."""
    v = np.asarray(v, np.float64)
    m = np.concatenate([np.abs(v), np.linalg.norm(v, axis=-1, keepdims=True)], axis=-1)
    return np.where(np.isfinite(v).all(axis=-1, keepdims=True), m, np.nan)


def index_samples(index: str, t, e, bounds, window=None, separation=None) -> np.ndarray:
    """The magnitudes (..., n, 4) [rad] of an index (one of INDICES) over the period."""
    if index not in INDICES:
        raise ValueError(f"unknown index {index!r} (one of {', '.join(INDICES)})")
    kind = "D" if index in DRIFT else index[0]  # A, M, R or D
    if kind == "A":
        return magnitudes(absolute(t, e, bounds))
    if kind == "M":
        return magnitudes(mean(t, e, bounds, window))
    if kind == "R":
        return magnitudes(relative(t, e, bounds, window))
    return magnitudes(drift(t, e, bounds, window, separation))


# --- statistics ---------------------------------------------------------------------------


def rank(level: float, n: int) -> int:
    """k = ceil(P_C n) (at least 1): the quantile's rank among n sorted samples."""
    return max(1, math.ceil(level * n - 1e-9 * max(n, 1)))


def quantile(x, level: float, axis: int = 0) -> np.ndarray:
    """The empirical P_C-quantile x_(k), k = ceil(P_C n), along ``axis``; NaN where a sample is."""
    x = np.asarray(x, np.float64)
    k = rank(level, x.shape[axis])
    q = np.take(np.partition(x, k - 1, axis=axis), k - 1, axis=axis)
    return np.where(np.isnan(x).any(axis=axis), np.nan, q)


def resolved(level: float, n: int) -> bool:
    """Whether a quantile at P_C over n samples means more than their maximum: k < n, i.e.
    n (1 - P_C) >= 1 (to round-off)."""
    return n > 0 and rank(level, n) < n


class Statistic(NamedTuple):
    values: np.ndarray  # (4,) rad: x, y, z, angle; NaN where no sample (samples 0) or a run diverged
    samples: int  # how many samples each quantile is over (n, S or S n)
    resolved: bool


def statistic(x, level: float, interpretation: str = "temporal", diverged_worst: bool = False) -> Statistic:
    """x (S, n, 4) magnitudes of S runs -> the interpretation's value per column (see the
    module). diverged_worst: a NaN sample (a diverged run) counts as +inf, larger than every
    other, rather than making the value NaN: an ensemble or mixed quantile at P_C then
    passes over up to a share 1 - P_C of diverged runs (a sweep's reading)."""
    if interpretation not in INTERPRETATIONS:
        raise ValueError(f"unknown interpretation {interpretation!r} (one of {', '.join(INTERPRETATIONS)})")
    x = np.asarray(x, np.float64)
    if diverged_worst:
        x = np.where(np.isnan(x), np.inf, x)
    S, n = x.shape[0], x.shape[1]
    count = {"temporal": n, "ensemble": S, "mixed": S * n}[interpretation] if n else 0
    if count == 0:
        return Statistic(np.full(x.shape[-1], np.nan), 0, False)
    if interpretation == "temporal":  # the worst run's (np.max: NaN, a diverged run, propagates)
        values = np.max(quantile(x, level, axis=1), axis=0)
    elif interpretation == "ensemble":  # the worst time's
        values = np.max(quantile(x, level, axis=0), axis=0)
    else:
        values = quantile(x.reshape(S * n, -1), level, axis=0)
    return Statistic(values, count, resolved(level, count))


# --- requirements -------------------------------------------------------------------------


@dataclass(frozen=True)
class Requirement:
    """index's magnitude on ``axis`` at confidence ``level`` <= ``limit`` [arcsec]; window,
    separation [s]; phase: its index, None for the whole run; after: where set, the period
    starts there instead [s] (phase "after fault": the mission's first fault)."""

    index: str
    axis: str
    level: float
    limit: float  # arcsec
    window: float | None = None  # s
    separation: float | None = None  # s, PDE / KDE
    phase: int | None = None
    interpretation: str = "temporal"
    name: str | None = None
    phase_name: str | None = None  # the phase's name, where the mission names its phases
    after: float | None = None  # s: the period's start (phase "after fault")

    @property
    def signal(self) -> str:
        """The signal the index reads: "performance" (e_P) or "knowledge" (e_K)."""
        return "knowledge" if "K" in self.index else "performance"

    def describe(self) -> str:
        """One line for a table: "[name: ]RPE angle at 0.95 (temporal), window 10 s, deployment: <= 5 arcsec"."""
        what = f"{self.index} {self.axis} at {self.level:g} ({self.interpretation})"
        if self.window is not None:
            what += f", window {self.window:g} s"
        if self.separation is not None:
            what += f", separation {self.separation:g} s"
        where = "whole run" if self.phase is None else self.phase_name or f"phase {self.phase}"
        if self.after is not None:
            where = f"{AFTER_FAULT} (from {self.after:g} s)"
        label = "" if self.name is None else f"{self.name}: "
        return f"{label}{what}, {where}: <= {self.limit:g} arcsec"


def _is_number(x) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(float(x))


def _phase_index(value, where, phase_names, n_phases):
    if value is None or value == AFTER_FAULT:
        return None
    if isinstance(value, str):
        if phase_names is None or value not in phase_names:
            known = "no phase names given" if phase_names is None else "one of " + ", ".join(map(str, phase_names))
            raise ValueError(f"{where}.phase: unknown phase {value!r} ({known})")
        return list(phase_names).index(value)
    if not isinstance(value, numbers.Integral) or isinstance(value, bool) or value < 0:
        raise ValueError(f"{where}.phase: must be a phase index >= 0, a phase name or None, got {value!r}")
    if n_phases is not None and value >= n_phases:
        raise ValueError(f"{where}.phase: phase {value} does not exist ({n_phases} phases)")
    return int(value)


def _positive(item, key, where):
    value = item[key]
    if not _is_number(value) or value <= 0:
        raise ValueError(f"{where}.{key}: must be a positive number of seconds, got {value!r}")
    return float(value)


def check_recorded(window: float, where: str, recording=None) -> None:
    """ValueError naming ``where`` unless a window of ``window`` [s] holds a recorded sample
    wherever it starts: at least the recording interval. recording: (the interval [s], what
    sets it), or None where it is not known."""
    if recording is not None and window < recording[0] * (1 - 1e-9):
        raise ValueError(f"{where}: {window:g} s is shorter than the recording interval, {recording[0]:g} s "
                         f"({recording[1]}): a window must hold a recorded sample")


def check_signal(requirement: Requirement, where: str, no_estimate=None) -> None:
    """ValueError naming ``where`` for a knowledge requirement (AKE, MKE, RKE, KDE) on runs with
    no estimate that can be wrong (e_K = 0: it would pass at 0 arcsec); no_estimate: why they
    have none (e.g. the estimator reads the true state), None where they have one."""
    if requirement.signal == "knowledge" and no_estimate is not None:
        label = "" if requirement.name is None else f" ({requirement.name!r})"
        raise ValueError(f"{where}.index: {requirement.index}{label} reads the knowledge error, and {no_estimate}: "
                         "there is no estimate to be wrong, so it would pass at 0 arcsec")


def parse_requirement(item, where: str = "requirement", phase_names=None, phase_bounds=None,
                      recording=None, no_estimate=None, first_fault=None) -> Requirement:
    """One requirement from a dict (see :func:`parse_requirements`)."""
    if not isinstance(item, dict):
        raise ValueError(f"{where}: must be a table of keys, got {checks.short(item)}")
    for key in item:
        if key not in KEYS:
            raise ValueError(f"{where}: unknown key {key!r} (one of {', '.join(KEYS)})")
    for key in REQUIRED:
        if key not in item:
            raise ValueError(f"{where}.{key}: missing")
    index, axis = item["index"], item["axis"]
    if index not in INDICES:
        raise ValueError(f"{where}.index: unknown index {index!r} (one of {', '.join(INDICES)})")
    if axis not in AXES:
        raise ValueError(f"{where}.axis: unknown axis {axis!r} (one of {', '.join(AXES)})")
    level, limit = item["level"], item["limit"]
    if not _is_number(level) or not 0.0 < level < 1.0:
        raise ValueError(f"{where}.level: must be a confidence level in (0, 1), got {level!r}")
    if not _is_number(limit) or limit < 0:
        raise ValueError(f"{where}.limit: must be a number of arcsec >= 0, got {limit!r}")
    interpretation = item.get("interpretation", "temporal")
    if interpretation not in INTERPRETATIONS:
        raise ValueError(f"{where}.interpretation: unknown {interpretation!r} (one of {', '.join(INTERPRETATIONS)})")
    window = separation = None
    if index in WINDOWED:
        if item.get("window") is None:
            raise ValueError(f"{where}.window: missing (the window Dt [s] of {index})")
        window = _positive(item, "window", where)
        check_recorded(window, f"{where}.window", recording)
    elif item.get("window") is not None:
        raise ValueError(f"{where}.window: {index} takes no window (only {', '.join(WINDOWED)})")
    if index in DRIFT:
        if item.get("separation") is None:
            raise ValueError(f"{where}.separation: missing (the separation Dt_s [s] of {index})")
        separation = _positive(item, "separation", where)
        try:
            windows_in(separation, window)
        except ValueError as error:
            raise ValueError(f"{where}.separation: {error}") from None
    elif item.get("separation") is not None:
        raise ValueError(f"{where}.separation: {index} takes no separation (only {', '.join(DRIFT)})")
    name = item.get("name")
    if name is not None and not isinstance(name, str):
        raise ValueError(f"{where}.name: must be a string, got {name!r}")
    n_phases = len(phase_names) if phase_names is not None else None
    n_phases = len(phase_bounds) if phase_bounds is not None else n_phases
    phase = _phase_index(item.get("phase"), where, phase_names, n_phases)
    phase_name = None if phase is None or phase_names is None or phase >= len(phase_names) else phase_names[phase]
    after = None
    if item.get("phase") == AFTER_FAULT:
        if first_fault is None:
            raise ValueError(f"{where}.phase: {AFTER_FAULT!r} starts at the mission's first fault: it needs a "
                             "mission with [[faults]] (in the mission's [[requirements]])")
        after = float(first_fault)
    requirement = Requirement(index, axis, float(level), float(limit), window, separation, phase, interpretation, name,
                              phase_name, after)
    check_signal(requirement, where, no_estimate)
    if phase_bounds is not None and window is not None:
        try:
            check_window(requirement_period(requirement, phase_bounds), window, separation)
        except ValueError as error:
            raise ValueError(f"{where}.window: {error}") from None
    return requirement


def parse_requirements(items, phase_names=None, phase_bounds=None, recording=None,
                       no_estimate=None, first_fault=None) -> tuple[Requirement, ...]:
    """Requirements from a list of dicts {index, axis, level, limit [arcsec], window [s],
    separation [s], phase, interpretation, name}; a one-line ValueError naming the entry and
    key for any bad one. phase: an index, a name of ``phase_names``, or None (whole run);
    ``phase_bounds`` (t_start, t_end) per phase, where known, also checks the windows fit;
    ``recording`` (the recording interval [s], what sets it), where known, that each window
    holds a sample (:func:`check_recorded`); ``no_estimate``, why the runs have no estimate
    that can be wrong where they have none, refuses the knowledge requirements (:func:`check_signal`);
    ``first_fault``, the time of the mission's first fault [s] where it has faults, lets a
    requirement take phase "after fault": from then to the end."""
    if not isinstance(items, (list, tuple)):
        raise ValueError(f"requirements: must be a list of tables, got {checks.short(items)}")
    return tuple(parse_requirement(item, f"requirements[{i}]", phase_names, phase_bounds, recording, no_estimate,
                                   first_fault) for i, item in enumerate(items))


def period(phase, phase_bounds) -> tuple[float, float]:
    """(t_start, t_end) [s] of a phase, or of the whole run (phase None)."""
    if phase is None:
        return (float(phase_bounds[0][0]), float(phase_bounds[-1][1]))
    return tuple(float(b) for b in phase_bounds[phase])


def requirement_period(requirement: Requirement, phase_bounds) -> tuple[float, float]:
    """(t_start, t_end) [s] a requirement is evaluated over: its phase's (:func:`period`),
    from ``requirement.after`` on where set."""
    start, end = period(requirement.phase, phase_bounds)
    return (start, end) if requirement.after is None else (max(start, requirement.after), end)


class Evaluation(NamedTuple):
    requirement: Requirement
    value: float | None  # arcsec: the worst of x, y, z for axis "each"; None: no sample; NaN: diverged
    passed: bool
    samples: int  # how many samples the quantile is over
    resolved: bool  # False: fewer samples than the level needs (the value is their maximum)
    values: dict  # arcsec per column x, y, z, angle

    def as_dict(self) -> dict:
        """JSON-ready (NaN, a diverged run, is a float: ``so3jax.results.io.dumps`` writes null)."""
        r = self.requirement
        return {"name": r.name, "requirement": r.describe(), "index": r.index, "axis": r.axis, "level": r.level,
                "interpretation": r.interpretation, "window": r.window, "separation": r.separation, "phase": r.phase,
                **({} if r.after is None else {"after": r.after}),
                "limit": r.limit, "value": self.value, "passed": self.passed, "samples": self.samples,
                "resolved": self.resolved, "unit": "arcsec"}


def evaluate(requirement: Requirement, t, e_runs, phase_bounds, diverged_worst: bool = False) -> Evaluation:
    """The requirement's value [arcsec] and pass/fail on e_runs (M, 3) or (S, M, 3) [rad] (the
    signal it reads: ``requirement.signal``) on the time grid t (M,) [s]; phase_bounds:
    (t_start, t_end) [s] per phase. Passed: value <= limit (False for NaN, +inf or no
    sample). diverged_worst: see :func:`statistic`."""
    e = np.asarray(e_runs, np.float64)
    e = e[None] if e.ndim == 2 else e
    x = index_samples(requirement.index, t, e, requirement_period(requirement, phase_bounds), requirement.window,
                      requirement.separation)
    stat = statistic(x, requirement.level, requirement.interpretation, diverged_worst)
    if stat.samples == 0:
        return Evaluation(requirement, None, False, 0, False, dict.fromkeys(COLUMNS))
    values = stat.values * ARCSEC
    value = float(np.max(values[:3]) if requirement.axis == "each" else values[COLUMNS.index(requirement.axis)])
    return Evaluation(requirement, value, bool(value <= requirement.limit), stat.samples, stat.resolved,
                      {c: float(v) for c, v in zip(COLUMNS, values)})


def outcome(checked: dict) -> str:
    """One line of a checked requirement (:meth:`Evaluation.as_dict`): "<requirement>: <value>,
    passed" or "FAILED"; a value None is "no sample" without samples, else infinite (JSON's
    null for +inf: diverged runs) or NaN (a diverged run)."""
    q = checked
    value = f"{q['value']:.4g} arcsec" if q["value"] is not None else "no sample" if not q["samples"] else "diverged"
    note = "" if q["resolved"] else " (fewer samples than the level needs: the maximum)"
    return f"{q['requirement']}: {value}, {'passed' if q['passed'] else 'FAILED'}{note}"


def check(requirements, t, performance, knowledge, phase_bounds, diverged_worst: bool = False) -> list[dict]:
    """Every requirement evaluated on its signal (performance e_P / knowledge e_K, (M, 3) or
    (S, M, 3) rad), as JSON-ready dicts. A knowledge requirement without e_K is refused.
    diverged_worst: see :func:`statistic`."""
    out = []
    for r in requirements:
        e = performance if r.signal == "performance" else knowledge
        if e is None:
            raise ValueError(f"{r.index} needs the knowledge error e_K, and this run records no estimate (R_hat)")
        out.append(evaluate(r, t, e, phase_bounds, diverged_worst).as_dict())
    return out


# --- report -------------------------------------------------------------------------------


SAMPLE_COLUMNS = ("APE", "RPE")  # the indices a sweep gives each sample's own of (:func:`column`)


def column(controller: str, index: str, level: float, phase: str) -> str:
    """The name of a sweep's per-sample column of an index's angle at a level in a phase [arcsec]."""
    return f"{controller}_{index.lower()}_p{100 * level:g}_{phase}_arcsec"


def reported(knowledge) -> tuple:
    """The indices a report gives: REPORTED, without the knowledge ones where e_K is None."""
    return REPORTED if knowledge is not None else tuple(i for i in REPORTED if "K" not in i)


def report(t, performance, knowledge, phase_bounds, *, window: float, levels=(0.95, 0.9973), phase_names=None,
           indices=REPORTED, interpretations=("temporal",), diverged_worst: bool = False) -> dict:
    """Every index of ``indices`` (APE, MPE, RPE, AKE, MKE, RKE by default; no PDE / KDE) of one run
    ((M, 3) signals) or S runs ((S, M, 3)), per phase, in each of ``interpretations``, at
    each level, per axis and angle [arcsec], JSON-ready. window [s]: that of the windowed
    indices. A value is None where the phase holds no (whole window of) sample, or for the
    knowledge indices without e_K; NaN where a run diverged (+inf with ``diverged_worst``,
    :func:`statistic`). Each row's ``resolved``: see the module."""
    reportable = tuple(i for i in INDICES if i not in DRIFT)
    for index in indices:
        if index not in reportable:
            raise ValueError(f"report: index {index!r} is not reported (one of {', '.join(reportable)})")
    phases = []
    for p, bounds in enumerate(phase_bounds):
        bounds = (float(bounds[0]), float(bounds[1]))
        rows = []
        for index in indices:
            e = knowledge if "K" in index else performance
            for interpretation in interpretations:
                for level in levels:
                    rows.append(_row(index, level, t, e, bounds, window if index in WINDOWED else None,
                                     interpretation, diverged_worst))
        phases.append({"phase": p, "name": None if phase_names is None else phase_names[p], "t_start": bounds[0],
                       "t_end": bounds[1], "samples": int(in_period(t, bounds).sum()), "rows": rows})
    return {"unit": "arcsec", "interpretations": list(interpretations), "window": float(window),
            "levels": [float(v) for v in levels], "quantile": "empirical: the k-th smallest sample, k = ceil(level n)",
            "phases": phases}


def _row(index, level, t, e, bounds, window, interpretation, diverged_worst) -> dict:
    row = {"index": index, "interpretation": interpretation, "level": float(level), "window": window}
    if e is None or (window is not None and whole_windows(bounds, window) < 1):
        return row | dict.fromkeys(COLUMNS) | {"samples": 0, "resolved": False}
    e = np.asarray(e, np.float64)
    x = index_samples(index, t, e[None] if e.ndim == 2 else e, bounds, window)
    stat = statistic(x, level, interpretation, diverged_worst)
    values = [None] * 4 if stat.samples == 0 else [float(v) for v in stat.values * ARCSEC]
    return row | dict(zip(COLUMNS, values)) | {"samples": stat.samples, "resolved": stat.resolved}
