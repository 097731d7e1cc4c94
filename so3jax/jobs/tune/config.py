"""A tuning campaign's configuration (one TOML file, tuning/*.toml): a mission (``mission =
"PATH"`` and/or mission tables inline; default the paper's) and a ``[tune]`` table,
parsed into a TuneConfig, with every check that can run before compilation."""

from __future__ import annotations

import dataclasses
import inspect
import json
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax

from so3jax.components import filters
from so3jax.components import registry as components
from so3jax.controllers import registry
from so3jax.controllers.gains import Nonnegative, gain_domain
from so3jax.core import checks
from so3jax.jobs.tune.gains import CONTROLLERS, NYQUIST_SHARE, diagonals, resolve_gains
from so3jax.jobs.tune.goals import MAX_DB, formed_before, parse_goals
from so3jax.missions import batched, draw
from so3jax.missions import config as cfg
from so3jax.missions import mission as missions
from so3jax.sim import memory
from so3jax.sim.gradients import MODES
from so3jax.sim.margins import alpha_of_db

TUNE = "tune"  # the campaign's own table; every other entry of the file is the mission's
COST_MODES = ("weighted", "equal_effort")
METHODS = ("gradient", "es")
OBJECTIVES = ("mean", "cvar")


@dataclasses.dataclass(frozen=True)
class ScenarioSet:
    """Scenarios = inertia_scales x seeds: the mission with every inertia matrix scaled
    [-], flown with each seed in place of the mission's. With [tune.dispersions]:
    ``samples`` dispersed missions drawn with the one sampling seed ``seeds[0]`` (training:
    a fresh batch every iteration; validation: one held-out batch)."""

    seeds: tuple[int, ...]  # disturbance and sensor-noise seeds (with dispersions: the one sampling seed)
    inertia_scales: tuple[float, ...] = (1.0,)  # factors on every inertia matrix [-]
    samples: int | None = None  # dispersed missions per batch (with [tune.dispersions])


@dataclasses.dataclass(frozen=True)
class CostConfig:
    """The tuning cost of docs/model.md §6. weight is lambda (weighted) or mu (equal_effort)."""

    mode: str = "weighted"  # weighted: + lambda Effort/Effort_ref; equal_effort: + mu max(0, Effort/budget - 1)^2
    weight: float = 1.0  # lambda (weighted) or mu (equal_effort)
    rmse_ref: float | None = None  # rad/s; None: the initial gains' batch mean
    effort_ref: float | None = None  # N^2 m^2 s, weighted mode; None: initial gains' batch mean
    budget: float | None = None  # N^2 m^2 s, equal_effort mode (or budget_controller)
    budget_controller: str | None = None  # effort budget = this controller's effort, per scenario
    budget_gains: Any = "mission"  # its gains: "mission", "paper", a table, or a best_gains.json path


@dataclasses.dataclass(frozen=True)
class OptimizerConfig:
    """optax.<name>(schedule or learning_rate, **options), clipped by global norm, guarded
    by optax.apply_if_finite. schedule: optax.<schedule>(learning_rate, **schedule_options)."""

    name: str = "adam"  # an optax optimizer taking learning_rate first (adam, sgd, ...)
    learning_rate: float = 0.05  # in log-gain units per step
    options: dict = dataclasses.field(default_factory=dict)  # its other keyword arguments
    schedule: str | None = None  # an optax schedule of the learning rate, e.g. cosine_decay_schedule
    schedule_options: dict = dataclasses.field(default_factory=dict)  # the schedule's keyword arguments
    clip_norm: float = 1.0  # the gradient's global norm is clipped to this


@dataclasses.dataclass(frozen=True)
class ESConfig:
    """Gradient-free baseline: elitist (1+lambda)-ES in log-gain space, 1/5th success rule."""

    population: int = 8  # lambda: candidates per iteration
    sigma: float = 0.2  # initial step, log-gain units
    seed: int = 0  # the candidates' sampling seed


