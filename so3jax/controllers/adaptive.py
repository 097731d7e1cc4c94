"""Adaptive backstepping on SO(3) (the paper's controller, corrected; docs/model.md §3.2), with two
optional robustness modifications of its update law against parameter drift.

Units (rad dimensionless): Phi [1/s^2], Theta [kg m^2], z [1/s], so Gamma [kg m^2 s^2]
(Theta_hat' = -Gamma Phi z^T in kg m^2/s). With dTheta = Theta_hat - Theta_0, Theta_0 =
Theta(J_hat) the initial estimate, and ||.|| the Frobenius norm of the (9, 3) matrix (per
batch element):

* sigma-modification (Ioannou & Sun, Robust Adaptive Control, 1996, sec. 8.5.2):
  Theta_hat' = -Gamma (Phi z^T + sigma_s dTheta), sigma [1/(kg m^2 s^3)] so that
  Gamma sigma is a rate [1/s]. ``leakage="fixed"``: sigma_s = sigma. ``"switching"``:
  sigma_s = 0 for ||dTheta|| <= M0, sigma (||dTheta|| / M0 - 1) for M0 < ||dTheta|| <= 2 M0,
  sigma beyond (continuous; M0 = ``theta_bound`` [kg m^2]). The leak pulls toward the
  nominal Theta_0, not zero: its bias is then proportional to ||Theta - Theta_0|| (none
  for a right prior), where Theta = 0 is a massless body.
* projection (Lavretsky & Wise, Robust and Adaptive Control, 2013, sec. 11.4): with
  theta_max = ``projection_bound`` [kg m^2] and eps = ``projection_eps``,
  f = ((1 + eps) ||dTheta||^2 - theta_max^2) / (eps theta_max^2) (f <= 0 on the inner
  ball ||dTheta|| <= theta_max / sqrt(1 + eps), f = 1 on ||dTheta|| = theta_max), and
  with y the unprojected rate (Gamma applied, leakage included),
  Theta_hat' = Proj(dTheta, y) = y - Gamma grad f <grad f, y> f / <grad f, Gamma grad f>
  where f > 0 and <grad f, y> > 0, else y (<A, B> = tr(A^T B)). Then <grad f, Theta_hat'>
  = (1 - f) <grad f, y>: reduced in the layer 0 < f < 1, zero on f = 1, negative beyond,
  so ||dTheta|| <= theta_max is invariant. A full (9, 9) Gamma acts on each of
  Theta_hat's three columns, i.e. the 27-vector gain I_3 kron Gamma, symmetric positive
  definite with Gamma: the operator uses that metric. The layer makes the flow stiff:
  the radial rate changes by ~2 (1 + eps) |y| / (eps theta_max) per unit of ||dTheta||,
  so an explicit integrator holds the bound only where dt ||y|| is small against
  eps theta_max; beyond, the estimate leaves the ball and gradients through a rollout
  grow without bound (the sampled wiring's tick clips: see :func:`adaptive_backstepping`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from so3jax.controllers.base import Controller, hashable, tracking_error
from so3jax.controllers.gains import PositiveDefinite, check_gains
from so3jax.controllers.pd import J_HAT
from so3jax.controllers.registry import ControllerSpec, register
from so3jax.core import so3
from so3jax.core._fusion import materialize
from so3jax.core.params import Param


class AdaptiveGains(NamedTuple):
    K_r: jax.Array  # 1/s
    K_w: jax.Array  # N m s / rad
    Gamma: jax.Array  # adaptation rate: scalar, (9,) diagonal, or (9, 9) SPD

    domains = {"Gamma": PositiveDefinite(9)}  # scalar, (9,) diagonal or (9, 9) SPD: acts on Phi's 9 entries


PAPER_ADAPTIVE_GAINS = AdaptiveGains(K_r=0.005, K_w=75.0, Gamma=1e8)

LOG_DERIVATIVES = ("exact", "paper")


def regressor_parameters(J):
    """Theta(J) (9, 3, ...) with Theta^T Phi = Omega x J Omega + J beta' (docs/model.md §3.2)."""
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
    """Phi = [yz, zx, xy, x^2, y^2, z^2, beta'] (9, ...) for Omega = (x, y, z) (docs/model.md §3.2)."""
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


