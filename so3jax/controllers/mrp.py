"""MRP feedback as Basilisk's ``mrpFeedback`` module computes it (Schaub & Junkins,
Analytical Mechanics of Space Systems, 4th ed., Example 8.14 and sec. 8.4.3).

With sigma = sigma_B/R the error MRP (short set, |sigma| <= 1), delta_omega = Omega - Omega_r
the rate error, [I] the nominal inertia (option ``J_hat``) and h_w the wheels' momentum:

    int_sigma <- clip(int_sigma + K dt sigma, -integral_limit, +integral_limit)   (per component)
    z   = int_sigma + [I] delta_omega
    H   = [I] Omega + h_w,   h_w = sum_i J_s,i (g_i^T Omega + Omega_w,i) g_i
    v   = Omega_r + K_i z   (law_type 0)   or   Omega   (law_type 1)
    L_r = K sigma + P delta_omega + P K_i z - v x H + [I](Omega x Omega_r - Omega_r') + L
    tau = -L_r

Omega_r' is the reference's inertial angular acceleration in body axes, R^T R_d Omega_d';
L is the module's known external torque (option ``known_torque``, knownTorquePntB_B,
zero by default). The integral advances at each control tick before the torque is
computed, with dt the time since the previous tick, as the module's ``Update`` does: the
module keeps the previous call's time, 0 standing for 'no previous call', so dt is 0 at
the first tick and at every tick that follows a tick at t = 0 (the sampled loop's first
tick is at t = 0: its first two ticks add nothing to the integral). The module's code
clips K int(sigma), the accumulated K dt sigma, where its documentation speaks of
clipping int(sigma): this law follows the code. The module turns the integral off for
K_i <= 0 (z = 0; its examples write K_i = -1); here K_i must be >= 0 (0: off), the
integral is accumulated for every K_i >= 0 and every term it enters is multiplied by
K_i, so the torque is the module's and its derivative with respect to K_i at K_i = 0 is
that of the K_i > 0 law. In the continuous wiring the integral is integrated with the
plant, held where a component sits at its limit and sigma would push it further out
(conditional integration).

The wheels' momentum is the one the actuator does not compensate itself
(:meth:`so3jax.components.base.Actuator.uncompensated_momentum`, in ``Feedback.wheel_momentum``):
with the wheels' momentum compensation on (the default) the actuator adds
Omega_hat x h_w_hat to the command, which is the law_type 1 term; for the module's
wiring with law_type 0, set ``[actuator.wheels] momentum_compensation = false``.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from so3jax.controllers.base import Controller, hashable, inertial_terms, nominal_inertia, tracking_error
from so3jax.controllers.gains import Nonnegative, check_gains
from so3jax.controllers.pd import J_HAT
from so3jax.controllers.registry import ControllerSpec, register
from so3jax.core import so3
from so3jax.core._fusion import materialize
from so3jax.core.params import Param


class MRPFeedbackGains(NamedTuple):
    K: jax.Array  # N m (per unit MRP)
    P: jax.Array  # N m s / rad
    K_i: jax.Array  # rad / (N m s^2), >= 0 (0: no integral term)
    integral_limit: jax.Array  # N m s, bound of each component of int(K sigma dt)

    # 0 turns the integral off; 1e-4: Basilisk's examples' size
    domains = {"K_i": Nonnegative(scale=1e-4, negative="0 turns the integral off: for Basilisk's K_i = -1, use 0")}


# K = 4 k_R and P = k_Omega of the paper's PD (sigma ~ e / 4 for small errors); no integral.
DEFAULT_GAINS = MRPFeedbackGains(K=2.2856, P=25.0, K_i=0.0, integral_limit=1.0)

LAW_TYPES = (0, 1)


class IntegralState(NamedTuple):
    integral: jax.Array  # (3,) int(K sigma dt), N m s, as of the previous tick
    dt: jax.Array  # () the next tick's dt [s]: 0 until a tick at t != 0 has run (the module's priorTime = 0)


def _tan_quarter_ratio(theta2):
    """tan(theta / 4) / theta for theta^2 = theta2 (its series below theta = 0.03)."""
    small = theta2 < 1e-3
    theta = jnp.sqrt(jnp.where(small, 1.0, theta2))
    series = 0.25 * (1.0 + theta2 * (1.0 / 48.0 + theta2 * (1.0 / 1920.0 + theta2 * (17.0 / 1290240.0))))
    return jnp.where(small, series, jnp.tan(0.25 * theta) / theta)


def mrp(R):
    """The MRP sigma = tan(theta / 4) axis (3, ...) of the rotation R (3, 3, ...), short set
    (|sigma| <= 1: the shadow set is never needed), from the rotation vector log(R)."""
    e = so3.log(R)
    return _tan_quarter_ratio(so3.dot(e, e)) * e


@dataclasses.dataclass(frozen=True)
class MRPFeedback(Controller):
    """Basilisk's mrpFeedback law with its options (see :func:`mrp_feedback`); J_hat as nested tuples."""

    J_hat: Any = None
    law_type: int = 0
    known_torque: Any = None

    gains_type = MRPFeedbackGains

    def __post_init__(self):
        if self.law_type not in LAW_TYPES:
            raise ValueError(f"law_type must be 0 or 1, got {self.law_type!r}")
        object.__setattr__(self, "J_hat", hashable(self.J_hat))
        object.__setattr__(self, "known_torque", hashable(self.known_torque))

    def init(self, gains):
        dtype = jnp.result_type(gains.K, float)
        return IntegralState(jnp.zeros(3, dtype), jnp.zeros((), dtype))

    @staticmethod
    def _advanced(gains, state, sigma, limit):
        """int_sigma after this tick's K dt sigma, clipped per component to +-limit."""
        return jnp.clip(state.integral + gains.K * state.dt * sigma, -limit, limit)

    def torque(self, gains, state, feedback, desired, t):
        nominal = nominal_inertia(self.J_hat)
        err = materialize(tracking_error(feedback, desired), t)
        Omega = feedback.Omega
        sigma = mrp(err.R_e)
        limit = so3.batch_like(gains.integral_limit, 0, sigma)
        integral = self._advanced(gains, state, sigma, limit)
        z = integral + nominal(err.Omega_e)
        H = nominal(Omega)
        if feedback.wheel_momentum is not None:
            H = H + feedback.wheel_momentum
        v = err.Omega_r + gains.K_i * z if self.law_type == 0 else Omega
        L_r = (
            gains.K * sigma
            + gains.P * err.Omega_e
            + gains.P * gains.K_i * z
            - so3.cross(v, H)
            + inertial_terms(nominal, Omega, err)[1]
        )
        if self.known_torque is not None:
            L_r = L_r + so3.batch_like(jnp.asarray(self.known_torque, L_r.dtype), 1, L_r)
        held = (jnp.abs(integral) >= limit) & (integral * sigma > 0)
        integral_dot = jnp.where(held, jnp.zeros_like(sigma), gains.K * sigma)
        return -L_r, IntegralState(integral_dot, jnp.zeros_like(state.dt))

    def update(self, gains, state, feedback, desired, t, period):
        """The integral advanced at a tick at t [s] (before the torque, as the module's Update);
        the next tick's dt: the period, or 0 after a tick at t = 0 (the module's priorTime = 0)."""
        sigma = mrp(tracking_error(feedback, desired).R_e)
        limit = so3.batch_like(gains.integral_limit, 0, sigma)
        dt = jnp.where(jnp.asarray(t) == 0, jnp.zeros_like(period), period)
        return IntegralState(self._advanced(gains, state, sigma, limit),
                             jnp.broadcast_to(dt, state.dt.shape).astype(state.dt.dtype))


def mrp_feedback(J_hat=None, law_type: int = 0, known_torque=None) -> MRPFeedback:
    """Basilisk's mrpFeedback law (module docstring); J_hat: the nominal inertia [I]
    (3, 3) [kg m^2], the identity by default; law_type 0 or 1 (v = Omega_r + K_i z or Omega);
    known_torque: the known external torque L (3,) in body axes [N m], zero by default."""
    return MRPFeedback(J_hat, law_type, known_torque)


register(
    ControllerSpec(
        name="mrp_feedback",
        label="MRP feedback",
        factory=mrp_feedback,
        gains_type=MRPFeedbackGains,
        defaults=DEFAULT_GAINS,
        check=check_gains,
        options=(J_HAT, Param("law_type", 0, low=0, high=1, integer=True,
                              doc="0: v = Omega_r + K_i z; 1: v = Omega (Basilisk's controlLawType)"),
                 Param("known_torque", None, "N m", shapes=((3,),),
                       doc="known external torque in body axes, cancelled (Basilisk's knownTorquePntB_B; default 0)")),
    )
)
