"""Gain tuning through the simulator: SPEC 6 costs, an optax loop with resumable
checkpoints, a gradient-free baseline, and the ``so3jax tune`` command.

Gains are tuned in log space (p = log g, so every gain stays positive). The cost of
gains g over a batch of B training scenarios (inertia scale x disturbance seed, see
:mod:`so3jax.gradients`) is the batch mean of (SPEC 6)

    weighted:      RMSE / RMSE_ref + lambda * Effort / Effort_ref
    equal_effort:  RMSE / RMSE_ref + mu * max(0, Effort / Effort_budget - 1)^2

RMSE_ref and Effort_ref default to the initial gains' batch means; Effort_budget is a
number or another controller's effort on the same scenario (e.g. the PD with the
paper's gains), scenario by scenario.

A run folder holds ``checkpoint.npz`` (rewritten atomically after every iteration, so
an interrupted run loses at most one iteration and ``--resume`` continues to the same
result), ``best_gains.json``, ``history.csv``, ``history.png`` and
``validation.json`` (initial and tuned gains on held-out seeds).
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import inspect
import io as _stringio
import json
import math
import sys
import time
import warnings
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.flatten_util import ravel_pytree
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from so3jax import config as cfg
from so3jax import distributed, io, runfolder
from so3jax.controllers import registry
from so3jax.gradients import MODES, Batch, batch_metrics, make_batch, value_and_grad
from so3jax.metrics import cell, finite_values, reported
from so3jax.scenario import Scenario, check_gains, check_scenario, paper_scenario

# One instance per controller, so that jit caches hit across runs in one process.
CONTROLLERS = {n: registry.get(n).factory() for n in registry.names(tunable=True)}
GAIN_TYPES = {n: registry.get(n).gains_type for n in CONTROLLERS}
PAPER_GAINS = {n: registry.get(n).defaults for n in CONTROLLERS}
COST_MODES = ("weighted", "equal_effort")
METHODS = ("gradient", "es")
CHECKPOINT = "checkpoint.npz"
DEFAULT_OUT = Path("results/tune")  # the shipped campaigns' folders are written only when named with --out


# --- configuration ---------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class ScenarioSet:
    """Scenarios = inertia_scales x seeds (every inertia matrix scaled, SPEC 4 noise seed)."""

    seeds: tuple[int, ...]
    inertia_scales: tuple[float, ...] = (1.0,)


@dataclasses.dataclass(frozen=True)
class CostConfig:
    """SPEC 6 tuning cost. weight is lambda (weighted) or mu (equal_effort)."""

    mode: str = "weighted"
    weight: float = 1.0
    rmse_ref: float | None = None  # rad/s; None: the initial gains' batch mean
    effort_ref: float | None = None  # N^2 m^2 s, weighted mode; None: initial gains' batch mean
    budget: float | None = None  # N^2 m^2 s, equal_effort mode (or budget_controller)
    budget_controller: str | None = None  # effort budget = this controller's effort, per scenario
    budget_gains: Any = "paper"  # its gains: "paper", a table, or a best_gains.json path


@dataclasses.dataclass(frozen=True)
class OptimizerConfig:
    """optax.<name>(schedule or learning_rate, **options), clipped by global norm, guarded
    by optax.apply_if_finite. schedule: optax.<schedule>(learning_rate, **schedule_options)."""

    name: str = "adam"
    learning_rate: float = 0.05  # in log-gain units per step
    options: dict = dataclasses.field(default_factory=dict)
    schedule: str | None = None
    schedule_options: dict = dataclasses.field(default_factory=dict)
    clip_norm: float = 1.0


@dataclasses.dataclass(frozen=True)
class ESConfig:
    """Gradient-free baseline: elitist (1+lambda)-ES in log-gain space, 1/5th success rule."""

    population: int = 8
    sigma: float = 0.2  # initial step, log-gain units
    seed: int = 0


@dataclasses.dataclass(frozen=True)
class TuneConfig:
    """A tuning campaign (one TOML file; see tuning/*.toml). Controllers are the default
    ones (nominal inertia I, exact log derivative)."""

    controller: str  # "pd" or "adaptive"
    iterations: int
    train: ScenarioSet
    validation: ScenarioSet  # held-out seeds
    initial_gains: Any = "paper"  # "paper", a table of gains, or a best_gains.json path
    scenario: dict = dataclasses.field(default_factory=dict)  # paper_scenario() arguments
    cost: CostConfig = CostConfig()
    optimizer: OptimizerConfig = OptimizerConfig()
    method: str = "gradient"
    gradient: str = "forward"  # differentiation mode, see so3jax.gradients
    record_every: int | None = None  # checkpoint block of the rollout (reverse mode memory)
    diagonal_gamma: bool = False  # adaptive: tune the 9 diagonal entries of Gamma
    es: ESConfig = ESConfig()


_SECTIONS = {
    "train": ScenarioSet,
    "validation": ScenarioSet,
    "cost": CostConfig,
    "optimizer": OptimizerConfig,
    "es": ESConfig,
}


def _build(cls, table: dict, prefix: str):
    """cls(**table), with a ValueError naming any unknown or missing key."""
    if not isinstance(table, dict):
        raise ValueError(f"config key {prefix.rstrip('.') or 'config'!r} must be a table, got {table!r}")  # noqa: TRY004
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for key in table:
        if key not in fields:
            raise ValueError(f"unknown config key '{prefix}{key}' (known: {', '.join(fields)})")
    for name, f in fields.items():
        if name not in table and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ValueError(f"missing config key '{prefix}{name}'")
    values = {}
    for key, value in table.items():
        if key in _SECTIONS and cls is TuneConfig:
            value = _build(_SECTIONS[key], value, f"{key}.")
        elif isinstance(value, list) and key in ("seeds", "inertia_scales"):
            value = tuple(value)
        elif key in ("seeds", "inertia_scales"):
            raise ValueError(f"config key '{prefix}{key}' must be a non-empty list of numbers, got {cfg.short(value)}")
        values[key] = value
    return cls(**values)


def _positive(name, value, integer=False):
    ok = isinstance(value, int) if integer else isinstance(value, (int, float))
    if isinstance(value, bool) or not ok or not cfg.finite(value) or value <= 0:
        kind = "a positive integer" if integer else "a positive finite number"
        raise ValueError(f"config key {name!r} must be {kind}, got {cfg.short(value)}")


def _choice(name, value, choices):
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"config key {name!r} must be one of {choices}, got {cfg.short(value)}")


def _check_kwargs(fn, options, where: str) -> None:
    """The keyword options of an optax function, each of the type of its default (a
    number, true or false) where it has one, a number where it is annotated int or float.
    A table is required; options without a typed default are left to the call."""
    if not isinstance(options, dict):
        got = cfg.short(options)
        raise ValueError(f"config key {where!r} must be a table of keyword arguments, got {got}")  # noqa: TRY004
    parameters = inspect.signature(fn).parameters
    for key, value in options.items():
        p = parameters.get(key)
        if p is None:
            continue  # the call names it
        default = p.default
        if isinstance(default, bool) or p.annotation in (bool, "bool"):
            cfg.boolean(value, f"config key '{where}.{key}'")
        elif (isinstance(default, (int, float)) or p.annotation in (int, float, "int", "float")) and (
            isinstance(value, bool) or not isinstance(value, (int, float))
        ):
            raise ValueError(f"config key '{where}.{key}' must be a number, got {cfg.short(value)}")


# The types of paper_scenario's arguments in a config's [scenario] table (by their defaults;
# None defaults: a number for n, a (3, 3) matrix for J1).
_SCENARIO_ARRAYS = {"J0": (3, 3), "J1": (3, 3), "J2": (3, 3)}


def _check_scenario_types(table: dict) -> None:
    """Each [scenario] entry of its type: a number, a (3, 3) matrix of numbers, or true/false."""
    for key, value in table.items():
        where = f"config key 'scenario.{key}'"
        if key in _SCENARIO_ARRAYS:
            cfg.array(value, where, _SCENARIO_ARRAYS[key])
        elif isinstance(inspect.signature(paper_scenario).parameters[key].default, bool):
            cfg.boolean(value, where)
        elif isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{where} must be a number, got {cfg.short(value)}")


def make_optimizer(config: OptimizerConfig) -> optax.GradientTransformation:
    """apply_if_finite(chain(clip_by_global_norm, optax.<name>(schedule, **options)))."""
    _positive("optimizer.learning_rate", config.learning_rate)
    _positive("optimizer.clip_norm", config.clip_norm)
    factory = getattr(optax, config.name, None) if isinstance(config.name, str) else None
    if not callable(factory) or next(iter(inspect.signature(factory).parameters), None) != "learning_rate":
        name = cfg.short(config.name)
        raise ValueError(f"config key 'optimizer.name': {name} is not an optax optimizer (e.g. adam, sgd)")
    _check_kwargs(factory, config.options, "optimizer.options")
    learning_rate = config.learning_rate
    if config.schedule is not None:
        schedule = getattr(optax, config.schedule, None) if isinstance(config.schedule, str) else None
        if not callable(schedule):
            raise ValueError(f"config key 'optimizer.schedule': {cfg.short(config.schedule)} is not an optax schedule")
        _check_kwargs(schedule, config.schedule_options, "optimizer.schedule_options")
        try:
            learning_rate = schedule(config.learning_rate, **config.schedule_options)
            learning_rate(0)
        except (TypeError, ValueError) as err:
            raise ValueError(f"config key 'optimizer.schedule_options': {err}") from err
    try:
        inner = factory(learning_rate, **config.options)
    except TypeError as err:
        raise ValueError(f"config key 'optimizer.options': {err}") from err
    # Large enough never to give up: the loop stops at the first non-finite gradient.
    tx = optax.apply_if_finite(optax.chain(optax.clip_by_global_norm(config.clip_norm), inner), 2**30)
    try:  # an optimizer that needs more than (grad, value), e.g. lbfgs's value_fn
        probe = jnp.zeros(2)
        with jax.numpy_dtype_promotion("standard"):  # optax mixes int32 step counts with floats
            tx.update(probe, tx.init(probe), probe, value=jnp.zeros(()))
    except Exception as err:  # any failure on a trivial update disqualifies it
        raise ValueError(f"config key 'optimizer.name': optax.{config.name} cannot be used here: {err}") from err
    return tx


def validate(config: TuneConfig) -> None:
    """Every check that can run before compilation (SPEC 6 style: a clear ValueError)."""
    _choice("controller", config.controller, tuple(CONTROLLERS))
    _choice("method", config.method, METHODS)
    _choice("gradient", config.gradient, MODES)
    _choice("cost.mode", config.cost.mode, COST_MODES)
    _positive("iterations", config.iterations, integer=True)
    if config.record_every is not None:
        _positive("record_every", config.record_every, integer=True)
    for section in ("train", "validation"):
        scenarios = getattr(config, section)
        if not scenarios.seeds or not all(
            isinstance(s, int) and not isinstance(s, bool) and 0 <= s < 2**31 for s in scenarios.seeds
        ):
            raise ValueError(f"config key '{section}.seeds' must be a non-empty list of integers in [0, 2^31)")
        if not scenarios.inertia_scales:
            raise ValueError(f"config key '{section}.inertia_scales' must be a non-empty list")
        for scale in scenarios.inertia_scales:
            _positive(f"{section}.inertia_scales", scale)
    held_out = set(config.train.seeds) & set(config.validation.seeds)
    if held_out:
        raise ValueError(f"config key 'validation.seeds' must be held out of train.seeds; both have {sorted(held_out)}")
    cost = config.cost
    _positive("cost.weight", cost.weight)
    for key in ("rmse_ref", "effort_ref", "budget"):
        if getattr(cost, key) is not None:
            _positive(f"cost.{key}", getattr(cost, key))
    if cost.mode == "equal_effort" and (cost.budget is None) == (cost.budget_controller is None):
        raise ValueError("equal_effort cost needs exactly one of config keys 'cost.budget', 'cost.budget_controller'")
    if cost.budget_controller is not None:
        _choice("cost.budget_controller", cost.budget_controller, tuple(CONTROLLERS))
    if not isinstance(config.scenario, dict):
        raise ValueError(f"config key 'scenario' must be a table of paper_scenario arguments, got {config.scenario!r}")  # noqa: TRY004
    signature = inspect.signature(paper_scenario).parameters
    for key in config.scenario:
        if key not in signature or key == "dtype":
            raise ValueError(f"unknown config key 'scenario.{key}' (paper_scenario arguments: {', '.join(signature)})")
    _check_scenario_types(config.scenario)
    try:
        paper_scenario(**config.scenario)  # its values: horizon, step, tau_J, inertias
    except (TypeError, ValueError) as err:
        raise ValueError(f"config key 'scenario': {err}") from None
    for key, controller, spec in (
        ("initial_gains", config.controller, config.initial_gains),
        ("cost.budget_gains", cost.budget_controller, cost.budget_gains),
    ):
        if controller is not None:
            try:
                resolve_gains(
                    controller, spec, jnp.result_type(float), config.diagonal_gamma and key == "initial_gains"
                )
            except (OSError, ValueError) as err:
                raise ValueError(f"config key {key!r}: {err}") from err
    make_optimizer(config.optimizer)
    _positive("es.population", config.es.population, integer=True)
    _positive("es.sigma", config.es.sigma)
    cfg.number(config.es.seed, "config key 'es.seed'", low=0, high=2**32 - 1, integer=True)
    cfg.boolean(config.diagonal_gamma, "config key 'diagonal_gamma'")
    if config.diagonal_gamma and config.controller != "adaptive":
        raise ValueError("config key 'diagonal_gamma' applies to the adaptive controller only")


def parse_config(table: dict, base_dir=".") -> TuneConfig:
    """A validated TuneConfig from a TOML-like table; gain-file paths relative to base_dir."""
    table = json.loads(json.dumps(table))  # a deep copy
    for section, key in (("", "initial_gains"), ("cost", "budget_gains")):
        holder = table.get(section, {}) if section else table
        value = holder.get(key) if isinstance(holder, dict) else None
        if isinstance(value, str) and value.endswith(".json"):
            holder[key] = str((Path(base_dir) / value).resolve())
    config = _build(TuneConfig, table, "")
    validate(config)
    return config


def load_config(path, overrides=()) -> TuneConfig:
    """Read a TOML campaign file and apply (dotted key, value) overrides."""
    table = cfg.read_toml(path)
    for key, value in overrides:
        cfg.set_dotted(table, key, value)
    return parse_config(table, Path(path).parent)


# --- gains -------------------------------------------------------------------------


def resolve_gains(controller: str, spec, dtype, diagonal_gamma=False):
    """Gains from "paper", a table {name: value}, or a best_gains.json path; checked (SPEC 6)."""
    cls = GAIN_TYPES[controller]
    if spec == "paper":
        table = PAPER_GAINS[controller]._asdict()
    elif isinstance(spec, str):
        saved = json.loads(Path(spec).read_text())
        if runfolder.incomplete(Path(spec).parent):
            warnings.warn(f"gains file {spec} is from a so3jax run that did not finish (its manifest says incomplete)")
        held = saved.get("controller") if isinstance(saved, dict) else None
        if held != controller or not isinstance(saved.get("gains"), dict):
            raise ValueError(f"gains file {spec} holds no table of {controller!r} gains ({held!r} gains)")
        table = saved["gains"]
    elif isinstance(spec, dict):
        table = spec
    else:
        raise ValueError(f"gains must be 'paper', a table or a .json path, got {cfg.short(spec)}")
    for name in table:
        if name not in cls._fields:
            raise ValueError(f"unknown gain {name!r} for the {controller} controller ({', '.join(cls._fields)})")
    missing = [name for name in cls._fields if name not in table]
    if missing:
        raise ValueError(f"missing gain {missing[0]!r} for the {controller} controller")
    registered = registry.get(controller)
    shapes = {name: tuple(s for s in allowed if len(s) < 2)  # tuning: a scalar or a (9,) diagonal Gamma
              for name, allowed in registered.gain_shapes().items()}
    table = cfg.gains(table, registered.defaults, shapes, "gains")._asdict()
    gains = cls(**{name: jnp.asarray(table[name], dtype) for name in cls._fields})
    if controller == "adaptive":
        if gains.Gamma.ndim > 1:
            raise ValueError("tuning supports a scalar or (9,) diagonal Gamma")
        if diagonal_gamma:
            gains = gains._replace(Gamma=jnp.broadcast_to(gains.Gamma, (9,)))
    check_gains(gains)
    return gains


def to_params(gains):
    """Log-gains, the tuned parameters."""
    return jax.tree.map(jnp.log, gains)


def to_gains(params):
    return jax.tree.map(jnp.exp, params)


def gains_table(gains) -> dict:
    return {name: np.asarray(value).tolist() for name, value in gains._asdict().items()}


def gain_columns(gains) -> dict:
    """Flat {column: value}: Gamma_0 .. Gamma_8 for a diagonal Gamma."""
    columns = {}
    for name, value in gains._asdict().items():
        value = np.asarray(value)
        if value.ndim == 0:
            columns[name] = float(value)
        else:
            columns.update({f"{name}_{i}": float(v) for i, v in enumerate(value)})
    return columns


# --- cost (SPEC 6) -----------------------------------------------------------------


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


BATCH = "batch"  # the mesh axis the scenario batch is split along


def _metrics(scenario, controller, gains, batch, record_every, mesh):
    """batch_metrics, split along the batch over the devices of mesh (None: one device).

    Each device runs the single-device rollout on its shard (``jax.shard_map``): nothing
    crosses devices inside the time loop. The batch is padded to a multiple of the mesh
    size by repeating its last scenario, and the padding is dropped from the result.
    """
    run = lambda scenario, gains, batch: batch_metrics(scenario, controller, gains, batch, record_every=record_every)
    if mesh is None:
        return run(scenario, gains, batch)
    n = batch.seed.shape[0]
    index = jnp.minimum(jnp.arange(-(-n // mesh.size) * mesh.size), n - 1)
    padded = jax.tree.map(lambda x: x[index], batch)
    # check_vma=False: the rollout's loop carries start from the shared scenario and become
    # per-device; without the check, the gradient of the shared gains sums over devices.
    sharded = jax.shard_map(
        run,
        mesh=mesh,
        in_specs=(PartitionSpec(), PartitionSpec(), PartitionSpec(BATCH)),
        out_specs=PartitionSpec(BATCH),
        check_vma=False,
    )
    return jax.tree.map(lambda x: x[:n], sharded(scenario, gains, padded))


@functools.partial(jax.jit, static_argnames=("controller", "record_every", "mesh"))
def _batch_metrics(scenario, controller, gains, batch, record_every, mesh=None):
    return _metrics(scenario, controller, gains, batch, record_every, mesh)


@functools.partial(jax.jit, static_argnames=("controller", "mode", "gradient", "record_every", "mesh"))
def cost_and_grad(params, scenario, controller, batch, refs, mode, gradient, record_every, mesh=None):
    """(Evaluation, d cost / d params) of log-gains params over the batch (split over mesh)."""

    def cost(p):
        summary = _summary(_metrics(scenario, controller, to_gains(p), batch, record_every, mesh), refs, mode)
        return summary.cost, summary

    (_, summary), grad = value_and_grad(cost, gradient)(params)
    return summary, grad


@functools.partial(jax.jit, static_argnames=("controller", "mode", "record_every", "mesh"))
def population_costs(population, scenario, controller, batch, refs, mode, record_every, mesh=None):
    """Evaluation of each member of a population of log-gains (leading axis P)."""

    def one(params):
        return _summary(_metrics(scenario, controller, to_gains(params), batch, record_every, mesh), refs, mode)

    return jax.vmap(one)(population)


# --- optimizers: the optax loop and the gradient-free baseline -----------------------


class GradientState(NamedTuple):
    params: Any
    opt_state: Any


class ESState(NamedTuple):
    params: Any
    cost: jax.Array
    rmse: jax.Array
    effort: jax.Array
    sigma: jax.Array


@functools.partial(jax.jit, static_argnames=("tx",))
def _optax_step(tx, state: GradientState, grad, value):
    with jax.numpy_dtype_promotion("standard"):  # optax mixes int32 step counts with floats
        updates, opt_state = tx.update(grad, state.opt_state, state.params, value=value)
    return GradientState(optax.apply_updates(state.params, updates), opt_state)


def es_candidates(params, sigma, key, population):
    """population log-gain vectors params + sigma * N(0, I) (leading axis)."""
    flat, unravel = ravel_pytree(params)
    noise = jax.random.normal(key, (population,) + flat.shape, flat.dtype)
    return jax.vmap(unravel)(flat + sigma * noise)


def es_select(state: ESState, candidates, evaluation: Evaluation) -> ESState:
    """Keep the best candidate if it beats the parent; sigma by the 1/5th success rule."""
    costs = jnp.where(jnp.isfinite(evaluation.cost), evaluation.cost, jnp.inf)
    best = jnp.argmin(costs)
    better = costs[best] < state.cost
    success = jnp.mean((costs < state.cost).astype(state.sigma.dtype))

    def pick(new, old):
        return jnp.where(better, new, old)

    return ESState(
        jax.tree.map(lambda c, p: pick(c[best], p), candidates, state.params),
        pick(costs[best], state.cost),
        pick(evaluation.rmse[best], state.rmse),
        pick(evaluation.effort[best], state.effort),
        state.sigma * jnp.exp((success - 0.2) / 0.8),
    )


class NonFiniteGradientError(FloatingPointError):
    """A cost or gradient became NaN/inf; the run stopped with its last good gains saved."""


# --- the run -------------------------------------------------------------------------


class Problem(NamedTuple):
    """What a run evaluates, built from the config, placed on the devices."""

    scenario: Scenario
    controller: str
    train: Batch
    validation: Batch
    record_every: int | None
    mesh: Mesh | None  # the devices the batch is split over (batch_devices), or None: one device


def place(tree, mesh: Mesh | None):
    """Put tree on every device of the mesh, replicated (the jitted functions split the
    scenario batch over the mesh themselves), so that jit sees the same placement at
    every call and compiles once per shape."""
    if mesh is None:
        return tree
    if jax.process_count() > 1:  # every process holds the same values: give them as host data
        tree = jax.tree.map(np.asarray, tree)
    return jax.device_put(tree, NamedSharding(mesh, PartitionSpec()))


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
    scenarios = len(config.train.seeds) * len(config.train.inertia_scales)
    rollouts = scenarios * (config.es.population if config.method == "es" else 1)
    return max(1, min(n_devices, scenarios, rollouts // MIN_SHARD))


def build_problem(config: TuneConfig) -> Problem:
    dtype = jnp.result_type(float)
    scenario = paper_scenario(**config.scenario, dtype=dtype)
    check_scenario(scenario)
    if jax.process_count() > 1:  # several processes: the batch is split over all of their devices
        devices = jax.devices()
    else:
        devices = jax.devices()[: batch_devices(config, jax.device_count())]
    mesh = Mesh(np.array(devices), (BATCH,)) if len(devices) > 1 else None
    train, validation = (
        place(make_batch(s.inertia_scales, s.seeds, dtype), mesh) for s in (config.train, config.validation)
    )
    return Problem(place(scenario, mesh), config.controller, train, validation, config.record_every, mesh)


def evaluate(problem: Problem, gains, batch: Batch, controller=None):
    """Per-scenario metrics of fixed gains (forward only)."""
    controller = CONTROLLERS[controller or problem.controller]
    return _batch_metrics(
        problem.scenario, controller, place(gains, problem.mesh), batch, problem.record_every, problem.mesh
    )


def cost_refs(config: TuneConfig, problem: Problem, initial_metrics, batch: Batch) -> CostRefs:
    """RMSE_ref, Effort_ref / budget (per scenario when taken from a controller run), weight."""
    dtype = initial_metrics.rmse.dtype
    cost = config.cost
    rmse = cost.rmse_ref if cost.rmse_ref is not None else jnp.mean(initial_metrics.rmse)
    if cost.mode == "weighted":
        effort = cost.effort_ref if cost.effort_ref is not None else jnp.mean(initial_metrics.effort)
    elif cost.budget is not None:
        effort = cost.budget
    else:
        gains = resolve_gains(cost.budget_controller, cost.budget_gains, dtype)
        effort = evaluate(problem, gains, batch, cost.budget_controller).effort
    return CostRefs(jnp.asarray(rmse, dtype), jnp.asarray(effort, dtype), jnp.asarray(cost.weight, dtype))


def _fingerprint(config: TuneConfig) -> str:
    """Fingerprint of everything but the iteration count (a resumed run may be extended)."""
    return runfolder.fingerprint(dataclasses.asdict(dataclasses.replace(config, iterations=0)))


def save_checkpoint(path, fingerprint, iteration, state, refs, rows) -> None:
    leaves = jax.tree.leaves(state) + list(refs)
    io.save_npz(
        path,
        fingerprint=np.array(fingerprint),
        iteration=np.array(iteration),
        rows=np.array(json.dumps(rows)),
        **{f"leaf_{i}": np.asarray(leaf) for i, leaf in enumerate(leaves)},
    )


def load_checkpoint(path, fingerprint, state_template, refs_template):
    """(iteration, state, refs, rows); leaf shapes and dtypes follow the templates."""
    leaves_template, treedef = jax.tree.flatten((state_template, refs_template))
    try:
        with np.load(path) as data:
            found = str(data["fingerprint"])
            iteration, rows = int(data["iteration"]), json.loads(str(data["rows"]))
            leaves = [data[f"leaf_{i}"] for i in range(len(leaves_template))]
    except Exception as err:  # a truncated or foreign file: zip, pickle, key or JSON errors
        raise runfolder.corrupt(path, err, "delete it to start the run over, or choose another --out") from None
    if found != fingerprint:
        raise ValueError(f"{path} was written for another configuration; use a new --out folder")
    for i, (leaf, template) in enumerate(zip(leaves, leaves_template)):
        if leaf.shape != np.shape(template):
            raise ValueError(f"{path}: checkpoint leaf {i} has shape {leaf.shape}, expected {np.shape(template)}")
    leaves = [jnp.asarray(leaf, np.asarray(template).dtype) for leaf, template in zip(leaves, leaves_template)]
    state, refs = jax.tree.unflatten(treedef, leaves)
    return iteration, state, CostRefs(*refs), rows


def write_history(out: Path, rows: list[dict]) -> None:
    buffer = _stringio.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    io.write_text(out / "history.csv", buffer.getvalue())


def plot_history(out: Path, rows: list[dict], gain_names: list[str]) -> None:
    from matplotlib.figure import Figure

    it = [r["iteration"] for r in rows]
    fig = Figure(figsize=(10, 6.5))
    axes = fig.subplots(2, 2, sharex=True)
    for ax, key, label in zip(axes.flat, ("cost", "rmse", "effort"), ("cost [-]", "RMSE [rad/s]", "effort [N² m² s]")):
        ax.plot(it, [r[key] for r in rows], marker=".")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    ax = axes.flat[3]
    for name in gain_names:
        first = rows[0][name]
        ax.plot(it, [r[name] / first for r in rows], label=name)
    ax.set_yscale("log")
    ax.set_ylabel("gain / initial gain")
    ax.legend(fontsize=7, ncol=2)
    ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("iteration")
    fig.tight_layout()
    io.save_figure(fig, out / "history.png")


def _row(iteration, evaluation: Evaluation, gains, wall, rollouts, **extra) -> dict:
    return {
        "iteration": iteration,
        "cost": float(evaluation.cost),
        "rmse": float(evaluation.rmse),
        "effort": float(evaluation.effort),
        "diverged": int(evaluation.diverged),
        **extra,
        "wall_s": round(wall, 3),
        "rollouts": rollouts,
        **gain_columns(gains),
    }


def _gains_from_row(row, template):
    """The gains recorded in a history row, shaped like template."""
    values = {}
    for name, value in template._asdict().items():
        size = np.size(value)
        values[name] = row[name] if np.ndim(value) == 0 else [row[f"{name}_{i}"] for i in range(size)]
    return type(template)(**{name: jnp.asarray(v, jnp.result_type(template[0])) for name, v in values.items()})


def _best_row(rows):
    """The row of the lowest finite cost (the first row when none is finite)."""
    return min(rows, key=lambda r: r["cost"] if math.isfinite(r["cost"]) else math.inf)


def _write_best(out: Path, config: TuneConfig, rows, template) -> None:
    """best_gains.json: the lowest training cost so far, and the last good gains."""
    best, last = _best_row(rows), rows[-1]
    record = {
        "controller": config.controller,
        "gains": gains_table(_gains_from_row(best, template)),
        "iteration": best["iteration"],
        "training": {key: best[key] for key in ("cost", "rmse", "effort")},
        "last_good": {"iteration": last["iteration"], "gains": gains_table(_gains_from_row(last, template))},
    }
    io.write_json(out / "best_gains.json", record)


def _metrics_table(metrics) -> dict:
    """Per-scenario RMSE and effort (None for a diverged scenario, flagged in ``diverged``)
    and their means over the scenarios that did not diverge (None if every one did)."""
    diverged = np.asarray(metrics.diverged, dtype=bool)
    rmse, effort = (reported(x, diverged) for x in (metrics.rmse, metrics.effort))

    def mean(x):
        finite, _ = finite_values(x)
        return float(np.mean(finite)) if len(finite) else None

    return {
        "rmse": io.to_builtin(rmse),
        "effort": io.to_builtin(effort),
        "diverged": diverged.tolist(),
        "diverged_count": int(np.sum(diverged | ~np.isfinite(rmse) | ~np.isfinite(effort))),
        "mean_rmse": mean(rmse),
        "mean_effort": mean(effort),
    }


def _mean_cost(metrics, refs, mode):
    """The SPEC 6 cost over the scenarios, None when a scenario diverged (its cost is not a number)."""
    cost = float(jnp.mean(scenario_costs(metrics, refs, mode)))
    return cost if math.isfinite(cost) and not np.any(metrics.diverged) else None


def validate_gains(config: TuneConfig, problem: Problem, initial, best, refs_train: CostRefs) -> dict:
    """Initial and tuned gains (and the budget controller's) on the held-out scenarios.

    The cost there uses the training RMSE_ref / Effort_ref, and a per-scenario budget
    recomputed on the held-out scenarios.
    """
    batch = problem.validation
    initial_metrics = evaluate(problem, initial, batch)
    best_metrics = evaluate(problem, best, batch)
    refs = refs_train
    report = {
        "controller": config.controller,
        "scenarios": {
            "seeds": np.asarray(batch.seed).tolist(),
            "inertia_scale": np.asarray(batch.inertia_scale).tolist(),
        },
        "initial": {"gains": gains_table(initial), **_metrics_table(initial_metrics)},
        "tuned": {"gains": gains_table(best), **_metrics_table(best_metrics)},
    }
    if config.cost.budget_controller is not None:
        dtype = problem.scenario.R0.dtype
        gains = resolve_gains(config.cost.budget_controller, config.cost.budget_gains, dtype)
        budget_metrics = evaluate(problem, gains, batch, config.cost.budget_controller)
        refs = refs._replace(effort=budget_metrics.effort)
        report["budget"] = {
            "controller": config.cost.budget_controller,
            "gains": gains_table(gains),
            **_metrics_table(budget_metrics),
        }
    report["cost"] = {
        "mode": config.cost.mode,
        "initial": _mean_cost(initial_metrics, refs, config.cost.mode),
        "tuned": _mean_cost(best_metrics, refs, config.cost.mode),
    }
    return report


def tune(config: TuneConfig, out, *, resume: bool = False, progress: bool = True) -> dict:
    """Run (or resume) a tuning campaign into folder ``out``; returns validation.json's content.

    Raises NonFiniteGradientError, after saving, when a cost or gradient is not finite.
    """
    validate(config)
    with runfolder.claim(out, "tune", dataclasses.asdict(config), resume=resume, lock=distributed.writer()) as run:
        if jax.process_count() > 1:
            run.start()  # the folder every process must see (distributed.check_shared)
        return _tune(config, run.out, resume, progress and distributed.writer())


def _tune(config: TuneConfig, out: Path, resume: bool, progress: bool) -> dict:
    from tqdm import tqdm

    distributed.check_shared(out)  # every process reads the checkpoint to resume
    checkpoint = out / CHECKPOINT
    if checkpoint.exists() and not resume:
        raise ValueError(f"{checkpoint} exists: pass --resume to continue that run, or choose another --out")
    problem = build_problem(config)
    controller = CONTROLLERS[config.controller]
    dtype = problem.scenario.R0.dtype
    initial = resolve_gains(config.controller, config.initial_gains, dtype, config.diagonal_gamma)
    n_train = problem.train.seed.shape[0]
    mode = config.cost.mode
    fingerprint = _fingerprint(config)

    params = to_params(initial)
    if config.method == "gradient":
        tx = make_optimizer(config.optimizer)
        state = GradientState(params, tx.init(params))
    else:
        zero = jnp.zeros((), dtype)
        state = ESState(params, zero, zero, zero, jnp.asarray(config.es.sigma, dtype))
    scalar = jnp.zeros((), dtype)
    per_scenario = mode == "equal_effort" and config.cost.budget_controller is not None
    refs = CostRefs(scalar, jnp.zeros((n_train,), dtype) if per_scenario else scalar, scalar)

    start = time.perf_counter()
    initial_diverged = 0  # training scenarios the initial gains diverge on
    if resume and checkpoint.exists():
        iteration, state, refs, rows = load_checkpoint(checkpoint, fingerprint, state, refs)
        start -= rows[-1]["wall_s"] if rows else 0.0
    else:
        initial_metrics = evaluate(problem, initial, problem.train)
        initial_diverged = int(np.sum(initial_metrics.diverged))
        refs = cost_refs(config, problem, initial_metrics, problem.train)
        iteration, rows = 0, []
        if config.method == "es":
            first = _summary(initial_metrics, refs, mode)
            state = state._replace(cost=first.cost, rmse=first.rmse, effort=first.effort)
    rollouts = rows[-1]["rollouts"] if rows else n_train  # the initial evaluation
    refs = place(refs, problem.mesh)

    bar = tqdm(total=config.iterations, initial=iteration, desc=f"tune {config.controller}", disable=not progress)
    try:
        while iteration < config.iterations:
            state = place(state, problem.mesh)
            if config.method == "gradient":
                evaluation, grad = cost_and_grad(
                    state.params,
                    problem.scenario,
                    controller,
                    problem.train,
                    refs,
                    mode,
                    config.gradient,
                    problem.record_every,
                    problem.mesh,
                )
                new_state = _optax_step(tx, state, grad, evaluation.cost)
                rollouts += n_train
                gains = to_gains(state.params)
                row = _row(
                    iteration,
                    evaluation,
                    gains,
                    time.perf_counter() - start,
                    rollouts,
                    grad_norm=float(optax.tree.norm(grad)),
                )
                finite = bool(new_state.opt_state.last_finite) and math.isfinite(row["cost"])
            else:
                key = jax.random.fold_in(jax.random.key(config.es.seed), iteration)
                candidates = place(es_candidates(state.params, state.sigma, key, config.es.population), problem.mesh)
                evaluations = population_costs(
                    candidates, problem.scenario, controller, problem.train, refs, mode, problem.record_every,
                    problem.mesh,
                )
                new_state = es_select(state, candidates, evaluations)
                rollouts += config.es.population * n_train
                # a finite cost has no diverged scenario; the parent stays the initial gains until one is finite
                parent_diverged = 0 if math.isfinite(float(new_state.cost)) else initial_diverged
                parent = Evaluation(new_state.cost, new_state.rmse, new_state.effort, parent_diverged)
                row = _row(
                    iteration,
                    parent,
                    to_gains(new_state.params),
                    time.perf_counter() - start,
                    rollouts,
                    sigma=float(new_state.sigma),
                )
                finite = math.isfinite(row["cost"])
            if not finite:
                if distributed.writer():
                    write_history(out, rows + [row])
                kept = (
                    f"best and last good gains: {out / 'best_gains.json'}"
                    if rows
                    else "no gains were written (the initial gains already fail)"
                )
                gradient = f", gradient norm {row['grad_norm']}" if "grad_norm" in row else ""
                raise NonFiniteGradientError(
                    f"non-finite cost or gradient at iteration {iteration} (cost {row['cost']}{gradient}, "
                    f"{row['diverged']} of {n_train} training rollouts diverged) with gains "
                    f"{gain_columns(to_gains(state.params))}; stopped; {kept}"
                )
            rows.append(row)
            state = new_state
            iteration += 1
            if distributed.writer():  # process 0 of a multi-process run writes; every process holds the same state
                save_checkpoint(checkpoint, fingerprint, iteration, state, refs, rows)
                write_history(out, rows)
                _write_best(out, config, rows, initial)
            bar.set_postfix(cost=f"{row['cost']:.4g}", rmse=f"{row['rmse']:.3e}", effort=f"{row['effort']:.4g}")
            bar.update(1)
    finally:
        bar.close()

    if distributed.writer():
        plot_history(out, rows, list(gain_columns(initial)))
    best_row = _best_row(rows)
    report = validate_gains(config, problem, initial, _gains_from_row(best_row, initial), refs)
    report["training"] = {
        "method": config.method,
        "gradient": config.gradient if config.method == "gradient" else None,
        "iterations": iteration,
        "best_iteration": best_row["iteration"],
        "best_cost": best_row["cost"],
        "wall_s": rows[-1]["wall_s"],
        "rollouts": rows[-1]["rollouts"],
        "T": problem.scenario.horizon,
        "scenarios": {
            "seeds": np.asarray(problem.train.seed).tolist(),
            "inertia_scale": np.asarray(problem.train.inertia_scale).tolist(),
        },
        "refs": {
            "rmse": np.asarray(refs.rmse).tolist(),
            "effort": np.asarray(refs.effort).tolist(),
            "weight": float(refs.weight),
        },
    }
    report = io.to_builtin(report)
    if distributed.writer():
        io.write_json(out / "validation.json", report)
    return report


# --- command line --------------------------------------------------------------------


def _command(args) -> int:
    distributed.initialize(args)  # before anything touches JAX's backend
    overrides = [cfg.parse_override(text) for text in args.set]
    if args.iterations is not None:
        overrides.append(("iterations", args.iterations))
    if args.T is not None:
        overrides.append(("scenario.T", args.T))
    config = load_config(args.config, overrides)
    out = Path(args.out) if args.out else DEFAULT_OUT / Path(args.config).stem
    try:
        report = tune(config, out, resume=args.resume)
    except NonFiniteGradientError as err:
        print(f"so3jax tune: {err}", file=sys.stderr)
        return 1
    if distributed.writer():
        print(markdown_table([report]))
        print(f"results in {out}/")
    return 0


def markdown_table(reports: list[dict]) -> str:
    """Paper (initial) vs tuned gains, RMSE and effort on the held-out scenarios (means
    over the scenarios that did not diverge, with their count; "diverged" if all did)."""
    lines = [
        "| campaign | controller | gains | held-out RMSE [rad/s] | held-out effort [N² m² s] |",
        "|---|---|---|---|---|",
    ]
    for report in reports:
        name = report.get("name", report["controller"])
        entries = [("initial", report["initial"]), ("tuned", report["tuned"])]
        if "budget" in report:
            entries.insert(0, (f"budget ({report['budget']['controller']})", report["budget"]))
        for label, entry in entries:
            gains = ", ".join(f"{k}={_fmt(v)}" for k, v in entry["gains"].items())
            controller = report["budget"]["controller"] if label.startswith("budget") else report["controller"]
            lines.append(
                f"| {name} ({label}) | {controller} | {gains} | {_mean_cell(entry, 'mean_rmse', '.4e')} "
                f"| {_mean_cell(entry, 'mean_effort', '.2f')} |"
            )
    return "\n".join(lines)


def _mean_cell(entry: dict, key: str, fmt: str) -> str:
    """A validation mean: the number, and how many scenarios diverged if any did."""
    total = len(entry["diverged"])
    count = entry.get("diverged_count", sum(map(bool, entry["diverged"])))
    value = entry[key]
    if value is None or not math.isfinite(value):
        return "diverged" if count else cell(None, fmt)
    return format(value, fmt) + (f" ({count} of {total} diverged)" if count else "")


def _fmt(value) -> str:
    if isinstance(value, list):
        return "[" + ", ".join(f"{v:.3g}" for v in value) + "]"
    return f"{value:.4g}"


def register(subparsers) -> None:
    from so3jax.cli import add_precision_argument

    parser = subparsers.add_parser("tune", help="tune controller gains by gradient descent through the simulator")
    parser.add_argument("config", help="campaign file (TOML), e.g. tuning/adaptive_equal_effort.toml")
    parser.add_argument("--iterations", type=int, help="number of iterations (overrides the config)")
    parser.add_argument("--T", type=float, help="horizon [s] (overrides scenario.T)")
    parser.add_argument("--out", help=f"run folder (default {DEFAULT_OUT}/NAME for NAME.toml)")
    parser.add_argument("--resume", action="store_true", help="continue the run saved in the run folder")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config key, e.g. optimizer.learning_rate=0.1",
    )
    distributed.add_arguments(parser)
    add_precision_argument(parser)
    parser.set_defaults(func=_command)
