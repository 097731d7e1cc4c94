"""The controller interface: an abstract base class whose instances are static options.

A controller is an instance of a subclass of :class:`Controller`, by convention a frozen
dataclass of its construction options (nominal inertia, boundary layer, ...). Its options
are hashable and compared by value, so two controllers built alike are equal and hash
alike: the rollout jits with the controller as a static argument, and repeated runs reuse
the compiled program. Its methods are pure functions of their arguments:

* ``init(gains) -> state``: the controller's initial internal state (a pytree, ``()``
  for a static law);
* ``torque(gains, state, feedback, desired, t) -> (tau, state_dot)``: the control torque
  [N m] and the time derivative of the internal state, which the continuous wiring
  integrates with the plant (docs/model.md §5). ``feedback`` (:class:`Feedback`) is what
  the controller reads of the body: the true state in the continuous wiring, the
  estimator's estimate in the sampled one. The true inertia is never passed in;
* ``gains_type`` (class attribute, optional): the NamedTuple of gains it takes, checked
  before a run (:mod:`so3jax.controllers.gains`); None: any;
* ``update`` (optional): None (the default: the tick applies forward Euler,
  ``state + period * state_dot``, docs/model.md §8.1), or a method
  ``update(gains, state, feedback, desired, t, period) -> state``, the state's discrete
  update at a control tick of the sampled wiring (t: the tick's time [s], period:
  Delta_c [s]), as flight software computes it;
* ``gain_axes`` (class attribute, default 0): the leading axes every gain carries before
  the law's own (1 for a schedule's gains, :mod:`so3jax.controllers.scheduled`).

:func:`from_functions` wraps plain functions (``init``, ``torque``, ...) as a controller.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Callable
from typing import Any, ClassVar, NamedTuple

import jax
import numpy as np

from so3jax.core import so3


class Feedback(NamedTuple):
    """What a controller reads of the body (not the sensors' raw measurements)."""

    R: jax.Array  # (3, 3) body -> inertial
    Omega: jax.Array  # (3,) body rate, rad/s
    wheel_momentum: Any = None  # (3,) N m s: h_w the law must account for (the actuator does not), or None


class Desired(NamedTuple):
    R_d: jax.Array  # (3, 3)
    Omega_d: jax.Array  # (3,) rad/s, desired frame
    Omega_d_dot: jax.Array  # (3,) rad/s^2


class Controller(abc.ABC):
    """The base of every controller (module docstring): ``init`` and ``torque`` to
    implement; ``gains_type`` and ``update`` defaulted (any gains; forward Euler at ticks).
    Subclasses are frozen dataclasses of hashable options (:func:`hashable` for arrays)."""

    gains_type: ClassVar[type | None] = None  # the NamedTuple of gains the law reads (checked by the rollout)
    update: ClassVar[Callable | None] = None  # update(gains, state, feedback, desired, t, period) -> state; None: Euler
    gain_axes: ClassVar[int] = 0  # leading axes of every gain before the law's own (a schedule's)

    @abc.abstractmethod
    def init(self, gains) -> Any:
        """The initial internal state (a pytree; ``()`` for a static law)."""

    @abc.abstractmethod
    def torque(self, gains, state, feedback: Feedback, desired: Desired, t) -> tuple[jax.Array, Any]:
        """(tau [N m] (3, ...), the internal state's time derivative)."""


def hashable(value):
    """A real array option (e.g. a nominal inertia) as nested tuples of floats: hashable
    and compared by value (``jnp.asarray`` of it gives back the array); None stays None."""
    if value is None:
        return None
    array = np.asarray(value)
    if array.dtype.kind not in "iuf":
        raise TypeError(f"expected a real numeric array, got {value!r}")
    return _tuples(array.astype(float).tolist())


def _tuples(x):
    return tuple(_tuples(v) for v in x) if isinstance(x, list) else x


@dataclasses.dataclass(frozen=True)
class FunctionController(Controller):
    """A controller of plain functions (see :func:`from_functions`): equal where the
    functions are the same objects."""

    init_fn: Callable[[Any], Any]
    torque_fn: Callable[..., tuple[jax.Array, Any]]
    gains_type: type | None = None
    update: Callable | None = None

    def init(self, gains):
        return self.init_fn(gains)

    def torque(self, gains, state, feedback, desired, t):
        return self.torque_fn(gains, state, feedback, desired, t)


def from_functions(init: Callable, torque: Callable, gains_type: type | None = None,
                   update: Callable | None = None) -> Controller:
    """A controller of functions ``init(gains)``, ``torque(gains, state, feedback, desired, t)``
    and optionally ``update(gains, state, feedback, desired, t, period)`` (module docstring);
    for a quick experiment. A registered controller is better a subclass of
    :class:`Controller` with its options as fields (equal options: one compilation)."""
    return FunctionController(init, torque, gains_type, update)


class TrackingError(NamedTuple):
    """R_e = R_d^T R, Omega_r = R^T R_d Omega_d, Omega_e = Omega - Omega_r (docs/model.md §2)."""

    R_e: jax.Array
    Omega_r: jax.Array
    Omega_e: jax.Array
    feedforward_dot: jax.Array  # R^T R_d Omega_d'


def tracking_error(feedback: Feedback, desired: Desired) -> TrackingError:
    R_e = so3.rmatmul(desired.R_d, feedback.R)
    Omega_r = so3.rmatvec(R_e, desired.Omega_d)
    feedforward_dot = so3.rmatvec(R_e, desired.Omega_d_dot)
    return TrackingError(R_e, Omega_r, feedback.Omega - Omega_r, feedforward_dot)


def nominal_inertia(J_hat):
    """v -> J_hat v [kg m^2 x v's unit] for v (3, ...), the identity where J_hat is None."""
    if J_hat is None:
        return lambda v: v
    return lambda v: so3.matvec(so3.batch_like(J_hat, 2, v), v)


def inertial_terms(nominal, Omega, err: TrackingError, extra=None):
    """(Omega x J_hat Omega, J_hat (Omega x Omega_r - R^T R_d Omega_d' [+ extra])) [N m], the
    rigid body's terms a law with a nominal inertia cancels (docs/model.md §3.1); nominal: v -> J_hat v."""
    rate = so3.cross(Omega, err.Omega_r) - err.feedforward_dot
    return so3.cross(Omega, nominal(Omega)), nominal(rate if extra is None else rate + extra)
