"""The closed-loop rollout: a ``lax.scan`` of SO(3) RK4 steps with metrics in the carry.

``rollout(scenario, controller, gains, seed)`` is a pure function: jit, vmap (over
scenarios, gains, seeds) and grad compose with it. ``simulate`` is the jitted,
validated entry point.

The scan is nested: an outer scan over blocks of ``record_every`` steps records the
state at each block start (the histories), and each block is ``jax.checkpoint``-ed, so
reverse-mode memory grows like N / record_every + record_every rather than N. Each step
inside a block is checkpointed as well (the backward pass stores one loop state per step,
not the RK4 stages' intermediates), and in the sampled wiring a block keeps its noise
draws (:data:`so3jax.dynamics.disturbance.NOISE`) instead of drawing them again. The
initial carry is seeded with the tangents its derivative reaches
(:func:`so3jax.core.tangents.seed`): a derivative is traced in one pass per scan.
"""

from __future__ import annotations

import functools
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.components import actuators
from so3jax.controllers.base import Controller, Feedback, tracking_error
from so3jax.controllers.gains import check_gains
from so3jax.core import so3, tangents
from so3jax.core.so3 import broadcast
from so3jax.dynamics import stepped
from so3jax.dynamics.disturbance import NOISE
from so3jax.dynamics.scenario import Scenario, check_scenario
from so3jax.sim import flight_metrics, metrics
from so3jax.sim.loop import (
    PAPER_LOOP,
    Loop,
    State,
    check_loop,
    inertia,
    initial_state,
    manage,
    observe,
    phase,
    step,
    tick,
    time,
)


class History(NamedTuple):
    """Samples of the true state and what the loop computed from it, at the start of every
    block of ``record_every`` steps (in the sampled wiring, the control tick there), each
    with a leading axis M. One record for both wirings: a field a wiring does not have is
    None (the estimate's fields in the continuous wiring, whose law reads the true state;
    ``actuator`` for an actuator without state; ``covariance`` without a filter)."""

    t: jax.Array  # (M,) s
    R: jax.Array  # (M, 3, 3) true attitude, body -> inertial
    Omega: jax.Array  # (M, 3) rad/s, true body rate
    R_d: jax.Array  # (M, 3, 3) desired attitude
    Omega_d: jax.Array  # (M, 3) rad/s, desired frame
    Omega_e: jax.Array  # (M, 3) rad/s, true tracking error (body)
    tau: jax.Array  # (M, 3) N m, the control torque delivered (the actuator's `delivered`)
    angle: jax.Array  # (M,) attitude error |log(R_e)^vee|, rad
    J: jax.Array  # (M, 3, 3) true inertia, kg m^2
    controller: Any  # controller state, leading axis M
    tau_cmd: Any = None  # (M, 3) N m, the controller's command
    actuator: Any = None  # the actuator's state (wheels: speeds (M, N) rad/s), or None
    momentum: Any = None  # (M, 3) N m s, the momentum the actuator stores, body frame (zeros without)
    R_hat: Any = None  # (M, 3, 3) estimate (sampled wiring), or None
    Omega_hat: Any = None  # (M, 3) rad/s (sampled wiring), or None
    bias: Any = None  # (M, 3) true gyro bias, rad/s (sampled wiring), or None
    bias_hat: Any = None  # (M, 3) rad/s (sampled wiring), or None
    std: Any = None  # (M, 6) the estimator's 1-sigma (attitude rad, bias rad/s) (sampled wiring), or None
    covariance: Any = None  # (M, 6, 6) the filter's P after the update (a filter in the sampled wiring), or None
    disturbance: Any = None  # (M, 3) N m, the disturbance torque d_k of the recorded step
    managed: Any = None  # the momentum manager's held input (magnetorquers: dipole (M, 3) A m^2), or None
    flexible: Any = None  # the flexible body's Modal (theta, theta_dot (M, N), rho, rho_dot (M, N_slosh)), or None


