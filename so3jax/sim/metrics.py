"""Tracking metrics accumulated step by step inside the scan (docs/model.md §6).

Every quantity is sampled at step starts k = 0 .. N-1 and summed per mission phase,
so a full mission needs no stored trajectory.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.core import so3


class Sample(NamedTuple):
    """What one step start contributes to the metrics (batch axes last, as in so3)."""

    Omega_e: jax.Array  # (3, ...) rad/s, body frame
    Omega_minus_Omega_d: jax.Array  # (3, ...) rad/s, unrotated (the paper's Fig. 2 error)
    tau: jax.Array  # (3, ...) N m
    angle: jax.Array  # (...) |log(R_e)^vee|, rad


class Accumulator(NamedTuple):
    """Per-phase running sums and maxima, each of shape (P, ...batch)."""

    sq_rate_error: jax.Array
    sq_rate_error_unrotated: jax.Array
    sq_torque: jax.Array
    sq_angle: jax.Array
    max_angle: jax.Array
    max_torque: jax.Array
    finite: jax.Array  # (...batch) bool: every state so far finite


class Metrics(NamedTuple):
    rmse: jax.Array  # rad/s
    rmse_unrotated: jax.Array  # rad/s
    effort: jax.Array  # N^2 m^2 s
    rmse_phase: jax.Array  # (P,) rad/s
    effort_phase: jax.Array  # (P,) N^2 m^2 s
    rms_angle_phase: jax.Array  # (P,) rad
    max_angle_phase: jax.Array  # (P,) rad
    max_torque_phase: jax.Array  # (P,) N m
    max_torque: jax.Array  # N m
    orthogonality_error: jax.Array  # |R^T R - I|_F at the end
    diverged: jax.Array  # bool: a state became non-finite

    units = {"rmse": "rad/s", "rmse_unrotated": "rad/s", "effort": "N^2 m^2 s", "rmse_phase": "rad/s",
             "effort_phase": "N^2 m^2 s", "rms_angle_phase": "rad", "max_angle_phase": "rad",
             "max_torque_phase": "N m", "max_torque": "N m", "orthogonality_error": "-", "diverged": "-"}


def init(n_phases: int, dtype, batch_shape=()) -> Accumulator:
    zeros = jnp.zeros((n_phases,) + tuple(batch_shape), dtype)
    return Accumulator(zeros, zeros, zeros, zeros, zeros, zeros, jnp.ones(batch_shape, bool))


def update(acc: Accumulator, phase, sample: Sample, finite) -> Accumulator:
    shape = (acc.sq_torque.shape[0],) + (1,) * (acc.sq_torque.ndim - 1)
    mask = (jnp.arange(shape[0], dtype=jnp.int32).reshape(shape) == phase).astype(acc.sq_torque.dtype)
    tau2 = so3.dot(sample.tau, sample.tau)
    return Accumulator(
        acc.sq_rate_error + mask * so3.dot(sample.Omega_e, sample.Omega_e),
        acc.sq_rate_error_unrotated + mask * so3.dot(sample.Omega_minus_Omega_d, sample.Omega_minus_Omega_d),
        acc.sq_torque + mask * tau2,
        acc.sq_angle + mask * sample.angle**2,
        jnp.maximum(acc.max_angle, mask * sample.angle),
        jnp.maximum(acc.max_torque, mask * so3.safe_norm(sample.tau)),
        acc.finite & finite,
    )


def safe_sqrt(x):
    """sqrt with a finite gradient at 0; NaN (a diverged run) stays NaN."""
    pos = x > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1.0)), jnp.where(x == 0, 0.0, jnp.nan).astype(x.dtype))


def finalize(acc: Accumulator, steps_per_phase, dt, final_R) -> Metrics:
    """Turn the sums into the metrics of docs/model.md §6. steps_per_phase: static tuple of ints."""
    n_phase = jnp.asarray(steps_per_phase, acc.sq_torque.dtype).reshape((-1,) + (1,) * (acc.sq_torque.ndim - 1))
    n_safe = jnp.maximum(n_phase, 1.0)
    n = float(sum(steps_per_phase))
    max_torque_phase = acc.max_torque
    return Metrics(
        rmse=safe_sqrt(jnp.sum(acc.sq_rate_error, axis=0) / n),
        rmse_unrotated=safe_sqrt(jnp.sum(acc.sq_rate_error_unrotated, axis=0) / n),
        effort=jnp.sum(acc.sq_torque, axis=0) * dt,
        rmse_phase=safe_sqrt(acc.sq_rate_error / n_safe),
        effort_phase=acc.sq_torque * dt,
        rms_angle_phase=safe_sqrt(acc.sq_angle / n_safe),
        max_angle_phase=acc.max_angle,
        max_torque_phase=max_torque_phase,
        max_torque=jnp.max(max_torque_phase, axis=0),
        orthogonality_error=so3.orthogonality_error(final_R),
        diverged=~(acc.finite & jnp.all(jnp.isfinite(final_R), axis=(0, 1))),
    )


# --- reporting ----------------------------------------------------------------------------
# Conventions of every report (paper, fly, sweep, tune): NaN is a diverged rollout's metric
# (null in JSON, "diverged" in tables); None is a per-phase metric of a phase the horizon
# never reached (null in JSON, "—" in tables), never 0.

UNREACHED = "—"


def reported(value, diverged):
    """A metric (NumPy, float) as reported: NaN wherever its rollout diverged, so that no
    diverged rollout reads as a number (a maximum taken before the blow-up, say).
    ``diverged``: bool of the batch shape, leading axes of ``value``."""
    value = np.asarray(value, dtype=float)
    diverged = np.asarray(diverged, dtype=bool)
    diverged = diverged.reshape(diverged.shape + (1,) * (value.ndim - diverged.ndim))
    return np.where(diverged, np.nan, value)


def reached_phases(steps_per_phase) -> list[bool]:
    """Which phases the horizon reaches (at least one step)."""
    return [n > 0 for n in steps_per_phase]


def phase_values(values, steps_per_phase) -> list:
    """Per-phase values (P,) as a list, None for a phase the horizon never reached."""
    values = np.asarray(values, dtype=float)
    return [float(v) if reached else None for v, reached in zip(values, reached_phases(steps_per_phase))]


def finite_values(values) -> tuple[np.ndarray, int]:
    """(the finite values, how many were not finite) of a 1-D sample."""
    values = np.asarray(values, dtype=float).reshape(-1)
    finite = np.isfinite(values)
    return values[finite], int((~finite).sum())


def cell(value, fmt: str) -> str:
    """A table cell: "diverged" for a non-finite metric, "—" for None (a phase never
    reached, or no finite sample), else the formatted number."""
    if value is None:
        return UNREACHED
    value = float(value)
    return format(value, fmt) if math.isfinite(value) else "diverged"
