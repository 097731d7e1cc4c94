"""Gain rules: each gains NamedTuple declares the domain of its gains in a class attribute
``domains`` ({field: domain}); a gain it does not name is :data:`POSITIVE`. One generic
check (:func:`check_gains`) reads them before a run; the config parser reads the shapes
they allow (:meth:`so3jax.controllers.registry.ControllerSpec.gain_shapes`) and the tuner
their parametrization (p = log g of a positive gain, g / scale of a nonnegative one).

    class MyGains(NamedTuple):
        k: jax.Array
        k_i: jax.Array
        Gamma: jax.Array

        domains = {"k_i": Nonnegative(scale=1e-4), "Gamma": PositiveDefinite(9)}
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from so3jax.dynamics.inertia import check_real_dtype, concrete_values


@dataclasses.dataclass(frozen=True)
class Positive:
    """g > 0 elementwise (every gain a type does not declare otherwise)."""

    shapes = None  # the default's shape

    def check(self, name: str, value: np.ndarray, batch_axes: int) -> None:
        if np.any(value <= 0):
            raise ValueError(f"gain {name} must be positive, got {value}")


@dataclasses.dataclass(frozen=True)
class Nonnegative:
    """g >= 0 elementwise (0 turns a term off). scale: the gain's typical size, in its
    unit: the tuner's parameter is g / scale. negative: what the message on a negative
    value adds (e.g. what to write instead)."""

    scale: float
    negative: str = dataclasses.field(default="", compare=False)  # a message, not the domain
    shapes = None  # the default's shape

    def check(self, name: str, value: np.ndarray, batch_axes: int) -> None:
        if np.any(value < 0):
            hint = f" ({self.negative})" if self.negative else ""
            raise ValueError(f"gain {name} must be >= 0, got {value}{hint}")


@dataclasses.dataclass(frozen=True)
class PositiveDefinite:
    """A positive scalar, a positive (n,) diagonal, or an (n, n) symmetric positive definite
    matrix (e.g. an adaptation rate acting on n parameters)."""

    n: int

    @property
    def shapes(self) -> tuple:
        return ((), (self.n,), (self.n, self.n))

    def check(self, name: str, value: np.ndarray, batch_axes: int) -> None:
        if value.ndim < 2 + batch_axes:
            return POSITIVE.check(name, value, batch_axes)
        n = self.n
        if value.shape[-2:] != (n, n):
            raise ValueError(f"gain {name} must be a scalar, a ({n},) diagonal or a ({n}, {n}) matrix, "
                             f"got {value.shape}")
        if not np.allclose(value, np.swapaxes(value, -1, -2), rtol=1e-12, atol=0):
            raise ValueError(f"gain {name} is not symmetric")
        if np.any(np.linalg.eigvalsh(value) <= 0):
            raise ValueError(f"gain {name} is not positive definite")


POSITIVE = Positive()


def gain_domain(gains, name: str):
    """The domain of gain ``name``: its gains type's declaration (class attribute
    ``domains``), else :data:`POSITIVE`. gains: a gains NamedTuple or its type."""
    cls = gains if isinstance(gains, type) else type(gains)
    return getattr(cls, "domains", {}).get(name, POSITIVE)


def check_gains(gains, *, batch_axes: int = 0) -> None:
    """Every gain real, finite and in its declared domain (:func:`gain_domain`), where its
    value is concrete. batch_axes: leading batch axes of every gain (a batch of gains)."""
    for path, value in jax.tree_util.tree_flatten_with_path(gains)[0]:
        name = jax.tree_util.keystr(path, simple=True, separator=".")
        check_real_dtype(value, f"gain {name}")
        value = concrete_values(value)
        if value is None:
            continue
        if not np.all(np.isfinite(value)):
            raise ValueError(f"gain {name} must be finite, got {value}")
        gain_domain(gains, name).check(name, value, batch_axes)
