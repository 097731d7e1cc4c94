"""Rigid-body attitude dynamics (docs/model.md §1, §8.4) and inertia profiles J(t).

The plant owns the rigid body: :func:`derivative` gives Omega' from J(t), the torque the
actuator puts on the body, the disturbance and the momentum the actuator stores
(:mod:`so3jax.components.actuators`), and the actuator's state rate given Omega';
:func:`flexible_derivative` the same for a hub carrying hinged panels and slosh particles
(docs/model.md §8.9, :mod:`so3jax.dynamics.flexible`), with their modal coordinates' rate.

An inertia profile is a pytree with ``__call__(t, phase) -> J (3, 3)`` [kg m^2]:
``phase`` is the index of the mission phase that holds at the start of the current
step (docs/model.md §5), so a profile may switch laws without straddling a step. A profile
with steps of its own (inertia events) also has ``in_step(t, phase, midpoint)``
(:func:`stage_inertia`): its steps switch on the integration step, not on the stage time.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.core import so3
from so3jax.core._fusion import materialize
from so3jax.core.pytree import pytree_dataclass, static_field
from so3jax.dynamics import flexible


class InertiaProfile(abc.ABC):
    """The shape of an inertia profile (docs/model.md §4): J(t, phase) (3, 3) [kg m^2], and
    :meth:`matrices`, {field name: matrix or stack of matrices} checked before a run
    (symmetric positive definite, the triangle inequality's warning), of which J(t) is a
    linear function (a profile scaled by s: each scaled by s). ``convex_phases``: every J(t) of a phase lies in the
    convex hull of those matrices and J at the phase's start, so checking them checks every
    J(t) (otherwise J(t) is checked at sample times, :mod:`so3jax.dynamics.inertia`); an
    optional ``check()`` raises a ValueError for bad parameters. A subclass is a pytree."""

    convex_phases = False

    @abc.abstractmethod
    def __call__(self, t, phase): ...

    def matrices(self) -> dict:
        return {}


@pytree_dataclass
class ConstantInertia(InertiaProfile):
    """J(t) = J."""

    J: jax.Array
    convex_phases = True  # constant: checking J checks every J(t)

    def __call__(self, t, phase):
        return self.J

    def matrices(self):
        return {"J": self.J}


@pytree_dataclass
class PaperInertia(InertiaProfile):
    """The paper's capture profile (docs/model.md §4, corrected eq. 18).

    phase 0: J0; phase 1 (deployment from t_deploy): J1 - (J1 - J0) exp(-(t - t_deploy)/tau_J);
    phase >= 2 (docking): J2.

    In phase 1, J(t) = (1 - w) J1 + w J0 with w = exp(-(t - t_deploy)/tau_J), which
    decreases from its value w_s at the phase's first step towards 0 (tau_J > 0), so every
    J(t) of the phase lies on the segment from J1 to J(t_s). Symmetric positive definite
    matrices form a convex set, and so do those whose principal moments satisfy the
    triangle inequality (2 lambda_max(J) <= tr J, lambda_max being convex): checking J0,
    J1, J2 and J at each phase's first step (``convex_phases``) checks every J(t).
    """

    J0: jax.Array
    J1: jax.Array
    J2: jax.Array
    t_deploy: jax.Array
    tau_J: jax.Array
    convex_phases = True

    def check(self):
        """tau_J > 0 and t_deploy finite (ValueError), where the values are concrete."""
        leaves = (self.tau_J, self.t_deploy)
        if any(isinstance(x, jax.core.Tracer) for x in leaves):
            return
        tau_J, t_deploy = (np.asarray(x, dtype=np.float64) for x in leaves)
        if not np.all(np.isfinite(tau_J) & (tau_J > 0)):
            raise ValueError(f"tau_J (deployment time constant) must be a positive number of seconds, got {tau_J}")
        if not np.all(np.isfinite(t_deploy)):
            raise ValueError(f"t_deploy must be finite, got {t_deploy}")

    def __call__(self, t, phase):
        blend = jnp.exp(-(t - self.t_deploy) / self.tau_J)
        deploying = self.J1 - (self.J1 - self.J0) * blend
        return jnp.where(phase == 0, self.J0, jnp.where(phase == 1, deploying, self.J2))

    def matrices(self):
        return {"J0": self.J0, "J1": self.J1, "J2": self.J2}


@pytree_dataclass
class InertiaFunction(InertiaProfile):
    """A user law J(t) (a JAX-traceable function of time [s]), the same in every phase.

    Checked before a run (symmetric positive definite, triangle inequality) at sample
    times spread over each phase of the horizon (:func:`so3jax.dynamics.scenario.check_scenario`).
    """

    fn: Callable = static_field()

    def __call__(self, t, phase):
        return self.fn(t)


def stage_inertia(profile, t, phase, midpoint):
    """J at time t [s] within the integration step whose midpoint is ``midpoint`` [s]
    (docs/model.md §5): a profile's own steps switch at the integration step nearest
    their time, on all four RK4 stages, as the paper's phases do, so no step straddles
    one; everything else is J(t)."""
    in_step = getattr(profile, "in_step", None)
    return profile(t, phase) if in_step is None else in_step(t, phase, midpoint)


def inertia_rate(profile, t, phase):
    """J'(t) by forward-mode differentiation of the profile in time."""
    return jax.jvp(lambda s: profile(s, phase), (t,), (jnp.ones_like(t),))[1]


def angular_acceleration(J, omega, torque, J_dot=None):
    """Omega' from J Omega' = -Omega x J Omega + torque [- J' Omega] (docs/model.md §1). rad/s^2."""
    rhs = torque - so3.cross(omega, so3.matvec(J, omega))
    if J_dot is not None:
        rhs = rhs - so3.matvec(J_dot, omega)
    return so3.solve_spd(J, rhs)


def derivative(actuator, J, Omega, state, held, d, t, J_dot=None, J_inv=None):
    """(Omega' [rad/s^2], the actuator state's rate) with the actuator's input ``held``:

        (J - J_locked [+ J_constrained]) Omega' = -Omega x (J Omega + h_rel) + tau_body + d [- J' Omega]

    (docs/model.md §8.4; §1 where the actuator stores no momentum, then computed as the
    paper's mode always has). J, J_dot (3, 3, ...) [kg m^2, kg m^2/s]; Omega, d (3, *b);
    t: the stage time [s] (a fusion boundary, :func:`so3jax.core._fusion.materialize`); J_inv:
    J^{-1} where it is precomputed (:mod:`so3jax.dynamics.stepped`; used for an actuator storing no
    momentum and no J' term)."""
    torque = actuator.body_torque(state, held, Omega)
    stored = actuator.stored_momentum(state)
    if stored is None and J_inv is not None and J_dot is None:
        rhs = materialize(torque + d, t) - so3.cross(Omega, so3.matvec(J, Omega))
        Omega_dot = so3.matvec(J_inv, rhs)
    elif stored is None:
        Omega_dot = angular_acceleration(J, Omega, materialize(torque + d, t), J_dot)
    else:
        rhs = torque + d - so3.cross(Omega, so3.matvec(J, Omega) + stored.relative)
        if J_dot is not None:
            rhs = rhs - so3.matvec(J_dot, Omega)
        Omega_dot = so3.solve_spd(_body_inertia(actuator, J, stored, held, Omega), materialize(rhs, t))
    return Omega_dot, actuator.derivative(state, held, Omega, Omega_dot)


def _body_inertia(actuator, J, stored, held, Omega):
    """J - J_locked [+ J_constrained]: the inertia the body's rate sees with the actuator's
    wheels spinning freely relative to it, a stuck wheel spinning with it (docs/model.md (8.22))."""
    J_body = J - so3.batch_like(stored.locked_inertia, 2, Omega)
    constrained = actuator.constrained_inertia(held)
    return J_body if constrained is None else J_body + constrained


def flexible_derivative(actuator, body, J, Omega, modal, state, held, d, t, J_dot=None):
    """(Omega' [rad/s^2], the actuator state's rate, the modal coordinates' rate) of a hub
    carrying hinged panels and slosh particles (docs/model.md §8.9, docs/flexible.md): the
    coupled equations (F.10) of ``body`` (a :class:`~so3jax.dynamics.flexible.FlexibleBody`)
    with the hub's inertia about B (its centre of mass)

        J_hub = J - J_locked [+ J_constrained]

    (what :func:`derivative` solves with) and the torque on the hub

        L = tau_body + d - Omega x ((J - J_hub) Omega + h_rel) [- J' Omega],

    the wheels' part of the gyroscopic term (the hub's own, -Omega x J_hub Omega, is in
    (F.10)): without panels and particles, Omega' is :func:`derivative`'s. modal:
    :class:`~so3jax.dynamics.flexible.Modal` (theta, theta_dot, rho, rho_dot); the other
    arguments as :func:`derivative`'s."""
    L = actuator.body_torque(state, held, Omega) + d
    stored = actuator.stored_momentum(state)
    J_hub = J
    if stored is not None:
        J_hub = _body_inertia(actuator, J, stored, held, Omega)
        L = L - so3.cross(Omega, so3.matvec(J - J_hub, Omega) + stored.relative)
    if J_dot is not None:
        L = L - so3.matvec(J_dot, Omega)
    body = dataclasses.replace(body, hub=dataclasses.replace(body.hub, inertia=J_hub))
    rate = flexible.derivative(body, flexible.FlexState(Omega, *modal), materialize(L, t))
    return rate.omega, actuator.derivative(state, held, Omega, rate.omega), flexible.Modal(*rate[1:])
