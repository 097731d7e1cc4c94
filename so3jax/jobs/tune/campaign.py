"""A tuning campaign's run: the optimizer loop (gradient or ES) with a checkpoint after
every iteration, resume, and the held-out validation at the end."""

from __future__ import annotations

import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax

from so3jax.jobs.tune import constraints, design
from so3jax.jobs.tune.config import TuneConfig, describe, make_optimizer, validate
from so3jax.jobs.tune.cost import CostRefs, Evaluation, cost_and_grad, cost_summary, population_costs
from so3jax.jobs.tune.gains import gain_columns, resolve_gains, to_gains, to_params, with_estimator
from so3jax.jobs.tune.optimizers import (
    ESState,
    GradientState,
    NonFiniteGradientError,
    es_candidates,
    es_select,
    optax_step,
)
from so3jax.jobs.tune.problem import batch_at, build_problem, cost_refs, evaluate, mission_of
from so3jax.jobs.tune.storage import (
    CHECKPOINT,
    best_history_row,
    check_fingerprint,
    gains_from_row,
    history_row,
    load_checkpoint,
    run_description,
    save_checkpoint,
    write_best_gains,
    write_history,
)
from so3jax.jobs.tune.validation import validate_gains
from so3jax.parallel import distributed
from so3jax.parallel.devices import place
from so3jax.results import io, runfolder
from so3jax.viz.tune import plot_history

# validation.json's units (so3jax.results.units): a cost is relative to its references, a
# disk margin's alpha a ratio; an inertia scale is a ratio.
UNITS = {"rmse": "rad/s", "effort": "N^2 m^2 s", "mean_rmse": "rad/s", "mean_effort": "N^2 m^2 s", "cost": "-",
         "best_cost": "-", "inertia_scale": "-", "min_db": "dB", "db": "dB", "smallest_db": "dB", "alpha": "-",
         "alpha_required": "-", "times": "s", "wall_s": "s", "T": "s", "weight": "-"}


def tune(config: TuneConfig, out, *, resume: bool = False, progress: bool = True) -> dict:
    """Run (or resume) a tuning campaign into folder ``out``; returns validation.json's content.

    Raises NonFiniteGradientError, after saving, when a cost or gradient is not finite.
    """
    validate(config)
    with runfolder.claim(out, "tune", describe(config), resume=resume, lock=distributed.writer()) as run:
        if jax.process_count() > 1:
            run.start()  # the folder every process must see (distributed.check_shared)
        if config.goals:
            if jax.process_count() > 1:
                raise ValueError("a design campaign ([[tune.goals]]) runs in one process")
            return design.run(config, run.out, resume, progress)
        return _tune(config, run.out, resume, progress and distributed.writer())


