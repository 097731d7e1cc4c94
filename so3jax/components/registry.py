"""One registry per kind of loop component (``sensor``, ``estimator``, ``actuator``):
name -> its parameters (units, shapes, domains, defaults) and a builder.

A mission's ``[sensors.NAME]``, ``[estimator.NAME]`` and ``[actuator.NAME]`` tables are
read through the registration, so the mission parser is generic: a new component is one
module that defines it and calls :func:`register`. Controllers keep their own registry
(:mod:`so3jax.controllers.registry`), whose options are declared with the same
:class:`Param`.

A schema of frozen dataclasses rather than a schema library (pydantic, msgspec): the
values are few, the domains are physical (units, shapes, positive definite matrices),
the errors must be one line naming the mission key, and a dependency would buy nothing
the checks below do not already do.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from so3jax.missions import config as cfg

KINDS = ("sensor", "estimator", "actuator")
MEASUREMENTS = ("rate", "attitude")  # what a sensor measures; an estimator reads them by these names


@dataclasses.dataclass(frozen=True)
class Param:
    """One parameter of a component or controller option.

    default: a number, list, bool or string; None: absent unless given (the builder then
    derives it, e.g. the MEKF's noise levels from the sensors). shapes: the array shapes
    it may take (None in a shape: any length, e.g. one value per wheel); () for a number.
    low/high: the closed domain of every element; integer: whole numbers; choices: a
    string among these; boolean: True or False.
    """

    name: str
    default: Any
    unit: str = ""
    shapes: tuple = ((),)
    low: float = -math.inf
    high: float = math.inf
    integer: bool = False
    choices: tuple = ()
    boolean: bool = False
    doc: str = ""

    def parse(self, value, where: str):
        """The value checked against the declaration: a Python number, bool or string, or a
        NumPy array; one-line ValueError naming ``where`` otherwise."""
        label = f"{where} [{self.unit}]" if self.unit else where
        if self.boolean:
            return cfg.boolean(value, label)
        if self.choices:
            return cfg.choice(value, label, self.choices)
        shape = next((shape for shape in self.shapes if len(shape) == _depth(value)), self.shapes[-1])
        if shape == ():
            return cfg.number(value, label, low=self.low, high=self.high, integer=self.integer)
        arr = cfg.array(value, label, shape, low=self.low)
        if np.any(arr > self.high):
            raise ValueError(f"{label} must be <= {self.high}, got {cfg.short(arr.tolist())}")
        return arr


def _depth(value) -> int:
    """How deep lists nest in value (0 for a number)."""
    return 1 + _depth(value[0]) if isinstance(value, list | tuple) and value else int(isinstance(value, list | tuple))


def parse_params(params: tuple, given: dict, where: str) -> dict:
    """{name: value} of every declared parameter: given values checked, defaults elsewhere
    (a None default stays None). Unknown keys are one-line errors."""
    if not isinstance(given, dict):
        raise ValueError(f"[{where}] must be a table, got {cfg.short(given)}")  # noqa: TRY004 (bad input)
    names = tuple(p.name for p in params)
    unknown = sorted(set(given) - set(names))
    if unknown:
        allowed = ", ".join(names) if names else "none"
        raise ValueError(f"unknown key(s) in [{where}]: {', '.join(unknown)}; allowed: {allowed}")
    out = {}
    for p in params:
        if p.name in given:
            out[p.name] = p.parse(given[p.name], f"{where}.{p.name}")
        elif p.default is None:
            out[p.name] = None
        else:
            out[p.name] = p.parse(p.default, f"{where}.{p.name}")
    return out


@dataclasses.dataclass(frozen=True)
class ComponentSpec:
    """A registered loop component.

    build(values, context) -> the component (a pytree), values: {param: parsed value},
    context: :class:`BuildContext`. complete(values) -> values: cross-parameter checks
    (one-line ValueErrors) and derived values (e.g. one value per wheel), at parse time. provides (sensors): the measurement it makes, one of
    ``MEASUREMENTS``; noise(values) (sensors): the noise levels an estimator may assume,
    {name: value}. needs (estimators): the measurements it reads; truth (estimators):
    whether it reads the true state (an explicit input only such estimators get; the
    continuous-time wiring takes only such an estimator). figures(histories, phase_times,
    T, values) (actuators): {file name: matplotlib Figure} of the actuator's own state,
    which ``so3jax fly`` adds to its figures; effort_label: what the flight metrics'
    actuator effort sums (wheels: the motor torques).
    """

    kind: str
    name: str
    params: tuple
    build: Callable[..., Any]
    doc: str = ""
    complete: Callable[[dict], dict] | None = None
    provides: str = ""
    noise: Callable[[dict], dict] | None = None
    needs: tuple = ()
    truth: bool = False
    figures: Callable[..., dict] | None = None
    effort_label: str = "actuator effort"

    def parse(self, given: dict, where: str) -> dict:
        values = parse_params(self.params, given, where)
        return values if self.complete is None else self.complete(values)


@dataclasses.dataclass(frozen=True)
class BuildContext:
    """What a builder may read besides its own values: as_array(x) casts to the run's
    dtype; sensor_noise: the noise levels the mission's sensors report ({name: value})."""

    as_array: Callable[[Any], Any]
    sensor_noise: dict


_REGISTRY: dict[str, dict[str, ComponentSpec]] = {kind: {} for kind in KINDS}


def register(spec: ComponentSpec) -> ComponentSpec:
    """Add a component to its kind's registry (re-registering the same spec is allowed)."""
    if spec.kind not in KINDS:
        raise ValueError(f"component kind must be one of {KINDS}, got {spec.kind!r}")
    if spec.kind == "sensor" and spec.provides not in MEASUREMENTS:
        raise ValueError(f"sensor {spec.name!r} must provide one of {MEASUREMENTS}, got {spec.provides!r}")
    existing = _REGISTRY[spec.kind].get(spec.name)
    if existing is not None and existing != spec:
        raise ValueError(f"a {spec.kind} named {spec.name!r} is already registered")
    _REGISTRY[spec.kind][spec.name] = spec
    return spec


def names(kind: str) -> tuple[str, ...]:
    """The registered names of a kind, in registration order."""
    _load_builtins()
    return tuple(_REGISTRY[kind])


def get(kind: str, name: str) -> ComponentSpec:
    """The spec of a registered component; ValueError naming the choices otherwise."""
    _load_builtins()
    try:
        return _REGISTRY[kind][name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown {kind} {name!r}; known: {', '.join(_REGISTRY[kind])}") from None


def _load_builtins() -> None:
    """Import the modules that register the built-in components."""
    from so3jax.components import actuators, estimators, sensors  # noqa: F401 (registration
