"""Initial and tuned gains on the held-out scenarios (validation.json), and a markdown
table of such reports."""

from __future__ import annotations

import math

import numpy as np

from so3jax.jobs.tune.config import TuneConfig
from so3jax.jobs.tune.cost import CostRefs, cost_summary
from so3jax.jobs.tune.gains import gains_table, resolve_gains, tables
from so3jax.jobs.tune.problem import Problem, build_problem, evaluate
from so3jax.results import io
from so3jax.sim.metrics import cell, finite_values, reported


def _metrics_table(metrics, valid=None) -> dict:
    """Per-scenario RMSE and effort (None for a diverged scenario, flagged in ``diverged``)
    and their means over the scenarios that did not diverge (None if every one did); of
    dispersed missions (``valid``: the draws that count), also the 95th percentile RMSE."""
    keep = slice(None) if valid is None else np.asarray(valid, bool)
    diverged = np.asarray(metrics.diverged, dtype=bool)[keep]
    rmse, effort = (reported(np.asarray(x)[keep], diverged) for x in (metrics.rmse, metrics.effort))

    def mean(x):
        finite, _ = finite_values(x)
        return float(np.mean(finite)) if len(finite) else None

    table = {
        "rmse": io.to_builtin(rmse),
        "effort": io.to_builtin(effort),
        "diverged": diverged.tolist(),
        "diverged_count": int(np.sum(diverged | ~np.isfinite(rmse) | ~np.isfinite(effort))),
        "mean_rmse": mean(rmse),
        "mean_effort": mean(effort),
    }
    if valid is not None:
        finite, _ = finite_values(rmse)
        table["p95_rmse"] = float(np.percentile(finite, 95)) if len(finite) else None
    return table


def _mean_cost(metrics, refs, mode, objective="mean", alpha=0.9, valid=None):
    """The objective (mean or CVaR) of the docs/model.md §6 costs over the scenarios, None when a
    scenario diverged (its cost is not a number)."""
    cost = float(cost_summary(metrics, refs, mode, objective, alpha, valid).cost)
    counted = np.asarray(metrics.diverged, bool) & (True if valid is None else np.asarray(valid, bool))
    return cost if math.isfinite(cost) and not np.any(counted) else None


def _scenarios(config: TuneConfig, problem: Problem) -> dict:
    batch = problem.validation
    valid = getattr(batch, "valid", None)
    if valid is None:
        return {"seeds": np.asarray(batch.seed).tolist(), "inertia_scale": np.asarray(batch.inertia_scale).tolist()}
    return {"dispersed_missions": int(np.sum(valid)), "sampling_seed": config.validation.seeds[0]}


def _budget(config: TuneConfig, problem: Problem):
    """(report entry, metrics) of the budget controller on the held-out scenarios."""
    batch = problem.validation
    dtype = problem.scenario.R0.dtype
    gains = resolve_gains(config.cost.budget_controller, config.cost.budget_gains, dtype, mission=config.mission)
    metrics = evaluate(problem, gains, batch, config.cost.budget_controller)
    entry = {"controller": config.cost.budget_controller, "gains": gains_table(gains),
             **_metrics_table(metrics, getattr(batch, "valid", None))}
    return entry, metrics


def held_out(config: TuneConfig, gains) -> dict:
    """Fixed gains of ``config.controller`` on the campaign's held-out scenarios (and its
    budget controller there), in validation.json's layout with the gains as ``tuned``."""
    problem = build_problem(config)
    metrics = evaluate(problem, gains, problem.validation)
    report = {"controller": config.controller, "scenarios": _scenarios(config, problem),
              "tuned": {"gains": gains_table(gains),
                        **_metrics_table(metrics, getattr(problem.validation, "valid", None))}}
    if config.cost.budget_controller is not None:
        report["budget"], _ = _budget(config, problem)
    return io.to_builtin(report)


def validate_gains(config: TuneConfig, problem: Problem, initial, best, refs_train: CostRefs) -> dict:
    """Initial and tuned gains (and the budget controller's) on the held-out scenarios.

    The cost there uses the training RMSE_ref / Effort_ref, and a per-scenario budget
    recomputed on the held-out scenarios.
    """
    batch = problem.validation
    valid = getattr(batch, "valid", None)  # dispersed missions: the draws that count
    initial_metrics = evaluate(problem, initial, batch)
    best_metrics = evaluate(problem, best, batch)
    refs = refs_train
    report = {
        "controller": config.controller,
        "scenarios": _scenarios(config, problem),
        "initial": {**tables(initial), **_metrics_table(initial_metrics, valid)},
        "tuned": {**tables(best), **_metrics_table(best_metrics, valid)},
    }
    if config.cost.budget_controller is not None:
        report["budget"], budget_metrics = _budget(config, problem)
        refs = refs._replace(effort=budget_metrics.effort)
    objective = (config.cost.mode, config.objective, config.alpha, valid)
    report["cost"] = {
        "mode": config.cost.mode,
        "objective": config.objective,
        **({"alpha": config.alpha} if config.objective == "cvar" else {}),
        "initial": _mean_cost(initial_metrics, refs, *objective),
        "tuned": _mean_cost(best_metrics, refs, *objective),
    }
    return report


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
            shown = {**entry["gains"], **entry.get("estimator", {}),
                     **{f"filter_{k}": v for k, v in entry.get("filter", {}).items()}}
            gains = ", ".join(f"{k}={gain_text(v)}" for k, v in shown.items())
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


def gain_text(value) -> str:
    """A gain for a table: 4 digits; a list (a diagonal, a schedule) 3 digits per entry."""
    if isinstance(value, list):
        return "[" + ", ".join(f"{v:.3g}" for v in np.ravel(value)) + "]"
    return f"{value:.4g}"
