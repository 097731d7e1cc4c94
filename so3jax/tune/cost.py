"""The SPEC 6 tuning cost of log-gains over a batch of scenarios, its gradient, and a
population's costs, with the batch split over a device mesh."""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from so3jax import devices
from so3jax.gradients import batch_metrics, value_and_grad
from so3jax.loop import PAPER_LOOP
from so3jax.tune.gains import to_gains


class CostRefs(NamedTuple):
    """Normalizers: RMSE_ref [rad/s]; Effort_ref or Effort_budget [N^2 m^2 s], a scalar or
    one per scenario; weight lambda or mu."""

    rmse: jax.Array
    effort: jax.Array
    weight: jax.Array


def scenario_costs(metrics, refs: CostRefs, mode: str):
    """SPEC 6 cost of each scenario (shape of metrics.rmse)."""
    ratio = metrics.effort / refs.effort
    if mode == "weighted":
        return metrics.rmse / refs.rmse + refs.weight * ratio
    return metrics.rmse / refs.rmse + refs.weight * jnp.maximum(ratio - 1.0, 0.0) ** 2


class Evaluation(NamedTuple):
    """Batch means of one evaluation."""

    cost: jax.Array
    rmse: jax.Array
    effort: jax.Array
    diverged: jax.Array  # number of diverged scenarios


def _summary(metrics, refs, mode) -> Evaluation:
    return Evaluation(
        jnp.mean(scenario_costs(metrics, refs, mode)),
        jnp.mean(metrics.rmse),
        jnp.mean(metrics.effort),
        jnp.sum(metrics.diverged.astype(jnp.int32)),
    )


def _metrics(scenario, controller, gains, batch, record_every, mesh, loop):
    """batch_metrics through ``loop``, the batch split over the devices of mesh (None: one
    device; :func:`so3jax.devices.split`)."""

    def run(scenario, gains, batch, loop):
        return batch_metrics(scenario, controller, gains, batch, record_every=record_every, loop=loop)

    return devices.split(run, mesh, batched=(False, False, True, False))(scenario, gains, batch, loop)


@functools.partial(jax.jit, static_argnames=("controller", "record_every", "mesh"))
def _batch_metrics(scenario, controller, gains, batch, record_every, mesh=None, loop=PAPER_LOOP):
    return _metrics(scenario, controller, gains, batch, record_every, mesh, loop)


@functools.partial(jax.jit, static_argnames=("controller", "mode", "gradient", "record_every", "mesh"))
def cost_and_grad(params, scenario, controller, batch, refs, mode, gradient, record_every, mesh=None, loop=PAPER_LOOP):
    """(Evaluation, d cost / d params) of log-gains params over the batch (split over mesh),
    flown through ``loop``."""

    def cost(p):
        summary = _summary(_metrics(scenario, controller, to_gains(p), batch, record_every, mesh, loop), refs, mode)
        return summary.cost, summary

    (_, summary), grad = value_and_grad(cost, gradient)(params)
    return summary, grad


@functools.partial(jax.jit, static_argnames=("controller", "mode", "record_every", "mesh"))
def population_costs(population, scenario, controller, batch, refs, mode, record_every, mesh=None, loop=PAPER_LOOP):
    """Evaluation of each member of a population of log-gains (leading axis P)."""

    def one(params):
        return _summary(_metrics(scenario, controller, to_gains(params), batch, record_every, mesh, loop), refs, mode)

    return jax.vmap(one)(population)
