"""Adaptive backstepping on SO(3) (the paper's controller, corrected; SPEC 3.2)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from so3jax import so3
from so3jax._fusion import materialize
from so3jax.components import Param
from so3jax.controllers.base import Controller, tracking_error
from so3jax.controllers.pd import J_HAT
from so3jax.controllers.registry import ControllerSpec, register
from so3jax.scenario import check_gains


class AdaptiveGains(NamedTuple):
    K_r: jax.Array  # 1/s
    K_w: jax.Array  # N m s / rad
    Gamma: jax.Array  # adaptation rate: scalar, (9,) diagonal, or (9, 9) SPD


PAPER_ADAPTIVE_GAINS = AdaptiveGains(K_r=0.005, K_w=75.0, Gamma=1e8)

LOG_DERIVATIVES = ("exact", "paper")
GAMMA_SHAPES = ((), (9,), (9, 9))  # scalar, diagonal, full


def regressor_parameters(J):
    """Theta(J) (9, 3, ...) with Theta^T Phi = Omega x J Omega + J beta' (SPEC 3.2)."""
    a, b, c = J[0, 0], J[1, 1], J[2, 2]
    d, e, f = J[0, 1], J[0, 2], J[1, 2]
    zero = jnp.zeros_like(a)
    rows = [
        [c - b, d, -e],  # Omega_y Omega_z
        [-d, a - c, f],  # Omega_z Omega_x
        [e, -f, b - a],  # Omega_x Omega_y
        [zero, -e, d],  # Omega_x^2
        [f, zero, -d],  # Omega_y^2
        [-f, e, zero],  # Omega_z^2
    ]
    monomial_rows = jnp.stack([jnp.stack(r) for r in rows])
    return jnp.concatenate([monomial_rows, J], 0)


def regressor(Omega, beta_dot):
    """Phi = [yz, zx, xy, x^2, y^2, z^2, beta'] (9, ...) for Omega = (x, y, z) (SPEC 3.2)."""
    x, y, z = Omega[0], Omega[1], Omega[2]
    monomials = jnp.stack([y * z, z * x, x * y, x * x, y * y, z * z])
    return jnp.concatenate([monomials, beta_dot], 0)


def _apply_gamma(Gamma, Phi):
    """Gamma Phi for a scalar, diagonal (9,) or full (9, 9) Gamma (each with Phi's batch axes)."""
    Gamma = jnp.asarray(Gamma)
    kind = Gamma.ndim - (Phi.ndim - 1)  # 0: scalar, 1: diagonal, 2: full
    if kind not in (0, 1, 2) or Gamma.shape[:kind] != (9,) * kind:  # shapes are static: checked while tracing
        raise ValueError(f"gain Gamma must be a scalar, a (9,) diagonal or a (9, 9) matrix (each with the batch "
                         f"axes of the regressor, shape {Phi.shape}), got shape {Gamma.shape}")
    if kind == 2:
        return jnp.stack([so3.sum_leading(Gamma[i] * Phi) for i in range(Gamma.shape[0])])
    return Gamma * Phi


class AdaptiveTerms(NamedTuple):
    """Intermediate signals of the law, exposed for the Lyapunov function and tests."""

    e: jax.Array  # log(R_e)^vee, rad
    z: jax.Array  # Omega - beta, rad/s
    Phi: jax.Array  # (9,) regressor


def adaptive_terms(gains, measured, desired, log_derivative="exact", t=None) -> AdaptiveTerms:
    """e, z, Phi of the law. t (the time, traced), when given, marks the tracking error
    and the terms for XLA:CPU to compute once (:mod:`so3jax._fusion`); values unchanged."""
    once = (lambda x: x) if t is None else (lambda x: materialize(x, t))
    err = once(tracking_error(measured, desired))
    Omega = measured.Omega
    e = so3.log(err.R_e)
    beta = -gains.K_r * e + err.Omega_r
    e_dot = so3.jr_inv_apply(e, err.Omega_e) if log_derivative == "exact" else err.Omega_e
    beta_dot = -gains.K_r * e_dot - so3.cross(Omega, err.Omega_r) + err.feedforward_dot
    return once(AdaptiveTerms(e, Omega - beta, regressor(Omega, beta_dot)))


def adaptive_backstepping(J_hat=None, log_derivative: str = "exact") -> Controller:
    """tau = -K_r e - K_w z + Theta_hat^T Phi,  Theta_hat' = -Gamma Phi z^T  (SPEC 3.2).

    J_hat: nominal inertia for the initial estimate Theta_hat(0) = Theta(J_hat)
    (identity by default). log_derivative: "exact" (e' = J_r^{-1}(e) Omega_e) or
    "paper" (e' = Omega_e, the paper's approximation).
    """
    if log_derivative not in LOG_DERIVATIVES:
        raise ValueError(f"log_derivative must be one of {LOG_DERIVATIVES}, got {log_derivative!r}")

    def init(gains):
        dtype = jnp.result_type(gains.K_r, float)
        J = jnp.eye(3, dtype=dtype) if J_hat is None else jnp.asarray(J_hat, dtype)
        return regressor_parameters(J)

    def torque(gains, theta_hat, measured, desired, t):
        terms = adaptive_terms(gains, measured, desired, log_derivative, t)
        feedforward = so3.sum_leading(theta_hat * terms.Phi[:, None])
        tau = -gains.K_r * terms.e - gains.K_w * terms.z + feedforward
        theta_dot = -_apply_gamma(gains.Gamma, terms.Phi)[:, None] * terms.z[None, :]
        return tau, theta_dot

    return Controller(init, torque, AdaptiveGains)


register(
    ControllerSpec(
        name="adaptive",
        label="adaptive",
        factory=adaptive_backstepping,
        gains_type=AdaptiveGains,
        defaults=PAPER_ADAPTIVE_GAINS,
        style=dict(ls="-", color="tab:blue", label="adaptive"),
        check=check_gains,
        shapes={"Gamma": GAMMA_SHAPES},
        options=(J_HAT, Param("log_derivative", "exact", choices=LOG_DERIVATIVES,
                              doc="exact: e' = J_r^-1(e) Omega_e; paper: e' = Omega_e")),
    )
)