@dataclasses.dataclass(frozen=True)
class DiskMarginConstraint:
    """The sampled loop's multi-loop disk margin (docs/model.md §19.3) held at or above
    min_db at each time ``at`` of each training scenario by a penalty on the cost."""

    min_db: float  # the floor on the disk margin's gain interval +-min_db [dB], in (0, 60] (6 dB: alpha = 0.665)
    at: tuple | None = None  # times [s], whole control periods within [0, T); None: the horizon's last tick
    weight: float = 100.0  # w >= 0: the cost adds w mean(max(0, alpha_req - alpha)^2) / alpha_req^2


@dataclasses.dataclass(frozen=True)
class Constraints:
    """``[tune.constraints]``: constraints on the tuned loop, each a penalty on the cost."""

    disk_margin: DiskMarginConstraint  # e.g. { min_db = 6.0, at = [3999.9], weight = 100.0 }


@dataclasses.dataclass(frozen=True)
class LagrangianConfig:
    """A design campaign's method (docs/model.md §16.6): the augmented Lagrangian on the hard
    goals' log g, and the smooth maximum of the soft goals' log g."""

    penalty: float = 1.0  # rho_0 > 0, the initial penalty on log g of the hard goals
    growth: float = 4.0  # rho *= growth (>= 1) where the hard goals' violation did not fall by a quarter
    update_every: int = 5  # iterations between updates of the multipliers and the penalty
    temperature: float = 0.05  # tau > 0 of the soft goals' smooth maximum, in log g


@dataclasses.dataclass(frozen=True)
class TuneConfig:
    """A tuning campaign: the ``[tune]`` table's fields and the mission it tunes (its
    scenario, loop, controller options and gains; None: the paper's mission)."""

    controller: str | None = None  # a tunable registered controller; None: the mission's first
    iterations: int = 16  # optimizer steps (ES: generations)
    train: ScenarioSet = ScenarioSet(seeds=(0,))  # the training scenarios
    validation: ScenarioSet = ScenarioSet(seeds=(100, 101))  # held-out seeds
    initial_gains: Any = "mission"  # "mission", "paper", a table of gains, or a best_gains.json path
    cost: CostConfig = CostConfig()
    optimizer: OptimizerConfig = OptimizerConfig()
    method: str = "gradient"  # gradient: the optax optimizer; es: the (1+lambda)-ES baseline
    gradient: str = "forward"  # differentiation mode, see so3jax.sim.gradients
    record_every: int | None = None  # checkpoint block of the rollout [steps] (reverse mode memory)
    diagonal_gamma: bool = False  # tune each entry of a gain that may be a diagonal (the adaptive Gamma: 9)
    es: ESConfig = ESConfig()
    objective: str = "mean"  # over the batch's scenario costs: "mean", or "cvar" (the worst 1 - alpha share's mean)
    alpha: float = 0.9  # the CVaR level
    # the sweep's [dispersions] syntax: a fresh batch of dispersed missions per iteration
    dispersions: dict | None = None
    estimator: tuple = ()  # parameters of the mission's estimator tuned beside the gains (its assumed noise levels)
    filter: tuple = ()  # parameters of the mission's structural filter tuned beside the gains (frequency, ...)
    constraints: Constraints | None = None  # [tune.constraints]: penalties on the sampled loop's margins; None: none
    goals: tuple = ()  # [[tune.goals]]: a design campaign's goals (docs/model.md §16.6); none: the cost above
    starts: int = 1  # initial gains run together: the given ones, then draws log-uniform within the bounds
    bounds: dict = dataclasses.field(default_factory=dict)  # {gain: [low, high]}; default a decade either side
    fixed: tuple = ()  # gains held at their initial values
    lagrangian: LagrangianConfig = LagrangianConfig()
    mission: Any = None  # so3jax.missions.mission.Mission

    def __post_init__(self):
        if self.mission is None:
            object.__setattr__(self, "mission", missions.from_dict({}, missions.PAPER))
        if self.controller is None:
            object.__setattr__(self, "controller", self.mission.controllers[0])


SECTIONS = {
    "train": ScenarioSet,
    "validation": ScenarioSet,
    "cost": CostConfig,
    "optimizer": OptimizerConfig,
    "es": ESConfig,
    "constraints": Constraints,
    "lagrangian": LagrangianConfig,
}
CONSTRAINTS = {"disk_margin": DiskMarginConstraint}  # the entries of [tune.constraints]


