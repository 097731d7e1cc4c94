"""The closed-loop rollout: a ``lax.scan`` of SO(3) RK4 steps with metrics in the carry.

``rollout(scenario, controller, gains, seed)`` is a pure function: jit, vmap (over
scenarios, gains, seeds) and grad compose with it. ``simulate`` is the jitted,
validated entry point.

The scan is nested: an outer scan over blocks of ``record_every`` steps records the
state at each block start (the histories), and each block is ``jax.checkpoint``-ed, so
reverse-mode memory grows like N / record_every + record_every rather than N.
"""

from __future__ import annotations

import functools
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from so3jax import metrics, so3
from so3jax.controllers.base import Controller, Desired, Measured, tracking_error
from so3jax.integrate import lie_rk4_step
from so3jax.plant import angular_acceleration, inertia_rate
from so3jax.scenario import Scenario, check_gains, check_scenario


class State(NamedTuple):
    R: jax.Array  # (3, 3)
    Omega: jax.Array  # (3,) rad/s
    controller: Any  # the controller's internal state
    R_d: Any  # (3, 3) when the reference is integrated, else ()


class History(NamedTuple):
    """Samples at the start of every block of ``record_every`` steps."""

    t: jax.Array  # (M,) s
    R: jax.Array  # (M, 3, 3)
    Omega: jax.Array  # (M, 3) rad/s, body
    R_d: jax.Array  # (M, 3, 3) desired attitude
    Omega_d: jax.Array  # (M, 3) rad/s, desired frame
    Omega_e: jax.Array  # (M, 3) rad/s, body
    tau: jax.Array  # (M, 3) N m
    angle: jax.Array  # (M,) attitude error |log(R_e)^vee|, rad
    J: jax.Array  # (M, 3, 3) true inertia, kg m^2
    controller: Any  # controller state, leading axis M


class Result(NamedTuple):
    metrics: metrics.Metrics
    history: History
    final: State


def _has_closed_form(reference) -> bool:
    return reference.attitude(0.0, 0) is not None


def _phase(scenario: Scenario, k):
    """Index of the phase holding at step k (phase switches on step boundaries)."""
    return sum((k >= K).astype(jnp.int32) for K in scenario.phase_steps) if scenario.phase_steps else 0


def _desired(scenario: Scenario, t, phase, integrated_R_d) -> Desired:
    ref = scenario.reference
    R_d = integrated_R_d if isinstance(integrated_R_d, jax.Array) else ref.attitude(t, phase)
    return Desired(R_d, ref.rate(t, phase), ref.rate_dot(t, phase))


def _field(scenario: Scenario, controller: Controller, gains, phase, disturbance):
    """The closed-loop vector field of one step (phase and disturbance held)."""

    def field(t, rotations, vectors):
        R = rotations[0]
        Omega, controller_state = vectors
        desired = _desired(scenario, t, phase, rotations[1] if len(rotations) > 1 else None)
        tau, controller_dot = controller.torque(gains, controller_state, Measured(R, Omega), desired, t)
        J = scenario.inertia(t, phase)
        J_dot = inertia_rate(scenario.inertia, t, phase) if scenario.variable_inertia_term else None
        Omega_dot = angular_acceleration(J, Omega, tau + disturbance, J_dot)
        rates = (Omega,) if len(rotations) == 1 else (Omega, desired.Omega_d)
        return rates, (Omega_dot, controller_dot), (tau, desired)

    return field


def _sample(state: State, tau, desired: Desired) -> metrics.Sample:
    err = tracking_error(Measured(state.R, state.Omega), desired)
    angle = so3.safe_norm(so3.log(err.R_e))
    return metrics.Sample(err.Omega_e, state.Omega - desired.Omega_d, tau, angle)


def initial_state(scenario: Scenario, controller: Controller, gains) -> State:
    R_d = () if _has_closed_form(scenario.reference) else jnp.eye(3, dtype=scenario.R0.dtype)
    return State(scenario.R0, scenario.Omega0, controller.init(gains), R_d)