def adaptive_terms(gains, feedback, desired, log_derivative="exact", t=None) -> AdaptiveTerms:
    """e, z, Phi of the law. t (the time, traced), when given, marks the tracking error
    and the terms for XLA:CPU to compute once (:mod:`so3jax.core._fusion`); values unchanged."""
    once = (lambda x: x) if t is None else (lambda x: materialize(x, t))
    err = once(tracking_error(feedback, desired))
    Omega = feedback.Omega
    e = so3.log(err.R_e)
    beta = -gains.K_r * e + err.Omega_r
    e_dot = so3.jr_inv_apply(e, err.Omega_e) if log_derivative == "exact" else err.Omega_e
    beta_dot = -gains.K_r * e_dot - so3.cross(Omega, err.Omega_r) + err.feedforward_dot
    return once(AdaptiveTerms(e, Omega - beta, regressor(Omega, beta_dot)))


def _gamma_columns(Gamma, M):
    """Gamma applied to each column of M (9, 3, ...): the 27-vector gain I_3 kron Gamma."""
    return jnp.stack([_apply_gamma(Gamma, M[:, k]) for k in range(M.shape[1])], 1)


def _inner(A, B):
    """<A, B> = tr(A^T B) over the leading (9, 3) axes, per batch element."""
    return so3.sum_leading(A * B, 2)


def leakage_rate(d, leakage: str, sigma: float, theta_bound: float | None = None):
    """sigma_s(dTheta) (batch shape) of the sigma-modification [1/(kg m^2 s^3)], dTheta
    (9, 3, ...) [kg m^2]: sigma (``"fixed"``) or the switching sigma of bound M0 =
    theta_bound (``"switching"``, module docstring); zero for ``"none"``."""
    n2 = _inner(d, d)
    if leakage == "none":
        return jnp.zeros_like(n2)
    if leakage == "fixed":
        return jnp.full_like(n2, sigma)
    ratio = so3.safe_sqrt(n2) / theta_bound
    return jnp.where(ratio <= 1.0, 0.0, jnp.where(ratio <= 2.0, sigma * (ratio - 1.0), sigma))


def project(d, y, Gamma, bound: float, eps: float):
    """Lavretsky & Wise's smooth projection Proj(dTheta, y) (module docstring): dTheta,
    y (9, 3, ...) [kg m^2, kg m^2/s], Gamma scalar, (9,) or (9, 9) (with y's batch axes),
    bound theta_max [kg m^2], eps in (0, 1]. grad f = 2 (1 + eps) dTheta / (eps theta_max^2),
    whose scale cancels: dTheta stands for it."""
    f = ((1.0 + eps) * _inner(d, d) - bound**2) / (eps * bound**2)
    g_y = _inner(d, y)
    gamma_g = _gamma_columns(Gamma, d)
    active = (f > 0) & (g_y > 0)  # f > 0 implies dTheta != 0, so <g, Gamma g> > 0
    scale = jnp.where(active, g_y * f / jnp.where(active, _inner(d, gamma_g), 1.0), 0.0)
    return jnp.where(active, y - gamma_g * scale, y)


def project_to_ball(d, bound: float):
    """dTheta scaled back onto ||dTheta|| <= theta_max (radially), unchanged inside."""
    norm = so3.safe_sqrt(_inner(d, d))
    return d * jnp.where(norm > bound, bound / jnp.where(norm > bound, norm, 1.0), 1.0)


LEAKAGES = ("none", "fixed", "switching")