def _key(name: str) -> str:
    return f"{TUNE}.{name}"


def _build(cls, table: dict, prefix: str, **extra):
    """cls(**table, **extra), with a ValueError naming any unknown or missing key of table."""
    if not isinstance(table, dict):
        raise ValueError(f"config key {prefix.rstrip('.')!r} must be a table, got {checks.short(table)}")  # noqa: TRY004
    fields = {f.name: f for f in dataclasses.fields(cls) if f.name != "mission"}
    for key in table:
        if key not in fields:
            raise ValueError(f"unknown config key '{prefix}{key}' (known: {', '.join(fields)})")
    for name, f in fields.items():
        if name not in table and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ValueError(f"missing config key '{prefix}{name}'")
    values = {}
    for key, value in table.items():
        if key in SECTIONS and cls is TuneConfig:
            value = _build(SECTIONS[key], value, f"{prefix}{key}.")
        elif key in CONSTRAINTS and cls is Constraints:
            value = _build(CONSTRAINTS[key], value, f"{prefix}{key}.")
        elif isinstance(value, list) and key in ("seeds", "inertia_scales", "estimator", "filter", "at", "goals",
                                                 "fixed"):
            value = tuple(value)
        elif key in ("seeds", "inertia_scales"):
            raise ValueError(f"config key '{prefix}{key}' must be a non-empty list of numbers, "
                             f"got {checks.short(value)}")
        elif key in ("estimator", "filter") and cls is TuneConfig:
            raise ValueError(f"config key '{prefix}{key}' must be a list of the {key}'s parameters, "
                             f"got {checks.short(value)}")
        values[key] = value
    return cls(**values, **extra)


def _positive(name, value, integer=False, high=None, why=""):
    """value > 0, finite (an integer if ``integer``), at most ``high`` where given (``why``:
    what bounds it, for the message)."""
    ok = isinstance(value, int) if integer else isinstance(value, (int, float))
    if (isinstance(value, bool) or not ok or not checks.finite(value) or value <= 0
            or high is not None and value > high):
        kind = "a positive integer" if integer else "a positive finite number"
        bound = "" if high is None else f" at most {high:g}{why}"
        raise ValueError(f"config key {_key(name)!r} must be {kind}{bound}, got {checks.short(value)}")


def _choice(name, value, choices):
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"config key {_key(name)!r} must be one of {choices}, got {checks.short(value)}")


def _check_kwargs(fn, options, where: str) -> None:
    """The keyword options of an optax function, each of the type of its default (a
    number, true or false) where it has one, a number where it is annotated int or float.
    A table is required; options without a typed default are left to the call."""
    where = _key(where)
    if not isinstance(options, dict):
        got = checks.short(options)
        raise ValueError(f"config key {where!r} must be a table of keyword arguments, got {got}")  # noqa: TRY004
    parameters = inspect.signature(fn).parameters
    for key, value in options.items():
        p = parameters.get(key)
        if p is None:
            continue  # the call names it
        default = p.default
        if isinstance(default, bool) or p.annotation in (bool, "bool"):
            checks.boolean(value, f"config key '{where}.{key}'")
        elif (isinstance(default, (int, float)) or p.annotation in (int, float, "int", "float")) and (
            isinstance(value, bool) or not isinstance(value, (int, float))
        ):
            raise ValueError(f"config key '{where}.{key}' must be a number, got {checks.short(value)}")


