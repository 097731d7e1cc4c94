"""A mission's ``[[faults]]`` and ``[fdir]`` (docs/model.md §8.7): parsed into plain data
with one-line errors naming the key, before anything compiles, and built into the loop's
:class:`~so3jax.components.faults.Faults`.

Each ``[[faults]]`` entry has a ``time`` [s] and one target: ``wheel = i`` (1-based) with
``mode = "off"``, ``"stuck"`` (at its speed), ``"degraded"`` with its torque limit's ``factor``
in [0, 1), or ``"friction"`` with its bearing friction's ``factor`` >= 0 (not 1); ``star_tracker = "outage"``
with its ``end`` [s]; ``gyro = "bias step"`` with its ``step`` [rad/s] (3,); ``thruster =
"+x"`` (one of :data:`THRUSTERS`: the thruster of the momentum manager's pair on that body
axis that fires a torque of that sign, ``momentum.kind = "thrusters"``) with ``mode = "off"``
(optional, the only mode). ``[fdir]`` says what the loop knows of a wheel or a thruster
that fails off or sticks (:data:`LOST_MODES`): ``detection = "never"`` (the default), or
``latency`` [s] after the fault, when the distribution drops that wheel, or the flight
software stops firing that thruster.
"""

from __future__ import annotations

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.components.faults import Faults
from so3jax.core import checks

TARGETS = ("wheel", "star_tracker", "gyro", "thruster")  # what an entry fails (one each)
KEYS = ("time", "end", "mode", "factor", "step") + TARGETS  # an entry's keys
WHEEL_MODES = ("off", "stuck", "degraded", "friction")
LOST_MODES = ("off", "stuck")  # a wheel that delivers none of its command: detected, dropped, < 3-D refused
THRUSTERS = ("+x", "-x", "+y", "-y", "+z", "-z")  # a thruster: the sign of its torque and its body axis
THRUSTER_MODES = ("off",)
TARGET_VALUES = {"star_tracker": "outage", "gyro": "bias step"}
DETECTIONS = ("never", "latency")
NO_FDIR = {"detection": "never"}  # the default: the loop never learns of a fault
RANK_TOLERANCE = 1e-9  # smallest singular value of the available wheels' axes below this: rank < 3


class ControllabilityWarning(UserWarning):
    """Wheels failed off leave the others spanning less than 3-D, the loop unaware of it."""


def parse_fdir(table) -> dict:
    """``[fdir]``: {"detection": "never"} or {"detection": "latency", "latency": tau [s] >= 0}.
    ``detection`` defaults to "latency" where a latency is given, else "never"; "never"
    turns detection off over a latency (``--set fdir.detection='never'`` over a file)."""
    if table is None:
        return dict(NO_FDIR)
    table = checks.table({"fdir": table}, "fdir", ("detection", "latency"))
    latency = None if "latency" not in table else checks.number(table["latency"], "fdir.latency [s]", low=0.0)
    detection = checks.choice(table.get("detection", "never" if latency is None else "latency"), "fdir.detection",
                              DETECTIONS)
    if detection == "never":
        return dict(NO_FDIR)
    if latency is None:
        raise ValueError("fdir.detection = 'latency' needs fdir.latency [s]: the time from a fault to its detection")
    return {"detection": "latency", "latency": latency}


def lost(fault: dict) -> bool:
    """Whether a parsed fault is a wheel's that delivers none of its command from its time
    (:data:`LOST_MODES`): the loop detects it and drops the wheel."""
    return fault.get("mode") in LOST_MODES and "wheel" in fault


def parse(entries, *, wheels: dict | None, sensors: tuple, momentum: str, sampled: bool, fdir: dict) -> tuple:
    """The ``[[faults]]`` entries as plain dicts, checked against the mission: wheels: the
    ``[actuator.wheels]`` table (None without wheels); sensors: the sensors flown; momentum: the
    momentum manager's kind; sampled: the loop has control ticks. One-line ValueError
    naming the key; a :class:`ControllabilityWarning` where wheels failed off leave the
    others spanning less than 3-D and the loop never drops them (an error where it does); a
    wheel failed off or stuck counts as failed."""
    if not isinstance(entries, (list, tuple)):
        raise ValueError(f"faults must be a list of tables ([[faults]]), got {checks.short(entries)}")
    if entries and not sampled:
        raise ValueError("faults act at the control ticks: they need the sampled loop (control.mode = 'sampled')")
    out = tuple(_entry(e, f"faults[{i}]", wheels, sensors, momentum) for i, e in enumerate(entries))
    off = sorted({f["wheel"] for f in out if lost(f)})
    if off and wheels is not None:
        axes = wheels["axes"]
        if not spanning(axes, np.isin(np.arange(1, np.shape(axes)[0] + 1), off)):
            what = (f"with wheel(s) {', '.join(map(str, off))} failed the others no longer span 3-D: the mission is no "
                    "longer controllable about some axis")
            if fdir["detection"] != "never":
                raise ValueError(f"faults: {what} (the reconfigured distribution has no inverse; "
                                 "fdir.detection = 'never' flies it unaware)")
            warnings.warn(f"faults: {what}", ControllabilityWarning, stacklevel=2)
    return out


