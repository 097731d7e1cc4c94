"""Geometric sliding mode on SO(3) with a boundary layer.

The sliding variable combines the rate and attitude errors (T. Lee, "Robust adaptive
attitude tracking on SO(3) with an application to a quadrotor UAV", IEEE TCST 21(5),
2013: e_Omega + c e_R), with R_e = R_d^T R:

    e_R = 1/2 (R_e - R_e^T)^vee           [rad]      (Lee's 1/2 (R_d^T R - R^T R_d)^vee)
    Omega_e = Omega - Omega_r,  Omega_r = R_e^T Omega_d                    [rad/s]
    s = Omega_e + lam e_R                 [rad/s]
    e_R' = E(R_e) Omega_e,  E = 1/2 (tr(R_e^T) I - R_e^T)  (Lee, Leok, McClamroch 2010)
    Omega_e' = Omega' + Omega x Omega_r - R^T R_d Omega_d'

With a nominal inertia J_hat (option ``J_hat``, the identity by default):

    tau = Omega x J_hat Omega - J_hat (Omega x Omega_r - R^T R_d Omega_d' + lam E(R_e) Omega_e)
          - k_s s - eta sat_phi(s)

sat_phi(s) = tanh(s / phi) (``boundary="tanh"``) or clip(s / phi, -1, 1) (``"sat"``),
elementwise: the switching term -eta sign(s) smoothed in a boundary layer of width phi
(Slotine & Li, Applied Nonlinear Control, 1991, sec. 7.1-7.2).

For J_hat = J constant and no disturbance, J Omega' = J Omega x Omega + tau gives
J s' = -k_s s - eta sat_phi(s), so V = 1/2 s^T J s has V' = -k_s |s|^2 - eta s^T sat_phi(s)
<= 0 (each s_i sat_phi(s_i) >= 0): s -> 0. On s = 0, Psi = 1/2 tr(I - R_e) = 1 - cos(angle)
has Psi' = e_R . Omega_e = -lam |e_R|^2: the attitude error falls from any angle below pi.

Units: lam [1/s], k_s [N m s/rad], eta [N m], phi [rad/s].
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from so3jax.controllers.base import Controller, hashable, inertial_terms, nominal_inertia, tracking_error
from so3jax.controllers.gains import check_gains
from so3jax.controllers.pd import J_HAT
from so3jax.controllers.registry import ControllerSpec, register
from so3jax.core import so3
from so3jax.core._fusion import materialize
from so3jax.core.params import Param


class SlidingModeGains(NamedTuple):
    lam: jax.Array  # 1/s: slope of the sliding surface s = Omega_e + lam e_R
    k_s: jax.Array  # N m s / rad: linear feedback on s
    eta: jax.Array  # N m: switching gain
    phi: jax.Array  # rad/s: boundary layer width


# k_s lam = k_R and k_s + lam ~ k_Omega of the paper's PD (its linearization with J_hat = I);
# eta, phi: a small boundary-layer term.
DEFAULT_GAINS = SlidingModeGains(lam=0.5714 / 25.0, k_s=25.0, eta=0.01, phi=1e-3)

BOUNDARIES = ("tanh", "sat")


def attitude_error_rate_matrix(R_e):
    """E(R_e) = 1/2 (tr(R_e^T) I - R_e^T) (3, 3, ...), with e_R' = E(R_e) Omega_e."""
    return 0.5 * (so3.trace(R_e) * so3.eye_like(R_e[0]) - so3.transpose(R_e))


def _surface(gains, err):
    """s = Omega_e + lam e_R [rad/s] (3, ...) of a tracking error."""
    return err.Omega_e + gains.lam * so3.skew_vee(err.R_e)


def sliding_variable(gains, feedback, desired):
    """s = Omega_e + lam e_R [rad/s] (3, ...)."""
    return _surface(gains, tracking_error(feedback, desired))


@dataclasses.dataclass(frozen=True)
class SlidingMode(Controller):
    """The sliding-mode law with its options (see :func:`sliding_mode`); J_hat as nested tuples."""

    J_hat: Any = None
    boundary: str = "tanh"

    gains_type = SlidingModeGains

    def __post_init__(self):
        if self.boundary not in BOUNDARIES:
            raise ValueError(f"boundary must be one of {BOUNDARIES}, got {self.boundary!r}")
        object.__setattr__(self, "J_hat", hashable(self.J_hat))

    def saturate(self, x):
        """sat(x): tanh(x) or clip(x, -1, 1) elementwise."""
        return jnp.tanh(x) if self.boundary == "tanh" else jnp.clip(x, -1.0, 1.0)

    def init(self, gains):
        return ()

    def torque(self, gains, state, feedback, desired, t):
        err = materialize(tracking_error(feedback, desired), t)
        Omega = feedback.Omega
        s = _surface(gains, err)
        # E(R_e) Omega_e = 1/2 (tr(R_e) Omega_e - R_e^T Omega_e)
        e_R_dot = 0.5 * (so3.trace(err.R_e) * err.Omega_e - so3.rmatvec(err.R_e, err.Omega_e))
        inertial, feedforward = inertial_terms(nominal_inertia(self.J_hat), Omega, err, gains.lam * e_R_dot)
        tau = inertial - feedforward - gains.k_s * s - gains.eta * self.saturate(s / gains.phi)
        return tau, ()


def sliding_mode(J_hat=None, boundary: str = "tanh") -> SlidingMode:
    """tau = Omega x J_hat Omega - J_hat (Omega x Omega_r - R^T R_d Omega_d' + lam E(R_e) Omega_e)
    - k_s s - eta sat_phi(s)  [N m], s = Omega_e + lam e_R (see the module).

    J_hat: nominal inertia (3, 3) [kg m^2], the identity by default. boundary: "tanh"
    (tanh(s / phi)) or "sat" (clip(s / phi, -1, 1)).
    """
    return SlidingMode(J_hat, boundary)


register(
    ControllerSpec(
        name="sliding_mode",
        label="sliding mode",
        factory=sliding_mode,
        gains_type=SlidingModeGains,
        defaults=DEFAULT_GAINS,
        check=check_gains,
        options=(J_HAT, Param("boundary", "tanh", choices=BOUNDARIES,
                              doc="sat_phi(s): tanh(s/phi), or sat: clip(s/phi, -1, 1)")),
    )
)