def make_optimizer(config: OptimizerConfig, clip: bool = True) -> optax.GradientTransformation:
    """apply_if_finite(chain(clip_by_global_norm, optax.<name>(schedule, **options)));
    ``clip`` False: optax.<name>(schedule, **options) alone (a caller that clips its own)."""
    _positive("optimizer.learning_rate", config.learning_rate)
    _positive("optimizer.clip_norm", config.clip_norm)
    name_key = _key("optimizer.name")
    factory = getattr(optax, config.name, None) if isinstance(config.name, str) else None
    if not callable(factory) or next(iter(inspect.signature(factory).parameters), None) != "learning_rate":
        raise ValueError(f"config key {name_key!r}: {checks.short(config.name)} is not an optax optimizer "
                         "(e.g. adam, sgd)")
    _check_kwargs(factory, config.options, "optimizer.options")
    learning_rate = config.learning_rate
    if config.schedule is not None:
        schedule = getattr(optax, config.schedule, None) if isinstance(config.schedule, str) else None
        if not callable(schedule):
            raise ValueError(f"config key {_key('optimizer.schedule')!r}: {checks.short(config.schedule)} "
                             "is not an optax schedule")
        _check_kwargs(schedule, config.schedule_options, "optimizer.schedule_options")
        try:
            learning_rate = schedule(config.learning_rate, **config.schedule_options)
            learning_rate(0)
        except (TypeError, ValueError) as err:
            raise ValueError(f"config key {_key('optimizer.schedule_options')!r}: {err}") from err
    try:
        inner = factory(learning_rate, **config.options)
    except TypeError as err:
        raise ValueError(f"config key {_key('optimizer.options')!r}: {err}") from err
    # Large enough never to give up: the loop stops at the first non-finite gradient.
    tx = inner if not clip else optax.apply_if_finite(
        optax.chain(optax.clip_by_global_norm(config.clip_norm), inner), 2**30)
    try:  # an optimizer that needs more than (grad, value), e.g. lbfgs's value_fn
        probe = jnp.zeros(2)
        with jax.numpy_dtype_promotion("standard"):  # optax mixes int32 step counts with floats
            tx.update(probe, tx.init(probe), probe, value=jnp.zeros(()))
    except Exception as err:  # any failure on a trivial update disqualifies it
        raise ValueError(f"config key {name_key!r}: optax.{config.name} cannot be used here: {err}") from err
    return tx


def validate(config: TuneConfig) -> None:
    """Every check that can run before compilation (docs/model.md §6 style: a clear ValueError)."""
    _choice("controller", config.controller, tuple(CONTROLLERS))
    _choice("method", config.method, METHODS)
    _choice("gradient", config.gradient, MODES)
    _choice("cost.mode", config.cost.mode, COST_MODES)
    _choice("objective", config.objective, OBJECTIVES)
    checks.number(config.alpha, f"config key {_key('alpha')!r}", low=0.0, high=1.0)
    if not 0.0 < config.alpha < 1.0:
        raise ValueError(f"config key {_key('alpha')!r} must lie strictly between 0 and 1, got {config.alpha}")
    _positive("iterations", config.iterations, integer=True)
    if config.record_every is not None:
        _positive("record_every", config.record_every, integer=True)
    for section in ("train", "validation"):
        scenarios = getattr(config, section)
        if not scenarios.seeds or not all(
            isinstance(s, int) and not isinstance(s, bool) and 0 <= s < 2**31 for s in scenarios.seeds
        ):
            raise ValueError(f"config key {_key(section + '.seeds')!r} must be a non-empty list of integers "
                             "in [0, 2^31)")
        if not scenarios.inertia_scales:
            raise ValueError(f"config key {_key(section + '.inertia_scales')!r} must be a non-empty list")
        for scale in scenarios.inertia_scales:
            _positive(f"{section}.inertia_scales", scale)
    if not isinstance(config.mission, missions.Mission):
        got = checks.short(config.mission)
        raise ValueError(f"a campaign's mission must be a so3jax Mission, got {got}")  # noqa: TRY004
    _check_dispersions(config)
    _check_estimator(config)
    _check_filter(config)
    _check_constraints(config)
    _check_design(config)
    held_out = set(config.train.seeds) & set(config.validation.seeds)
    if held_out:
        raise ValueError(f"config key {_key('validation.seeds')!r} must be held out of {_key('train.seeds')}; "
                         f"both have {sorted(held_out)}")
    cost = config.cost
    _positive("cost.weight", cost.weight)
    for key in ("rmse_ref", "effort_ref", "budget"):
        if getattr(cost, key) is not None:
            _positive(f"cost.{key}", getattr(cost, key))
    if cost.mode == "equal_effort" and (cost.budget is None) == (cost.budget_controller is None):
        raise ValueError(f"equal_effort cost needs exactly one of config keys {_key('cost.budget')!r}, "
                         f"{_key('cost.budget_controller')!r}")
    if cost.budget_controller is not None:
        _choice("cost.budget_controller", cost.budget_controller, tuple(CONTROLLERS))
    checks.boolean(config.diagonal_gamma, f"config key {_key('diagonal_gamma')!r}")
    if config.diagonal_gamma and not diagonals(config.controller):
        raise ValueError(f"config key {_key('diagonal_gamma')!r}: no gain of the {config.controller} controller "
                         "may be a diagonal")
    for key, controller, spec in (
        ("initial_gains", config.controller, config.initial_gains),
        ("cost.budget_gains", cost.budget_controller, cost.budget_gains),
    ):
        if controller is not None:
            try:
                diagonal = config.diagonal_gamma and key == "initial_gains"
                resolve_gains(controller, spec, jnp.result_type(float), diagonal, config.mission)
            except (OSError, ValueError) as err:
                raise ValueError(f"config key {_key(key)!r}: {err}") from None
    make_optimizer(config.optimizer)
    _positive("es.population", config.es.population, integer=True)
    _positive("es.sigma", config.es.sigma)
    checks.number(config.es.seed, f"config key {_key('es.seed')!r}", low=0, high=2**32 - 1, integer=True)


