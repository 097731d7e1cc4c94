"""The mission's reference kinds (``[reference] kind``, docs/model.md §2): registrations of
:mod:`so3jax.dynamics.reference`'s trajectories, each with its parameters.

* ``paper``: the paper's piecewise-constant rates in multiples of the orbital rate (§4);
* ``inertial``: a fixed attitude, R_d = exp(hat(attitude));
* ``lvlh``: the orbit frame of a circular orbit of rate n (``[orbit] n``): body x along the
  velocity, z toward nadir, y opposite the orbit normal, turned by ``offset``; the inertial
  frame is that frame at t = 0;
* ``slews``: rest-to-rest eigenaxis slews through attitudes at given start times, under a
  rate and an acceleration limit (:func:`so3jax.dynamics.attitude_profiles.eigenaxis_slews`);
* ``table``: a tabulated attitude history (times and unit quaternions, inline or from a
  file), interpolated through every sample (:func:`so3jax.dynamics.attitude_profiles.tabulated`).

The constant-rate kinds (paper, inertial, lvlh) are :class:`~so3jax.dynamics.reference.PiecewiseConstantRate`:
the batched loop's fast path (:mod:`so3jax.dynamics.stepped`) takes them sample by sample.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.components import registry as components
from so3jax.core import so3
from so3jax.core.params import Param
from so3jax.dynamics import attitude_profiles as profiles
from so3jax.dynamics import reference as ref


class ReferenceContext(NamedTuple):
    """What a reference's builder may read: as_array(x) casts to the run's dtype; the
    orbital rate n [rad/s] (a sample's, in a sweep); the scenario's phase start times [s]
    after the first; the paper's reference of the same n. Only a
    :class:`~so3jax.dynamics.reference.PiecewiseConstantRate` may depend on n: a sweep's
    samples share a reference of another class (:func:`so3jax.missions.batched.sample_metrics`)."""

    as_array: Callable[[Any], Any]
    orbit_rate: Any
    phase_times: tuple
    paper: Any


def rotation(rotvec, as_array=np.asarray):
    """exp(hat(rotvec)) of a rotation vector (3,) or several (K, 3): in float64 by Rodrigues'
    formula where concrete, by :func:`so3jax.core.so3.exp` where traced (a sweep's samples)."""
    if isinstance(rotvec, jax.core.Tracer):
        v = jnp.asarray(rotvec)
        return jnp.moveaxis(so3.exp(jnp.moveaxis(v, -1, 0)), (0, 1), (-2, -1))
    v = np.asarray(rotvec, np.float64)
    if v.ndim > 1:
        return as_array(np.stack([rotation(x) for x in v]))
    angle = float(np.linalg.norm(v))
    K = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]]) / max(angle, 1e-300)
    return as_array(np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K))


def constant_rate(rate, start, ctx: ReferenceContext) -> ref.PiecewiseConstantRate:
    """R_d(t) = start exp(hat(rate) t), Omega_d = rate (body, [rad/s]), in every phase of the
    scenario (start attitudes at each phase's start, so the phase index selects nothing)."""
    rate, start = ctx.as_array(rate), ctx.as_array(start)
    times = (0.0,) + tuple(ctx.phase_times)
    starts = jnp.stack([so3.matmul(start, so3.exp(rate * t)) for t in times])
    return ref.PiecewiseConstantRate(jnp.stack([rate] * len(times)), ctx.as_array(times), starts)


def _lvlh(values, ctx: ReferenceContext):
    offset = rotation(values["offset"], ctx.as_array)
    orbit = jnp.stack([jnp.zeros(()), -ctx.as_array(ctx.orbit_rate), jnp.zeros(())])  # LVLH's rate, in LVLH
    return constant_rate(offset.T @ orbit, offset, ctx)


components.register(components.ComponentSpec(
    kind="reference", name="paper", component=ref.PiecewiseConstantRate, params=(),
    build=lambda v, ctx: ctx.paper,
    doc="the paper's: Omega_d = n [1, -10, 2] in capture and deployment, 0 once docked (docs/model.md §4)",
))
components.register(components.ComponentSpec(
    kind="reference", name="inertial", component=ref.PiecewiseConstantRate,
    params=(Param("attitude", [0.0, 0.0, 0.0], "rad", shapes=((3,),), doc="R_d = exp(hat(attitude))"),),
    build=lambda v, ctx: constant_rate(np.zeros(3), rotation(v["attitude"], ctx.as_array), ctx),
    doc="a fixed inertial attitude: Omega_d = 0",
))
components.register(components.ComponentSpec(
    kind="reference", name="lvlh", component=ref.PiecewiseConstantRate,
    params=(Param("offset", [0.0, 0.0, 0.0], "rad", shapes=((3,),),
                  doc="the desired body frame turned from LVLH by exp(hat(offset))"),),
    build=_lvlh,
    doc="the orbit frame of [orbit] n: x along the velocity, z to nadir; Omega_d = offset^T [0, -n, 0]",
))


