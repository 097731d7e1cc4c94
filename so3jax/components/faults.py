"""Faults the loop rides through, and what it knows of them (docs/model.md §8.7).

A :class:`Faults` holds a mission's failures as arrays of times and effects; the control
tick at t [s] reads the components through it: the wheels with their torque limits scaled
and the wheels the loop has detected as failed dropped from the distribution
(:meth:`Faults.actuator`), the measurements with a star-tracker outage and a gyro bias
step (:meth:`Faults.measured`), the thrusters with those it has detected as failed never
fired (:meth:`Faults.momentum`) and the body's torque without the failed ones' pulses
(:meth:`Faults.delivered`). Each fault acts from the first control tick at or after
its time, by ``jnp.where(t >= time, ...)``: the times stay traced (one compilation for
any), and a fault past the horizon leaves every value as without it. Arrays follow
:mod:`so3jax.core.so3`: components first, batch axes (if any) last.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from so3jax.components.base import Measurements
from so3jax.core import so3
from so3jax.core.pytree import pytree_dataclass


def after(t, time):
    """Whether a fault at ``time`` [s] acts at the tick at t [s]: t >= time."""
    return t >= jnp.asarray(time).astype(jnp.asarray(t).dtype)


@pytree_dataclass
class Faults:
    """A mission's faults (docs/model.md §8.7); an empty kind is None.

    wheel: (F,) the 0-based wheel of each wheel fault (a number: a sweep draws it per
    sample); wheel_time: (F,) its time [s]; wheel_factor: (F,) its motor torque limit's
    factor from then on (0: off; in (0, 1): degraded); wheel_detected: (F,) when the loop
    knows of it and drops that wheel from the distribution [s] (inf: never; a degraded
    wheel is kept). outage_start, outage_end: (K,)
    the star tracker's outages [start, end) [s]. bias_time: (M,) the gyro bias steps'
    times [s]; bias_step: (3, M) the steps [rad/s]. thruster_axis: (P,) the 0-based body
    axis of each failed thruster; thruster_sign: (P,) the sign of the torque it fires
    (+1, -1); thruster_time: (P,) when it fails off [s]; thruster_detected: (P,) when the
    loop knows of it and never fires it again [s] (inf: never).
    """

    wheel: jax.Array | None = None
    wheel_time: jax.Array | None = None
    wheel_factor: jax.Array | None = None
    wheel_detected: jax.Array | None = None
    wheel_stuck: jax.Array | None = None
    wheel_friction: jax.Array | None = None
    outage_start: jax.Array | None = None
    outage_end: jax.Array | None = None
    bias_time: jax.Array | None = None
    bias_step: jax.Array | None = None
    thruster_axis: jax.Array | None = None
    thruster_sign: jax.Array | None = None
    thruster_time: jax.Array | None = None
    thruster_detected: jax.Array | None = None

    def torque_scale(self, t, count: int):
        """s_i(t) (N, *b): the product of the factors of wheel i's faults acting at t (8.16)."""
        return self._product(t, count, self.wheel_factor)

    def _product(self, t, count: int, factors):
        """(N, *b): the product of ``factors`` (F,) of wheel i's faults acting at t."""
        scale = self._ones(t, count)
        for f in range(len(self.wheel)):
            hit = self._hits(f, count) & after(t, self.wheel_time[f])
            scale = jnp.where(hit, scale * factors[f], scale)
        return scale

    def stuck(self, t, count: int):
        """(N, *b): 1 for a wheel stuck at its speed at t (8.22), 0 else."""
        return 1.0 - self._product(t, count, 1.0 - jnp.asarray(self.wheel_stuck))

    def _ones(self, t, count: int):
        """(N, *b) ones in the factors' dtype, of the batch shape of the ticks' times."""
        ones = jnp.ones_like(after(t, self.wheel_time[0]), dtype=jnp.asarray(self.wheel_factor).dtype)
        return jnp.stack([ones] * count)

    def _hits(self, f: int, count: int):
        """(N, *b) whether wheel fault f strikes each wheel: i == wheel_f."""
        wheel = jnp.asarray(self.wheel[f])
        return jnp.stack([wheel == i for i in range(count)])

    def available(self, t, count: int):
        """a_i(t) (N, *b): 1 for a wheel the distribution uses at t, 0 for one detected failed (8.17)."""
        mask = self._ones(t, count)
        for f in range(len(self.wheel)):
            mask = jnp.where(self._hits(f, count) & after(t, self.wheel_detected[f]), 0.0, mask)
        return mask

    def actuator(self, actuator, t):
        """The actuator as the tick at t [s] drives it: each wheel's motor torque limit
        u_max,i s_i(t), the distribution over the wheels available (a_i(t)), the wheels stuck
        (8.22) and their friction factors (8.23) where the mission has such faults; the
        actuator itself where no wheel fails."""
        if self.wheel is None:
            return actuator
        count = actuator.count
        limit = jnp.asarray(actuator.max_torque)
        scale = self.torque_scale(t, count).astype(limit.dtype)
        scale = scale.reshape(scale.shape + (1,) * max(0, limit.ndim - scale.ndim))
        limit = limit.reshape(limit.shape + (1,) * max(0, scale.ndim - limit.ndim))
        stuck = None if self.wheel_stuck is None else self.stuck(t, count)
        friction = None if self.wheel_friction is None else self._product(t, count, self.wheel_friction)
        return dataclasses.replace(actuator, max_torque=limit * scale, available=self.available(t, count),
                                   stuck=stuck, friction_factor=friction)

    def judged(self, actuator, t):
        """The actuator whose limits the flight metrics read at the tick at t [s]: each
        wheel's torque limit u_max,i s_i(t), a wheel off (s_i = 0) never binding (its limit
        infinite); the actuator itself where no wheel fails."""
        if self.wheel is None:
            return actuator
        faulted = self.actuator(actuator, t)
        limit = jnp.asarray(faulted.max_torque)
        return dataclasses.replace(faulted, max_torque=jnp.where(limit > 0, limit, jnp.inf))

    def outage(self, t):
        """Whether the star tracker is out at t [s]: start_k <= t < end_k for some k (*b)."""
        t = jnp.asarray(t)
        out = [after(t, s) & ~after(t, e) for s, e in zip(self.outage_start, self.outage_end)]
        return jnp.any(jnp.stack(out), axis=0)

    def biased(self, x, t, reading=True):
        """x (3, *b) [rad/s] plus the gyro bias steps acting at t, x + sum_m [t >= t_m] Delta b_m
        (8.18); x itself, bit for bit, where none acts (or not ``reading``)."""
        step = jnp.asarray(self.bias_step).astype(x.dtype)
        for m in range(step.shape[1]):
            acting = so3.batch_like(after(t, self.bias_time[m]) & reading, 0, x)
            x = jnp.where(acting, x + so3.batch_like(step[:, m], 1, x), x)
        return x

    def measured(self, measured: Measurements, t, reading: bool = True) -> Measurements:
        """The measurements of the tick at t [s] with the faults acting: no star-tracker
        sample during an outage, the gyro bias steps in omega_m where the gyro has a
        reading (``reading``: the tick is at or after its first)."""
        if self.outage_start is not None:
            measured = measured._replace(star_valid=measured.star_valid & ~self.outage(t))
        if self.bias_time is not None:
            measured = measured._replace(omega_m=self.biased(measured.omega_m, t, reading))
        return measured

    def true_bias(self, bias, t):
        """The true gyro bias b_j plus the steps acting at t (3, *b) [rad/s]."""
        return bias if self.bias_time is None else self.biased(bias, t)

    def failed_thrusters(self, t, times):
        """(2, 3, *b) bool: whether the thruster of each sign (row 0: +, row 1: -) on each
        body axis has a fault whose ``times`` (thruster_time or thruster_detected) [s] are
        reached at the tick at t [s]."""
        failed = False
        for f in range(len(self.thruster_axis)):
            axis, sign = jnp.asarray(self.thruster_axis[f]), jnp.asarray(self.thruster_sign[f])
            hits = jnp.stack([jnp.stack([(axis == i) & (sign == s) for i in range(3)]) for s in (1, -1)])
            failed = failed | (hits & after(t, times[f]))
        return failed

    def momentum(self, manager, t):
        """The momentum manager as the tick at t [s] commands it: the thrusters the loop has
        detected as failed never fired (docs/model.md (8.21)); the manager itself where no
        thruster fails."""
        if self.thruster_axis is None:
            return manager
        return dataclasses.replace(manager, available=~self.failed_thrusters(t, self.thruster_detected))

    def delivered(self, held, t):
        """The thrusters' torque the body gets over the period of the tick at t [s]: held
        (3, *b) [N m], the torque commanded, less the pulse of every thruster failed at t
        (docs/model.md (8.20)); held itself where no thruster fails."""
        if self.thruster_axis is None:
            return held
        failed = so3.batch_like(self.failed_thrusters(t, self.thruster_time), 2, held)
        return jnp.where(((held > 0) & failed[0]) | ((held < 0) & failed[1]), jnp.zeros_like(held), held)