def _check_dispersions(config: TuneConfig) -> None:
    """[tune.dispersions]: parsed against the mission; then each scenario set names one
    sampling seed and its sample count, with no inertia scales, and the method is the
    gradient's (the ES's elitist selection would compare costs across batches)."""
    for section in ("train", "validation"):
        s = getattr(config, section)
        if config.dispersions is None:
            if s.samples is not None:
                raise ValueError(f"config key {_key(section + '.samples')!r} draws dispersed missions: "
                                 f"it needs a [{TUNE}.dispersions] table")
            continue
        _positive(f"{section}.samples", s.samples, integer=True)
        if len(s.seeds) != 1 or tuple(s.inertia_scales) != (1.0,):
            raise ValueError(f"with [{TUNE}.dispersions], {_key(section + '.seeds')} holds one sampling seed and "
                             f"{_key(section + '.inertia_scales')} is not given (the dispersions scale the inertias)")
    if config.dispersions is None:
        return
    if not isinstance(config.dispersions, dict):
        raise ValueError(f"config key {_key('dispersions')!r} must be a table, got {checks.short(config.dispersions)}")
    if config.method != "gradient":
        raise ValueError(f"config key {_key('dispersions')!r} needs {_key('method')} = \"gradient\": a fresh batch "
                         "every iteration, where the ES's elitist selection would compare costs of different batches")
    try:
        _, leaves = draw.parse(config.dispersions, config.mission)
    except ValueError as err:
        message = str(err)  # names the sweep's key, dispersions.X: here it is the campaign's
        raise ValueError(f"{TUNE}.{message}" if message.startswith("dispersions.") else
                         f"{_key('dispersions')}: {message}") from None
    _check_samples(config, leaves)


def _check_samples(config: TuneConfig, leaves: tuple) -> None:
    """The dispersed missions a campaign draws: sample indices within
    :data:`~so3jax.missions.draw.MAX_SAMPLES` (training: samples x iterations), and
    each batch within the memory available, before anything is drawn."""
    for section, count in (("train", config.train.samples * config.iterations),
                           ("validation", config.validation.samples)):
        if count > draw.MAX_SAMPLES:
            raise ValueError(f"{_key(section + '.samples')} draws {count} dispersed missions"
                             f"{' over the iterations' if section == 'train' else ''}, more than the "
                             f"{draw.MAX_SAMPLES} a sampling seed numbers; lower it")
        samples = getattr(config, section).samples
        memory.check(batched.samples_bytes(leaves, samples, jnp.result_type(float)), None,
                     f"{_key(section + '.samples')} = {samples} dispersed missions",
                     f"lower {_key(section + '.samples')}")


def constraint_times(config: TuneConfig) -> tuple:
    """The times [s] of the disk-margin constraint: its ``at``, or the horizon's last tick."""
    at = config.constraints.disk_margin.at
    mission = config.mission
    return tuple(float(t) for t in at) if at is not None else (round(mission.T - mission.period, 12),)