def _slews_values(values: dict) -> dict:
    """The slews' attitudes and times given, as many of each, and the plan possible (each
    slew ends before the next starts): one-line ValueErrors at parse time."""
    attitudes, times = values.get("attitudes"), values.get("times")
    if attitudes is None or times is None:
        raise ValueError("reference.slews: give attitudes (a rotation vector per slew) and times (each slew's start)")
    if len(attitudes) != len(times):
        raise ValueError(f"reference.slews: {len(attitudes)} attitudes and {len(times)} times: one start time per slew")
    try:
        _slews(values, np.asarray)
    except ValueError as error:
        raise ValueError(f"reference.slews: {error}") from None
    return values


def _slews(values: dict, as_array):
    return profiles.eigenaxis_slews(rotation(values["start"], as_array), rotation(values["attitudes"], as_array),
                                    as_array(values["times"]), as_array(values["max_rate"]),
                                    as_array(values["max_acceleration"]))


def _table_values(values: dict) -> dict:
    """The table's samples: from ``file`` or inline ``times`` and ``quaternions``, one of the
    two; adds ``rotations`` (K, 3, 3)."""
    inline = values.get("times") is not None or values.get("quaternions") is not None
    if (values.get("file") is not None) == inline:
        raise ValueError("reference.table: give file, or times and quaternions, one of the two")
    try:
        if values.get("file") is not None:
            times, rotations = profiles.read_attitude_table(values["file"])
        else:
            q = np.asarray(values.get("quaternions"), np.float64)
            norms = np.linalg.norm(q, axis=-1) if q.ndim == 2 else np.zeros(0)
            bad = np.flatnonzero(np.abs(norms - 1.0) > 1e-6)
            if bad.size:
                raise ValueError(f"quaternions[{bad[0]}] is not a unit quaternion (norm {norms[bad[0]]:.9g})")
            times, rotations = np.asarray(values.get("times"), np.float64), profiles.quaternion_to_rotation(q)
        profiles.tabulated(times, rotations)
    except ValueError as error:
        raise ValueError(f"reference.table: {error}") from None
    return {**values, "times": times, "rotations": rotations}


components.register(components.ComponentSpec(
    kind="reference", name="slews", component=profiles.EigenaxisSlews,
    params=(
        Param("start", [0.0, 0.0, 0.0], "rad", shapes=((3,),), doc="R_d(0) = exp(hat(start)), a rotation vector"),
        Param("attitudes", None, "rad", shapes=((None, 3),), doc="each slew's target attitude, a rotation vector"),
        Param("times", None, "s", shapes=((None,),), low=0.0, doc="each slew's start time, ascending"),
        Param("max_rate", 0.02, "rad/s", low=0.0, low_excluded=True, doc="rate limit |Omega_d| <= max_rate"),
        Param("max_acceleration", 1e-3, "rad/s^2", low=0.0, low_excluded=True,
              doc="peak angular acceleration of each raised-sine pulse"),
    ),
    complete=_slews_values,
    build=lambda v, ctx: _slews(v, ctx.as_array),
    doc="rest-to-rest eigenaxis slews through the attitudes, each in minimum time under the limits, holding between",
))
components.register(components.ComponentSpec(
    kind="reference", name="table", component=profiles.Tabulated,
    params=(
        Param("file", None, text=True, doc="a CSV (header t, qw, qx, qy, qz) or .npz (t, q) of unit quaternions, "
                                           "relative to the mission file"),
        Param("times", None, "s", shapes=((None,),), doc="the samples' times, increasing (instead of file)"),
        Param("quaternions", None, shapes=((None, 4),), doc="the samples' attitudes [w, x, y, z], unit"),
    ),
    complete=_table_values,
    build=lambda v, ctx: profiles.tabulated(ctx.as_array(v["times"]), ctx.as_array(v["rotations"])),
    doc="a tabulated attitude history, a cubic through every sample (rates: central differences), held outside",
))
