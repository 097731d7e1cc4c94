"""The tuning cost of docs/model.md §6 over a batch of scenarios (its mean, or its CVaR, §16.4),
its gradient, and a population's costs, with the batch split over a device mesh."""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from so3jax.jobs.tune.gains import parts, to_gains
from so3jax.missions import batched
from so3jax.parallel import devices
from so3jax.sim.gradients import batch_metrics, value_and_grad
from so3jax.sim.loop import PAPER_LOOP
from so3jax.sim.metrics import Metrics


class CostRefs(NamedTuple):
    """Normalizers: RMSE_ref [rad/s]; Effort_ref or Effort_budget [N^2 m^2 s], a scalar or
    one per scenario; weight lambda or mu."""

    rmse: jax.Array
    effort: jax.Array
    weight: jax.Array


def scenario_costs(metrics, refs: CostRefs, mode: str):
    """The docs/model.md §6 cost of each scenario (shape of metrics.rmse)."""
    ratio = metrics.effort / refs.effort
    if mode == "weighted":
        return metrics.rmse / refs.rmse + refs.weight * ratio
    return metrics.rmse / refs.rmse + refs.weight * jnp.maximum(ratio - 1.0, 0.0) ** 2


def batch_mean(x, valid=None):
    """The mean over the batch's scenarios (those ``valid``, a (B,) mask, where given)."""
    if valid is None:
        return jnp.mean(x)
    w = valid.astype(x.dtype)
    return jnp.sum(w * x) / jnp.sum(w)


def cvar(costs, alpha, valid=None):
    """CVaR_alpha of the batch's costs, the mean of its worst (1 - alpha) share, in the
    Rockafellar-Uryasev form t + E[(c - t)+] / (1 - alpha) at its minimizer t = VaR_alpha,
    the ceil(alpha B)-th smallest of B costs. Its derivative is that of the piecewise
    linear function itself: the tail costs' gradients over (1 - alpha) B, plus the VaR
    cost's with the weight the tail leaves it (zero where (1 - alpha) B is whole).
    ``valid``: a (B,) mask of the scenarios that count."""
    w = jnp.ones_like(costs) if valid is None else valid.astype(costs.dtype)
    n = jnp.sum(w)
    ranked = jnp.sort(jnp.where(w > 0, costs, jnp.inf))
    k = jnp.clip(jnp.ceil(alpha * n).astype(jnp.int32) - 1, 0, costs.shape[0] - 1)
    t = ranked[k]
    tail = (w > 0) & (costs > t)
    return t + jnp.sum(jnp.where(tail, costs - t, 0.0)) / ((1.0 - alpha) * n)


class Evaluation(NamedTuple):
    """One evaluation of a batch: the objective over its scenario costs (their mean or
    CVaR), the means of RMSE and effort, the number of diverged scenarios."""

    cost: jax.Array
    rmse: jax.Array
    effort: jax.Array
    diverged: jax.Array  # number of diverged scenarios


def cost_summary(metrics, refs, mode, objective="mean", alpha=0.9, valid=None) -> Evaluation:
    costs = scenario_costs(metrics, refs, mode)
    return Evaluation(
        batch_mean(costs, valid) if objective == "mean" else cvar(costs, alpha, valid),
        batch_mean(metrics.rmse, valid),
        batch_mean(metrics.effort, valid),
        jnp.sum(metrics.diverged.astype(jnp.int32) * (1 if valid is None else valid.astype(jnp.int32))),
    )


def _metrics(scenario, controller, gains, batch, record_every, mesh, loop, mission=None):
    """Per-scenario metrics, the batch split over the devices of mesh (None: one device;
    :func:`so3jax.parallel.devices.split`): batch_metrics through ``loop``, or with ``mission`` (a
    :class:`~so3jax.missions.mission.Mission`) the dispersed missions of a DispersedBatch.
    ``gains``: the law's, or tuned parameters with the estimator's and the structural
    filter's (:func:`with_estimator`), which then replace the loop's estimator and filter
    parameters."""
    if mission is not None:
        def missions(gains, batch):
            gains, tuned = parts(gains)
            m = batched.sample_metrics((batch.params, batch.leaves), gains, controller=controller, mission=mission,
                                       record_every=record_every, estimator=tuned["estimator"],
                                       filter=tuned["filter"])
            return Metrics(**{k: m[k] for k in Metrics._fields})

        return devices.split(missions, mesh, batched=(False, True))(gains, batch)

    def run(scenario, gains, batch, loop):
        gains, tuned = parts(gains)
        if tuned["estimator"]:
            loop = dataclasses.replace(loop, estimator=dataclasses.replace(loop.estimator, **tuned["estimator"]))
        if tuned["filter"]:
            loop = dataclasses.replace(loop, filter=dataclasses.replace(loop.filter, **tuned["filter"]))
        return batch_metrics(scenario, controller, gains, batch, record_every=record_every, loop=loop)

    return devices.split(run, mesh, batched=(False, False, True, False))(scenario, gains, batch, loop)


@functools.partial(jax.jit, static_argnames=("controller", "record_every", "mesh", "mission"))
def batch_cost_metrics(scenario, controller, gains, batch, record_every, mesh=None, loop=PAPER_LOOP, mission=None):
    return _metrics(scenario, controller, gains, batch, record_every, mesh, loop, mission)


@functools.partial(jax.jit, static_argnames=("controller", "mode", "gradient", "record_every", "mesh", "objective",
                                             "alpha", "mission"))
def cost_and_grad(params, scenario, controller, batch, refs, mode, gradient, record_every, mesh=None, loop=PAPER_LOOP,
                  objective="mean", alpha=0.9, mission=None):
    """(Evaluation, d objective / d params) of log-gains params over the batch (split over
    mesh), flown through ``loop`` (or the dispersed missions of ``mission``, see _metrics);
    the objective is the mean or the CVaR_alpha of the scenario costs."""

    def cost(p):
        metrics = _metrics(scenario, controller, to_gains(p), batch, record_every, mesh, loop, mission)
        summary = cost_summary(metrics, refs, mode, objective, alpha, getattr(batch, "valid", None))
        return summary.cost, summary

    (_, summary), grad = value_and_grad(cost, gradient)(params)
    return summary, grad


@functools.partial(jax.jit, static_argnames=("controller", "mode", "record_every", "mesh", "objective", "alpha"))
def population_costs(population, scenario, controller, batch, refs, mode, record_every, mesh=None, loop=PAPER_LOOP,
                     objective="mean", alpha=0.9):
    """Evaluation of each member of a population of log-gains (leading axis P)."""

    def one(params):
        metrics = _metrics(scenario, controller, to_gains(params), batch, record_every, mesh, loop)
        return cost_summary(metrics, refs, mode, objective, alpha)

    return jax.vmap(one)(population)
