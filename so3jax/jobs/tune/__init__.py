"""Gain tuning through the simulator: docs/model.md §6 costs, an optax loop with resumable
checkpoints, a gradient-free baseline: the job ``so3jax tune`` (:mod:`so3jax.commands.tune`) runs.

A campaign file is a mission (``mission = "PATH"`` relative to the file, and/or mission
keys and tables inline; default the paper's mission) and a ``[tune]`` table. Its
rollouts fly the mission's scenario through the mission's loop (sensors, estimator,
actuator, control period) with the mission's controller options.

Gains are tuned in log space (p = log g, so every gain stays positive). The cost of
gains g over a batch of B training scenarios (inertia scale x seed, see
:mod:`so3jax.sim.gradients`) is the batch mean of (docs/model.md §6)

    weighted:      RMSE / RMSE_ref + lambda * Effort / Effort_ref
    equal_effort:  RMSE / RMSE_ref + mu * max(0, Effort / Effort_budget - 1)^2

RMSE_ref and Effort_ref default to the initial gains' batch means; Effort_budget is a
number or another controller's effort on the same scenario (e.g. the PD with the
paper's gains), scenario by scenario. ``objective = "cvar"`` replaces the batch mean by
the mean of the worst 1 - alpha share of the scenario costs. With a
``[tune.dispersions]`` table the scenarios are dispersed missions (drawn by
:mod:`so3jax.missions.draw`, flown by :mod:`so3jax.missions.batched`), a fresh batch of them
every iteration. A ``[tune.constraints]`` table adds a penalty on the sampled loop's disk
margin below a floor (:mod:`so3jax.jobs.tune.constraints`).
``estimator = [names]`` tunes positive parameters of the mission's estimator (the noise
levels the MEKF assumes) beside the gains, in log space too
(:func:`so3jax.jobs.tune.gains.with_estimator`); ``filter = [names]`` the mission's structural
filter's frequency and damping ratios by the same mechanism (``filter_NAME``, one value per
phase where the mission gives them per phase, the frequency held below 0.99 of the Nyquist
frequency).

A run folder holds ``checkpoint.npz`` (rewritten atomically after every iteration, so
an interrupted run loses at most one iteration and ``--resume`` continues to the same
result; a resume under another mission, [tune] table or precision is refused),
``best_gains.json``, ``history.csv``, ``history.png`` and ``validation.json`` (initial
and tuned gains on held-out seeds).

A campaign with ``[[tune.goals]]`` is a design campaign (docs/model.md §16.6): the mission's
requirements, disk-margin floors and budgets, each hard or soft and normalized to g =
value / limit over a fixed batch of dispersed missions, minimized from several starts at
once by an augmented Lagrangian, then checked on a held-out batch (design.md, design.json).

Modules: config (TuneConfig, parsing, checks, the campaign's description), goals (a design
campaign's goals), goal_values (their values and derivatives over a batch, for several
starts), design (the design campaign's loop and verdict), design_report (its files), constraints
(the disk-margin penalty and its gradient), gains (the
mission's controllers, gains and log-gains), cost (docs/model.md §6 cost and gradient over a
device mesh), optimizers (optax step, ES), problem (the mission's scenario and loop,
batches on devices, evaluations, normalizers), storage (checkpoint, history, best
gains), campaign (the loop, resume), validation (held-out report, markdown); history.png
is drawn by :mod:`so3jax.viz.tune`.
"""

from so3jax.jobs.tune.campaign import tune
from so3jax.jobs.tune.config import (
    COST_MODES,
    METHODS,
    OBJECTIVES,
    SECTIONS,  # noqa: F401 (tests walk the config's sections)
    TUNE,
    Constraints,
    CostConfig,
    DiskMarginConstraint,
    ESConfig,
    OptimizerConfig,
    ScenarioSet,
    TuneConfig,
    describe,
    load_config,
    make_optimizer,
    parse_config,
    tune_table,
    validate,
)
from so3jax.jobs.tune.cost import (
    CostRefs,
    Evaluation,
    batch_cost_metrics,  # noqa: F401 (tests: the cost's metrics without the gradient)
    cost_and_grad,
    cvar,
    population_costs,
    scenario_costs,
)
from so3jax.jobs.tune.gains import (
    CONTROLLERS,
    GAIN_TYPES,
    PAPER_GAINS,
    diagonals,
    gain_columns,
    gains_table,
    resolve_gains,
    to_gains,
    to_params,
)
from so3jax.jobs.tune.goal_values import GoalValues
from so3jax.jobs.tune.goals import Goal, parse_goals
from so3jax.jobs.tune.optimizers import ESState, GradientState, NonFiniteGradientError, es_candidates, es_select
from so3jax.jobs.tune.problem import MIN_SHARD, Problem, batch_devices, build_problem, cost_refs, evaluate
from so3jax.jobs.tune.storage import (
    CHECKPOINT,
    best_history_row,  # noqa: F401 (tests)
    check_fingerprint,
    load_checkpoint,
    save_checkpoint,
    write_history,
)
from so3jax.jobs.tune.validation import markdown_table, validate_gains
from so3jax.viz.tune import plot_history

__all__ = [
    "CHECKPOINT",
    "CONTROLLERS",
    "COST_MODES",
    "Constraints",
    "CostConfig",
    "CostRefs",
    "DiskMarginConstraint",
    "ESConfig",
    "ESState",
    "Evaluation",
    "GAIN_TYPES",
    "Goal",
    "GoalValues",
    "GradientState",
    "METHODS",
    "OBJECTIVES",
    "MIN_SHARD",
    "NonFiniteGradientError",
    "OptimizerConfig",
    "parse_goals",
    "PAPER_GAINS",
    "Problem",
    "ScenarioSet",
    "TUNE",
    "TuneConfig",
    "batch_devices",
    "build_problem",
    "check_fingerprint",
    "cost_and_grad",
    "cost_refs",
    "cvar",
    "describe",
    "diagonals",
    "es_candidates",
    "es_select",
    "evaluate",
    "gain_columns",
    "gains_table",
    "load_checkpoint",
    "load_config",
    "make_optimizer",
    "markdown_table",
    "parse_config",
    "plot_history",
    "population_costs",
    "resolve_gains",
    "save_checkpoint",
    "scenario_costs",
    "to_gains",
    "to_params",
    "tune",
    "tune_table",
    "validate",
    "validate_gains",
    "write_history",
]
