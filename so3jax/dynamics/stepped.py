"""A step's time terms computed once per step, for a batch whose scenarios differ per trajectory.

The four RK4 stages of step k evaluate the reference and the inertia at t_k, t_k + dt/2
(twice) and t_k + dt, with the phase p of step k held. When each trajectory of a natively
batched rollout has its own scenario (a sweep's samples), these are evaluated lane by
lane, and what is constant per sample and phase is computed once, before the loop:

* reference (:class:`~so3jax.dynamics.reference.PiecewiseConstantRate`): R_d(t_k) in closed form,
  then R_d(t_k + c dt) = R_d(t_k) exp(hat(Omega_p) c dt), the step rotations of each phase
  precomputed (one trigonometric evaluation per step instead of one per stage, by the
  vectorized sine of :mod:`so3jax.core._trig`);
* inertia (:class:`~so3jax.dynamics.plant.PaperInertia`, :class:`~so3jax.dynamics.plant.ConstantInertia`):
  J and J^{-1} of the constant phases precomputed; in the deployment, the blend
  w(t_k) = exp(-(t_k - t_deploy)/tau_J) once per step, w(t_k + c dt) = w(t_k) exp(-c dt/tau_J),
  and J^{-1} by its adjugate at each of the three times. On CPU only the phase's own
  branch runs.

The values equal the stage-by-stage evaluation's to round-off (R_d within 1e-14, the
closed form's own round-off at angles of ~10 rad; J^{-1} within 1e-13 relative:
tests/test_stepped.py); a shared scenario (one for the whole batch, the paper's mode)
never takes this path.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from so3jax.core import _trig, so3
from so3jax.dynamics.plant import ConstantInertia, PaperInertia
from so3jax.dynamics.reference import PiecewiseConstantRate

STAGE_OF_CALL = (0, 1, 1, 2)  # RK4's four field evaluations -> the step's three times (t, t + dt/2, t + dt)


class StageTerms(NamedTuple):
    """The time terms at one of a step's three stage times; None: evaluated by the field itself."""

    R_d: Any  # (3, 3, B) desired attitude, or None
    J: Any  # (3, 3, B) inertia [kg m^2], or None
    J_inv: Any  # (3, 3, B) its inverse [1/(kg m^2)], or None


class Constants(NamedTuple):
    """Per sample and phase, computed before the loop (leaves: trailing batch axis B)."""

    step_rotations: Any  # (P, 2, 3, 3, B): exp(hat(Omega_p) dt/2), exp(hat(Omega_p) dt); or None
    inertia: Any  # the profile's (see _inertia_constants), or None


def per_trajectory(x, core_ndim: int) -> bool:
    """Whether x carries a trailing batch axis of more than one trajectory."""
    return jnp.ndim(x) > core_ndim and jnp.shape(x)[-1] > 1


def constants(scenario) -> Constants | None:
    """The per-sample constants of a natively batched scenario (batch axis last), or None
    when neither its reference nor its inertia varies per trajectory in a form this
    module knows."""
    ref, inertia, dt = scenario.reference, scenario.inertia, scenario.dt
    rotations = None
    if isinstance(ref, PiecewiseConstantRate) and per_trajectory(ref.rates, 2):
        h = jnp.asarray(dt, ref.rates.dtype)
        rotations = jnp.stack([jnp.stack([so3.exp(rate * (c * h)) for c in (0.5, 1.0)]) for rate in ref.rates])
    inertia_constants = _inertia_constants(inertia, dt)
    if rotations is None and inertia_constants is None:
        return None
    return Constants(rotations, inertia_constants)


def _inertia_constants(inertia, dt):
    if isinstance(inertia, PaperInertia) and per_trajectory(inertia.J0, 2):
        tau = inertia.tau_J
        return (so3.inv_spd(inertia.J0), so3.inv_spd(inertia.J2), jnp.exp(-0.5 * dt / tau), jnp.exp(-dt / tau))
    if isinstance(inertia, ConstantInertia) and per_trajectory(inertia.J, 2):
        return (so3.inv_spd(inertia.J),)
    return None


def stage_terms(scenario, consts: Constants, t, phase, with_inverse: bool) -> tuple[StageTerms, ...]:
    """The time terms at t, t + dt/2, t + dt of a step starting at t [s] in ``phase``."""
    R_d = ((None,) * 3 if consts.step_rotations is None
           else _attitudes(scenario.reference, consts.step_rotations, t, phase))
    J, J_inv = (None,) * 3, (None,) * 3
    if consts.inertia is not None:
        J, J_inv = _inertias(scenario.inertia, consts.inertia, t, phase, with_inverse)
    return tuple(StageTerms(*terms) for terms in zip(R_d, J, J_inv))


def _attitudes(ref: PiecewiseConstantRate, rotations, t, phase):
    start = ref.attitude(t, phase, _trig.sin)
    half, full = rotations[phase, 0], rotations[phase, 1]
    return start, so3.matmul(start, half), so3.matmul(start, full)


def _inertias(inertia, consts, t, phase, with_inverse: bool):
    """(J, J^{-1}) at the step's three times; J^{-1} (None,) * 3 unless ``with_inverse``."""
    inverses = (lambda Js: tuple(so3.inv_spd(J) for J in Js)) if with_inverse else (lambda Js: (None,) * 3)
    if isinstance(inertia, ConstantInertia):
        return (inertia.J,) * 3, (consts[0] if with_inverse else None,) * 3
    J0_inv, J2_inv, e_half, e_full = consts

    def constant(J, J_inv):
        return lambda: ((J,) * 3, (J_inv if with_inverse else None,) * 3)

    def deploying():
        w = jnp.exp(-(t - inertia.t_deploy) / inertia.tau_J)
        Js = tuple(inertia.J1 - (inertia.J1 - inertia.J0) * x for x in (w, w * e_half, w * e_full))
        return Js, inverses(Js)

    branches = (constant(inertia.J0, J0_inv), deploying, constant(inertia.J2, J2_inv))
    index = jnp.clip(phase, 0, 2)

    def every_branch():  # selected elementwise: on a GPU, a branch per step costs more than it saves
        values = [branch() for branch in branches]
        return jax.tree.map(lambda *xs: jnp.select([index == i for i in range(len(xs))], xs), *values)

    return jax.lax.platform_dependent(cpu=lambda: jax.lax.switch(index, branches), default=every_branch)
