"""Momentum management beside the wheels (``[momentum] kind``, docs/model.md §8.6): devices
that put an external torque on the body so that the attitude law, holding the attitude,
moves the wheels' momentum h_w (h_rel, body frame [N m s]) toward a target.

* ``thrusters``: a pair of thrusters per body axis, each pair a pure torque of a fixed
  level; dumping starts when |h_w| exceeds ``start`` and stops below ``stop``; while it
  lasts, the pair of every axis with |h_w,i| > stop / sqrt(3) fires against h_w,i, each
  firing lasting at least ``min_on_time`` (whole control periods);
* ``magnetorquers``: three orthogonal coils, dipole m = k (B_m x (h_target - h_w)) / |B_m|^2
  from a magnetometer's reading B_m, scaled down as a whole to the per-axis limits (a coil
  of limit 0, a failed one, gives none); the
  body feels m x B (the cross-product law: torque -k (Δh - (B^·Δh) B^), Δh = h_w - h_target).

Settings under which a device can never act are refused when the mission is read (one-line
ValueErrors naming the key): thrusters of no torque, a start threshold at or above the most
momentum the wheels store (:meth:`~so3jax.components.actuators.Wheels.momentum_capacity`),
magnetorquers of gain 0 or with every coil's limit 0, a target beyond the wheels' capacity.
A thruster pair of no torque beside others is a :class:`MomentumWarning`: that axis is never
dumped.

The attitude law sees their torques as disturbances, which the wheels absorb; the thrusters'
pulses, known to the flight software, are also taken off the wheels' command
(``feedforward``), so that the body feels them only where the wheels cannot follow. Firing
decisions are piecewise constant in the state: a gradient (``so3jax tune``) sees the torque
of the pulses fired and not how a change of gains would move them.
"""

from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.components import registry as components
from so3jax.components.base import MomentumManager
from so3jax.components.sensors import sensor_noise
from so3jax.core import checks, so3
from so3jax.core.params import Param
from so3jax.core.pytree import pytree_dataclass, static_field

MAGNETOMETER_STREAM = 7  # sensor noise stream of the magnetometer (docs/model.md §8.2's keys)


class MomentumWarning(UserWarning):
    """A momentum-management setting under which part of the device never acts (a thruster
    pair of no torque beside others)."""


def _capacity_text(capacity: float) -> str:
    return (f"the wheels store at most {capacity:.6g} N m s (|G_s J_s Omega_w| with every wheel at its "
            "actuator.wheels.max_speed)")


class ThrusterState(NamedTuple):
    dumping: jax.Array  # (*b) bool: between |h_w| > start and |h_w| < stop
    remaining: jax.Array  # (3, *b) int32: control periods each axis's current firing still lasts
    sign: jax.Array  # (3, *b) the firing direction of each axis (-1, 0, +1)


