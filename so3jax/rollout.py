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
from so3jax._fusion import materialize
from so3jax.controllers.base import Controller, Desired, Measured, tracking_error
from so3jax.integrate import lie_rk4_step
from so3jax.plant import angular_acceleration, inertia_rate
from so3jax.scenario import Scenario, check_gains, check_scenario


class State(NamedTuple):
    """Closed-loop state; batch axes, if any, last."""

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


def _broadcast(x, core_ndim, batch_shape):
    """x (core, [batch or unit axes]) -> (core, *batch)."""
    x = jnp.asarray(x)
    x = x.reshape(x.shape + (1,) * (core_ndim + len(batch_shape) - x.ndim))
    return jnp.broadcast_to(x, x.shape[:core_ndim] + tuple(batch_shape))


def _desired(scenario: Scenario, t, phase, integrated_R_d, like) -> Desired:
    """R_d, Omega_d, Omega_d' at t; a reference shared by a batch is computed once."""
    ref = scenario.reference
    R_d = integrated_R_d if isinstance(integrated_R_d, jax.Array) else so3.batch_like(ref.attitude(t, phase), 2, like)
    return Desired(R_d, so3.batch_like(ref.rate(t, phase), 1, like), so3.batch_like(ref.rate_dot(t, phase), 1, like))


def _field(scenario: Scenario, controller: Controller, gains, phase, disturbance):
    """The closed-loop vector field of one step (phase and disturbance held)."""

    def field(t, rotations, vectors):
        R = rotations[0]
        Omega, controller_state = vectors
        desired = _desired(scenario, t, phase, rotations[1] if len(rotations) > 1 else None, Omega)
        tau, controller_dot = controller.torque(gains, controller_state, Measured(R, Omega), desired, t)
        J = so3.batch_like(scenario.inertia(t, phase), 2, Omega)
        J_dot = (
            so3.batch_like(inertia_rate(scenario.inertia, t, phase), 2, Omega)
            if scenario.variable_inertia_term
            else None
        )
        # computed once (XLA:CPU would otherwise recompute the torque for each component of the solve)
        Omega_dot = angular_acceleration(J, Omega, materialize(tau + disturbance, t), J_dot)
        rates = (Omega,) if len(rotations) == 1 else (Omega, desired.Omega_d)
        return rates, (Omega_dot, controller_dot), (tau, desired)

    return field


def _sample(state: State, tau, desired: Desired) -> metrics.Sample:
    err = tracking_error(Measured(state.R, state.Omega), desired)
    angle = so3.angle(err.R_e)
    return metrics.Sample(err.Omega_e, state.Omega - desired.Omega_d, tau, angle)


def initial_state(scenario: Scenario, controller: Controller, gains, batch_shape=()) -> State:
    """The state at t = 0, every leaf broadcast to (core, *batch_shape)."""
    dtype = scenario.R0.dtype
    R_d = () if _has_closed_form(scenario.reference) else _broadcast(jnp.eye(3, dtype=dtype), 2, batch_shape)
    controller_state = jax.tree.map(lambda x: _broadcast(x, x.ndim, batch_shape), controller.init(gains))
    return State(
        _broadcast(scenario.R0, 2, batch_shape), _broadcast(scenario.Omega0, 1, batch_shape), controller_state, R_d
    )


def _time(scenario, k):
    dtype = scenario.R0.dtype
    return k.astype(dtype) * jnp.asarray(scenario.dt, dtype)


def disturbance_at(scenario: Scenario, key, k):
    """d_k (3, ...) [N m]."""
    return scenario.disturbance(key, k, _time(scenario, k))


def disturbances(scenario: Scenario, key, k0, count: int):
    """d_k for k = k0 .. k0 + count - 1 as its three axes, each (count, ...), drawn in one
    vectorized call (per axis where the disturbance offers ``components``: on CPU, one loop
    that interleaves the axes runs the noise draw ~2x slower)."""
    ks = k0 + jnp.arange(count, dtype=k0.dtype)
    draw = getattr(scenario.disturbance, "components", None) or (lambda *args: tuple(scenario.disturbance(*args)))
    return jax.vmap(lambda k: tuple(draw(key, k, _time(scenario, k))))(ks)