def _check_constraints(config: TuneConfig) -> None:
    """[tune.constraints]: a disk-margin floor min_db > 0 with a weight >= 0 at ticks within
    the horizon of a sampled loop, in a gradient campaign on the gains alone over fixed
    scenario sets (no dispersions, ES or tuned estimator: refused, not half-supported)."""
    if config.constraints is None:
        return
    if not isinstance(config.constraints, Constraints):
        raise ValueError(f"config key {_key('constraints')!r} must be a table, "  # noqa: TRY004
                         f"got {checks.short(config.constraints)}")
    margin = config.constraints.disk_margin
    if not isinstance(margin, DiskMarginConstraint):
        raise ValueError(f"config key {_key('constraints.disk_margin')!r} must be a table "  # noqa: TRY004
                         f"{{ min_db, at, weight }}, got {checks.short(margin)}")
    where = "constraints.disk_margin"
    for key, why in ((config.method != "gradient", f"{_key('method')} = \"es\" (the constraint's penalty is "
                      "differentiated: a gradient campaign only)"),
                     (config.dispersions is not None, f"[{TUNE}.dispersions] (its nominal flights are the fixed "
                      "training scenarios')"),
                     (bool(config.estimator), f"{_key('estimator')} (the loop is linearized with the mission's "
                      "estimator)"),
                     (bool(config.filter), f"{_key('filter')} (the loop is linearized with the mission's "
                      "filter)")):
        if key:
            raise ValueError(f"config key {_key(where)!r} cannot be combined with {why}")
    mission = config.mission
    if mission.period_steps is None:
        raise ValueError(f"config key {_key(where)!r} needs a sampled loop (control.mode = \"sampled\"): "
                         "the mission's control is continuous")
    _positive(f"{where}.min_db", margin.min_db, high=MAX_DB,
              why=f" dB (alpha = {alpha_of_db(MAX_DB):.4g}: the disk margin alpha stays below 2)")
    checks.number(margin.weight, f"config key {_key(where + '.weight')!r}", low=0.0)
    at = margin.at
    if at is not None and (not isinstance(at, tuple) or not at or not all(
            isinstance(t, (int, float)) and not isinstance(t, bool) for t in at)):
        raise ValueError(f"config key {_key(where + '.at')!r} must be a non-empty list of times [s], "
                         f"got {checks.short(at)}")
    period = mission.period
    for t in constraint_times(config):
        if not (checks.finite(t) and 0 <= t < mission.T):
            raise ValueError(f"config key {_key(where + '.at')!r}: t = {t:g} s is outside the horizon "
                             f"[0, {mission.T:g}) s")
        if abs(t - round(t / period) * period) > 1e-9 * max(period, abs(t)):
            raise ValueError(f"config key {_key(where + '.at')!r}: t = {t:g} s is not a whole number of control "
                             f"periods ({period:g} s)")
        formed_before(mission, t, f"config key {_key(where + '.at')!r}")


DESIGN_KEYS = ("goals", "starts", "bounds", "fixed", "lagrangian")  # a design campaign's [tune] keys