@pytree_dataclass
class Thrusters(MomentumManager):
    """Thruster momentum dumping: torque (3,) [N m] per axis pair; start, stop [N m s]
    thresholds on |h_w|; pulses of ``min_periods`` control periods at least (>= 1);
    feedforward_pulses: the wheels are commanded to absorb each pulse (tau_c - tau_m);
    available: (2, 3, *b) bool, whether the flight software fires the thruster of each sign
    (row 0: +, row 1: -) on each axis (False: one it knows failed, docs/model.md §8.7;
    :meth:`so3jax.components.faults.Faults.momentum`), None: all of them."""

    torque: jax.Array
    start: jax.Array
    stop: jax.Array
    min_periods: int = static_field(default=1)
    feedforward_pulses: bool = static_field(default=True)
    available: jax.Array | None = None

    def init(self, batch_shape, dtype):
        zero = jnp.zeros((3, *batch_shape), dtype)
        state = ThrusterState(jnp.zeros(batch_shape, bool), jnp.zeros((3, *batch_shape), jnp.int32), zero)
        return state, zero

    def command(self, state, h_rel, environment, t, R, key, j):
        size = jnp.sqrt(so3.sum_leading(h_rel * h_rel))
        dumping = jnp.where(size > self.start, True, jnp.where(size < self.stop, False, state.dumping))
        axis_limit = self.stop / math.sqrt(3.0)
        begin = dumping & (state.remaining <= 0) & (jnp.abs(h_rel) > axis_limit)
        sign = jnp.where(state.remaining > 0, state.sign, jnp.where(begin, -jnp.sign(h_rel), 0.0))
        remaining = jnp.where(state.remaining > 0, state.remaining - 1, jnp.where(begin, self.min_periods - 1, 0))
        if self.available is not None:  # a thruster known failed is never fired: its pulse ends, none begins
            available = so3.batch_like(self.available, 2, h_rel)
            fired = jnp.where(sign > 0, available[0], available[1]) | (sign == 0)
            sign, remaining = jnp.where(fired, sign, jnp.zeros_like(sign)), jnp.where(fired, remaining, 0)
        torque = so3.batch_like(jnp.asarray(self.torque, h_rel.dtype), 1, h_rel)
        return ThrusterState(dumping, remaining.astype(jnp.int32), sign), sign * torque

    def body_torque(self, held, environment, t, R):
        return held

    def feedforward(self, held):
        return held if self.feedforward_pulses else None

    def check(self):
        torque, start, stop = (checks.concrete(x, name) for x, name in (
            (self.torque, "momentum.thrusters.torque"), (self.start, "momentum.thrusters.start"),
            (self.stop, "momentum.thrusters.stop")))
        if start is not None and stop is not None and not np.all(stop < start):
            raise ValueError(f"momentum.thrusters: stop ({stop}) must be below start ({start}) [N m s]")
        if torque is not None:
            _check_thruster_torque(torque)

    def check_capacity(self, capacity):
        start = checks.concrete(self.start, "momentum.thrusters.start")
        if start is not None and np.any(start >= capacity):
            raise ValueError(f"momentum.thrusters.start = {checks.short(start.tolist())} N m s is never exceeded: "
                             f"{_capacity_text(capacity)}; set start below it (or momentum.kind = 'none')")


@pytree_dataclass
class Magnetorquers(MomentumManager):
    """Cross-product unloading: gain [1/s], max_dipole (3,) [A m^2] (0: a failed coil, its
    dipole 0), target (3,) [N m s], magnetometer_noise [T] (1-sigma per axis, white)."""

    reads_field = True

    gain: jax.Array
    max_dipole: jax.Array
    target: jax.Array
    magnetometer_noise: jax.Array

    def init(self, batch_shape, dtype):
        return (), jnp.zeros((3, *batch_shape), dtype)

    def command(self, state, h_rel, environment, t, R, key, j):
        B = environment.magnetic_field_body(t, R)
        noise = sensor_noise(key, MAGNETOMETER_STREAM, j, h_rel.dtype)
        B_m = B + jnp.asarray(self.magnetometer_noise, h_rel.dtype) * noise
        error = so3.batch_like(jnp.asarray(self.target, h_rel.dtype), 1, h_rel) - h_rel
        squared = so3.sum_leading(B_m * B_m)
        m = self.gain * so3.cross(B_m, error) / jnp.where(squared > 0, squared, 1.0)
        limit = so3.batch_like(jnp.asarray(self.max_dipole, h_rel.dtype), 1, h_rel)
        working = limit > 0  # a coil of limit 0 (a failed one) gives none
        m = jnp.where(working, m, 0.0)
        ratio = jnp.max(jnp.abs(m) / jnp.where(working, limit, 1.0), axis=0)
        return (), m / jnp.maximum(ratio, 1.0)

    def body_torque(self, held, environment, t, R):
        return so3.cross(held, environment.magnetic_field_body(t, R))

    def check(self):
        for x, name in ((self.gain, "gain"), (self.max_dipole, "max_dipole"), (self.magnetometer_noise,
                                                                                 "magnetometer_noise")):
            v = checks.concrete(x, f"momentum.magnetorquers.{name}")
            if v is not None and not np.all(np.isfinite(v) & (v >= 0)):
                raise ValueError(f"momentum.magnetorquers.{name} must be finite and >= 0, got {v.tolist()}")
        gain = checks.concrete(self.gain, "momentum.magnetorquers.gain")
        if gain is not None and np.any(gain == 0):
            raise ValueError("momentum.magnetorquers.gain = 0 1/s: the magnetorquers never act (m = 0); give a "
                             "positive gain (or momentum.kind = 'none')")
        dipole = checks.concrete(self.max_dipole, "momentum.magnetorquers.max_dipole")
        if dipole is not None and np.all(dipole == 0):
            raise ValueError(f"momentum.magnetorquers.max_dipole = {checks.short(dipole.tolist())} A m^2: every coil "
                             "is failed (limit 0) and the magnetorquers never act; give a coil a positive limit "
                             "(or momentum.kind = 'none')")

    def check_capacity(self, capacity):
        target = checks.concrete(self.target, "momentum.magnetorquers.target")
        if target is not None and np.linalg.norm(target) > capacity:
            raise ValueError(f"momentum.magnetorquers.target = {checks.short(target.tolist())} N m s "
                             f"(|target| = {np.linalg.norm(target):.6g}) is out of reach: {_capacity_text(capacity)}")


