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

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.components import registry as components
from so3jax.components.base import Estimate, Estimator

from so3jax.core import so3
from so3jax.core import checks
from so3jax.core.pytree import pytree_dataclass
from so3jax.core.params import Param


def _batch(x, core_ndim, batch_shape, dtype):
    x = jnp.asarray(x).astype(dtype)
    x = x.reshape(x.shape[:core_ndim] + (1,) * (core_ndim + len(batch_shape) - x.ndim) + x.shape[core_ndim:])
    return jnp.broadcast_to(x, x.shape[:core_ndim] + tuple(batch_shape))


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
    """The prior at the next tick."""

    R_hat: jax.Array  # (3, 3, *b)
    bias_hat: jax.Array  # (3, *b) rad/s
    P: Covariance


def _sym(M):
    return 0.5 * (M + so3.transpose(M))


def _diag(M):
    return jnp.stack([M[0, 0], M[1, 1], M[2, 2]])


@pytree_dataclass
class MEKF(Estimator):
    """Multiplicative EKF on (R_hat, b_hat) with R = R_hat exp(hat(delta theta)) (docs/model.md §8.3):
    star-tracker update (Joseph form), output Omega_hat = omega_m - b_hat, then
    propagation to the next tick with w = Omega_hat."""

    sigma_theta0: jax.Array  # initial attitude sigma [rad]
    sigma_b0: jax.Array  # initial bias sigma [rad/s]
    theta0: jax.Array  # (3,) initial error: R_hat(0) = R0 exp(hat(theta0)) [rad]
    arw: jax.Array  # the filter's gyro angle random walk sigma_v [rad/sqrt(s)]
    rrw: jax.Array  # the filter's gyro rate random walk sigma_u [rad/s^(3/2)]
    sigma_st: jax.Array  # the filter's star-tracker sigma [rad]

    needs = ("rate", "attitude")

    def init(self, R0, batch_shape, dtype):
        R0 = _batch(R0, 2, batch_shape, dtype)
        theta0 = _batch(self.theta0, 1, batch_shape, dtype)
        eye = so3.eye_like(theta0)
        zero = jnp.zeros_like(eye)
        var = lambda s: jnp.asarray(s).astype(dtype) ** 2
        P = Covariance(var(self.sigma_theta0) * eye, zero, var(self.sigma_b0) * eye)
        return MEKFState(so3.matmul(R0, so3.exp(theta0)), jnp.zeros_like(theta0), P)

    def update(self, state: MEKFState, measured, period, truth=None):
        Omega = measured.omega_m  # shape and dtype only: the filter never reads the true state
        dtype = Omega.dtype
        param = lambda x: jnp.asarray(x).astype(dtype)
        dc = jnp.asarray(period, dtype)
        R_hat, b_hat, (A, B, C) = state
        eye = so3.eye_like(Omega)
        # measurement update (docs/model.md §8.3), where a star-tracker sample exists
        mm = so3.matmul_compact  # the covariance algebra
        s2 = param(self.sigma_st) ** 2
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
        updated = MEKFState(so3.matmul(R_hat, so3.exp(so3.matvec(K1, r), select=True)), b_hat + so3.matvec(K2, r),
                            Covariance(A_u, B_u, C_u))
        R_hat, b_hat, (A, B, C) = jax.tree.map(lambda u, p: jnp.where(measured.star_valid, u, p), updated, state)
        Omega_hat = measured.omega_m - b_hat
        std = jnp.sqrt(jnp.concatenate([_diag(A), _diag(C)]))
        estimate = Estimate(R_hat, Omega_hat, b_hat, std, Covariance(A, B, C).matrix())
        # propagation to the next tick with w = Omega_hat
        E = so3.exp(-Omega_hat * dc, select=True)  # exp(-hat(w) Delta_c)
        EB = mm(E, B)
        qv, qu = param(self.arw) ** 2, param(self.rrw) ** 2
        A_p = _sym(mm(mm(E, A), so3.transpose(E)) - dc * (EB + so3.transpose(EB)) + dc**2 * C
                   + (qv * dc + qu * dc**3 / 3.0) * eye)
        B_p = EB - dc * C - (qu * dc**2 / 2.0) * eye
        C_p = C + qu * dc * eye
        R_next = so3.matmul(R_hat, so3.exp(Omega_hat * dc, select=True))
        return MEKFState(R_next, b_hat, Covariance(A_p, B_p, C_p)), estimate

    def check(self) -> None:
        for name in ("sigma_theta0", "sigma_b0", "arw", "rrw", "sigma_st"):
            v = checks.concrete(getattr(self, name), f"estimator {name}")
            if v is None:
                continue
            if v.shape != () or not np.isfinite(v) or v < 0:
                raise ValueError(f"estimator {name} must be a finite non-negative number, got {checks.short(v.tolist())}")
        t = checks.concrete(self.theta0, "estimator theta0 [rad]")
        if t is not None and (t.shape != (3,) or not np.all(np.isfinite(t))):
            raise ValueError(f"estimator theta0 must be 3 finite numbers [rad], got {checks.short(t.tolist())}")
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
        Param("sigma_st", None, "rad", low=0.0, doc="assumed star-tracker sigma (default: the star tracker's)"),
    ),
    build=lambda v, ctx: MEKF(ctx.as_array(v["sigma_theta0"]), ctx.as_array(v["sigma_b0"]), ctx.as_array(v["theta0"]),
                              _believed(v, ctx, "arw", "arw"), _believed(v, ctx, "rrw", "rrw"),
                              _believed(v, ctx, "sigma_st", "sigma_st")),
    doc="multiplicative EKF on attitude and gyro bias (docs/model.md §8.3)",
))