def _check_design(config: TuneConfig) -> None:
    """A design campaign: goals over dispersed missions (jobs.tune.goals), flown by the
    gradient method, without the cost's table, constraints or a tuned estimator; starts >= 1,
    bounds 0 < low < high on the law's gains (0 <= low for a nonnegative one), fixed gains named."""
    if not config.goals:
        given = [k for k in DESIGN_KEYS if getattr(config, k) != getattr(TuneConfig, k, None)
                 and k not in ("goals", "bounds", "fixed")] + [k for k in ("bounds", "fixed") if getattr(config, k)]
        if given:
            raise ValueError(f"config key {_key(given[0])!r} belongs to a design campaign: it needs [[{TUNE}.goals]]")
        return
    parse_goals(list(config.goals), config.mission)
    for refused, why in ((config.dispersions is None, f"a [{TUNE}.dispersions] table (the goals hold over a batch "
                          "of dispersed missions)"),):
        if refused:
            raise ValueError(f"config key {_key('goals')!r} needs {why}")
    for given, key in ((config.method != "gradient", "method"), (config.constraints is not None, "constraints"),
                       (bool(config.estimator), "estimator"), (bool(config.filter), "filter"),
                       (config.cost != CostConfig(), "cost"),
                       (config.objective != "mean", "objective")):
        if given:
            raise ValueError(f"config key {_key(key)!r} cannot be combined with [[{TUNE}.goals]]: a design campaign "
                             "minimizes its soft goals under its hard ones (margins and budgets are goals)")
    _positive("starts", config.starts, integer=True)
    lagrangian = config.lagrangian
    for key in ("penalty", "temperature"):
        _positive(f"lagrangian.{key}", getattr(lagrangian, key))
    checks.number(lagrangian.growth, f"config key {_key('lagrangian.growth')!r}", low=1.0, high=1e6)
    _positive("lagrangian.update_every", lagrangian.update_every, integer=True)
    fields = registry.get(config.controller).gains_type._fields
    if not isinstance(config.bounds, dict):
        raise ValueError(f"config key {_key('bounds')!r} must be a table {{gain = [low, high]}}, "  # noqa: TRY004
                         f"got {checks.short(config.bounds)}")
    for name, pair in config.bounds.items():
        where = _key(f"bounds.{name}")
        if name not in fields:
            raise ValueError(f"config key {where!r}: the {config.controller} controller has no gain {name!r} "
                             f"({', '.join(fields)})")
        nonnegative = isinstance(gain_domain(registry.get(config.controller).gains_type, name), Nonnegative)
        if (not isinstance(pair, list) or len(pair) != 2 or not all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and checks.finite(x) for x in pair)):
            raise ValueError(f"config key {where!r} must be [low, high], got {checks.short(pair)}")
        low, high = pair
        if not (low >= 0 if nonnegative else low > 0) or not low < high:
            floor = "0 <= low" if nonnegative else "0 < low"
            raise ValueError(f"config key {where!r} must have {floor} < high, got [{low:g}, {high:g}]")
    checks.names(list(config.fixed), f"config key {_key('fixed')!r}", fields) if config.fixed else None
    if set(config.fixed) >= set(fields):
        raise ValueError(f"config key {_key('fixed')!r} holds every gain: nothing is left to tune")


def tunable_estimator(mission) -> tuple:
    """The parameters of the mission's estimator that can be tuned: positive real numbers."""
    kind = mission.estimator["kind"]
    return tuple(p.name for p in components.get("estimator", kind).params
                 if p.shapes == ((),) and p.low >= 0.0 and not (p.integer or p.boolean or p.choices))


def _check_tuned(table: str, names, kind: str, tunable: tuple, built) -> None:
    """tune.estimator or tune.filter (``table``): distinct names among the component's
    ``tunable`` parameters, each positive (every element) in the component the loop
    ``built``, since their logarithms are tuned."""
    where = _key(table)
    if not all(isinstance(n, str) for n in names) or len(set(names)) != len(names):
        raise ValueError(f"config key {where!r} must list distinct parameter names, got {checks.short(list(names))}")
    for name in names:
        if name not in tunable:
            raise ValueError(f"config key {where!r}: the mission's {table} {kind!r} has no tunable parameter "
                             f"{name!r} (tunable: {', '.join(tunable) or 'none'})")
    for name in names:
        if not np.all(np.asarray(getattr(built, name)) > 0.0):
            raise ValueError(f"config key {where!r}: {name} is 0 in the mission; its logarithm is tuned, so it "
                             "must start positive")


def _check_estimator(config: TuneConfig) -> None:
    """tune.estimator: distinct tunable parameters of the mission's estimator, each positive
    as the loop builds it (their logarithms are tuned)."""
    if config.estimator:
        _check_tuned("estimator", config.estimator, config.mission.estimator["kind"],
                     tunable_estimator(config.mission), config.mission.loop(jnp.result_type(float)).estimator)


def tunable_filter(mission) -> tuple:
    """The parameters of the mission's structural filter that can be tuned (positive reals,
    each one number or one per phase): frequency, zeta_pole and a notch's zeta_zero."""
    kind = mission.filter["kind"]
    return tuple(p.name for p in components.get("filter", kind).params if p.name in filters.TUNABLE)