def spanning(axes, failed) -> np.ndarray:
    """Whether the wheels not ``failed`` (..., N) bool span 3-D: the smallest singular value
    of their axes (N, 3), a failed wheel's row zeroed, at least RANK_TOLERANCE (...)."""
    left = np.where(np.asarray(failed)[..., None], 0.0, np.asarray(axes, float))
    return np.linalg.svd(left, compute_uv=False)[..., -1] >= RANK_TOLERANCE


def _entry(entry, where: str, wheels, sensors: tuple, momentum: str) -> dict:
    """One ``[[faults]]`` entry."""
    if not isinstance(entry, dict):
        raise ValueError(f"{where} must be a table, got {checks.short(entry)}")  # noqa: TRY004 (bad input)
    unknown = sorted(set(entry) - set(KEYS))
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(KEYS)}")
    targets = [k for k in TARGETS if k in entry]
    if len(targets) != 1:
        raise ValueError(f"{where}: one target among {', '.join(TARGETS)}, got {', '.join(targets) or 'none'}")
    target = targets[0]
    if "time" not in entry:
        raise ValueError(f"{where}.time [s] is missing: when the fault acts")
    out = {"time": checks.number(entry["time"], f"{where}.time [s]", low=0.0)}
    allowed = {"wheel": ("mode", "factor"), "star_tracker": ("end",), "gyro": ("step",), "thruster": ("mode",)}[target]
    extra = sorted(set(entry) - {"time", target, *allowed})
    if extra:
        raise ValueError(f"{where}: {', '.join(extra)} not taken by a {target} fault "
                         f"(it takes time{''.join(', ' + k for k in allowed)})")
    if target == "thruster":
        return {**out, **_thruster(entry, where, momentum)}
    if target == "wheel":
        return {**out, **_wheel(entry, where, wheels)}
    value = entry[target]
    if value != TARGET_VALUES[target]:
        raise ValueError(f"{where}.{target} must be {TARGET_VALUES[target]!r}, got {checks.short(value)}")
    if target not in sensors:
        raise ValueError(f"{where}.{target}: the mission flies no {target.replace('_', ' ')} "
                         f"(sensors.{target} is left out)")
    if target == "star_tracker":
        if "end" not in entry:
            raise ValueError(f"{where}.end [s] is missing: when the outage ends")
        end = checks.number(entry["end"], f"{where}.end [s]", low=0.0)
        if end <= out["time"]:
            raise ValueError(f"{where}.end = {end:g} s must come after its time = {out['time']:g} s "
                             "(the outage is [time, end))")
        return {**out, "star_tracker": "outage", "end": end}
    if "step" not in entry:
        raise ValueError(f"{where}.step [rad/s] is missing: the bias step (3,)")
    return {**out, "gyro": "bias step", "step": checks.array(entry["step"], f"{where}.step [rad/s]", (3,))}


def _wheel(entry, where: str, wheels) -> dict:
    """A wheel fault: {"wheel": i (1-based), "mode", "factor"}."""
    if wheels is None:
        raise ValueError(f"{where}.wheel: the mission flies no wheels (actuator.kind = 'wheels')")
    n = np.shape(wheels["axes"])[0]
    index = entry["wheel"]
    if isinstance(index, bool) or not isinstance(index, int) or not 1 <= index <= n:
        raise ValueError(f"{where}.wheel must be a wheel's index, 1 to {n} (the mission's wheels), "
                         f"got {checks.short(index)}")
    mode = checks.choice(entry.get("mode", "off"), f"{where}.mode", WHEEL_MODES)
    if mode in LOST_MODES:
        if "factor" in entry:
            raise ValueError(f"{where}.factor is a degraded wheel's or its friction's (mode = 'degraded' or "
                             f"'friction'); a wheel {mode} delivers no torque")
        return {"wheel": index, "mode": mode, "factor": 0.0}
    if mode == "friction":
        return {"wheel": index, "mode": mode, "factor": _friction_factor(entry, where, wheels)}
    if "factor" not in entry:
        raise ValueError(f"{where}.factor is missing: the degraded wheel's torque limit factor, in [0, 1)")
    factor = checks.number(entry["factor"], f"{where}.factor", low=0.0, high=1.0)
    if factor >= 1.0:
        raise ValueError(f"{where}.factor must be in [0, 1) (1: no fault), got {factor:g}")
    return {"wheel": index, "mode": "degraded", "factor": factor}


