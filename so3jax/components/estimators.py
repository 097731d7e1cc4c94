"""Estimators: measurements in, attitude and rate estimates out, once per control tick
(docs/model.md §8.3): ``truth``, ``raw`` and a multiplicative EKF on attitude and gyro bias.

Each is a :class:`~so3jax.components.base.Estimator`: ``init(R0, batch_shape, dtype)`` ->
state, ``update(state, measured, period, truth)`` -> (state for the next tick,
:class:`~so3jax.components.base.Estimate`), and the class attributes ``needs`` (the
measurements it reads) and ``reads_truth`` (only such an estimator gets the true state,
``truth`` = (R, Omega) at the tick; None for every other). Arrays follow
:mod:`so3jax.core.so3` (batch axes last); parameters have no batch axes.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.components import registry as components
from so3jax.components.base import Estimate, Estimator
from so3jax.components.sensors import GYRO_OUTPUTS
from so3jax.core import checks, so3
from so3jax.core.params import Param
from so3jax.core.pytree import pytree_dataclass, static_field


def _batch(x, core_ndim, batch_shape, dtype):
    return so3.broadcast(jnp.asarray(x).astype(dtype), core_ndim, batch_shape)


def _zero_std(Omega):
    return jnp.zeros((6,) + Omega.shape[1:], Omega.dtype)


@pytree_dataclass
class Truth(Estimator):
    """R_hat = R(t_j), Omega_hat = Omega(t_j)."""

    reads_truth = True

    def init(self, R0, batch_shape, dtype):
        return ()

    def update(self, state, measured, period, truth):
        R, Omega = truth
        return state, Estimate(R, Omega, jnp.zeros_like(Omega), _zero_std(Omega))


@pytree_dataclass
class Raw(Estimator):
    """R_hat = the latest star-tracker sample (held between samples), Omega_hat = omega_m.
    State: that sample (3, 3, *b), R0 before the first."""

    needs = ("attitude",)

    def init(self, R0, batch_shape, dtype):
        return _batch(R0, 2, batch_shape, dtype)

    def update(self, state, measured, period, truth=None):
        R_hat = jnp.where(measured.star_valid, measured.R_m, state)
        omega = measured.omega_m
        return R_hat, Estimate(R_hat, omega, jnp.zeros_like(omega), _zero_std(omega))


class Covariance(NamedTuple):
    """P (6 x 6) of the error state (delta theta, delta b) by its 3 x 3 blocks, each (3, 3, *b)."""

    A: jax.Array  # attitude-attitude, rad^2
    B: jax.Array  # attitude-bias, rad^2/s
    C: jax.Array  # bias-bias, rad^2/s^2

    def matrix(self):
        """P as (6, 6, *b)."""
        top = jnp.concatenate([self.A, self.B], axis=1)
        bottom = jnp.concatenate([so3.transpose(self.B), self.C], axis=1)
        return jnp.concatenate([top, bottom], axis=0)


class MEKFState(NamedTuple):
    """The filter between two ticks: the prior at the next tick (a sampled-rate gyro), or
    the posterior at the last tick and the time since it (a rate-integrating gyro)."""

    R_hat: jax.Array  # (3, 3, *b)
    bias_hat: jax.Array  # (3, *b) rad/s
    P: Covariance
    elapsed: Any = ()  # (*b,) s: the period the next update propagates over (rate-integrating gyro), or ()


def _sym(M):
    return 0.5 * (M + so3.transpose(M))


def _diag(M):
    return jnp.stack([M[0, 0], M[1, 1], M[2, 2]])


@pytree_dataclass
class MEKF(Estimator):
    """Multiplicative EKF on (R_hat, b_hat) with R = R_hat exp(hat(delta theta)) (docs/model.md §8.3).

    With a rate-integrating gyro (``gyro="increment"``: omega_m is the mean rate over the
    last period), each tick propagates over the period with w = omega_m - b_hat, then
    takes the star-tracker update (Joseph form) and outputs Omega_hat = omega_m - b_hat.
    With a sampled-rate gyro (``gyro="rate"``), each tick takes the update, outputs
    Omega_hat, then propagates to the next tick with w = Omega_hat held over the period.
    Both propagate the covariance with Phi = [[exp(-hat(w) dt), -dt I], [0, I]] and the
    continuous model's Q (docs/model.md §8.3)."""

    sigma_theta0: jax.Array  # initial attitude sigma [rad]
    sigma_b0: jax.Array  # initial bias sigma [rad/s]
    theta0: jax.Array  # (3,) initial error: R_hat(0) = R0 exp(hat(theta0)) [rad]
    arw: jax.Array  # the filter's gyro angle random walk sigma_v [rad/sqrt(s)]
    rrw: jax.Array  # the filter's gyro rate random walk sigma_u [rad/s^(3/2)]
    sigma_st: jax.Array  # the filter's star-tracker sigma [rad]
    gyro: str = static_field(default="rate")  # what the gyro delivers: "increment" or "rate"

    needs = ("rate", "attitude")

    def init(self, R0, batch_shape, dtype):
        R0 = _batch(R0, 2, batch_shape, dtype)
        theta0 = _batch(self.theta0, 1, batch_shape, dtype)
        eye = so3.eye_like(theta0)
        zero = jnp.zeros_like(eye)
        var = lambda s: jnp.asarray(s).astype(dtype) ** 2
        P = Covariance(var(self.sigma_theta0) * eye, zero, var(self.sigma_b0) * eye)
        elapsed = jnp.zeros(tuple(batch_shape), dtype) if self.gyro == "increment" else ()
        return MEKFState(so3.matmul(R0, so3.exp(theta0)), jnp.zeros_like(theta0), P, elapsed)

    def update(self, state: MEKFState, measured, period, truth=None):
        Omega = measured.omega_m  # shape and dtype only: the filter never reads the true state
        dtype = Omega.dtype
        dc = jnp.asarray(period, dtype)
        R_hat, b_hat, P, elapsed = state
        eye = so3.eye_like(Omega)
        if self.gyro == "increment":  # propagate over the period the increment covers (none at tick 0)
            R_hat, P = self._propagate(R_hat, P, measured.omega_m - b_hat, elapsed, eye)
            elapsed = jnp.full(elapsed.shape, dc)
        R_hat, b_hat, (A, B, C) = self._star_update(R_hat, b_hat, P, measured, eye)
        Omega_hat = measured.omega_m - b_hat
        std = jnp.sqrt(jnp.concatenate([_diag(A), _diag(C)]))
        estimate = Estimate(R_hat, Omega_hat, b_hat, std, Covariance(A, B, C).matrix())
        if self.gyro == "increment":
            return MEKFState(R_hat, b_hat, Covariance(A, B, C), elapsed), estimate
        R_next, P_next = self._propagate(R_hat, Covariance(A, B, C), Omega_hat, dc, eye)  # to the next tick
        return MEKFState(R_next, b_hat, P_next), estimate

    def _star_update(self, R_hat, b_hat, P, measured, eye):
        """(R_hat, b_hat, P) after the star tracker's sample (Joseph form), where one exists."""
        dtype = measured.omega_m.dtype
        A, B, C = P
        mm = so3.matmul_compact  # the covariance algebra
        s2 = jnp.asarray(self.sigma_st).astype(dtype) ** 2
        r = so3.log(so3.rmatmul(R_hat, measured.R_m), select=True)
        S_inv = so3.inv_spd(A + s2 * eye)  # S = A + s2 I
        K1, K2 = mm(A, S_inv), mm(so3.transpose(B), S_inv)  # A S^-1, B^T S^-1
        I_K1 = eye - K1
        M11, M12 = mm(I_K1, A), mm(I_K1, B)
        M21, M22 = so3.transpose(B) - mm(K2, A), C - mm(K2, B)
        K1T, K2T = so3.transpose(K1), so3.transpose(K2)
        A_u = _sym(mm(M11, so3.transpose(I_K1)) + s2 * mm(K1, K1T))
        B_u = M12 - mm(M11, K2T) + s2 * mm(K1, K2T)
        C_u = _sym(M22 - mm(M21, K2T) + s2 * mm(K2, K2T))
        updated = (so3.matmul(R_hat, so3.exp(so3.matvec(K1, r), select=True)), b_hat + so3.matvec(K2, r),
                   Covariance(A_u, B_u, C_u))
        return jax.tree.map(lambda u, p: jnp.where(measured.star_valid, u, p), updated, (R_hat, b_hat, P))

    def _propagate(self, R_hat, P, w, dt, eye):
        """(R_hat exp(hat(w) dt), Phi P Phi^T + Q) over dt [s] with the rate w (3, *b) [rad/s]."""
        A, B, C = P
        mm = so3.matmul_compact
        E = so3.exp(-w * dt, select=True)  # exp(-hat(w) dt)
        EB = mm(E, B)
        qv, qu = (jnp.asarray(x).astype(w.dtype) ** 2 for x in (self.arw, self.rrw))
        A_p = _sym(mm(mm(E, A), so3.transpose(E)) - dt * (EB + so3.transpose(EB)) + dt**2 * C
                   + (qv * dt + qu * dt**3 / 3.0) * eye)
        B_p = EB - dt * C - (qu * dt**2 / 2.0) * eye
        C_p = C + qu * dt * eye
        return so3.matmul(R_hat, so3.exp(w * dt, select=True)), Covariance(A_p, B_p, C_p)

    def check(self) -> None:
        for name in ("sigma_theta0", "sigma_b0", "arw", "rrw", "sigma_st"):
            v = checks.concrete(getattr(self, name), f"estimator {name}")
            if v is None:
                continue
            if v.shape != () or not np.isfinite(v) or v < 0:
                raise ValueError(f"estimator {name} must be a finite non-negative number, "
                                 f"got {checks.short(v.tolist())}")
        t = checks.concrete(self.theta0, "estimator theta0 [rad]")
        if t is not None and (t.shape != (3,) or not np.all(np.isfinite(t))):
            raise ValueError(f"estimator theta0 must be 3 finite numbers [rad], got {checks.short(t.tolist())}")
        if not isinstance(self.gyro, str) or self.gyro not in GYRO_OUTPUTS:
            raise ValueError(f"estimator gyro must be one of {', '.join(GYRO_OUTPUTS)}, got {checks.short(self.gyro)}")
        sigma_st = checks.concrete(self.sigma_st, "estimator sigma_st")
        if sigma_st is not None and float(sigma_st) == 0.0:
            raise ValueError("estimator 'mekf' needs a star tracker with sigma > 0")


