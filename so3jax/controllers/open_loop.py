"""Open loop: a constant commanded body torque (actuator tests, identification runs)."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from so3jax import so3
from so3jax.controllers.base import Controller
from so3jax.components import Param
from so3jax.controllers.registry import ControllerSpec, register


class NoGains(NamedTuple):
    """A law without gains."""


def open_loop(torque=(0.0, 0.0, 0.0)) -> Controller:
    """tau = torque (3,) [N m], whatever the state; no internal state."""

    def init(gains):
        return ()

    def tau(gains, state, measured, desired, t):
        command = so3.batch_like(jnp.asarray(torque, measured.Omega.dtype), 1, measured.Omega)
        return jnp.broadcast_to(command, measured.Omega.shape), ()

    return Controller(init, tau, NoGains)


def _check(gains) -> None:
    if not isinstance(gains, NoGains):
        raise ValueError(f"open_loop takes no gains, got {gains!r}")


register(
    ControllerSpec(
        name="open_loop",
        label="open loop",
        factory=open_loop,
        gains_type=NoGains,
        defaults=NoGains(),
        style=dict(ls=":", color="tab:gray", label="open loop"),
        check=_check,
        tunable=False,
        options=(Param("torque", [0.0, 0.0, 0.0], "N m", shapes=((3,),), doc="constant body torque"),),
    )
)