def _check_thruster_torque(torque) -> None:
    """ValueError where no thruster pair gives a torque (the thrusters never act)."""
    if np.all(np.asarray(torque) == 0):
        raise ValueError(f"momentum.thrusters.torque = {checks.short(np.asarray(torque).tolist())} N m: no pair "
                         "gives a torque and the thrusters never act; give a positive torque (or "
                         "momentum.kind = 'none')")


def _thrusters(values, ctx):
    periods = max(1, math.ceil(values["min_on_time"] / ctx.period - 1e-9))
    torque = np.broadcast_to(values["torque"], (3,)).copy()
    return Thrusters(ctx.as_array(torque), ctx.as_array(values["start"]), ctx.as_array(values["stop"]), periods,
                     values["feedforward"])


def _thrusters_values(values: dict) -> dict:
    if not values["stop"] < values["start"]:
        raise ValueError(f"momentum.thrusters: stop ({values['stop']}) must be below start ({values['start']}) "
                         "[N m s]")
    _check_thruster_torque(values["torque"])
    torque = np.broadcast_to(values["torque"], (3,))
    idle = [axis for axis, value in zip("xyz", torque) if value == 0]
    if idle:
        warnings.warn(f"momentum.thrusters.torque = {checks.short(torque.tolist())} N m: the {' and '.join(idle)} "
                      f"pair{'s' * (len(idle) > 1)} give{'s' * (len(idle) == 1)} no torque, so the wheels' momentum "
                      f"about body {'/'.join(idle)} is never dumped", MomentumWarning, stacklevel=2)
    return values


components.register(components.ComponentSpec(
    kind="momentum", name="none", component=MomentumManager, params=(), build=lambda v, ctx: None,
    doc="no momentum management: the wheels keep what they absorb",
))
components.register(components.ComponentSpec(
    kind="momentum", name="thrusters", component=Thrusters,
    params=(
        Param("torque", 0.2, "N m", shapes=((), (3,)), low=0.0, doc="the torque of a firing pair, per body axis"),
        Param("start", 50.0, "N m s", low=0.0, doc="dumping starts when |h_w| exceeds this"),
        Param("stop", 20.0, "N m s", low=0.0, doc="dumping stops when |h_w| falls below this"),
        Param("min_on_time", 1.0, "s", low=0.0, doc="shortest firing (rounded up to whole control periods)"),
        Param("feedforward", True, boolean=True,
              doc="the wheels are commanded to absorb each pulse (the command tau_c - tau_m)"),
    ),
    complete=_thrusters_values,
    build=_thrusters,
    doc="a thruster pair per body axis dumping the wheels' momentum between two thresholds",
))
components.register(components.ComponentSpec(
    kind="momentum", name="magnetorquers", component=Magnetorquers,
    params=(
        Param("gain", 1e-3, "1/s", low=0.0, doc="k of m = k (B_m x (target - h_w)) / |B_m|^2"),
        Param("max_dipole", 50.0, "A m^2", shapes=((), (3,)), low=0.0,
              doc="dipole limit per coil (0: a failed coil, giving none)"),
        Param("target", [0.0, 0.0, 0.0], "N m s", shapes=((3,),), doc="the wheels' momentum aimed at, body frame"),
        Param("magnetometer_noise", 1e-7, "T", low=0.0, doc="the magnetometer's 1-sigma white noise per axis"),
    ),
    build=lambda v, ctx: Magnetorquers(ctx.as_array(v["gain"]), ctx.as_array(np.broadcast_to(v["max_dipole"], (3,))
                                                                               .copy()),
                                       ctx.as_array(v["target"]), ctx.as_array(v["magnetometer_noise"])),
    doc="three magnetorquers unloading the wheels by the cross-product law, read through a magnetometer",
))