def _believed(v: dict, ctx, name: str, sensor_key: str):
    """The filter's assumed noise level: its own value, else the sensors' (docs/model.md §8.3)."""
    value = v[name] if v[name] is not None else ctx.sensor_noise.get(sensor_key)
    if value is None:
        raise ValueError(f"estimator 'mekf': estimator.mekf.{name} is not given and no sensor reports it")
    return ctx.as_array(value)


components.register(components.ComponentSpec(
    kind="estimator", name="truth", component=Truth, params=(), build=lambda v, ctx: Truth(),
    doc="the true state (perfect knowledge)",
))
components.register(components.ComponentSpec(
    kind="estimator", name="raw", component=Raw, params=(), build=lambda v, ctx: Raw(),
    doc="the latest star-tracker sample and the gyro reading, unfiltered",
))
components.register(components.ComponentSpec(
    kind="estimator", name="mekf", component=MEKF,
    params=(
        Param("sigma_theta0", 1e-3, "rad", low=0.0, doc="initial attitude sigma"),
        Param("sigma_b0", 1e-3, "rad/s", low=0.0, doc="initial bias sigma"),
        Param("theta0", [0.0, 0.0, 0.0], "rad", shapes=((3,),), doc="initial error: R_hat(0) = R0 exp(hat(theta0))"),
        Param("arw", None, "rad/sqrt(s)", low=0.0, doc="assumed gyro sigma_v (default: the gyro's)"),
        Param("rrw", None, "rad/s^(3/2)", low=0.0, doc="assumed gyro sigma_u (default: the gyro's)"),
        Param("sigma_st", None, "rad", low=0.0, low_excluded=True,
              doc="assumed star-tracker sigma (default: the star tracker's)"),
        Param("gyro", None, choices=GYRO_OUTPUTS,
              doc="what the gyro delivers: its angle increment over a period, or its rate at the tick "
                  "(default: the gyro's output; a rate sensor that does not say: rate)"),
    ),
    build=lambda v, ctx: MEKF(ctx.as_array(v["sigma_theta0"]), ctx.as_array(v["sigma_b0"]), ctx.as_array(v["theta0"]),
                              _believed(v, ctx, "arw", "arw"), _believed(v, ctx, "rrw", "rrw"),
                              _believed(v, ctx, "sigma_st", "sigma_st"),
                              v["gyro"] or ctx.sensor_noise.get("gyro_output", "rate")),
    doc="multiplicative EKF on attitude and gyro bias (docs/model.md §8.3)",
))