def _checked(name: str, value, unit: str, zero: bool = False) -> float | None:
    """value as a float, finite and > 0 (>= 0 with zero=True); None stays None."""
    if value is None:
        return None
    x = float(value)
    if not (math.isfinite(x) and (x >= 0.0 if zero else x > 0.0)):
        label = f"{name} {unit}" if unit else name
        raise ValueError(f"{label} must be finite and {'>=' if zero else '>'} 0, got {value!r}")
    return x


@dataclasses.dataclass(frozen=True)
class AdaptiveBackstepping(Controller):
    """The adaptive backstepping law with its options, checked and normalized (see
    :func:`adaptive_backstepping`): leakage "none" where not given, sigma and the bounds
    as floats, projection_eps 0.1 where not given; J_hat as nested tuples."""

    J_hat: Any = None
    log_derivative: str = "exact"
    leakage: str | None = None
    sigma: float | None = None
    theta_bound: float | None = None
    projection_bound: float | None = None
    projection_eps: float | None = None

    gains_type = AdaptiveGains

    def __post_init__(self):
        if self.log_derivative not in LOG_DERIVATIVES:
            raise ValueError(f"log_derivative must be one of {LOG_DERIVATIVES}, got {self.log_derivative!r}")
        leakage = "none" if self.leakage is None else self.leakage
        if leakage not in LEAKAGES:
            raise ValueError(f"leakage must be one of {LEAKAGES}, got {leakage!r}")
        sigma = _checked("sigma", self.sigma, "[1/(kg m^2 s^3)]", zero=True)
        theta_bound = _checked("theta_bound", self.theta_bound, "[kg m^2]")
        projection_bound = _checked("projection_bound", self.projection_bound, "[kg m^2]")
        projection_eps = 0.1 if self.projection_eps is None else _checked("projection_eps", self.projection_eps, "")
        if projection_eps > 1.0:
            raise ValueError(f"projection_eps must be in (0, 1], got {projection_eps!r}")
        if leakage != "none" and sigma is None:
            raise ValueError(f"leakage {leakage!r} needs sigma [1/(kg m^2 s^3)]")
        if leakage == "switching" and theta_bound is None:
            raise ValueError("leakage 'switching' needs theta_bound (M0) [kg m^2]")
        for name, value in (("J_hat", hashable(self.J_hat)), ("leakage", leakage), ("sigma", sigma),
                            ("theta_bound", theta_bound), ("projection_bound", projection_bound),
                            ("projection_eps", projection_eps)):
            object.__setattr__(self, name, value)

    @property
    def robust(self) -> bool:
        """Whether a robustness modification is on (off: the paper's law, bit for bit)."""
        return self.leakage != "none" or self.projection_bound is not None

    def nominal(self, dtype):
        """Theta_0 = Theta(J_hat) (9, 3), the identity's where J_hat is None."""
        J = jnp.eye(3, dtype=dtype) if self.J_hat is None else jnp.asarray(self.J_hat, dtype)
        return regressor_parameters(J)

    def _nominal_like(self, theta_hat):
        """Theta_0 with theta_hat's batch axes (of size 1)."""
        theta_0 = self.nominal(theta_hat.dtype)
        return theta_0.reshape(theta_0.shape + (1,) * (theta_hat.ndim - 2))

    def init(self, gains):
        return self.nominal(jnp.result_type(gains.K_r, float))

    def torque(self, gains, theta_hat, feedback, desired, t):
        terms = adaptive_terms(gains, feedback, desired, self.log_derivative, t)
        feedforward = so3.sum_leading(theta_hat * terms.Phi[:, None])
        tau = -gains.K_r * terms.e - gains.K_w * terms.z + feedforward
        theta_dot = -_apply_gamma(gains.Gamma, terms.Phi)[:, None] * terms.z[None, :]
        if not self.robust:
            return tau, theta_dot
        d = theta_hat - self._nominal_like(theta_hat)
        if self.leakage != "none":
            leak = leakage_rate(d, self.leakage, self.sigma, self.theta_bound)
            theta_dot = theta_dot - leak * _gamma_columns(gains.Gamma, d)
        if self.projection_bound is not None:
            theta_dot = project(d, theta_dot, gains.Gamma, self.projection_bound, self.projection_eps)
        return tau, theta_dot

    @property
    def update(self):
        """With a projection: the tick's forward-Euler step scaled back onto the ball
        (:meth:`projected_update`); without: None (forward Euler)."""
        return None if self.projection_bound is None else self.projected_update

    def projected_update(self, gains, theta_hat, feedback, desired, t, period):
        theta_0 = self._nominal_like(theta_hat)
        stepped = theta_hat + period * self.torque(gains, theta_hat, feedback, desired, t)[1]
        return theta_0 + project_to_ball(stepped - theta_0, self.projection_bound)


