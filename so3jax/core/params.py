"""The one schema primitive: a declared parameter (unit, shapes, domain, default, meaning),
read by the mission parser, the components' and controllers' registrations and the docs."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from so3jax.core import checks


@dataclasses.dataclass(frozen=True)
class Param:
    """One parameter of a component or controller option.

    default: a number, list, bool or string; None: absent unless given (the builder then
    derives it, e.g. the MEKF's noise levels from the sensors). shapes: the array shapes
    it may take (None in a shape: any length, e.g. one value per wheel); () for a number.
    low/high: the closed domain of every element (low_excluded: (low, high], a value that is
    divided by, e.g. a limit); integer: whole numbers; choices: a string among these;
    boolean: True or False; text: any string (e.g. a file's path).
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
    text: bool = False
    doc: str = ""
    low_excluded: bool = False

    def parse(self, value, where: str):
        """The value checked against the declaration: a Python number, bool or string, or a
        NumPy array; one-line ValueError naming ``where`` otherwise."""
        label = f"{where} [{self.unit}]" if self.unit else where
        if self.boolean:
            return checks.boolean(value, label)
        if self.text:
            if not isinstance(value, str) or not value:
                raise ValueError(f"{label} must be a non-empty string, got {checks.short(value)}")
            return value
        if self.choices:
            return checks.choice(value, label, self.choices)
        shape = next((shape for shape in self.shapes if len(shape) == _depth(value)), self.shapes[-1])
        if shape == ():
            out = checks.number(value, label, low=self.low, high=self.high, integer=self.integer)
        else:
            out = checks.array(value, label, shape, low=self.low)
            if np.any(out > self.high):
                raise ValueError(f"{label} must be <= {self.high}, got {checks.short(out.tolist())}")
        if self.low_excluded and np.any(np.asarray(out) <= self.low):
            raise ValueError(f"{label} must be > {self.low}, got {checks.short(np.asarray(out).tolist())}")
        return out


def _depth(value) -> int:
    """How deep lists nest in value (0 for a number)."""
    return 1 + _depth(value[0]) if isinstance(value, list | tuple) and value else int(isinstance(value, list | tuple))


def parse_params(params: tuple, given: dict, where: str) -> dict:
    """{name: value} of every declared parameter: given values checked, defaults elsewhere
    (a None default stays None). Unknown keys are one-line errors."""
    if not isinstance(given, dict):
        raise ValueError(f"[{where}] must be a table, got {checks.short(given)}")  # noqa: TRY004 (bad input)
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
