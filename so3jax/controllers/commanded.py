"""Open loop: a commanded body torque that ignores the state (actuator tests,
identification manoeuvres).

    tau_i(t) = torque_i + amplitude_i sign(sin(2 pi t / period_i + phase_i)),   i = x, y, z

A constant torque, plus a square wave per body axis (amplitude 0 by default). With
different periods per axis the body's rate sweeps directions and magnitudes that excite
every inertia entry (``missions/identify.toml``). With wheels, the actuator distributes
it to per-wheel motor torques (minimum norm, docs/model.md §8.4) and clips each wheel; a square
wave of period P moves a wheel's speed by at most u P / (4 J_s) around its mean.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax.numpy as jnp

from so3jax.controllers.base import Controller, hashable
from so3jax.controllers.registry import ControllerSpec, register
from so3jax.core import so3
from so3jax.core.params import Param


class NoGains(NamedTuple):
    """A law without gains."""


@dataclasses.dataclass(frozen=True)
class OpenLoop(Controller):
    """The open-loop torque with its options (see :func:`open_loop`), each a 3-tuple."""

    constant: Any = (0.0, 0.0, 0.0)  # the factory's torque: constant body torque [N m]
    amplitude: Any = (0.0, 0.0, 0.0)
    period: Any = (100.0, 140.0, 60.0)
    phase: Any = (0.0, 0.0, 0.0)

    gains_type = NoGains

    def __post_init__(self):
        for name in ("constant", "amplitude", "period", "phase"):
            object.__setattr__(self, name, hashable(getattr(self, name)))

    def init(self, gains):
        return ()

    def torque(self, gains, state, feedback, desired, t):
        like = feedback.Omega
        c, a, p, f = (so3.batch_like(jnp.asarray(x, like.dtype), 1, like)
                      for x in (self.constant, self.amplitude, self.period, self.phase))
        command = c + a * jnp.sign(jnp.sin(2.0 * jnp.pi * jnp.asarray(t, like.dtype) / p + f))
        return jnp.broadcast_to(command, like.shape), ()


def open_loop(torque=(0.0, 0.0, 0.0), amplitude=(0.0, 0.0, 0.0), period=(100.0, 140.0, 60.0),
              phase=(0.0, 0.0, 0.0)) -> OpenLoop:
    """tau = torque + amplitude sign(sin(2 pi t / period + phase)) per body axis, whatever
    the state: torque, amplitude (3,) [N m], period (3,) [s], phase (3,) [rad]; no
    internal state."""
    return OpenLoop(torque, amplitude, period, phase)


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
        check=_check,
        tunable=False,
        options=(Param("torque", [0.0, 0.0, 0.0], "N m", shapes=((3,),), doc="constant body torque"),
                 Param("amplitude", [0.0, 0.0, 0.0], "N m", shapes=((3,),), low=0.0,
                       doc="square-wave amplitude per body axis"),
                 Param("period", [100.0, 140.0, 60.0], "s", shapes=((3,),), low=1e-9,
                       doc="square-wave period per body axis"),
                 Param("phase", [0.0, 0.0, 0.0], "rad", shapes=((3,),), doc="square-wave phase per body axis")),
    )
)
