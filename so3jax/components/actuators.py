"""Actuators: the controller's command tau_c in, the torque on the body out (docs/model.md §8.4).

The interface and its defaults are :class:`so3jax.components.base.Actuator`'s (only
``command`` is required): ``init``, ``command(state, tau_c, Omega_hat)``, ``body_torque``,
``stored_momentum``, ``derivative``, ``delivered``, ``effort``, ``limits``, ``speed_ratio``,
``uncompensated_momentum``, ``spin_inertia_values`` and ``check``. Arrays follow
:mod:`so3jax.core.so3`: components first, batch axes last; wheel arrays are (N, *b).
Parameters are cast to the dtype of the arrays they meet.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.components import registry as components
from so3jax.components.base import Actuator, StoredMomentum, no_limit
from so3jax.core import checks, so3
from so3jax.core.params import Param
from so3jax.core.pytree import pytree_dataclass, static_field

_UNIT_TOLERANCE = 1e-9  # | |g_i| - 1 | allowed for a spin axis (float64; 100 eps in a coarser dtype)
_RANK_TOLERANCE = 1e-9  # smallest singular value of G_s below this: rank < 3
MAX_CORNER_WHEELS = 16  # Wheels.momentum_capacity: up to 2^16 corners, then the sum bound


def _values(x):
    """x as a numpy array, or None for a traced value (checked when it is concrete)."""
    try:
        return np.asarray(x, dtype=float)
    except jax.errors.TracerArrayConversionError:
        return None


def _check_values(name: str, x, shape, positive: bool = False, nonnegative: bool = False) -> None:
    """One-line ValueError unless x is real numbers of ``shape``, finite (positive / non-negative)."""
    checks.values(name, x, shape, positive, nonnegative)


# --- stored momentum, ideal and saturated body torques -----------------------------------


def momentum(actuator: Actuator, state, Omega):
    """J_locked Omega + h_rel (3, *b) [N m s]: the angular momentum the actuator stores,
    body frame; zeros where it stores none."""
    stored = actuator.stored_momentum(state)
    if stored is None:
        return jnp.zeros_like(Omega)
    return so3.matvec(so3.batch_like(stored.locked_inertia, 2, Omega), Omega) + stored.relative


@pytree_dataclass
class Ideal(Actuator):
    """tau = tau_c (docs/model.md §8.4 ``ideal``)."""

    def command(self, state, tau_c, Omega_hat):
        return tau_c


@pytree_dataclass
class Saturated(Actuator):
    """tau_i = clip(tau_c,i, -max_torque_i, max_torque_i) per body axis (docs/model.md §8.4 ``saturated``).

    max_torque: (3,) or a scalar for every axis, N m.
    """

    max_torque: jax.Array

    def _limit(self, like):
        return so3.batch_like(jnp.asarray(self.max_torque).astype(like.dtype), 1, like)

    def command(self, state, tau_c, Omega_hat):
        limit = self._limit(tau_c)
        return jnp.clip(tau_c, -limit, limit)

    def limits(self, state, held, tau_c):
        """(any |tau_c,i| > max_torque_i, False), of the batch shape."""
        over = jnp.abs(tau_c) > self._limit(tau_c)
        return over[0] | over[1] | over[2], no_limit(held)

    def check(self) -> None:
        """One-line ValueErrors: max_torque (3,) or a scalar, finite, non-negative."""
        scalar = np.shape(self.max_torque) == ()
        _check_values("saturated max_torque [N m]", self.max_torque, () if scalar else (3,), nonnegative=True)


# --- reaction wheels ---------------------------------------------------------------------


def _per_wheel(x, like):
    """A (N,) parameter as (N, 1, ...) in the dtype of ``like`` (N or 3, *b)."""
    return so3.batch_like(jnp.asarray(x).astype(like.dtype), 1, like)


def _spin_sum(G, x):
    """G x = sum_i g_i x_i for G (3, N, ...), x (N, ...) -> (3, ...)."""
    total = G[:, 0] * x[0]
    for i in range(1, G.shape[1]):
        total = total + G[:, i] * x[i]
    return total


def _weighted_gram(G, w):
    """sum_i w_i g_i g_i^T = G diag(w) G^T, (3, 3), for G (3, N), w (N,)."""
    total = w[0] * so3.outer(G[:, 0], G[:, 0])
    for i in range(1, G.shape[1]):
        total = total + w[i] * so3.outer(G[:, i], G[:, i])
    return total


class WheelCommand(NamedTuple):
    """What the wheels hold over a control period (docs/model.md §8.4), computed at the tick."""

    u: jax.Array  # (N, *b) motor torques, N m (the body receives -G_s u)
    compensation: jax.Array  # (3, *b) Omega_hat x h_w_hat included in u, N m (zeros without)
    stuck: jax.Array | None = None  # (N, *b) 1 for a wheel stuck at its speed (8.22), 0 else; None: none sticks
    friction: jax.Array | None = None  # (N, *b) each wheel's friction factor k_i (8.23); None: 1


@pytree_dataclass
class Wheels(Actuator):
    """N reaction wheels (docs/model.md §8.4 ``wheels``).

    axes: G_s (3, N), unit spin axes g_i as columns; spin_inertia: J_s (N,) kg m^2;
    max_torque: u_max (N,) N m; max_speed: Omega_max (N,) rad/s; initial_speed:
    Omega_w(0) (N,) rad/s, relative to the body. The state is Omega_w (N, *b); the held
    input a :class:`WheelCommand`. momentum_compensation: the command becomes
    tau_c + Omega_hat x h_w_hat before it is distributed. motor_torque: None, or a
    constant motor-torque command per wheel (N,) [N m] that replaces the distributed
    command (open-loop and identification runs: the controller's command is not used),
    each wheel clipped on its own.

    axes and spin_inertia are the wheels as the flight software knows them (the command's
    distribution and momentum compensation); plant_axes (3, N) and plant_spin_inertia (N,)
    are the wheels the body carries, where they differ (a misaligned spin axis, a spin
    inertia error; None: as known).

    available: None, or (N,) 1 for a wheel the distribution uses and 0 for one it drops (a
    wheel known failed, docs/model.md §8.7): u = -W G_s^T (G_s W G_s^T)^{-1} tau with
    W = diag(available), the distribution of all wheels where every one is available.

    coulomb_friction f_c (N,) [N m], viscous_friction c_v (N,) [N m s/rad], friction_speed
    omega_lc (N,) [rad/s]: the bearing friction of the wheels the body carries (8.13a), None
    without friction. stuck (N,): 1 for a wheel stuck at its speed (8.22); friction_factor
    (N,): k_i, each wheel's friction scaled (8.23); None without such faults (set at a tick by
    :meth:`so3jax.components.faults.Faults.actuator`, held in the :class:`WheelCommand`).
    """

    axes: jax.Array
    spin_inertia: jax.Array
    max_torque: jax.Array
    max_speed: jax.Array
    initial_speed: jax.Array
    momentum_compensation: bool = static_field(default=True)
    motor_torque: jax.Array | None = None
    plant_axes: jax.Array | None = None
    plant_spin_inertia: jax.Array | None = None
    available: jax.Array | None = None
    coulomb_friction: jax.Array | None = None
    viscous_friction: jax.Array | None = None
    friction_speed: jax.Array | None = None
    stuck: jax.Array | None = None
    friction_factor: jax.Array | None = None

    @property
    def count(self) -> int:
        return np.shape(self.axes)[1]

    @property
    def has_friction(self) -> bool:
        """Whether the wheels the body carries have bearing friction (8.13a)."""
        return self.coulomb_friction is not None

    def _axes(self, like, plant: bool = False):
        """G_s (the plant's with ``plant``) as (3, N, 1, ...) in the dtype of ``like`` (3 or N, *b)."""
        G = self._plant_axes() if plant else self.axes
        return so3.batch_like(jnp.asarray(G).astype(like.dtype), 2, like)

    def _plant_axes(self):
        """G_s of the wheels the body carries (3, N)."""
        return self.axes if self.plant_axes is None else self.plant_axes

    def _plant_spin_inertia(self):
        """J_s of the wheels the body carries (N,) [kg m^2]."""
        return self.spin_inertia if self.plant_spin_inertia is None else self.plant_spin_inertia

    def init(self, batch_shape, dtype):
        """Omega_w(0) broadcast to (N, *batch_shape) [rad/s]."""
        return so3.broadcast(jnp.asarray(self.initial_speed).astype(dtype), 1, batch_shape)

    def _spin_inertia_matrix(self, dtype):
        """G_s J_s G_s^T (3, 3) [kg m^2] of the wheels the body carries."""
        G, J_s = self._plant_axes(), self._plant_spin_inertia()
        return _weighted_gram(jnp.asarray(G).astype(dtype), jnp.asarray(J_s).astype(dtype))

    def spin_inertia_values(self):
        """G_s J_s G_s^T (3, 3) [kg m^2] as a NumPy array, or None where a parameter is
        traced (the checks' host-side copy of :meth:`_spin_inertia_matrix`)."""
        G, J_s = _values(self._plant_axes()), _values(self._plant_spin_inertia())
        if G is None or J_s is None or G.ndim != 2 or J_s.shape != G.shape[1:]:
            return None
        return (G * J_s) @ G.T

    def momentum_capacity(self) -> float | None:
        """The most momentum the wheels the body carries store relative to it [N m s]: the
        largest |G_s J_s Omega_w| over |Omega_w,i| <= Omega_max,i, at a corner of that box
        (every wheel at its speed limit; beyond MAX_CORNER_WHEELS wheels, its bound
        sum_i J_s,i Omega_max,i); None where a parameter is traced."""
        G, J_s, limit = _values(self._plant_axes()), _values(self._plant_spin_inertia()), _values(self.max_speed)
        if G is None or J_s is None or limit is None or G.ndim != 2:
            return None
        n = G.shape[1]
        reach = np.abs(np.broadcast_to(J_s * limit, (n,)))
        if n > MAX_CORNER_WHEELS:
            return float(np.sum(reach))
        signs = 1.0 - 2.0 * ((np.arange(2**n)[:, None] >> np.arange(n)) & 1)  # every corner (2^n, N)
        return float(np.max(np.linalg.norm((signs * reach) @ G.T, axis=1)))

    def locked_wheel_inertia(self, J):
        """J_B = J - G_s J_s G_s^T [kg m^2] for J (3, 3, ...) (docs/model.md §8.4): the body without
        the wheels' spin inertia."""
        J = jnp.asarray(J)
        return J - so3.broadcast(self._spin_inertia_matrix(J.dtype), 2, J.shape[2:])

    def momentum(self, state, Omega):
        """h_w = G_s J_s (G_s^T Omega + Omega_w) (3, *b) [N m s] (docs/model.md §8.4), as the flight
        software models it (the momentum compensation's h_w_hat)."""
        G = self._axes(Omega)
        return _spin_sum(G, _per_wheel(self.spin_inertia, Omega) * (so3.rmatvec(G, Omega) + state))

    def stored_momentum(self, state):
        """(G_s J_s G_s^T, G_s J_s Omega_w): h_w = G_s J_s G_s^T Omega + G_s J_s Omega_w (docs/model.md §8.4),
        of the wheels the body carries."""
        relative = _spin_sum(self._axes(state, plant=True), _per_wheel(self._plant_spin_inertia(), state) * state)
        return StoredMomentum(self._spin_inertia_matrix(state.dtype), relative)

    def distribute(self, tau):
        """Minimum-norm motor torques u = -G_s^T (G_s G_s^T)^{-1} tau (N, *b) [N m], so that
        -G_s u = tau (docs/model.md §8.4), before any limit."""
        G = jnp.asarray(self.axes).astype(tau.dtype)
        gram = so3.batch_like(_weighted_gram(G, jnp.ones(self.count, tau.dtype)), 2, tau)
        u = -so3.rmatvec(self._axes(tau), so3.solve_spd(gram, tau))
        if self.available is None:
            return u
        return jnp.where(jnp.all(self._available(tau) > 0, axis=0), u, self.distribute_available(tau))

    def _available(self, like):
        """a (N, *b) in the dtype of ``like`` (3, *b)."""
        return _per_wheel(self.available, like)

    def distribute_available(self, tau):
        """u = -W G_s^T (G_s W G_s^T)^{-1} tau (N, *b) [N m], W = diag(available) (docs/model.md
        (8.17)): the minimum-norm motor torques of the available wheels, so that -G_s u = tau
        where they span 3-D, and 0 on a wheel dropped."""
        G, w = self._axes(tau), self._available(tau)
        gram = w[0] * so3.outer(G[:, 0], G[:, 0])
        for i in range(1, self.count):
            gram = gram + w[i] * so3.outer(G[:, i], G[:, i])
        return -w * so3.rmatvec(G, so3.solve_spd(gram, tau))

    def command(self, state, tau_c, Omega_hat):
        """The motor torques u (N, *b) [N m] held over the period (docs/model.md §8.4): the command
        (plus Omega_hat x h_w_hat with momentum compensation, h_w_hat from Omega_hat and the
        tachometers' Omega_w) distributed at minimum norm, clipped to +-u_max, and zero on a
        wheel at its speed limit that it would spin faster; with the compensation they include."""
        if self.motor_torque is not None:  # a per-wheel command: nothing distributed, nothing compensated
            compensation = jnp.zeros_like(tau_c)
            wanted = jnp.broadcast_to(_per_wheel(self.motor_torque, state), state.shape)
        else:
            compensation = self._compensation(state, Omega_hat) if self.momentum_compensation else jnp.zeros_like(tau_c)
            wanted = self.distribute(tau_c + compensation)
        tau = tau_c + compensation
        u = self.torque_limited(wanted, _per_wheel(self.max_torque, tau))
        faster = (jnp.abs(state) >= _per_wheel(self.max_speed, tau)) & (u * state > 0)
        held = [None if x is None else jnp.broadcast_to(_per_wheel(x, state), state.shape)
                for x in (self.stuck, self.friction_factor)]
        return WheelCommand(jnp.where(faster, jnp.zeros_like(u), u), compensation, *held)

    def torque_limited(self, u, u_max):
        """The motor torques u (N, *b) clipped to +-u_max (N, *b) [N m]."""
        return jnp.clip(u, -u_max, u_max)

    def friction_torque(self, state, factor=None):
        """tau_f (N, *b) [N m], the bearing friction on each wheel at its relative speed
        Omega_w (N, *b) (docs/model.md (8.13a), Basilisk's reactionWheelStateEffector without
        Stribeck): -(f_c sign(Omega_w) + c_v Omega_w) for |Omega_w| >= omega_lc, linear within
        (-(f_c + c_v omega_lc) / omega_lc Omega_w); f_c and c_v scaled by ``factor`` k_i (N, *b)."""
        f_c, c_v = _per_wheel(self.coulomb_friction, state), _per_wheel(self.viscous_friction, state)
        limit = _per_wheel(self.friction_speed, state)
        if factor is not None:
            f_c, c_v = factor * f_c, factor * c_v
        outside = jnp.sign(state) * f_c + c_v * state
        inside = (f_c + c_v * limit) / limit * state
        return -jnp.where(jnp.abs(state) < limit, inside, outside)

    def _spin_torque(self, state, held):
        """u + tau_f (N, *b) [N m], the torque on each wheel about its axis besides a stuck
        wheel's constraint (0 on a stuck wheel: the body carries it, (8.22))."""
        torque = held.u if not self.has_friction else held.u + self.friction_torque(state, held.friction)
        return torque if held.stuck is None else jnp.where(held.stuck > 0, jnp.zeros_like(torque), torque)

    def body_torque(self, state, held, Omega):
        """-G_s (u + tau_f) (3, *b) [N m], along the axes the body carries."""
        return -_spin_sum(self._axes(held.u, plant=True), self._spin_torque(state, held))

    def constrained_inertia(self, held):
        """sum_i s_i J_s,i g_i g_i^T (3, 3, *b) [kg m^2] of the wheels stuck (s_i = 1, (8.22)),
        None where none can stick."""
        if held.stuck is None:
            return None
        G = self._axes(held.u, plant=True)
        w = held.stuck * _per_wheel(self._plant_spin_inertia(), held.u)
        total = so3.outer(G[:, 0], G[:, 0]) * w[0]
        for i in range(1, self.count):
            total = total + so3.outer(G[:, i], G[:, i]) * w[i]
        return total

    def uncompensated_momentum(self, state, Omega_hat):
        """h_w_hat (from Omega_hat and the tachometers) without the momentum compensation,
        None with it (the command then adds Omega_hat x h_w_hat itself)."""
        return None if self.momentum_compensation else self.momentum(state, Omega_hat)

    def _compensation(self, state, Omega_hat):
        """Omega_hat x h_w_hat (3, *b) [N m]."""
        return so3.cross(Omega_hat, self.momentum(state, Omega_hat))

    def delivered(self, state, held, Omega):
        """-G_s u less the momentum compensation it includes (Omega_hat x h_w_hat of the
        tick): the command tau_c itself where no limit binds [N m]."""
        return self.body_torque(state, held, Omega) - held.compensation

    def derivative(self, state, held, Omega, Omega_dot):
        """Omega_w' = J_s^{-1} (u + tau_f) - G_s^T Omega' (N, *b) [rad/s^2] (docs/model.md §8.4),
        0 on a wheel stuck at its speed (8.22)."""
        rate = (self._spin_torque(state, held) / _per_wheel(self._plant_spin_inertia(), Omega)
                - so3.rmatvec(self._axes(Omega, plant=True), Omega_dot))
        return rate if held.stuck is None else jnp.where(held.stuck > 0, jnp.zeros_like(rate), rate)

    def effort(self, held):
        """sum_i u_i^2 [N^2 m^2]."""
        return so3.sum_leading(held.u * held.u)

    def limits(self, state, held, tau_c):
        """(a motor torque clipped at u_max, a wheel at |Omega_w,i| >= Omega_max,i), of
        the batch shape. Clipping is read from the held u, |u_i| = u_max,i exactly where
        the clip binds: the distributed command includes the momentum compensation,
        which tau_c does not show. A clipped torque then zeroed by the speed limit counts
        at the speed limit only."""
        at_torque = jnp.any(jnp.abs(held.u) >= _per_wheel(self.max_torque, held.u), axis=0)
        return at_torque, jnp.any(jnp.abs(state) >= _per_wheel(self.max_speed, state), axis=0)

    def speed_ratio(self, state):
        """max_i |Omega_w,i| / Omega_max,i, of the batch shape."""
        return jnp.max(jnp.abs(state) / _per_wheel(self.max_speed, state), axis=0)

    def check(self) -> None:
        """One-line ValueErrors: shapes, finite values, unit axes spanning 3-D, J_s > 0,
        u_max > 0, Omega_max > 0 (J_B > 0 is checked against the plant's inertia elsewhere)."""
        shape = np.shape(self.axes)
        if len(shape) != 2 or shape[0] != 3 or shape[1] < 1:
            raise ValueError(f"wheel axes must be a (3, N) array of spin axes (columns), got shape {shape}")
        n = shape[1]
        _check_values("wheel axes", self.axes, shape)
        _check_values("wheel spin_inertia [kg m^2]", self.spin_inertia, (n,), positive=True)
        _check_values("wheel max_torque [N m]", self.max_torque, (n,), positive=True)
        _check_values("wheel max_speed [rad/s]", self.max_speed, (n,), positive=True)
        _check_values("wheel initial_speed [rad/s]", self.initial_speed, (n,))
        if self.motor_torque is not None:
            _check_values("wheel motor_torque [N m]", self.motor_torque, (n,))
        if self.available is not None:
            _check_values("wheel available", self.available, (n,), nonnegative=True)
            flags = _values(self.available)
            if flags is not None and not np.all((flags == 0) | (flags == 1)):
                raise ValueError(f"wheel available must be 1 (used) or 0 (dropped) per wheel, got {flags.tolist()}")
        if self.plant_axes is not None:
            _check_values("wheel plant_axes", self.plant_axes, shape)
        if self.plant_spin_inertia is not None:
            _check_values("wheel plant_spin_inertia [kg m^2]", self.plant_spin_inertia, (n,), positive=True)
        friction = (self.coulomb_friction, self.viscous_friction, self.friction_speed)
        for x, name, sign in zip(friction, ("coulomb_friction [N m]", "viscous_friction [N m s/rad]",
                                            "friction_speed [rad/s]"), ("nonnegative", "nonnegative", "positive")):
            if x is not None:
                _check_values(f"wheel {name}", x, (n,), **{sign: True})
        if any(x is None for x in friction) and not all(x is None for x in friction):
            raise ValueError("wheel friction needs coulomb_friction, viscous_friction and friction_speed together")
        for x, name in ((self.stuck, "stuck"), (self.friction_factor, "friction_factor")):
            if x is not None:
                _check_values(f"wheel {name}", x, (n,), nonnegative=True)
        speed, limit = _values(self.initial_speed), _values(self.max_speed)
        if speed is not None and limit is not None and np.any(np.abs(speed) > limit):
            i = int(np.argmax(np.abs(speed) > limit))
            raise ValueError("actuator.wheels.initial_speed [rad/s] must not exceed actuator.wheels.max_speed in "
                             f"magnitude (wheel {i + 1}: {speed[i]:g} against {limit[i]:g})")
        if not isinstance(self.momentum_compensation, bool):
            raise ValueError(f"wheel momentum_compensation must be True or False, got {self.momentum_compensation!r}")
        G = _values(self.axes)
        if G is None:
            return
        tolerance = max(_UNIT_TOLERANCE, 100 * float(np.finfo(np.asarray(self.axes).dtype).eps))
        norms = np.linalg.norm(G, axis=0)
        if np.any(np.abs(norms - 1.0) > tolerance):
            raise ValueError(f"wheel spin axes must be unit vectors, got norms {norms.tolist()}")
        if n < 3 or np.linalg.svd(G, compute_uv=False).min() < _RANK_TOLERANCE:
            raise ValueError(f"the {n} wheel spin axes span less than 3-D: "
                             "the wheels cannot produce torque about every axis")


def pyramid_axes(n: int = 4, elevation_deg: float = 54.74, azimuth0_deg: float = 0.0) -> np.ndarray:
    """(3, n) unit spin axes at ``elevation_deg`` from the body z axis, 360/n degrees apart
    in azimuth from ``azimuth0_deg`` (docs/model.md §8.5: four wheels at 54.74 deg, 90 deg apart)."""
    elevation = math.radians(elevation_deg)
    azimuth = np.radians(azimuth0_deg + 360.0 / n * np.arange(n))
    return np.stack([math.sin(elevation) * np.cos(azimuth), math.sin(elevation) * np.sin(azimuth),
                     np.full(n, math.cos(elevation))])



# --- registrations (so3jax.components.registry): a mission's [actuator.NAME] tables ---------------------

_PYRAMID = [[0.8165408118857462, 0.0, 0.5772877120855479], [0.0, 0.8165408118857462, 0.5772877120855479],
            [-0.8165408118857462, 0.0, 0.5772877120855479], [0.0, -0.8165408118857462, 0.5772877120855479]]
_PER_WHEEL = ((), (None,))  # one value for every wheel, or one per wheel
FRICTION_KEYS = ("coulomb_friction", "viscous_friction", "friction_speed")  # a wheel's bearing friction (8.13a)
MAX_FRICTION_STEP = 2.0  # dt times friction_rate() at most: within RK4's real-axis stability limit (about 2.79)
_WHEEL_LISTS = ("spin_inertia", "max_torque", "max_speed", "initial_speed", "spin_inertia_error") + FRICTION_KEYS


def _wheel_values(values: dict) -> dict:
    """The per-wheel parameters broadcast to (N,) for N = the number of axes (Omega_w(0)
    within the speed limit is :meth:`Wheels.check`'s, when the mission's loop is checked)."""
    n = values["axes"].shape[0]
    out = dict(values)
    for key in _WHEEL_LISTS:
        v = np.asarray(values[key], float)
        if v.shape not in ((), (n,)):
            raise ValueError(f"actuator.wheels.{key} must be one number or {n} (one per wheel), got {v.shape[0]}")
        out[key] = np.broadcast_to(v, (n,)).copy()
    if out["misalignment"] is None:
        out["misalignment"] = np.zeros((n, 3))
    elif np.shape(out["misalignment"]) != (n, 3):
        raise ValueError(f"actuator.wheels.misalignment [rad] must hold {n} rotation vectors (one per wheel), "
                         f"got shape {np.shape(out['misalignment'])}")
    motor = values["motor_torque"]
    if motor is not None and np.shape(motor) != (n,):
        raise ValueError(f"actuator.wheels.motor_torque [N m] must hold {n} values (one per wheel), "
                         f"got {np.size(motor)}")
    return out


def friction_rate(values: dict, factor: float = 1.0) -> float:
    """The fastest rate the wheels' friction alone sets a wheel's speed to decay at [1/s]:
    max_i k (f_c,i / omega_lc,i + c_v,i) / J_s,i, the friction's slope at rest (8.13a) over
    the wheel's spin inertia, with its friction scaled by ``factor`` k (a fault's, (8.23));
    the plant's RK4 step dt is stable for dt times it up to about 2.8 (checked against
    :data:`MAX_FRICTION_STEP`)."""
    slope = np.asarray(values["coulomb_friction"], float) / np.asarray(values["friction_speed"], float)
    spin = np.asarray(values["spin_inertia"], float) * (1.0 + np.asarray(values["spin_inertia_error"], float))
    return float(np.max(factor * (slope + np.asarray(values["viscous_friction"], float)) / spin))


def _known_zero(x) -> bool:
    """x is concrete and all zero (a dispersed, traced value is not)."""
    return isinstance(x, (int, float, np.ndarray, list)) and not np.any(np.asarray(x))


def _wheels(w: dict, ctx) -> Wheels:
    """The wheels; where misalignment or spin_inertia_error is not zero, the plant's axes
    g_i' = exp(hat(misalignment_i)) g_i and spin inertias J_s (1 + spin_inertia_error)."""
    a = ctx.as_array
    motor = None if w["motor_torque"] is None else a(w["motor_torque"])
    axes, spin = a(w["axes"].T), a(w["spin_inertia"])
    plant_axes = None if _known_zero(w["misalignment"]) else so3.matvec(so3.exp(a(w["misalignment"]).T), axes)
    plant_spin = None if _known_zero(w["spin_inertia_error"]) else spin * (1 + a(w["spin_inertia_error"]))
    frictionless = _known_zero(w["coulomb_friction"]) and _known_zero(w["viscous_friction"])
    friction = (None,) * 3 if frictionless else tuple(a(w[k]) for k in FRICTION_KEYS)
    return Wheels(axes, spin, a(w["max_torque"]), a(w["max_speed"]), a(w["initial_speed"]),
                  bool(w["momentum_compensation"]), motor, plant_axes, plant_spin, None, *friction)


components.register(components.ComponentSpec(
    kind="actuator", name="ideal", component=Ideal, params=(), build=lambda v, ctx: Ideal(),
    doc="tau = tau_c",
))
components.register(components.ComponentSpec(
    kind="actuator", name="saturated", component=Saturated,
    params=(Param("max_torque", [0.25, 0.25, 0.25], "N m", shapes=((), (3,)), low=0.0, doc="limit per body axis"),),
    build=lambda v, ctx: Saturated(ctx.as_array(np.broadcast_to(v["max_torque"], (3,)).copy())),
    doc="tau_i = clip(tau_c,i, -max_torque_i, max_torque_i)",
))
components.register(components.ComponentSpec(
    kind="actuator", name="wheels", component=Wheels,
    params=(
        Param("axes", _PYRAMID, "", shapes=((None, 3),), doc="one unit spin axis per wheel (rows)"),
        Param("spin_inertia", 0.16, "kg m^2", shapes=_PER_WHEEL, low=0.0, low_excluded=True, doc="J_s"),
        Param("max_torque", 0.25, "N m", shapes=_PER_WHEEL, low=0.0, low_excluded=True,
              doc="motor torque limit u_max"),
        Param("max_speed", 628.0, "rad/s", shapes=_PER_WHEEL, low=0.0, low_excluded=True,
              doc="speed limit Omega_max"),
        Param("initial_speed", 0.0, "rad/s", shapes=_PER_WHEEL, doc="Omega_w(0), relative to the body"),
        Param("momentum_compensation", True, boolean=True, doc="command tau_c + Omega_hat x h_w_hat"),
        Param("motor_torque", None, "N m", shapes=((None,),),
              doc="a constant motor-torque command per wheel, replacing the controller's (open loop)"),
        Param("misalignment", None, "rad", shapes=((None, 3),),
              doc="each wheel's spin axis in the body rotated by this rotation vector, the flight software "
                  "keeping `axes` (default: none)"),
        Param("spin_inertia_error", 0.0, "-", shapes=_PER_WHEEL, low=-0.9, high=10.0,
              doc="the body's wheels have J_s (1 + error), the flight software keeping `spin_inertia`"),
        Param("coulomb_friction", 0.0, "N m", shapes=_PER_WHEEL, low=0.0,
              doc="bearing friction f_c, against the wheel's speed relative to the body (Basilisk's fCoulomb)"),
        Param("viscous_friction", 0.0, "N m s/rad", shapes=_PER_WHEEL, low=0.0,
              doc="bearing friction c_v Omega_w (Basilisk's cViscous)"),
        Param("friction_speed", 1e-4, "rad/s", shapes=_PER_WHEEL, low=0.0, low_excluded=True,
              doc="below this speed the friction is linear in it, to 0 at rest (Basilisk's omegaLimitCycle)"),
    ),
    complete=_wheel_values,
    effort_label="motor effort",
    build=_wheels,
    doc="N reaction wheels (docs/model.md §8.4)",
))
