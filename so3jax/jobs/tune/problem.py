"""What a campaign evaluates: the mission's scenario and loop, the training and validation
batches placed on the devices (how many, by the batch size), fixed-gain evaluations and
the cost's normalizers."""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh

from so3jax.dynamics.scenario import Scenario
from so3jax.jobs.tune.config import TuneConfig
from so3jax.jobs.tune.cost import CostRefs, batch_cost_metrics, batch_mean
from so3jax.jobs.tune.gains import resolve_gains
from so3jax.missions import batched, draw
from so3jax.parallel import devices
from so3jax.parallel.devices import place
from so3jax.sim.gradients import Batch, checkpoint_steps, make_batch
from so3jax.sim.loop import Loop


class DispersedBatch(NamedTuple):
    """B dispersed missions (:mod:`so3jax.missions.draw`): their parameters and component
    values, leading axis B, and which were drawn valid (a rejected draw flies the batch's
    first valid sample in its place and counts for nothing)."""

    params: object  # so3jax.missions.draw.RolloutParams
    leaves: dict
    valid: jax.Array  # (B,) bool


class Sampler(NamedTuple):
    """[tune.dispersions] parsed: what draws a batch of dispersed missions."""

    dispersions: object  # so3jax.missions.draw.Dispersions
    leaves: tuple  # so3jax.missions.draw.Leaf, the dispersed component parameters
    mission: object  # so3jax.missions.mission.Mission, the campaign's (a static argument of jit)


MAX_DRAWS = 20  # attempts at a positive definite inertia before a sample is rejected (the sweep's default)


class Problem(NamedTuple):
    """What a run evaluates, built from the config, placed on the devices."""

    scenario: Scenario
    controller: str
    train: Batch | None  # None with dispersions: a fresh batch every iteration (batch_at)
    validation: Batch | DispersedBatch
    record_every: int | None
    mesh: Mesh | None  # the devices the batch is split over (batch_devices), or None: one device
    loop: Loop  # the mission's sensors, estimator, actuator and control period
    mission: object  # so3jax.missions.mission.Mission: the controllers' options and gains
    sampler: Sampler | None = None  # with [tune.dispersions]


# Rollouts per device and evaluation, at least, for a batch to be split. One device runs a
# batch natively vectorized (CPU time of a tuning step, PD, forward gradient, T = 20 s, an
# AMD EPYC core: 1 scenario 6.7 ms, 2: 11.7, 4: 13.2, 32: ~60, 64: ~104), and the shards
# of a split cost more CPU time together than the whole batch (2 x 32: 120-130 ms): a split
# gains only where cores are free, and loses on a loaded machine. Small batches (the
# shipped gradient campaigns' 2 scenarios) therefore stay on one device.
MIN_SHARD = 4


def batch_devices(config: TuneConfig, n_devices: int) -> int:
    """How many devices the training batch is split over: each gets at least MIN_SHARD
    rollouts per evaluation (scenarios x ES population members) and one scenario."""
    scenarios = config.train.samples or len(config.train.seeds) * len(config.train.inertia_scales)
    rollouts = scenarios * (config.es.population if config.method == "es" else 1)
    return min(scenarios, devices.devices_for(rollouts, n_devices, MIN_SHARD))


def build_problem(config: TuneConfig) -> Problem:
    dtype = jnp.result_type(float)
    scenario, loop = config.mission.scenario(dtype), config.mission.loop(dtype)
    if jax.process_count() > 1:  # several processes: the batch is split over all of their devices
        used = jax.devices()
    else:
        used = jax.devices()[: batch_devices(config, jax.device_count())]
    mesh = devices.mesh(used) if len(used) > 1 else None
    mode = config.gradient if config.method == "gradient" else None  # the ES differentiates nothing
    record_every = checkpoint_steps(loop, mode, config.record_every)
    if config.dispersions is not None:
        parsed, leaves = draw.parse(config.dispersions, config.mission)
        sampler = Sampler(parsed, leaves, config.mission)
        validation = draw_batch(sampler, config.validation.seeds[0], config.validation.samples, 0, dtype, mesh)
        return Problem(place(scenario, mesh), config.controller, None, validation, record_every, mesh,
                       place(loop, mesh), config.mission, sampler)
    train, validation = (
        place(make_batch(s.inertia_scales, s.seeds, dtype), mesh) for s in (config.train, config.validation)
    )
    return Problem(place(scenario, mesh), config.controller, train, validation, record_every, mesh,
                   place(loop, mesh), config.mission)


def draw_batch(sampler: Sampler, seed: int, samples: int, first: int, dtype, mesh) -> DispersedBatch:
    """Dispersed missions first .. first + samples - 1 of sampling seed ``seed``."""
    drawn = draw.draw(sampler.dispersions, sampler.leaves, seed, samples, MAX_DRAWS, first, sampler.mission)
    valid = np.asarray(drawn.valid)
    if not valid.any():
        raise ValueError(f"every dispersed mission {first}..{first + samples - 1} of sampling seed {seed} is rejected "
                         "(an inertia not positive definite, or a value outside its domain): narrow the dispersions")
    params, leaves = batched.inputs(drawn, dtype)
    stand_in = np.where(valid, np.arange(samples), int(np.argmax(valid)))  # a rejected draw flies a valid one
    params, leaves = jax.tree.map(lambda x: x[stand_in], (params, leaves))
    return place(DispersedBatch(params, leaves, valid), mesh)


def batch_at(config: TuneConfig, problem: Problem, iteration: int):
    """The training batch of an iteration: the scenario set's, or with dispersions the
    iteration's fresh draw (samples iteration * B .. (iteration + 1) * B - 1)."""
    if problem.sampler is None:
        return problem.train
    B = config.train.samples
    return draw_batch(problem.sampler, config.train.seeds[0], B, iteration * B, problem.scenario.R0.dtype, problem.mesh)


def evaluate(problem: Problem, gains, batch, controller=None):
    """Per-scenario metrics of fixed gains (forward only)."""
    controller = problem.mission.controller(controller or problem.controller)[0]
    return batch_cost_metrics(
        problem.scenario, controller, place(gains, problem.mesh), batch, problem.record_every, problem.mesh,
        problem.loop, mission=mission_of(problem),
    )


def mission_of(problem: Problem):
    """The mission that dispersed batches vary (None without dispersions)."""
    return None if problem.sampler is None else problem.sampler.mission


def cost_refs(config: TuneConfig, problem: Problem, initial_metrics, batch) -> CostRefs:
    """RMSE_ref, Effort_ref / budget (per scenario when taken from a controller run), weight."""
    dtype = initial_metrics.rmse.dtype
    cost = config.cost
    mean = functools.partial(batch_mean, valid=getattr(batch, "valid", None))
    rmse = cost.rmse_ref if cost.rmse_ref is not None else mean(initial_metrics.rmse)
    if cost.mode == "weighted":
        effort = cost.effort_ref if cost.effort_ref is not None else mean(initial_metrics.effort)
    elif cost.budget is not None:
        effort = cost.budget
    else:
        gains = resolve_gains(cost.budget_controller, cost.budget_gains, dtype, mission=config.mission)
        effort = evaluate(problem, gains, batch, cost.budget_controller).effort
    return CostRefs(jnp.asarray(rmse, dtype), jnp.asarray(effort, dtype), jnp.asarray(cost.weight, dtype))
