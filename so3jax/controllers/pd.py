"""Geometric PD with feedforward (Lee, Leok, McClamroch 2010; SPEC 3.1)."""

from __future__ import annotations

from typing import NamedTuple

import jax

from so3jax import so3
from so3jax._fusion import materialize
from so3jax.controllers.base import Controller, tracking_error
from so3jax.components import Param
from so3jax.controllers.registry import ControllerSpec, register
from so3jax.scenario import check_gains

J_HAT = Param("J_hat", None, "kg m^2", shapes=((3, 3),), doc="nominal inertia (default: the identity)")


def nominal_inertia(J_hat):
    """v -> J_hat v [kg m^2 x v's unit] for v (3, ...), the identity where J_hat is None."""
    if J_hat is None:
        return lambda v: v
    return lambda v: so3.matvec(so3.batch_like(J_hat, 2, v), v)


class PDGains(NamedTuple):
    k_R: jax.Array  # N m / rad
    k_Omega: jax.Array  # N m s / rad


PAPER_PD_GAINS = PDGains(k_R=0.5714, k_Omega=25.0)


def geometric_pd(J_hat=None) -> Controller:
    """tau = -k_R e_R - k_Omega Omega_e + Omega x J_hat Omega - J_hat (Omega x Omega_r - R^T R_d Omega_d').

    J_hat: nominal inertia (3, 3) [kg m^2]; identity by default (the paper: "no knowledge").
    """
    nominal = nominal_inertia(J_hat)

    def init(gains):
        return ()

    def torque(gains, state, measured, desired, t):
        err = materialize(tracking_error(measured, desired), t)
        Omega = measured.Omega
        e_R = so3.skew_vee(err.R_e)
        inertial = so3.cross(Omega, nominal(Omega))
        feedforward = nominal(so3.cross(Omega, err.Omega_r) - err.feedforward_dot)
        tau = -gains.k_R * e_R - gains.k_Omega * err.Omega_e + inertial - feedforward
        return tau, ()

    return Controller(init, torque, PDGains)


register(
    ControllerSpec(
        name="pd",
        label="PD",
        factory=geometric_pd,
        gains_type=PDGains,
        defaults=PAPER_PD_GAINS,
        style=dict(ls="--", color="tab:red", label="PD"),
        check=check_gains,
        options=(J_HAT,),
    )
)
