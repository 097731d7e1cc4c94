"""One registry of controllers: name -> factory, gains type, defaults, checks, options.

Every command (``paper``, ``fly``, ``tune``, ``sweep``) and the plots read it (the plots'
line styles are in :mod:`so3jax.viz.styles`). A new
controller is one module that builds its :class:`ControllerSpec` and calls
:func:`register`, imported by :mod:`so3jax.controllers`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np

from so3jax.controllers.base import Controller
from so3jax.controllers.gains import gain_domain
from so3jax.core.params import parse_params


@dataclasses.dataclass(frozen=True)
class ControllerSpec:
    """What the commands need to know of a controller.

    factory(**options) -> Controller; options are the law's construction choices
    (nominal inertia J_hat, log_derivative, a torque for open loop, ...).
    gains_type: the NamedTuple of its gains; defaults: the paper's values (or a
    neutral set). check(gains) raises ValueError on gains the law cannot use.
    tunable: whether ``tune`` may optimize its gains (a law without gains cannot).
    shapes: the shapes a gain may take, {field: ((), (9,), ...)}, for the fields that
    take more than their default's shape and whose domain does not say
    (:mod:`so3jax.controllers.gains`); every other gain has its default's shape
    (:meth:`gain_shapes`). The config parser checks gains read from files against them.
    options: the factory's keywords as :class:`so3jax.core.params.Param` (a mission's
    ``[controller.NAME]`` table); a None default is left to the factory.
    """

    name: str
    label: str
    factory: Callable[..., Controller]
    gains_type: type
    defaults: Any
    check: Callable[[Any], None]
    tunable: bool = True
    shapes: dict = dataclasses.field(default_factory=dict)
    options: tuple = ()  # components.Param of each factory keyword (J_hat, log_derivative, ...)

    def gain_shapes(self) -> dict:
        """{field: allowed shapes} of every gain: ``shapes``' entry, else its domain's
        (:func:`so3jax.controllers.gains.gain_domain`), else the default's shape."""
        def allowed(f):
            return (self.shapes.get(f) or gain_domain(self.gains_type, f).shapes
                    or (np.shape(getattr(self.defaults, f)),))

        return {f: tuple(allowed(f)) for f in self.gains_type._fields}


_REGISTRY: dict[str, ControllerSpec] = {}


def register(spec: ControllerSpec) -> ControllerSpec:
    if spec.name in _REGISTRY and _REGISTRY[spec.name] != spec:
        raise ValueError(f"a controller named {spec.name!r} is already registered")
    _REGISTRY[spec.name] = spec
    return spec


def unregister(name: str) -> ControllerSpec:
    """Remove a registered controller (e.g. a test's or a notebook's); returns its spec."""
    get(name)
    return _REGISTRY.pop(name)


def names(tunable: bool | None = None) -> tuple[str, ...]:
    """Registered names, in registration order (only the tunable ones if tunable=True)."""
    return tuple(n for n, s in _REGISTRY.items() if tunable is None or s.tunable == tunable)


def get(name: str) -> ControllerSpec:
    """The spec of a registered controller; ValueError naming the choices otherwise."""
    try:
        return _REGISTRY[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown controller {name!r}; known: {', '.join(_REGISTRY)}") from None


def parse_options(name: str, given: dict) -> dict:
    """The factory keywords of a mission's ``[controller.NAME]`` table, checked against
    the registration's options (a None default is left out)."""

    values = parse_params(get(name).options, given, f"controller.{name}")
    return {k: v for k, v in values.items() if v is not None}
