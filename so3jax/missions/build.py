"""A mission's :class:`~so3jax.dynamics.scenario.Scenario`: the one builder of the nominal
mission (:meth:`so3jax.missions.mission.Mission.scenario`) and of its dispersed samples
(:func:`so3jax.missions.batched.sample_metrics`)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.components import registry as components
from so3jax.components.inertias import InertiaContext
from so3jax.components.references import ReferenceContext, rotation
from so3jax.core import checks
from so3jax.dynamics.environment import circular_orbit
from so3jax.dynamics.flexible import FlexibleBody, HingedPanel, Hub, SloshParticle
from so3jax.dynamics.orbit import MAX_MEAN_MOTION, MIN_ALTITUDE
from so3jax.dynamics.plant import ConstantInertia
from so3jax.dynamics.scenario import Scenario, paper_scenario
from so3jax.dynamics.space import Environment


def scenario(mission, params=None, dtype=None) -> Scenario:
    """The scenario of ``mission`` (a :class:`~so3jax.missions.mission.Mission`): its own
    values, in ``dtype`` (default: JAX's float), or with ``params`` (a
    :class:`~so3jax.missions.draw.RolloutParams` of one sample, traceable: vmap over
    samples) its inertias, time constant, orbital rate and disturbance, and its R(0) and
    Omega(0) composed with the mission's (R(0) = R_mission(0) R_sample(0), Omega(0) =
    Omega_sample(0) + Omega_mission(0)), in the dtype of params.J0."""
    m, p = mission, params
    if p is None:
        values = dict(tau_J=m.tau_J, n=m.n, J0=m.J0, J1=m.J1, J2=m.J2, disturbance_amplitude=m.disturbance["amplitude"],
                      disturbance_frequency=m.disturbance["frequency"], noise_std=m.disturbance["noise_std"])
    else:
        values = dict(tau_J=p.tau_J, n=p.n, J0=p.J0, J1=p.J1, J2=p.J2, disturbance_amplitude=p.amplitude,
                      disturbance_frequency=p.frequency, noise_std=p.noise_std)
        dtype = p.J0.dtype
    s = paper_scenario(m.T, m.dt, **values, dtype=dtype)
    # the mission's initial state: where it is the default (R(0) = I, Omega(0) = 0), the
    # scenario's (or the sample's) is kept as it is
    changes = {} if p is None else {"R0": p.R0, "Omega0": p.Omega0}
    if np.any(m.initial["attitude"]):
        R0 = jnp.asarray(rotation(m.initial["attitude"]), s.R0.dtype if p is None else p.R0.dtype)
        changes["R0"] = R0 if p is None else R0 @ p.R0
    if np.any(m.initial["rate"]):
        Omega0 = jnp.asarray(m.initial["rate"], s.R0.dtype if p is None else p.Omega0.dtype)
        changes["Omega0"] = Omega0 if p is None else p.Omega0 + Omega0
    if m.constant_inertia:
        changes["inertia"] = ConstantInertia(jnp.asarray(m.J0, s.R0.dtype) if p is None else p.J0)
    if tuple(m.phases["start"][1:]) != s.phase_times:
        s = dataclasses.replace(s, phase_times=tuple(m.phases["start"][1:]))  # the paper's profiles need the paper's
    if m.reference["kind"] != "paper":
        changes["reference"] = reference(m, s, values["n"])
    if m.inertia["kind"] != "paper":
        changes["inertia"] = inertia(m, s)
    if orbit_users(m):
        changes["environment"] = environment(m, values["n"], s.R0.dtype)
    if getattr(m, "flexible", False):  # hinged panels and slosh (docs/model.md §8.9), the mission's own
        changes["flexible"], changes["flexible_initial"] = flexible(m, s.R0.dtype)
    return dataclasses.replace(s, **changes) if changes else s


def flexible(mission, dtype):
    """(the mission's :class:`~so3jax.dynamics.flexible.FlexibleBody`, (theta(0) (N,) [rad], rho(0)
    (M,) [m])) of ``[hub]``, ``[[appendages]]`` and ``[[slosh]]`` in ``dtype`` (the hub's inertia a
    placeholder, J0: each stage's is J(t) less the wheels', so3jax.dynamics.plant.flexible_derivative)."""
    as_array = lambda x: jnp.asarray(x, dtype)
    body = flexible_body(mission.hub_mass, mission.appendages, mission.slosh, mission.J0, as_array,
                         phases=len(mission.phase_names))
    theta0 = as_array([a["angle"] for a in mission.appendages]).reshape(-1)
    rho0 = as_array([p["displacement"] for p in mission.slosh]).reshape(-1)
    return body, (theta0, rho0)


def panel_frame(axis, direction) -> np.ndarray:
    """The hinge frame's rows (h1, h2, h3) of a panel: h1 = -direction (Basilisk's panel extends
    along -s1 from the hinge), h2 = axis, h3 = h1 x h2 (docs/flexible.md (F.1))."""
    h1, h2 = -np.asarray(direction, float), np.asarray(axis, float)
    return np.stack([h1, h2, np.cross(h1, h2)])


def flexible_body(hub_mass, appendages, slosh, J, as_array=np.asarray, phases: int = 0) -> FlexibleBody:
    """The :class:`~so3jax.dynamics.FlexibleBody` of parsed ``[[appendages]]`` and
    ``[[slosh]]`` on a hub of ``hub_mass`` [kg] and inertia J (3, 3) [kg m^2] about its centre of
    mass, the body origin B (in a flight, J(t) less the wheels' at each stage). phases: the
    mission's number of phases; where any k or c is a list (one value per phase), every k and c
    is given per phase ((phases,), a number repeated: FlexibleBody.phases), else each one value."""
    per_phase = any(np.ndim(e[f]) for e in (*appendages, *slosh) for f in ("k", "c"))
    modal = (lambda x: jnp.broadcast_to(as_array(x), (phases,))) if per_phase else as_array
    zero = as_array(np.zeros(3))
    panels = tuple(HingedPanel(as_array(a["mass"]), as_array(a["inertia"]), as_array(a["distance"]),
                                        modal(a["k"]), modal(a["c"]), as_array(a["hinge"]),
                                        as_array(panel_frame(a["axis"], a["direction"])))
                   for a in appendages)
    particles = tuple(SloshParticle(as_array(p["mass"]), as_array(p["location"]), as_array(p["direction"]),
                                             modal(p["k"]), modal(p["c"])) for p in slosh)
    return FlexibleBody(Hub(as_array(hub_mass), as_array(J), zero), panels, particles,
                        phases=phases if per_phase else 0)


def orbit_users(mission) -> tuple[str, ...]:
    """What of the mission flies on its orbit (and so needs orbit.n > 0): the torques of
    ``[environment]`` and a momentum manager that reads the geomagnetic field, as keys."""
    kind = mission.momentum["kind"]
    return (*(f"environment.{name}" for name in mission.environment),
            *((f"momentum.kind = {kind!r}",) if components.get("momentum", kind).component.reads_field else ()))


def environment(mission, n, dtype):
    """The mission's :class:`~so3jax.dynamics.space.Environment`: its orbit (``[orbit]``, of rate
    n [rad/s]: a sample's in a sweep) and the torque models of ``[environment]``
    (:mod:`so3jax.components.environment`), in ``dtype``."""
    as_array = lambda x: jnp.asarray(x, dtype)
    concrete = checks.concrete(n, "orbit.n")  # None in a sweep (traced): its samples' are checked when drawn
    if concrete is not None and np.any(concrete == 0.0):
        raise ValueError(f"orbit.n = 0 rad/s is no orbit, but {', '.join(orbit_users(mission))} fly on one: give "
                         f"orbit.n > 0 (at most {MAX_MEAN_MOTION:.6g} rad/s, an orbit {MIN_ALTITUDE / 1e3:g} km high)")
    angles = {name: as_array(np.deg2rad(value)) for name, value in mission.orbit.items()}
    orbit = circular_orbit(as_array(n), **angles)
    context = components.BuildContext(as_array, {})
    torques = tuple(components.get("environment", name).build(values, context)
                    for name, values in mission.environment.items())
    return Environment(orbit, torques)


def inertia(mission, scenario: Scenario):
    """The mission's inertia profile of ``[inertia] kind`` (:mod:`so3jax.components.inertias`)
    in the scenario's dtype (the same for every sample of a sweep)."""
    kind = mission.inertia["kind"]
    context = InertiaContext(lambda x: jnp.asarray(x, scenario.R0.dtype), scenario.inertia)
    with jax.ensure_compile_time_eval():
        return components.get("inertia", kind).build(mission.inertia[kind], context)


def reference(mission, scenario: Scenario, n):
    """The mission's reference (``[reference] kind``, :mod:`so3jax.components.references`) in
    the scenario's dtype, for the orbital rate n [rad/s] (traced in a sweep: what depends on
    it is traced, the rest computed when traced)."""
    kind = mission.reference["kind"]
    dtype = scenario.R0.dtype
    context = ReferenceContext(lambda x: jnp.asarray(x, dtype), n, scenario.phase_times, scenario.reference)
    with jax.ensure_compile_time_eval():  # a builder that checks its values sees them, also inside jit
        return components.get("reference", kind).build(mission.reference[kind], context)