def _friction_factor(entry, where: str, wheels: dict) -> float:
    """A friction fault's factor k >= 0 (not 1) on wheels that have bearing friction."""
    if not np.any(np.asarray(wheels["coulomb_friction"])) and not np.any(np.asarray(wheels["viscous_friction"])):
        raise ValueError(f"{where}: the mission's wheels have no bearing friction to scale (set "
                         "actuator.wheels.coulomb_friction or viscous_friction)")
    if "factor" not in entry:
        raise ValueError(f"{where}.factor is missing: the factor the wheel's bearing friction is scaled by, >= 0")
    factor = checks.number(entry["factor"], f"{where}.factor", low=0.0)
    if factor == 1.0:
        raise ValueError(f"{where}.factor = 1 scales the friction by nothing: no fault")
    return factor


def _thruster(entry, where: str, momentum: str) -> dict:
    """A thruster fault: {"thruster": "+x" (one of THRUSTERS)}, failed off."""
    if momentum != "thrusters":
        raise ValueError(f"{where}.thruster: the mission flies no thrusters (momentum.kind = {momentum!r}; "
                         "a thruster fault needs momentum.kind = 'thrusters')")
    name = entry["thruster"]
    if name not in THRUSTERS:
        raise ValueError(f"{where}.thruster must be one of {', '.join(THRUSTERS)} (the thruster of the pair on that "
                         f"body axis that fires a torque of that sign), got {checks.short(name)}")
    mode = entry.get("mode", "off")
    if mode != "off":
        raise ValueError(f"{where}.mode = {checks.short(mode)} is not modeled for a thruster: it fails off "
                         "(mode = 'off', the default)")
    return {"thruster": name}


def model(faults: tuple, fdir: dict, as_array) -> Faults | None:
    """The loop's :class:`~so3jax.components.faults.Faults` of the parsed entries, None
    without any. A wheel or a thruster failed off is detected ``fdir.latency`` after its
    time (never with ``detection = "never"``), as is a wheel stuck; a degraded wheel, or one
    whose friction changes, stays in the distribution."""
    if not faults:
        return None
    latency = fdir.get("latency") if fdir["detection"] == "latency" else None
    wheel = [f for f in faults if "wheel" in f]
    outage = [f for f in faults if "star_tracker" in f]
    bias = [f for f in faults if "gyro" in f]
    thruster = [f for f in faults if "thruster" in f]
    values = {}
    if wheel:
        detected = [f["time"] + latency if lost(f) and latency is not None else math.inf for f in wheel]
        friction = [f["mode"] == "friction" for f in wheel]
        values.update(wheel=as_array(_stack([f["wheel"] for f in wheel])) - 1,
                      wheel_time=as_array(_stack([f["time"] for f in wheel])),
                      wheel_factor=as_array(_stack([1.0 if rubs else f["factor"] for f, rubs in zip(wheel, friction)])),
                      wheel_detected=as_array(_stack(detected)))
        if any(f["mode"] == "stuck" for f in wheel):
            values["wheel_stuck"] = as_array(_stack([float(f["mode"] == "stuck") for f in wheel]))
        if any(friction):
            values["wheel_friction"] = as_array(_stack([f["factor"] if rubs else 1.0
                                                        for f, rubs in zip(wheel, friction)]))
    if outage:
        values.update(outage_start=as_array(_stack([f["time"] for f in outage])),
                      outage_end=as_array(_stack([f["end"] for f in outage])))
    if bias:
        values.update(bias_time=as_array(_stack([f["time"] for f in bias])),
                      bias_step=as_array(_stack([f["step"] for f in bias], axis=1)))
    if thruster:
        detected = [f["time"] + latency if latency is not None else math.inf for f in thruster]
        values.update(thruster_axis=as_array(_stack(["xyz".index(f["thruster"][1]) for f in thruster])),
                      thruster_sign=as_array(_stack([1.0 if f["thruster"][0] == "+" else -1.0 for f in thruster])),
                      thruster_time=as_array(_stack([f["time"] for f in thruster])),
                      thruster_detected=as_array(_stack(detected)))
    return Faults(**values)


def _stack(values: list, axis: int = 0):
    """The entries' values stacked along ``axis``: a NumPy float array, or a JAX one where a
    value is traced (a sweep's dispersed fault, :func:`so3jax.missions.batched.loop`)."""
    if any(isinstance(v, jax.Array) for v in values):
        return jnp.stack([jnp.asarray(v) for v in values], axis=axis)
    return np.stack([np.asarray(v, float) for v in values], axis=axis)
