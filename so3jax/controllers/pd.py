"""Geometric PD with feedforward (Lee, Leok, McClamroch 2010; docs/model.md §3.1)."""

from __future__ import annotations

from typing import NamedTuple

import jax

from so3jax.core import so3
from so3jax.core._fusion import materialize
from so3jax.controllers.base import Controller, inertial_terms, nominal_inertia, tracking_error
from so3jax.core.params import Param
from so3jax.controllers.registry import ControllerSpec, register
from so3jax.dynamics.scenario import check_gains

J_HAT = Param("J_hat", None, "kg m^2", shapes=((3, 3),), doc="nominal inertia (default: the identity)")


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
        inertial, feedforward = inertial_terms(nominal, Omega, err)
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