def _check_filter(config: TuneConfig) -> None:
    """tune.filter: distinct tunable parameters of the mission's structural filter, each
    positive as the loop builds it (their logarithms are tuned); the frequency below
    NYQUIST_SHARE of the Nyquist frequency 1 / (2 Delta_c) (the tuner holds it there)."""
    names = config.filter
    if not names:
        return
    where = _key("filter")
    kind = config.mission.filter["kind"]
    if kind == "none":
        raise ValueError(f"config key {where!r}: the mission has no structural filter (filter.kind = \"none\"); "
                         "give it one ([filter] kind = \"notch\" or \"lowpass\") or leave tune.filter out")
    structural = config.mission.loop(jnp.result_type(float)).filter
    _check_tuned("filter", names, kind, tunable_filter(config.mission), structural)
    high = NYQUIST_SHARE * 0.5 / config.mission.period
    if "frequency" in names and np.any(np.asarray(structural.frequency) >= high):
        raise ValueError(f"config key {where!r}: filter.{kind}.frequency = "
                         f"{float(np.max(structural.frequency)):g} Hz must start below {high:g} Hz, "
                         f"{NYQUIST_SHARE:g} of the Nyquist frequency {0.5 / config.mission.period:g} Hz of the "
                         "control period, where a tuned frequency is held")


def tune_table(config: TuneConfig) -> dict:
    """The ``[tune]`` table of a config, every field (defaults included) but those of a
    feature the campaign does not use (no dispersions: their table and sample counts; the
    mean objective: alpha; no tuned estimator; no constraints), which change nothing it computes."""
    table = {f.name: (dataclasses.asdict(v) if dataclasses.is_dataclass(v) else v)
             for f in dataclasses.fields(config) if f.name != "mission" for v in [getattr(config, f.name)]}
    if config.dispersions is None:
        del table["dispersions"]
        for section in ("train", "validation"):
            del table[section]["samples"]
    if config.objective == "mean":
        del table["objective"], table["alpha"]
    if not config.estimator:
        del table["estimator"]
    if not config.filter:
        del table["filter"]
    if config.constraints is None:
        del table["constraints"]
    if not config.goals:
        for key in DESIGN_KEYS:
            del table[key]
    return table


def describe(config: TuneConfig) -> dict:
    """What fixes a campaign's results: its mission (less the trajectory sampling, which
    no tuning rollout records), its [tune] table and the precision of the run."""
    mission = {k: v for k, v in config.mission.describe().items() if k != "record_every"}
    return {"mission": mission, TUNE: tune_table(config), "precision": str(jnp.dtype(jnp.result_type(float)))}


def parse_config(table: dict, base_dir=".", base: dict = missions.PAPER) -> TuneConfig:
    """A validated TuneConfig from a campaign's tables: ``mission`` (a mission file relative
    to base_dir) and/or mission tables over ``base``, and ``[tune]``; gain-file paths
    relative to base_dir."""
    if not isinstance(table, dict):
        raise ValueError(f"a campaign must be a table, got {checks.short(table)}")  # noqa: TRY004 (bad input)
    table = json.loads(json.dumps(table))  # a deep copy
    mission, jobs = missions.load_job(table, base_dir, (TUNE,), base)
    tune = jobs.get(TUNE, {})  # every [tune] key has a default: a mission file alone is a campaign
    cost = tune.get("cost") if isinstance(tune, dict) else None
    for holder, key in ((tune, "initial_gains"), (cost, "budget_gains")):
        value = holder.get(key) if isinstance(holder, dict) else None
        if isinstance(value, str) and value.endswith(".json"):
            holder[key] = str((Path(base_dir) / value).resolve())
    config = _build(TuneConfig, tune, f"{TUNE}.", mission=mission)
    validate(config)
    return config


def load_config(path, overrides=()) -> TuneConfig:
    """Read a TOML campaign file and apply (dotted key, value) overrides: mission keys
    (``T``, ``gains.pd.k_R``) or ``tune.*`` keys."""
    table = cfg.read_toml(path)
    for key, value in overrides:
        cfg.set_dotted(table, key, value)
    return parse_config(table, Path(path).parent)
