"""One registry per kind of component (the loop's ``sensor``, ``estimator``, ``actuator``,
and the mission's ``reference`` and ``inertia``): name -> its parameters (units, shapes, domains, defaults)
and a builder.

A mission's ``[sensors.NAME]``, ``[estimator.NAME]``, ``[actuator.NAME]``,
``[reference.NAME]`` and ``[inertia.NAME]`` tables are read through the registration, so the mission parser is
generic: a new component is one module that defines it (a subclass of its kind's base,
:mod:`so3jax.components.base`, :class:`so3jax.dynamics.reference.Reference` or
:class:`so3jax.dynamics.plant.InertiaProfile`) and calls :func:`register`. Controllers keep their own registry
(:mod:`so3jax.controllers.registry`), whose options are declared with the same
:class:`~so3jax.core.params.Param`.

A schema of frozen dataclasses rather than a schema library (pydantic, msgspec): the
values are few, the domains are physical (units, shapes, positive definite matrices),
the errors must be one line naming the mission key, and a dependency would buy nothing
the checks below do not already do.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

from so3jax.components import base
from so3jax.core import params
from so3jax.dynamics.plant import InertiaProfile
from so3jax.dynamics.reference import Reference
from so3jax.dynamics.space import EnvironmentTorque

KINDS = ("sensor", "estimator", "actuator", "momentum", "filter", "environment", "reference", "inertia")
BASES = {"sensor": base.Sensor, "estimator": base.Estimator, "actuator": base.Actuator, "filter": base.Filter,
         "momentum": base.MomentumManager, "environment": EnvironmentTorque, "reference": Reference,
         "inertia": InertiaProfile}
MEASUREMENTS = ("rate", "attitude")  # what a sensor measures; an estimator reads them by these names


@dataclasses.dataclass(frozen=True)
class ComponentSpec:
    """A registered loop component.

    component: the class ``build`` returns, a subclass of its kind's base
    (:class:`~so3jax.components.base.Sensor`, :class:`~so3jax.components.base.Estimator`,
    :class:`~so3jax.components.base.Actuator`). build(values, context) -> the component (a
    pytree), values: {param: parsed value}, context: :class:`BuildContext` (a reference's:
    :class:`so3jax.components.references.ReferenceContext`).
    complete(values) -> values: cross-parameter checks (one-line ValueErrors) and derived
    values (e.g. one value per wheel), at parse time. provides (sensors): the measurement
    it makes, one of ``MEASUREMENTS``; noise(values) (sensors): the noise levels an
    estimator may assume, {name: value}. What an estimator reads is its class's
    declaration (``needs``, ``reads_truth``), shown here as :attr:`needs` and
    :attr:`truth`. effort_label: what the flight metrics' actuator effort sums (wheels:
    the motor torques). Figures of an actuator's own state are :mod:`so3jax.viz.flight`'s,
    by name.
    """

    kind: str
    name: str
    component: type
    params: tuple
    build: Callable[..., Any]
    doc: str = ""
    complete: Callable[[dict], dict] | None = None
    provides: str = ""
    noise: Callable[[dict], dict] | None = None
    effort_label: str = "actuator effort"

    @property
    def needs(self) -> tuple[str, ...]:
        """The measurements an estimator reads (its class's ``needs``); () for another kind."""
        return tuple(self.component.needs) if self.kind == "estimator" else ()

    @property
    def truth(self) -> bool:
        """Whether an estimator reads the true state (its class's ``reads_truth``)."""
        return self.kind == "estimator" and bool(self.component.reads_truth)

    def parse(self, given: dict, where: str) -> dict:
        values = params.parse_params(self.params, given, where)
        return values if self.complete is None else self.complete(values)


@dataclasses.dataclass(frozen=True)
class BuildContext:
    """What a builder may read besides its own values: as_array(x) casts to the run's
    dtype; sensor_noise: the noise levels the mission's sensors report ({name: value});
    period: the time between control ticks [s] (the control period; dt in the continuous
    wiring)."""

    as_array: Callable[[Any], Any]
    sensor_noise: dict
    period: float = 0.0


_REGISTRY: dict[str, dict[str, ComponentSpec]] = {kind: {} for kind in KINDS}


def register(spec: ComponentSpec) -> ComponentSpec:
    """Add a component to its kind's registry (re-registering the same spec is allowed)."""
    if spec.kind not in KINDS:
        raise ValueError(f"component kind must be one of {KINDS}, got {spec.kind!r}")
    if not (isinstance(spec.component, type) and issubclass(spec.component, BASES[spec.kind])):
        raise ValueError(f"{spec.kind} {spec.name!r}: its component must be a subclass of "
                         f"{BASES[spec.kind].__module__}.{BASES[spec.kind].__name__}, got {spec.component!r}")
    if spec.kind == "sensor" and spec.provides not in MEASUREMENTS:
        raise ValueError(f"sensor {spec.name!r} must provide one of {MEASUREMENTS}, got {spec.provides!r}")
    if spec.kind == "estimator" and not set(spec.needs) <= set(MEASUREMENTS):
        raise ValueError(f"estimator {spec.name!r} must need some of {MEASUREMENTS}, got {spec.needs!r}")
    existing = _REGISTRY[spec.kind].get(spec.name)
    if existing is not None and existing != spec:
        raise ValueError(f"a {spec.kind} named {spec.name!r} is already registered")
    _REGISTRY[spec.kind][spec.name] = spec
    return spec


def names(kind: str) -> tuple[str, ...]:
    """The registered names of a kind, in registration order."""
    return tuple(_REGISTRY[kind])


def get(kind: str, name: str) -> ComponentSpec:
    """The spec of a registered component; ValueError naming the choices otherwise."""
    try:
        return _REGISTRY[kind][name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown {kind} {name!r}; known: {', '.join(_REGISTRY[kind])}") from None


def unregister(kind: str, name: str) -> ComponentSpec:
    """Remove a registered component (e.g. a test's or a notebook's); returns its spec."""
    get(kind, name)
    return _REGISTRY[kind].pop(name)
