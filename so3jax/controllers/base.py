"""The controller interface (optax style: a NamedTuple of pure functions).

A controller is ``Controller(init, torque)``:

* ``init(gains) -> state``: the controller's initial internal state (a pytree,
  ``()`` for a static law);
* ``torque(gains, state, measured, desired, t) -> (tau, state_dot)``: the control
  torque [N m] and the time derivative of the internal state, which the continuous
  wiring integrates with the plant (docs/model.md §5). The true inertia is never passed in;
* ``gains_type`` (optional): the NamedTuple of gains it takes, checked before a run;
* ``update`` (optional): ``update(gains, state, measured, desired, t, period) -> state``,
  the state's discrete update at a control tick of the sampled wiring (t: the tick's
  time [s], period: Delta_c [s]), as flight software computes it. Without it the tick
  applies forward Euler, ``state + period * state_dot`` (docs/model.md §8.1).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax

from so3jax.core import so3


class Measured(NamedTuple):
    R: jax.Array  # (3, 3) body -> inertial
    Omega: jax.Array  # (3,) body rate, rad/s
    wheel_momentum: Any = None  # (3,) N m s: h_w the law must account for (the actuator does not), or None


class Desired(NamedTuple):
    R_d: jax.Array  # (3, 3)
    Omega_d: jax.Array  # (3,) rad/s, desired frame
    Omega_d_dot: jax.Array  # (3,) rad/s^2


class Controller(NamedTuple):
    init: Callable[[Any], Any]
    torque: Callable[[Any, Any, Measured, Desired, jax.Array], tuple[jax.Array, Any]]
    gains_type: type | None = None  # the NamedTuple of gains the law reads (checked by the rollout); None: any
    update: Callable[[Any, Any, Measured, Desired, jax.Array, jax.Array], Any] | None = None  # at ticks; None: Euler


class TrackingError(NamedTuple):
    """R_e = R_d^T R, Omega_r = R^T R_d Omega_d, Omega_e = Omega - Omega_r (docs/model.md §2)."""

    R_e: jax.Array
    Omega_r: jax.Array
    Omega_e: jax.Array
    feedforward_dot: jax.Array  # R^T R_d Omega_d'


def tracking_error(measured: Measured, desired: Desired) -> TrackingError:
    R_e = so3.rmatmul(desired.R_d, measured.R)
    Omega_r = so3.rmatvec(R_e, desired.Omega_d)
    feedforward_dot = so3.rmatvec(R_e, desired.Omega_d_dot)
    return TrackingError(R_e, Omega_r, measured.Omega - Omega_r, feedforward_dot)


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
