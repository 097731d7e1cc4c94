"""Geometric PD with feedforward (Lee, Leok, McClamroch 2010; docs/model.md §3.1)."""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax

from so3jax.controllers.base import Controller, hashable, inertial_terms, nominal_inertia, tracking_error
from so3jax.controllers.gains import check_gains
from so3jax.controllers.registry import ControllerSpec, register
from so3jax.core import so3
from so3jax.core._fusion import materialize
from so3jax.core.params import Param

J_HAT = Param("J_hat", None, "kg m^2", shapes=((3, 3),), doc="nominal inertia (default: the identity)")


class PDGains(NamedTuple):
    k_R: jax.Array  # N m / rad
    k_Omega: jax.Array  # N m s / rad


PAPER_PD_GAINS = PDGains(k_R=0.5714, k_Omega=25.0)


@dataclasses.dataclass(frozen=True)
class GeometricPD(Controller):
    """tau = -k_R e_R - k_Omega Omega_e + Omega x J_hat Omega - J_hat (Omega x Omega_r - R^T R_d Omega_d').

    J_hat: nominal inertia (3, 3) [kg m^2] (nested tuples: :func:`~so3jax.controllers.base.hashable`);
    None: the identity (the paper: "no knowledge").
    """

    J_hat: Any = None

    gains_type = PDGains

    def __post_init__(self):
        object.__setattr__(self, "J_hat", hashable(self.J_hat))

    def init(self, gains):
        return ()

    def torque(self, gains, state, feedback, desired, t):
        err = materialize(tracking_error(feedback, desired), t)
        Omega = feedback.Omega
        e_R = so3.skew_vee(err.R_e)
        inertial, feedforward = inertial_terms(nominal_inertia(self.J_hat), Omega, err)
        tau = -gains.k_R * e_R - gains.k_Omega * err.Omega_e + inertial - feedforward
        return tau, ()


def geometric_pd(J_hat=None) -> GeometricPD:
    """tau = -k_R e_R - k_Omega Omega_e + Omega x J_hat Omega - J_hat (Omega x Omega_r - R^T R_d Omega_d').

    J_hat: nominal inertia (3, 3) [kg m^2]; identity by default (the paper: "no knowledge").
    """
    return GeometricPD(J_hat)


register(
    ControllerSpec(
        name="pd",
        label="PD",
        factory=geometric_pd,
        gains_type=PDGains,
        defaults=PAPER_PD_GAINS,
        check=check_gains,
        options=(J_HAT,),
    )
)
