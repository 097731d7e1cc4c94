"""The loop's components: the abstract base of each kind (:mod:`so3jax.components.base`),
the registry of each kind and the built-in sensors, estimators, actuators, filters and the
mission's reference and inertia kinds, registered
when this package is imported (the registry imports no member)."""

from so3jax.components import (  # noqa: F401 (registration)
    actuators,
    environment,
    estimators,
    filters,
    inertias,
    momentum,
    navigation,
    references,
    sensors,
)
from so3jax.components.registry import BuildContext, ComponentSpec, get, names, register, unregister

__all__ = ["BuildContext", "ComponentSpec", "get", "names", "register", "unregister"]