def step(scenario: Scenario, controller: Controller, gains, key, state: State, k):
    """Advance the closed loop over step k: returns (state, metrics sample at t_k)."""
    dtype = scenario.R0.dtype
    t = k.astype(dtype) * jnp.asarray(scenario.dt, dtype)
    phase = _phase(scenario, k)
    d = scenario.disturbance(key, k, t)
    field = _field(scenario, controller, gains, phase, d)
    integrated = isinstance(state.R_d, jax.Array)
    rotations = (state.R, state.R_d) if integrated else (state.R,)
    rotations, (Omega, ctrl), (tau, desired) = lie_rk4_step(
        field, t, jnp.asarray(scenario.dt, dtype), rotations, (state.Omega, state.controller)
    )
    new = State(rotations[0], Omega, ctrl, rotations[1] if integrated else ())
    return new, phase, _sample(state, tau, desired)


def observe(scenario: Scenario, controller: Controller, gains, state: State, k):
    """Time, torque, desired signals, metrics sample and J at step start k (no step taken)."""
    dtype = scenario.R0.dtype
    t = k.astype(dtype) * jnp.asarray(scenario.dt, dtype)
    phase = _phase(scenario, k)
    field = _field(scenario, controller, gains, phase, jnp.zeros(3, dtype))
    rotations = (state.R, state.R_d) if isinstance(state.R_d, jax.Array) else (state.R,)
    _, _, (tau, desired) = field(t, rotations, (state.Omega, state.controller))
    return t, tau, desired, _sample(state, tau, desired), scenario.inertia(t, phase)


def default_record_every(n_steps: int) -> int:
    """About sqrt(N): the reverse-mode memory optimum of two-level checkpointing."""
    n_blocks = max(1, math.isqrt(max(n_steps, 1)))
    return -(-n_steps // n_blocks)


def rollout(
    scenario: Scenario,
    controller: Controller,
    gains,
    seed,
    *,
    record_every: int | None = None,
    unroll: int = 1,
) -> Result:
    """Simulate the closed loop over scenario.n_steps steps (SPEC 1-6). Pure; no validation.

    record_every: steps per block (history sample and checkpoint), ~sqrt(N) by default.
    When it does not divide N, the last block's surplus steps are computed but masked.
    """
    n = scenario.n_steps
    block = min(record_every or default_record_every(n), n)
    n_blocks = -(-n // block)
    masked = n_blocks * block != n
    key = jax.random.key(seed)
    dtype = scenario.R0.dtype

    def one_step(carry, _):
        state, k, acc = carry
        new, phase, sample = step(scenario, controller, gains, key, state, k)
        finite = jnp.isfinite(jnp.sum(new.Omega) + jnp.sum(new.R))
        new_acc = metrics.update(acc, phase, sample, finite)
        if masked:
            live = k < n
            new, new_acc = jax.tree.map(lambda a, b: jnp.where(live, a, b), (new, new_acc), (state, acc))
        return (new, k + 1, new_acc), None

    @functools.partial(jax.checkpoint, prevent_cse=False)
    def run_block(carry):
        return jax.lax.scan(one_step, carry, None, length=block, unroll=min(unroll, block))[0]

    def outer(carry, _):
        return run_block(carry), (carry[0], carry[1])

    acc0 = metrics.init(len(scenario.phase_steps) + 1, dtype)
    carry = (initial_state(scenario, controller, gains), jnp.zeros((), jnp.int32), acc0)
    (final, _, acc), (states, ks) = jax.lax.scan(outer, carry, None, length=n_blocks)

    observe_all = jax.vmap(lambda s, k: observe(scenario, controller, gains, s, k))
    t, tau, desired, sample, J = observe_all(states, ks)
    history = History(
        t, states.R, states.Omega, desired.R_d, desired.Omega_d, sample.Omega_e, tau, sample.angle, J, states.controller
    )
    result_metrics = metrics.finalize(acc, scenario.steps_per_phase, scenario.dt, final.R)
    return Result(result_metrics, history, final)


@functools.partial(jax.jit, static_argnames=("controller", "record_every", "unroll"))
def _simulate_jit(scenario, controller, gains, seed, record_every, unroll):
    return rollout(scenario, controller, gains, seed, record_every=record_every, unroll=unroll)


def simulate(scenario: Scenario, controller: Controller, gains, seed=0, *, record_every=None, unroll=1) -> Result:
    """Validate the inputs (SPEC 6), then run the jitted rollout."""
    check_scenario(scenario)
    check_gains(gains)
    if record_every is not None and (int(record_every) != record_every or record_every < 1):
        raise ValueError(f"record_every must be a positive integer, got {record_every!r}")
    gains = jax.tree_util.tree_map(lambda g: jnp.asarray(g, scenario.R0.dtype), gains)
    return _simulate_jit(scenario, controller, gains, seed, record_every, unroll)
