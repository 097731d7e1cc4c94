"""Registrations of the built-in actuators (SPEC 8.4) in :mod:`so3jax.components`."""

from __future__ import annotations

import numpy as np

from so3jax import components
from so3jax.actuators import Ideal, Saturated, Wheels
from so3jax.components import Param

_PYRAMID = [[0.8165408118857462, 0.0, 0.5772877120855479], [0.0, 0.8165408118857462, 0.5772877120855479],
            [-0.8165408118857462, 0.0, 0.5772877120855479], [0.0, -0.8165408118857462, 0.5772877120855479]]
_PER_WHEEL = ((), (None,))  # one value for every wheel, or one per wheel
_WHEEL_LISTS = ("spin_inertia", "max_torque", "max_speed", "initial_speed")


def _per_wheel(values: dict) -> dict:
    """The per-wheel parameters broadcast to (N,) for N = the number of axes."""
    n = values["axes"].shape[0]
    out = dict(values)
    for key in _WHEEL_LISTS:
        v = np.asarray(values[key], float)
        if v.shape not in ((), (n,)):
            raise ValueError(f"actuator.wheels.{key} must be one number or {n} (one per wheel), got {v.shape[0]}")
        out[key] = np.broadcast_to(v, (n,)).copy()
    return out


def _complete_wheels(values: dict) -> dict:
    """One value per wheel for each per-wheel parameter; Omega_w(0) within the speed limit."""
    w = _per_wheel(values)
    over = np.abs(w["initial_speed"]) > w["max_speed"]
    if np.any(over):
        i = int(np.argmax(over))
        raise ValueError("actuator.wheels.initial_speed [rad/s] must not exceed actuator.wheels.max_speed in magnitude "
                         f"(wheel {i + 1}: {w['initial_speed'][i]:g} against {w['max_speed'][i]:g})")
    return w


def _wheels(w: dict, ctx) -> Wheels:
    a = ctx.as_array
    return Wheels(a(w["axes"].T), a(w["spin_inertia"]), a(w["max_torque"]), a(w["max_speed"]), a(w["initial_speed"]),
                  bool(w["momentum_compensation"]))


components.register(components.ComponentSpec(
    kind="actuator", name="ideal", params=(), build=lambda v, ctx: Ideal(),
    doc="tau = tau_c",
))
components.register(components.ComponentSpec(
    kind="actuator", name="saturated",
    params=(Param("max_torque", [0.25, 0.25, 0.25], "N m", shapes=((), (3,)), low=0.0, doc="limit per body axis"),),
    build=lambda v, ctx: Saturated(ctx.as_array(np.broadcast_to(v["max_torque"], (3,)).copy())),
    doc="tau_i = clip(tau_c,i, -max_torque_i, max_torque_i)",
))
components.register(components.ComponentSpec(
    kind="actuator", name="wheels",
    params=(
        Param("axes", _PYRAMID, "", shapes=((None, 3),), doc="one unit spin axis per wheel (rows)"),
        Param("spin_inertia", 0.16, "kg m^2", shapes=_PER_WHEEL, low=0.0, doc="J_s"),
        Param("max_torque", 0.25, "N m", shapes=_PER_WHEEL, low=0.0, doc="motor torque limit u_max"),
        Param("max_speed", 628.0, "rad/s", shapes=_PER_WHEEL, low=0.0, doc="speed limit Omega_max"),
        Param("initial_speed", 0.0, "rad/s", shapes=_PER_WHEEL, doc="Omega_w(0), relative to the body"),
        Param("momentum_compensation", True, boolean=True, doc="command tau_c + omega_hat x h_w_hat"),
    ),
    complete=_complete_wheels,
    build=_wheels,
    doc="N reaction wheels (SPEC 8.4)",
))