class Result(NamedTuple):
    metrics: metrics.Metrics
    history: History
    final: State
    flight: Any = None  # flight_metrics.FlightMetrics of the sampled wiring, else None


def _time(scenario, k):
    return time(scenario, k)


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


def _keys(seed):
    """PRNG key(s) for an int seed or an array of seeds (batch shape = seed's shape)."""
    seed = jnp.asarray(seed)
    if seed.ndim == 0:
        return jax.random.key(seed)
    return jax.vmap(jax.random.key)(seed.reshape(-1)).reshape(seed.shape)


# A sampled wiring's block keeps its noise draws for the backward pass (its recomputation
# then draws nothing): a tick's draws and its period's disturbance, ~40 numbers per
# trajectory and tick, about as much as the block's starting state.
_SAVE_NOISE = jax.checkpoint_policies.save_only_these_names(NOISE)
_MAX_DRAWN_AHEAD = 1 << 22  # elements of disturbance drawn ahead per block (32 MiB in float64)


def default_record_every(n_steps: int) -> int:
    """About sqrt(N): the reverse-mode memory optimum of two-level checkpointing."""
    n_blocks = max(1, math.isqrt(max(n_steps, 1)))
    return -(-n_steps // n_blocks)


def block_steps(n_steps: int, record_every: int | None, period_steps: int | None) -> int:
    """Steps per block: record_every (~sqrt(N) by default), at most N, and a whole
    number of control periods in the sampled wiring."""
    block = min(record_every or default_record_every(n_steps), n_steps)
    m = period_steps or 1
    return -(-block // m) * m


def check_inputs(
    scenario, controller, gains, loop, record_every, *, seed=0, batch_last=False, gains_batch_axes=0
) -> None:
    """The checks of docs/model.md §6 on a rollout's inputs, before tracing: types and shapes always,
    values where concrete (so jit, vmap and grad of a rollout keep working).
    batch_last: the scenario's leaves carry a trailing batch axis (inside :func:`rollout_batch`)."""
    seed_dtype = seed.dtype if hasattr(seed, "dtype") else np.asarray(seed).dtype
    if isinstance(seed, bool) or seed_dtype.kind not in "iu":
        raise TypeError(f"seed must be an integer or an array of integers, got {seed!r}")
    if not isinstance(controller, Controller):
        raise TypeError("controller must be a so3jax Controller (e.g. so3jax.geometric_pd()), "
                        f"got {type(controller).__name__}")
    expected = getattr(controller, "gains_type", None)
    if expected is not None and not isinstance(gains, expected):
        raise TypeError(
            f"gains must be {expected.__name__}({', '.join(expected._fields)}) for this controller, "
            f"got {type(gains).__name__}{'(' + ', '.join(gains._fields) + ')' if hasattr(gains, '_fields') else ''}"
        )
    if not isinstance(loop, Loop):
        raise TypeError(f"loop must be a so3jax Loop, got {type(loop).__name__}")
    if record_every is not None and (
        isinstance(record_every, bool) or not isinstance(record_every, (int, np.integer)) or record_every < 1
    ):
        raise ValueError(f"record_every must be a positive integer, got {record_every!r}")
    check_scenario(scenario, batch_last=batch_last)
    check_gains(gains, batch_axes=gains_batch_axes + controller.gain_axes)
    matrices = scenario.inertia.matrices() if hasattr(scenario.inertia, "matrices") else {}
    if batch_last:
        matrices = {k: jnp.moveaxis(J, -1, 0) if jnp.ndim(J) > 2 else J for k, J in matrices.items()}
    check_loop(loop, matrices)


def rollout(
    scenario: Scenario,
    controller: Controller,
    gains,
    seed,
    *,
    loop: Loop = PAPER_LOOP,
    record_every: int | None = None,
    unroll: int = 1,
) -> Result:
    """Simulate the closed loop over scenario.n_steps steps (docs/model.md §1-§6; §8 for a
    sampled ``loop``). Pure; its inputs are checked first (:func:`check_inputs`: values
    only where concrete, so it composes with jit, vmap and grad).

    One trajectory for an integer seed. For seeds of shape (B,), the batch that shares the
    scenario, the gains and the loop, with the batch axis FIRST in every output (the one
    batch convention of the public API, as :func:`rollout_batch` and ``jax.vmap`` give).

    record_every: steps per block (history sample and checkpoint), ~sqrt(N) by default
    (rounded up to whole control periods). When blocks overrun N, the surplus steps are
    computed but masked.
    """
    if jnp.ndim(seed) > 0:
        return rollout_batch(scenario, controller, gains, seed, scenario_axes=None, loop=loop,
                             record_every=record_every, unroll=unroll)
    check_inputs(scenario, controller, gains, loop, record_every, seed=seed)
    return _rollout(scenario, controller, gains, seed, loop=loop, record_every=record_every, unroll=unroll)


def _rollout(scenario, controller, gains, seed, *, loop=PAPER_LOOP, record_every=None, unroll=1) -> Result:
    """:func:`rollout` without the checks."""
    n = scenario.n_steps
    block = block_steps(n, record_every, loop.period_steps)
    n_blocks = -(-n // block)
    masked = n_blocks * block != n
    key = _keys(seed)
    dtype = scenario.R0.dtype
    # The disturbance of a whole block is drawn in one vectorized call (the PRNG's
    # per-call overhead is then paid once per block), unless that array would be big.
    draw_ahead = 3 * block * math.prod(key.shape) <= _MAX_DRAWN_AHEAD

    m = loop.period_steps
    ticks = None if loop.continuous else block // m

    def blocks(scenario, gains, key, loop):
        """The outer scan's body, one block of steps, of these inputs (also what
        :func:`so3jax.core.tangents.seed` reads: explicit, not closed over)."""

        def advance(state, k, acc, d, take_step):
            d = disturbance_at(scenario, key, k) if d is None else jnp.stack(d)  # None: not drawn ahead (too large)
            new, phase, sample = take_step(d, state, k)
            finite = jnp.isfinite(so3.sum_leading(new.R, 2) + so3.sum_leading(new.Omega))
            new_acc = metrics.update(acc, phase, sample, finite)
            if masked:
                live = k < n
                new, new_acc = jax.tree.map(lambda a, b: jnp.where(live, a, b), (new, new_acc), (state, acc))
            return new, k + 1, new_acc

        def draw(k0):
            return disturbances(scenario, key, k0, block) if draw_ahead else None

        constants = stepped.constants(scenario) if key.ndim else None  # per-trajectory scenarios of a native batch
        take_step = lambda d, state, k: step(scenario, controller, gains, d, state, k, loop, constants, key)

        # Each step is checkpointed inside its block: a backward pass stores the loop state at
        # each step of a block and recomputes the step, rather than storing the RK4 stages'
        # intermediates (a much smaller program to compile; no effect without differentiation).
        @functools.partial(jax.checkpoint, prevent_cse=False)
        def one_step(carry, d):
            return advance(*carry, d, take_step), None

        if loop.continuous:

            @functools.partial(jax.checkpoint, prevent_cse=False)
            def run_block(carry):
                return jax.lax.scan(one_step, carry, draw(carry[1]), length=block, unroll=min(unroll, block))[0]

            return run_block

        def one_tick(carry, ds):
            state, k, acc, flight = carry
            new, out = tick(scenario, loop, controller, gains, key, state, k // m)
            sample = _tick_sample(loop, state, new, out, time(scenario, k))
            record = _flight_record(scenario, loop, state, out, k, key)._replace(managed=_or_none(new.managed))
            share = None if not masked else jnp.clip((n - k) / m, 0, 1)  # of a last period that overruns N
            flight = flight_metrics.update(flight, sample, k < n, share)
            if masked:
                new = jax.tree.map(lambda a, b: jnp.where(k < n, a, b), new, state)
            new, k, acc = jax.lax.scan(one_step, (new, k, acc), ds, length=m, unroll=min(unroll, m))[0]
            return (new, k, acc, flight), record

        @functools.partial(jax.checkpoint, prevent_cse=False, policy=_SAVE_NOISE)
        def run_block(carry):
            ds = draw(carry[1])
            ds = None if ds is None else tuple(x.reshape((ticks, m) + x.shape[1:]) for x in ds)
            if ticks == 1:  # one period per block (reverse mode): no loop over the block's ticks
                return one_tick(carry, None if ds is None else tuple(x[0] for x in ds))
            carry, records = jax.lax.scan(one_tick, carry, ds, length=ticks)
            return carry, jax.tree.map(lambda x: x[0], records)

        return run_block

    inputs = (scenario, gains, key, loop)
    run_block = blocks(*inputs)
    one_pass = (lambda c, x: blocks(*x)(c)) if loop.continuous else (lambda c, x: blocks(*x)(c)[0])

    def from_start(carry):
        """The initial carry batched wherever an input is, and given the tangents its derivative
        reaches (so3jax.core.tangents): the scans' derivative and batching traced in one pass."""
        return tangents.seed(one_pass, _batched_from_start(carry, inputs), inputs)

    if loop.continuous:

        def record(carry):
            state, k = carry[0], carry[1]
            seen = observe(scenario, controller, gains, state, k, loop)
            return History(seen.t, state.R, state.Omega, seen.desired.R_d, seen.desired.Omega_d, seen.sample.Omega_e,
                           seen.tau, seen.sample.angle, seen.J, state.controller, seen.tau_cmd,
                           _or_none(state.actuator),
                           actuators.momentum(loop.actuator, state.actuator, state.Omega),
                           disturbance=disturbance_at(scenario, key, k),
                           managed=None if loop.momentum is None else manage(scenario, loop, state, seen.t, key, k)[1],
                           flexible=_or_none(state.flexible))

        carry = (initial_state(scenario, controller, gains, key.shape, loop), jnp.zeros((), jnp.int32),
                 metrics.init(len(scenario.phase_steps) + 1, dtype, key.shape))
        carry = from_start(carry)
        # The block-start states are emitted by the scan, their torque and desired signals
        # derived after it: derived inside, they change XLA:CPU's fusion of the step, and
        # with it the last bits of the paper's results.
        (final, _, acc), starts = jax.lax.scan(lambda c, _: (run_block(c), c), carry, None, length=n_blocks)
        history = jax.vmap(record)(starts)
        return Result(metrics.finalize(acc, scenario.steps_per_phase, scenario.dt, final.R), history, final)

    carry = (initial_state(scenario, controller, gains, key.shape, loop), jnp.zeros((), jnp.int32),
             metrics.init(len(scenario.phase_steps) + 1, dtype, key.shape), flight_metrics.init(dtype, key.shape))
    carry = from_start(carry)
    (final, _, acc, flight), history = jax.lax.scan(lambda c, _: run_block(c), carry, None, length=n_blocks)
    return Result(
        metrics.finalize(acc, scenario.steps_per_phase, scenario.dt, final.R),
        history,
        final,
        flight_metrics.finalize(flight, jnp.asarray(m * scenario.dt, dtype)),
    )


def _batched_from_start(carry, inputs):
    """The rollout's initial carry, unchanged, its leaves (the step counter's aside) made to
    depend on every array of ``inputs`` by select(p, x, x), which XLA folds to x: under
    jax.vmap, each is then batched from the start wherever an input is, and the scans' batching
    rule finds the carry's batch axes in one pass over the step's equations instead of a pass per
    promotion and level of nesting (the flight loop's vmapped trace: 4 passes to 1)."""
    arrays = [jax.random.key_data(x) if jnp.issubdtype(x.dtype, jax.dtypes.prng_key) else x
              for x in jax.tree.leaves(inputs) if isinstance(x, jax.Array) and x.size]
    if not arrays:
        return carry
    p = jnp.any(jnp.concatenate([jnp.ravel(x)[:1].astype(bool) for x in arrays]))
    same = lambda tree: jax.tree.map(lambda x: jnp.where(p, x, x), tree)
    return (same(carry[0]), carry[1], *same(carry[2:]))


def _tick_sample(loop: Loop, before: State, after: State, out, t) -> flight_metrics.TickSample:
    """A tick's contribution to the flight metrics at t_j [s]: estimation errors against the
    truth, limits (with faults, each wheel's degraded limit, a wheel off never binding)."""
    est = out.estimate
    actuator = loop.actuator if loop.faults is None else loop.faults.judged(loop.actuator, t)
    at_torque, at_speed = actuator.limits(before.actuator, after.held, out.tau_cmd)
    return flight_metrics.TickSample(
        so3.angle(so3.rmatmul(est.R_hat, before.R)),
        est.bias_hat - out.bias,
        out.tau_cmd,
        loop.actuator.effort(after.held),
        at_torque,
        at_speed,
        loop.actuator.speed_ratio(before.actuator),
    )


def _flight_record(scenario: Scenario, loop: Loop, state: State, out, k, key) -> History:
    """The sampled wiring's history sample at tick step k (state: before the tick)."""
    err = tracking_error(Feedback(state.R, state.Omega), out.desired)
    est = out.estimate
    batch = state.Omega.shape[1:]
    R_d, Omega_d = (broadcast(x, n, batch) for x, n in ((out.desired.R_d, 2), (out.desired.Omega_d, 1)))
    J = broadcast(so3.batch_like(inertia(scenario, out.t, phase(scenario, k)), 2, state.Omega), 2, batch)
    return History(
        out.t, state.R, state.Omega, R_d, Omega_d, err.Omega_e, out.tau_applied, so3.angle(err.R_e), J,
        state.controller, out.tau_cmd, _or_none(state.actuator),
        actuators.momentum(loop.actuator, state.actuator, state.Omega), est.R_hat, est.Omega_hat, out.bias,
        est.bias_hat, est.std, _or_none(est.covariance), disturbance_at(scenario, key, k),
        flexible=_or_none(state.flexible),
    )


def _or_none(x):
    """None for an absent record (an empty tuple: a component without that state)."""
    return None if isinstance(x, tuple) and not x else x


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
    loop: Loop = PAPER_LOOP,
    loop_axes=None,
    record_every: int | None = None,
    unroll: int = 1,
) -> Result:
    """``jax.vmap(rollout)`` over seeds (B,), computed natively batched (batch axis last
    inside): the same values up to round-off (~1e-16 relative). Which of the two is
    faster depends on the device and batch size: see benchmarks/throughput.py.

    scenario_axes / gains_axes / loop_axes: vmap-style in_axes prefixes, 0 (leading batch
    axis) or None (shared by the batch). The components broadcast their parameters
    themselves: a shared one has no batch axis, a per-trajectory one its batch axis last
    (a loop built per trajectory: ``jax.vmap`` of a function returning a Loop, loop_axes=0).
    A shared reference or inertia is evaluated once per
    stage for the whole batch. Outputs have the batch axis first, as vmap's would.
    On CPU, batches above ``CPU_SUB_BATCH`` run as consecutive sub-batches of that size.
    """
    seeds = jnp.asarray(seeds)
    if seeds.ndim != 1 or not jnp.issubdtype(seeds.dtype, jnp.integer):
        raise ValueError(f"seeds must be a (B,) array of integers, got shape {seeds.shape} and dtype {seeds.dtype}")
    args = (scenario, gains, seeds, loop)
    for arg, tree, axes_prefix in (("scenario", scenario, scenario_axes), ("gains", gains, gains_axes),
                                   ("loop", loop, loop_axes)):
        try:
            leaf_axes = _axes_tree(axes_prefix, tree)
        except ValueError as err:
            raise ValueError(f"{arg}_axes must be 0, None or a prefix of {arg}'s tree "
                             f"(0 or None per subtree): {err}") from None
        paths, treedef = jax.tree_util.tree_flatten_with_path(tree)
        for (path, leaf), ax in zip(paths, treedef.flatten_up_to(leaf_axes)):  # a None field: no leaf, no axis
            if ax == 0 and (jnp.ndim(leaf) == 0 or jnp.shape(leaf)[0] != seeds.shape[0]):
                raise ValueError(
                    f"{arg}{jax.tree_util.keystr(path)} must have a leading batch axis of size {seeds.shape[0]} "
                    f"(that of seeds), got shape {jnp.shape(leaf)}"
                )
    per_loop = _axes_tree(loop_axes, loop)
    first = jax.tree.map(lambda x, ax: x if ax is None else x[0], loop, per_loop)  # one trajectory's, for the checks
    check_inputs(_batch_last(scenario, scenario_axes), controller, gains, first, record_every, batch_last=True,
                 gains_batch_axes=1 if gains_axes == 0 else 0)
    axes = (_axes_tree(scenario_axes, scenario), _axes_tree(gains_axes, gains), 0, per_loop)

    def run(args):
        scenario, gains, seeds, loop = args
        result = _rollout(
            _batch_last(scenario, scenario_axes),
            controller,
            _batch_last(gains, gains_axes),
            seeds,
            loop=jax.tree.map(lambda x, ax: x if ax is None else jnp.moveaxis(x, 0, -1), loop, per_loop),
            record_every=record_every,
            unroll=unroll,
        )
        history = jax.tree.map(
            lambda x: jnp.moveaxis(x, -1, 0) if x.ndim > 1 else jnp.broadcast_to(x, (seeds.shape[0],) + x.shape),
            result.history,
        )
        return Result(_batch_first(result.metrics), history, _batch_first(result.final), _batch_first(result.flight))

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
def _simulate_jit(scenario, controller, gains, seed, loop, record_every, unroll):
    return _rollout(scenario, controller, gains, seed, loop=loop, record_every=record_every, unroll=unroll)


@functools.partial(jax.jit, static_argnames=("controller", "record_every", "unroll"))
def _simulate_batch_jit(scenario, controller, gains, seeds, loop, record_every, unroll):
    return rollout_batch(scenario, controller, gains, seeds, scenario_axes=None, loop=loop, record_every=record_every,
                         unroll=unroll)


def _simulate_program(scenario, controller, gains, seed, loop, record_every, unroll):
    """(the jitted program :func:`simulate` runs, its arguments): gains and loop in the
    scenario's dtype; one trajectory for an integer seed, a batch for seeds (B,)."""
    as_dtype = lambda tree: jax.tree_util.tree_map(lambda g: jnp.asarray(g, scenario.R0.dtype), tree)
    if jnp.ndim(seed) > 0:
        return _simulate_batch_jit, (scenario, controller, as_dtype(gains), jnp.asarray(seed), as_dtype(loop),
                                     record_every, unroll)
    return _simulate_jit, (scenario, controller, as_dtype(gains), seed, as_dtype(loop), record_every, unroll)


def simulate(
    scenario: Scenario, controller: Controller, gains, seed=0, *, loop: Loop = PAPER_LOOP, record_every=None, unroll=1
) -> Result:
    """Validate the inputs (docs/model.md §6, :func:`check_inputs`), then run the jitted
    rollout: one trajectory for an integer seed, a batch (batch axis first) for seeds (B,)."""
    check_inputs(scenario, controller, gains, loop, record_every, seed=seed)
    program, args = _simulate_program(scenario, controller, gains, seed, loop, record_every, unroll)
    return program(*args)


def simulate_shapes(
    scenario: Scenario, controller: Controller, gains, seed=0, *, loop: Loop = PAPER_LOOP, record_every=None, unroll=1
) -> Result:
    """:func:`simulate`'s outputs as ``jax.ShapeDtypeStruct`` leaves, from tracing alone: the
    trace of the program simulate runs, which simulate then reuses (nothing is traced twice)."""
    program, args = _simulate_program(scenario, controller, gains, seed, loop, record_every, unroll)
    return jax.eval_shape(program, *args)
