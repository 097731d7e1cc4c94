"""Excitation: an open-loop square-wave body torque for identification manoeuvres.

    tau_i(t) = amplitude_i sign(sin(2 pi t / period_i + phase_i)),   i = x, y, z

Each axis switches at its own period, so the body's rate sweeps directions and
magnitudes that excite every inertia entry. With wheels, the actuator distributes it to
per-wheel motor torques (minimum norm, SPEC 8.4) and clips each wheel; a square wave of
period P moves a wheel's speed by at most u P / (4 J_s) around its mean, which keeps
the wheels off their speed limit when chosen so (``missions/identify.toml``).
"""

from __future__ import annotations

import jax.numpy as jnp

from so3jax import so3
from so3jax.components import Param
from so3jax.controllers.base import Controller
from so3jax.controllers.open_loop import NoGains, _check
from so3jax.controllers.registry import ControllerSpec, register


def excitation(amplitude=(0.2, 0.2, 0.2), period=(100.0, 140.0, 180.0), phase=(0.0, 0.0, 0.0)) -> Controller:
    """Square waves per body axis: amplitude (3,) [N m], period (3,) [s], phase (3,) [rad]."""

    def init(gains):
        return ()

    def tau(gains, state, measured, desired, t):
        like = measured.Omega
        a, p, f = (so3.batch_like(jnp.asarray(x, like.dtype), 1, like) for x in (amplitude, period, phase))
        command = a * jnp.sign(jnp.sin(2.0 * jnp.pi * jnp.asarray(t, like.dtype) / p + f))
        return jnp.broadcast_to(command, like.shape), ()

    return Controller(init, tau, NoGains)


register(
    ControllerSpec(
        name="excitation",
        label="excitation",
        factory=excitation,
        gains_type=NoGains,
        defaults=NoGains(),
        style=dict(ls="-.", color="tab:brown", label="excitation"),
        check=_check,
        tunable=False,
        options=(
            Param("amplitude", [0.2, 0.2, 0.2], "N m", shapes=((3,),), low=0.0, doc="square-wave amplitude per body axis"),
            Param("period", [100.0, 140.0, 180.0], "s", shapes=((3,),), low=1e-9, doc="square-wave period per body axis"),
            Param("phase", [0.0, 0.0, 0.0], "rad", shapes=((3,),), doc="phase per body axis"),
        ),
    )
)