def _tune(config: TuneConfig, out: Path, resume: bool, progress: bool) -> dict:
    from tqdm import tqdm  # here: only a run that shows progress needs it

    distributed.check_shared(out)  # every process reads the checkpoint to resume
    checkpoint = out / CHECKPOINT
    if checkpoint.exists() and not resume:
        raise ValueError(f"{checkpoint} exists: pass --resume to continue that run, or choose another --out")
    description = run_description(config)
    fingerprint = runfolder.fingerprint(description)
    if resume and checkpoint.exists():  # before any work: another configuration or precision is refused
        check_fingerprint(checkpoint, fingerprint, description)
    problem = build_problem(config)
    controller = config.mission.controller(config.controller)[0]
    dtype = problem.scenario.R0.dtype
    initial = resolve_gains(config.controller, config.initial_gains, dtype, config.diagonal_gamma, config.mission)
    initial = with_estimator(initial, {n: jnp.asarray(getattr(problem.loop.estimator, n), dtype)
                                       for n in config.estimator},
                             {n: jnp.asarray(getattr(problem.loop.filter, n), dtype) for n in config.filter},
                             0.5 / config.mission.period if config.filter else None)  # a filter: a sampled loop
    n_train = config.train.samples or problem.train.seed.shape[0]
    mode = config.cost.mode
    mission = mission_of(problem)
    budget = None  # with dispersions and a budget controller: its gains, flown on every fresh batch
    if mission is not None and mode == "equal_effort" and config.cost.budget_controller is not None:
        budget = resolve_gains(config.cost.budget_controller, config.cost.budget_gains, dtype, mission=config.mission)

    margin = None if config.constraints is None else constraints.MarginConstraint(config, problem)
    train_scales = None if margin is None else constraints.distinct(config.train.inertia_scales)

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
        iteration, state, refs, rows = load_checkpoint(checkpoint, fingerprint, state, refs, description)
        start -= rows[-1]["wall_s"] if rows else 0.0
    else:
        first_batch = batch_at(config, problem, 0)
        initial_metrics = evaluate(problem, initial, first_batch)
        initial_diverged = int(np.sum(initial_metrics.diverged))
        refs = cost_refs(config, problem, initial_metrics, first_batch)
        iteration, rows = 0, []
        if config.method == "es":
            first = cost_summary(initial_metrics, refs, mode, config.objective, config.alpha)
            state = state._replace(cost=first.cost, rmse=first.rmse, effort=first.effort)
    rollouts = rows[-1]["rollouts"] if rows else n_train  # the initial evaluation
    refs = place(refs, problem.mesh)

    bar = tqdm(total=config.iterations, initial=iteration, desc=f"tune {config.controller}", disable=not progress)
    try:
        while iteration < config.iterations:
            state = place(state, problem.mesh)
            batch = batch_at(config, problem, iteration)
            if budget is not None:  # the budget on this batch's missions (common random numbers)
                refs = refs._replace(effort=evaluate(problem, budget, batch, config.cost.budget_controller).effort)
                rollouts += n_train
            if config.method == "gradient":
                evaluation, grad = cost_and_grad(
                    state.params,
                    problem.scenario,
                    controller,
                    batch,
                    refs,
                    mode,
                    config.gradient,
                    problem.record_every,
                    problem.mesh,
                    problem.loop,
                    objective=config.objective,
                    alpha=config.alpha,
                    mission=mission,
                )
                held = {}  # [tune.constraints]: the margin's penalty and gradient, and its history columns
                if margin is not None:
                    penalty, penalty_grad, held = margin.evaluate(state.params, train_scales)
                    evaluation = evaluation._replace(cost=evaluation.cost + penalty)
                    grad = jax.tree.map(jnp.add, grad, penalty_grad)
                new_state = optax_step(tx, state, grad, evaluation.cost)
                rollouts += n_train
                gains = to_gains(state.params)
                row = history_row(
                    iteration,
                    evaluation,
                    gains,
                    time.perf_counter() - start,
                    rollouts,
                    grad_norm=float(optax.tree.norm(grad)),
                    **held,
                )
                finite = bool(new_state.opt_state.last_finite) and math.isfinite(row["cost"])
            else:
                key = jax.random.fold_in(jax.random.key(config.es.seed), iteration)
                candidates = place(es_candidates(state.params, state.sigma, key, config.es.population), problem.mesh)
                evaluations = population_costs(
                    candidates, problem.scenario, controller, batch, refs, mode, problem.record_every,
                    problem.mesh, problem.loop, objective=config.objective, alpha=config.alpha,
                )
                new_state = es_select(state, candidates, evaluations)
                rollouts += config.es.population * n_train
                # a finite cost has no diverged scenario; the parent stays the initial gains until one is finite
                parent_diverged = 0 if math.isfinite(float(new_state.cost)) else initial_diverged
                parent = Evaluation(new_state.cost, new_state.rmse, new_state.effort, parent_diverged)
                row = history_row(
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
                save_checkpoint(checkpoint, fingerprint, iteration, state, refs, rows, description)
                write_history(out, rows)
                write_best_gains(out, config, rows, initial)
            bar.set_postfix(cost=f"{row['cost']:.4g}", rmse=f"{row['rmse']:.3e}", effort=f"{row['effort']:.4g}")
            bar.update(1)
    finally:
        bar.close()

    if distributed.writer():
        plot_history(out, rows, list(gain_columns(initial)),
                     budget=np.asarray(refs.effort) if mode == "equal_effort" else None)
    best_row = best_history_row(rows, config.dispersions is not None)
    best = gains_from_row(best_row, initial)
    report = validate_gains(config, problem, initial, best, refs)
    if margin is not None:
        report["disk_margin"] = constraints.validation_report(margin, config, initial, best)
    report["training"] = {
        "method": config.method,
        "gradient": config.gradient if config.method == "gradient" else None,
        "iterations": iteration,
        "best_iteration": best_row["iteration"],
        "best_cost": best_row["cost"],
        "wall_s": rows[-1]["wall_s"],
        "rollouts": rows[-1]["rollouts"],
        "T": problem.scenario.horizon,
        "scenarios": _training_scenarios(config, problem),
        "refs": {
            "rmse": np.asarray(refs.rmse).tolist(),
            "effort": np.asarray(refs.effort).tolist(),
            "weight": float(refs.weight),
        },
    }
    report["units"] = UNITS
    report = io.to_builtin(report)
    if distributed.writer():
        io.write_json(out / "validation.json", report)
    return report


def _training_scenarios(config: TuneConfig, problem) -> dict:
    """What the training batches were: the scenario set, or the dispersed draws."""
    if problem.train is None:
        return {"dispersed_missions_per_iteration": config.train.samples, "sampling_seed": config.train.seeds[0],
                "objective": config.objective, "alpha": config.alpha if config.objective == "cvar" else None}
    return {"seeds": np.asarray(problem.train.seed).tolist(),
            "inertia_scale": np.asarray(problem.train.inertia_scale).tolist()}
