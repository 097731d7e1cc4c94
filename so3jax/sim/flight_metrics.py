"""Metrics of the sampled-data loop (docs/model.md §13), accumulated at control ticks inside
the scan, beside the §6 metrics of :mod:`so3jax.sim.metrics`."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from so3jax.core import so3
from so3jax.sim.metrics import safe_sqrt


class Accumulator(NamedTuple):
    """Running sums and maxima over ticks, each of the batch shape."""

    ticks: jax.Array  # live ticks so far
    sq_attitude_error: jax.Array  # sum |log(R_hat^T R)^vee|^2, rad^2
    max_attitude_error: jax.Array  # rad
    sq_bias_error: jax.Array  # sum |b_hat - b|^2, (rad/s)^2
    max_bias_error: jax.Array  # rad/s
    sq_command: jax.Array  # sum |tau_c|^2, N^2 m^2
    sq_actuator: jax.Array  # sum of actuator.effort, |held input|^2 (wheel motor torques u or body torques), N^2 m^2
    torque_limit_ticks: jax.Array  # periods (within the horizon) with a torque limit binding
    speed_limit_ticks: jax.Array  # periods (within the horizon) with a wheel at its speed limit
    max_wheel_speed_ratio: jax.Array  # max_i |Omega_w,i| / Omega_max,i (0 without wheels)


class FlightMetrics(NamedTuple):
    attitude_estimation_rms: jax.Array  # rad, |log(R_hat^T R)^vee| at ticks
    attitude_estimation_max: jax.Array  # rad
    bias_estimation_rms: jax.Array  # rad/s, |b_hat - b| at ticks
    bias_estimation_max: jax.Array  # rad/s
    command_effort: jax.Array  # sum |tau_c|^2 Delta_c, N^2 m^2 s
    actuator_effort: jax.Array  # sum |u|^2 Delta_c (wheels: motor torques), N^2 m^2 s
    time_at_torque_limit: jax.Array  # s
    time_at_speed_limit: jax.Array  # s
    max_wheel_speed_ratio: jax.Array  # max |Omega_w,i| / Omega_max,i

    units = {"attitude_estimation_rms": "rad", "attitude_estimation_max": "rad", "bias_estimation_rms": "rad/s",
             "bias_estimation_max": "rad/s", "command_effort": "N^2 m^2 s", "actuator_effort": "N^2 m^2 s",
             "time_at_torque_limit": "s", "time_at_speed_limit": "s", "max_wheel_speed_ratio": "-"}


def init(dtype, batch_shape=()) -> Accumulator:
    zero = jnp.zeros(batch_shape, dtype)
    return Accumulator(*([zero] * len(Accumulator._fields)))


class TickSample(NamedTuple):
    """What one tick contributes (batch shape each, vectors (3, ...) / (N, ...))."""

    attitude_error: jax.Array  # (...) rad
    bias_error: jax.Array  # (3, ...) rad/s
    tau_cmd: jax.Array  # (3, ...) N m
    actuator_effort: jax.Array  # (...) |held input|^2 (the actuator's `effort`), N^2 m^2
    at_torque_limit: jax.Array  # (...) bool
    at_speed_limit: jax.Array  # (...) bool
    wheel_speed_ratio: jax.Array  # (...) max_i |Omega_w,i| / Omega_max,i


def update(acc: Accumulator, s: TickSample, live=True, share=None) -> Accumulator:
    """Add a tick (``live`` False: a tick past the horizon, counted nowhere). ``share``:
    the part of its period [0, 1] inside the horizon (default: all of it where live),
    which weighs what the tick holds over its period (efforts, time at a limit)."""
    one = jnp.asarray(live, acc.ticks.dtype)
    held = one if share is None else one * jnp.asarray(share, acc.ticks.dtype)
    bias = so3.safe_norm(s.bias_error)
    return Accumulator(
        acc.ticks + one,
        acc.sq_attitude_error + one * s.attitude_error**2,
        jnp.maximum(acc.max_attitude_error, one * s.attitude_error),
        acc.sq_bias_error + one * bias**2,
        jnp.maximum(acc.max_bias_error, one * bias),
        acc.sq_command + held * so3.dot(s.tau_cmd, s.tau_cmd),
        acc.sq_actuator + held * s.actuator_effort,
        acc.torque_limit_ticks + held * s.at_torque_limit.astype(one.dtype),
        acc.speed_limit_ticks + held * s.at_speed_limit.astype(one.dtype),
        jnp.maximum(acc.max_wheel_speed_ratio, one * s.wheel_speed_ratio),
    )


def _rms(total, count):
    """sqrt(total / count); NaN stays NaN, 0 -> 0 with a finite gradient."""
    return safe_sqrt(total / jnp.maximum(count, 1.0))


def finalize(acc: Accumulator, period) -> FlightMetrics:
    """Sums -> metrics; period: Delta_c [s]."""
    return FlightMetrics(
        attitude_estimation_rms=_rms(acc.sq_attitude_error, acc.ticks),
        attitude_estimation_max=acc.max_attitude_error,
        bias_estimation_rms=_rms(acc.sq_bias_error, acc.ticks),
        bias_estimation_max=acc.max_bias_error,
        command_effort=acc.sq_command * period,
        actuator_effort=acc.sq_actuator * period,
        time_at_torque_limit=acc.torque_limit_ticks * period,
        time_at_speed_limit=acc.speed_limit_ticks * period,
        max_wheel_speed_ratio=acc.max_wheel_speed_ratio,
    )