def step(scenario: Scenario, controller: Controller, gains, d, state: State, k):
    """Advance the closed loop over step k with disturbance d_k held.
    Returns (state, phase, metrics sample at t_k)."""
    dtype = scenario.R0.dtype
    t = _time(scenario, k)
    phase = _phase(scenario, k)
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
    field = _field(scenario, controller, gains, phase, jnp.zeros_like(state.Omega))
    rotations = (state.R, state.R_d) if isinstance(state.R_d, jax.Array) else (state.R,)
    _, _, (tau, desired) = field(t, rotations, (state.Omega, state.controller))
    batch = state.Omega.shape[1:]
    desired = Desired(*(_broadcast(x, x.ndim - len(batch), batch) for x in desired))
    J = _broadcast(so3.batch_like(scenario.inertia(t, phase), 2, state.Omega), 2, batch)
    return t, tau, desired, _sample(state, tau, desired), J


def _keys(seed):
    """PRNG key(s) for an int seed or an array of seeds (batch shape = seed's shape)."""
    seed = jnp.asarray(seed)
    if seed.ndim == 0:
        return jax.random.key(seed)
    return jax.vmap(jax.random.key)(seed.reshape(-1)).reshape(seed.shape)


_MAX_DRAWN_AHEAD = 1 << 22  # elements of disturbance drawn ahead per block (32 MiB in float64)


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

    One trajectory for an int seed. For an array of seeds of shape (B,), a natively
    batched rollout with the batch axis LAST everywhere (the so3 convention): every
    scenario/gains leaf then carries a trailing batch axis of size B or 1 (shared);
    see :func:`rollout_batch` for the batch-first interface.

    record_every: steps per block (history sample and checkpoint), ~sqrt(N) by default.
    When it does not divide N, the last block's surplus steps are computed but masked.
    """
    n = scenario.n_steps
    block = min(record_every or default_record_every(n), n)
    n_blocks = -(-n // block)
    masked = n_blocks * block != n
    key = _keys(seed)
    dtype = scenario.R0.dtype
    # The disturbance of a whole block is drawn in one vectorized call (the PRNG's
    # per-call overhead is then paid once per block), unless that array would be big.
    draw_ahead = 3 * block * math.prod(key.shape) <= _MAX_DRAWN_AHEAD

    def one_step(carry, d):
        state, k, acc = carry
        d = disturbance_at(scenario, key, k) if d is None else jnp.stack(d)  # None: not drawn ahead (too large)
        new, phase, sample = step(scenario, controller, gains, d, state, k)
        finite = jnp.isfinite(so3.sum_leading(new.R, 2) + so3.sum_leading(new.Omega))
        new_acc = metrics.update(acc, phase, sample, finite)
        if masked:
            live = k < n
            new, new_acc = jax.tree.map(lambda a, b: jnp.where(live, a, b), (new, new_acc), (state, acc))
        return (new, k + 1, new_acc), None

    @functools.partial(jax.checkpoint, prevent_cse=False)
    def run_block(carry):
        ds = disturbances(scenario, key, carry[1], block) if draw_ahead else None
        return jax.lax.scan(one_step, carry, ds, length=block, unroll=min(unroll, block))[0]

    def outer(carry, _):
        return run_block(carry), (carry[0], carry[1])

    acc0 = metrics.init(len(scenario.phase_steps) + 1, dtype, key.shape)
    carry = (initial_state(scenario, controller, gains, key.shape), jnp.zeros((), jnp.int32), acc0)
    (final, _, acc), (states, ks) = jax.lax.scan(outer, carry, None, length=n_blocks)

    observe_all = jax.vmap(lambda s, k: observe(scenario, controller, gains, s, k))
    t, tau, desired, sample, J = observe_all(states, ks)
    history = History(
        t, states.R, states.Omega, desired.R_d, desired.Omega_d, sample.Omega_e, tau, sample.angle, J, states.controller
    )
    result_metrics = metrics.finalize(acc, scenario.steps_per_phase, scenario.dt, final.R)
    return Result(result_metrics, history, final)


def _axes_tree(axes, tree):
    """Broadcast a vmap-style in_axes prefix (0 or None per subtree) to every leaf of tree."""
    return jax.tree.map(lambda ax, sub: jax.tree.map(lambda _: ax, sub), axes, tree, is_leaf=lambda x: x is None)


def _batch_last(tree, axes):
    """Batched leaves (batch axis 0) -> batch axis last; shared leaves get a unit axis."""
    return jax.tree.map(
        lambda x, ax: jnp.moveaxis(jnp.asarray(x), 0, -1) if ax == 0 else jnp.asarray(x)[..., None],
        tree,
        _axes_tree(axes, tree),
    )


def _batch_first(tree):
    return jax.tree.map(lambda x: jnp.moveaxis(x, -1, 0) if jnp.ndim(x) else x, tree)


# Trajectories per natively batched XLA:CPU loop. Larger batches are slower per
# trajectory there (the step's temporaries leave the L1/L2 caches): 2-core AMD EPYC,
# float64, M steps/s PD / adaptive at batch 64: 3.9 / 2.0, 128: 4.6 / 2.1, 256: 3.4 / 1.8,
# 1024: 2.7 / 1.6 (benchmarks/throughput.py). GPUs take the whole batch at once.
CPU_SUB_BATCH = 128


def rollout_batch(
    scenario: Scenario,
    controller: Controller,
    gains,
    seeds,
    *,
    scenario_axes=0,
    gains_axes=None,
    record_every: int | None = None,
    unroll: int = 1,
) -> Result:
    """``jax.vmap(rollout)`` over seeds (B,), computed natively batched (batch axis last
    inside): the same values up to round-off (~1e-16 relative). Which of the two is
    faster depends on the device and batch size: see benchmarks/throughput.py.

    scenario_axes / gains_axes: vmap-style in_axes prefixes, 0 (leading batch axis)
    or None (shared by the batch). A shared reference or inertia is evaluated once per
    stage for the whole batch. Outputs have the batch axis first, as vmap's would.
    On CPU, batches above ``CPU_SUB_BATCH`` run as consecutive sub-batches of that size.
    """
    args = (scenario, gains, jnp.asarray(seeds))
    axes = (_axes_tree(scenario_axes, scenario), _axes_tree(gains_axes, gains), 0)

    def run(args):
        scenario, gains, seeds = args
        result = rollout(
            _batch_last(scenario, scenario_axes),
            controller,
            _batch_last(gains, gains_axes),
            seeds,
            record_every=record_every,
            unroll=unroll,
        )
        metrics_, history, final = result
        history = jax.tree.map(
            lambda x: jnp.moveaxis(x, -1, 0) if x.ndim > 1 else jnp.broadcast_to(x, (seeds.shape[0],) + x.shape),
            history,
        )
        return Result(_batch_first(metrics_), history, _batch_first(final))

    if args[2].shape[0] <= CPU_SUB_BATCH:
        return run(args)
    sub_batched = lambda args: _in_sub_batches(run, args, axes, CPU_SUB_BATCH)
    return jax.lax.platform_dependent(args, cpu=sub_batched, default=run)


def _in_sub_batches(run, args, axes, size: int):
    """run(args) computed sub-batch by sub-batch (``lax.map``) of at most ``size``
    elements of the leaves whose axis is 0 (the last sub-batch padded by repeating the
    last element), concatenated back; leaves with axis None are shared."""
    n = args[2].shape[0]
    count = -(-n // size)
    index = jnp.minimum(jnp.arange(count * size), n - 1).reshape(count, size)
    leaves, treedef = jax.tree.flatten(args)
    leaf_axes = treedef.flatten_up_to(axes)
    take = lambda i: treedef.unflatten([x if ax is None else jnp.asarray(x)[i] for x, ax in zip(leaves, leaf_axes)])
    parts = jax.lax.map(lambda i: run(take(i)), index)
    return jax.tree.map(lambda x: x.reshape((count * size,) + x.shape[2:])[:n], parts)


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