def adaptive_backstepping(J_hat=None, log_derivative: str = "exact", leakage: str | None = None,
                          sigma: float | None = None, theta_bound: float | None = None,
                          projection_bound: float | None = None,
                          projection_eps: float | None = None) -> AdaptiveBackstepping:
    """tau = -K_r e - K_w z + Theta_hat^T Phi,  Theta_hat' = -Gamma Phi z^T  (docs/model.md §3.2).

    J_hat: nominal inertia for the initial estimate Theta_hat(0) = Theta_0 = Theta(J_hat)
    (identity by default). log_derivative: "exact" (e' = J_r^{-1}(e) Omega_e) or
    "paper" (e' = Omega_e, the paper's approximation).

    Robustness modifications (module docstring), off by default (the paper's law, bit for bit):
    leakage: "none" (default), "fixed" or "switching" sigma-modification, with sigma
    [1/(kg m^2 s^3)] >= 0 (Gamma sigma [1/s]) and, for "switching", theta_bound M0
    [kg m^2] > 0 (checked and unused with "none"). projection_bound: theta_max [kg m^2]
    > 0 of ||Theta_hat - Theta_0||_F (None: no projection), with projection_eps in
    (0, 1] (default 0.1; checked and unused without a bound). The true Theta - Theta_0
    should lie in the inner ball theta_max / sqrt(1 + eps) for the Lyapunov argument, and
    within M0 for the switching sigma's. With the projection, the sampled wiring's tick
    (``update``) takes the forward-Euler step and scales the result back onto the ball
    (the continuous operator bounds the continuous flow only). With leakage, forward
    Euler at a tick of period Delta_c is stable for lambda_max(Gamma) sigma Delta_c < 2.
    """
    return AdaptiveBackstepping(J_hat, log_derivative, leakage, sigma, theta_bound, projection_bound, projection_eps)


register(
    ControllerSpec(
        name="adaptive",
        label="adaptive",
        factory=adaptive_backstepping,
        gains_type=AdaptiveGains,
        defaults=PAPER_ADAPTIVE_GAINS,
        check=check_gains,
        # the robustness options default to None (absent unless given): a mission that does
        # not set them describes, fingerprints and flies as one without these options
        options=(J_HAT, Param("log_derivative", "exact", choices=LOG_DERIVATIVES,
                              doc="exact: e' = J_r^-1(e) Omega_e; paper: e' = Omega_e"),
                 Param("leakage", None, choices=LEAKAGES,
                       doc="sigma-modification toward Theta(J_hat): none (default) | fixed | switching"),
                 Param("sigma", None, "1/(kg m^2 s^3)", low=0.0,
                       doc="leakage sigma (Gamma sigma is a rate [1/s]); needed by fixed and switching"),
                 Param("theta_bound", None, "kg m^2", low=0.0,
                       doc="switching sigma's M0: no leakage while ||Theta_hat - Theta_0||_F <= M0, full beyond 2 M0"),
                 Param("projection_bound", None, "kg m^2", low=0.0,
                       doc="projection keeps ||Theta_hat - Theta_0||_F <= this (default: no projection)"),
                 Param("projection_eps", None, low=0.0, high=1.0,
                       doc="projection's boundary layer eps in (0, 1] (default 0.1)")),
    )
)
