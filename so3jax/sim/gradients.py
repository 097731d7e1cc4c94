"""Differentiable batched rollouts and their gradients in forward or reverse mode.

A *batch* is a set of training scenarios: the base scenario with every inertia matrix
scaled by ``inertia_scale[i]``, driven by seed ``seed[i]`` (disturbance and sensor
noise), flown through one loop. Its metrics are a vmap of :func:`so3jax.sim.rollout` over
the batch, a pure function of the gains.

Two ways to differentiate a scalar function of the gains:

* ``"forward"``: ``jax.jacfwd``, one JVP per parameter, vmapped. Memory does not
  depend on the horizon (nothing is stored for a backward pass); time grows with the
  number of parameters (2 for the PD, 3 for the adaptive law with a scalar Gamma, 11
  with a diagonal one).
* ``"reverse"``: ``jax.value_and_grad``. Time does not depend on the number of
  parameters; memory is bounded by the rollout's two-level checkpointing (the state at
  each of the N / record_every block starts, plus the state at each step of the one block
  whose backward pass runs, each step recomputed from it): O(N / record_every +
  record_every), smallest at record_every = sqrt(N), the rollout's default. Through a
  sampled loop the block is one control period (:func:`checkpoint_steps`).

``benchmarks/gradients.py`` measures which is faster for which controller.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp

from so3jax.controllers import Controller
from so3jax.dynamics.scenario import Scenario
from so3jax.sim.loop import PAPER_LOOP, Loop
from so3jax.sim.metrics import Metrics
from so3jax.sim.rollout import rollout_batch

MODES = ("forward", "reverse")


def checkpoint_steps(loop: Loop, mode: str, record_every: int | None = None) -> int | None:
    """Steps per checkpointed block of a rollout differentiated in ``mode``: record_every
    where given; in reverse mode through a sampled loop, one control period, so that the
    backward pass nests one loop (the period's RK4 steps) in the loop over ticks, not two
    (XLA:CPU compiles it several times sooner, and it runs faster: benchmarks/gradients.md;
    memory: one loop state per tick); else None, the rollout's ~sqrt(N)."""
    if record_every is not None or mode != "reverse" or loop.continuous:
        return record_every
    return loop.period_steps


class Batch(NamedTuple):
    """B training scenarios: inertia scale factors (B,) [-] and disturbance seeds (B,)."""

    inertia_scale: jax.Array
    seed: jax.Array


def make_batch(inertia_scales, seeds, dtype) -> Batch:
    """The Cartesian product inertia_scales x seeds, flattened (scale-major)."""
    scales = jnp.repeat(jnp.asarray(inertia_scales, dtype), len(seeds))
    seeds = jnp.tile(jnp.asarray(seeds, jnp.int32), len(inertia_scales))
    return Batch(scales, seeds)


def scale_inertia(scenario: Scenario, scale) -> Scenario:
    """The scenario with every matrix (or stack of matrices) of its inertia profile multiplied
    by ``scale`` (a scalar, or (B,) for a batch: each gets a leading batch axis)."""
    inertia = scenario.inertia
    scale = jnp.asarray(scale)
    scaled = dataclasses.replace(inertia, **{name: scale.reshape(scale.shape + (1,) * jnp.ndim(J)) * J
                                             for name, J in inertia.matrices().items()})
    return dataclasses.replace(scenario, inertia=scaled)


def batch_metrics(
    scenario: Scenario, controller: Controller, gains, batch: Batch, *, record_every=None, loop: Loop = PAPER_LOOP
) -> Metrics:
    """Metrics of every scenario of the batch (leading axis B). Pure and differentiable.

    ``rollout_batch`` computes the vmap of :func:`so3jax.sim.rollout` over the batch with the
    reference, the time-only parts of the inertia and the loop (sensors, estimator,
    actuator, control period; default the paper's) shared by the batch.
    """
    shared = jax.tree.map(lambda _: None, scenario)
    axes = dataclasses.replace(
        shared, inertia=dataclasses.replace(shared.inertia, **dict.fromkeys(scenario.inertia.matrices(), 0))
    )
    scaled = scale_inertia(scenario, batch.inertia_scale)
    return rollout_batch(
        scaled, controller, gains, batch.seed, scenario_axes=axes, loop=loop, record_every=record_every
    ).metrics


def value_and_grad(fun: Callable, mode: str) -> Callable:
    """``fun(params) -> (scalar, aux)`` to ``params -> ((scalar, aux), d scalar / d params)``.

    The same contract as ``jax.value_and_grad(fun, has_aux=True)``, in either mode; the
    primal (and aux) is computed once in both.
    """
    if mode == "reverse":
        return jax.value_and_grad(fun, has_aux=True)
    if mode != "forward":
        raise ValueError(f"gradient mode must be one of {MODES}, got {mode!r}")

    def value_as_aux(params):
        value, aux = fun(params)
        return value, (value, aux)

    jacobian = jax.jacfwd(value_as_aux, has_aux=True)

    def forward(params):
        grad, (value, aux) = jacobian(params)
        return (value, aux), grad

    return forward
