"""Tuning over dispersed missions ([tune.dispersions]) for the mean or the CVaR of the
costs: the CVaR against a sort of the costs and its gradient against central
differences; a campaign's fresh batch every iteration, its held-out batch, its report,
and a resume equal to an uninterrupted run."""

import csv

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from so3jax.jobs import tune
from so3jax.jobs.tune import campaign
from so3jax.jobs.tune.cost import cvar
from so3jax.jobs.tune.problem import batch_at, build_problem
from so3jax.missions import draw

pytestmark = pytest.mark.filterwarnings("ignore::so3jax.dynamics.inertia.InertiaWarning")

COSTS = np.array([3.0, 0.5, 7.0, 1.5, 2.0, 9.0, 4.0, 0.1, 6.0, 5.0, 8.0, 2.5, 1.0, 3.5, 4.5, 6.5, 7.5, 0.7, 5.5, 9.5])


@pytest.mark.parametrize("alpha", [0.9, 0.75, 0.5, 0.05])
def test_cvar_is_the_mean_of_the_worst_share(alpha):
    """(1 - alpha) B a whole number: the mean of the (1 - alpha) B largest costs."""
    worst = int(round((1 - alpha) * len(COSTS)))
    assert float(cvar(jnp.asarray(COSTS), alpha)) == pytest.approx(np.sort(COSTS)[-worst:].mean(), rel=1e-14)


def test_cvar_minimizes_the_rockafellar_uryasev_function_and_skips_masked_costs():
    """Any alpha: the minimum over t of t + mean((c - t)+) / (1 - alpha), attained at a
    cost (the function is piecewise linear and convex); masked costs count for nothing."""
    alpha = 0.83
    ru = lambda c, t: t + np.mean(np.maximum(c - t, 0.0)) / (1 - alpha)
    assert float(cvar(jnp.asarray(COSTS), alpha)) == pytest.approx(min(ru(COSTS, t) for t in COSTS), rel=1e-14)
    valid = np.arange(len(COSTS)) % 3 != 0
    kept = COSTS[valid]
    got = float(cvar(jnp.asarray(np.where(valid, COSTS, 1e9)), alpha, jnp.asarray(valid)))
    assert got == pytest.approx(min(ru(kept, t) for t in kept), rel=1e-14)


@pytest.mark.parametrize("alpha", [0.8, 0.83])
def test_cvar_gradient_agrees_with_central_differences(alpha):
    """Smooth costs of two parameters, at a point where the tail set does not change; with
    a whole (1 - alpha) B and without (the VaR cost's fractional weight)."""
    a = jnp.asarray(COSTS)
    b = jnp.asarray(np.cos(np.arange(len(COSTS))))

    def objective(theta):
        costs = a * jnp.exp(0.1 * theta[0]) + b * theta[1] ** 2
        return cvar(costs, alpha)

    theta = jnp.asarray([0.3, -0.4])
    grad = jax.grad(objective)(theta)
    h = 1e-6
    for i in range(2):
        e = jnp.zeros(2).at[i].set(h)
        central = (objective(theta + e) - objective(theta - e)) / (2 * h)
        assert float(grad[i]) == pytest.approx(float(central), rel=1e-7)
    assert float(grad[0]) != 0.0


CAMPAIGN = {
    "T": 1.0,
    "tune": {
        "controller": "pd", "iterations": 2, "objective": "cvar", "alpha": 0.5,
        "train": {"seeds": [0], "samples": 4}, "validation": {"seeds": [1], "samples": 4},
        "cost": {"mode": "weighted"}, "optimizer": {"learning_rate": 0.1},
        "dispersions": {
            "seed": "random",
            "deployment": {"tau_J": {"dist": "uniform", "low": 200.0, "high": 400.0}},
            "initial": {"rate": {"norm": {"dist": "uniform", "low": 0.0, "high": 0.05}}},
        },
    },
}


def _history(out):
    with open(out / "history.csv") as f:
        return [{k: v for k, v in row.items() if k != "wall_s"} for row in csv.DictReader(f)]


def test_a_dispersed_campaign_draws_a_fresh_batch_each_iteration_and_resumes_as_it_ran(tmp_path, monkeypatch):
    config = tune.parse_config(CAMPAIGN)
    problem = build_problem(config)
    # iteration i trains on samples 4i .. 4i + 3 of sampling seed 0; validation on seed 1's first 6
    drawn = draw.draw(problem.sampler.dispersions, problem.sampler.leaves, 0, 4, 20, first=8)
    np.testing.assert_array_equal(batch_at(config, problem, 2).params.tau_J, drawn.params.tau_J)  # samples 8-11
    assert not np.array_equal(batch_at(config, problem, 0).params.tau_J, batch_at(config, problem, 1).params.tau_J)
    held_out = draw.draw(problem.sampler.dispersions, problem.sampler.leaves, 1, 4, 20)
    np.testing.assert_array_equal(problem.validation.params.tau_J, held_out.params.tau_J)

    report = tune.tune(config, tmp_path / "straight", progress=False)
    assert report["training"]["scenarios"] == {"dispersed_missions_per_iteration": 4, "sampling_seed": 0,
                                               "objective": "cvar", "alpha": 0.5}
    assert report["scenarios"] == {"dispersed_missions": 4, "sampling_seed": 1}
    assert report["cost"]["objective"] == "cvar" and report["cost"]["alpha"] == 0.5
    assert report["initial"]["p95_rmse"] > 0 and len(report["tuned"]["rmse"]) == 4
    assert report["training"]["best_iteration"] == 1  # the last iterate: costs of fresh batches do not compare
    rows = _history(tmp_path / "straight")
    assert len({row["k_R"] for row in rows}) == 2

    original, calls = campaign.cost_and_grad, []

    def interrupted(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:  # the second iteration
            raise KeyboardInterrupt
        return original(*args, **kwargs)

    monkeypatch.setattr(campaign, "cost_and_grad", interrupted)
    with pytest.raises(KeyboardInterrupt):
        tune.tune(config, tmp_path / "resumed", progress=False)
    monkeypatch.setattr(campaign, "cost_and_grad", original)
    tune.tune(config, tmp_path / "resumed", resume=True, progress=False)
    assert _history(tmp_path / "resumed") == rows


@pytest.mark.parametrize(("change", "message"), [
    ({"method": "es"}, "needs tune.method = \"gradient\""),
    ({"train": {"seeds": [0, 1], "samples": 4}}, "holds one sampling seed"),
    ({"train": {"seeds": [0]}}, "tune.train.samples"),
    ({"alpha": 1.0}, "strictly between 0 and 1"),
    ({"objective": "worst"}, "tune.objective"),
    ({"dispersions": {"orbit": {"n": {"dist": "uniform", "low": -1.0, "high": 1.0}}}}, "tune.dispersions"),
])
def test_bad_dispersed_campaigns_are_one_line_errors(change, message):
    table = {**CAMPAIGN, "tune": {**CAMPAIGN["tune"], **change}}
    with pytest.raises(ValueError, match=message) as err:
        tune.parse_config(table)
    assert "\n" not in str(err.value)


def test_samples_without_dispersions_are_an_error():
    table = {"T": 1.0, "tune": {**{k: v for k, v in CAMPAIGN["tune"].items() if k != "dispersions"}}}
    with pytest.raises(ValueError, match=r"needs a \[tune.dispersions\] table"):
        tune.parse_config(table)
