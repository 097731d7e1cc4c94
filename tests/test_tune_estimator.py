"""The estimator's assumed noise levels tuned beside the gains ([tune] estimator): the
tuned parameters' layout, the derivative of the cost with respect to them against
central differences through the sensors, the MEKF and the zero-order hold, the dispersed
path against the same mission written with those values, and the config's checks."""

import jax.numpy as jnp
import numpy as np
import pytest

from so3jax.controllers.pd import PDGains
from so3jax.jobs.tune.config import parse_config
from so3jax.jobs.tune.cost import CostRefs, cost_and_grad
from so3jax.jobs.tune.gains import split, tables, to_gains, to_params, with_estimator
from so3jax.jobs.tune.problem import build_problem
from so3jax.missions import batched, draw
from so3jax.missions import mission as missions

pytestmark = pytest.mark.filterwarnings("ignore::so3jax.dynamics.inertia.InertiaWarning")

NAMES = ("arw", "sigma_st", "sigma_b0")


def _campaign(**tune):
    table = {"T": 3.0, "controllers": ["pd"],
             "tune": {"controller": "pd", "iterations": 1, "estimator": list(NAMES), "train": {"seeds": [0]},
                      "validation": {"seeds": [5]}, "cost": {"mode": "weighted"}, **tune}}
    return parse_config(table, ".", missions.FLIGHT)


def test_the_tuned_parameters_are_the_gains_then_the_estimator_s():
    gains = PDGains(jnp.asarray(0.5), jnp.asarray(25.0))
    tuned = with_estimator(gains, {"arw": jnp.asarray(1e-6), "sigma_st": jnp.asarray(3e-5)})
    assert tuned._fields == ("k_R", "k_Omega", "estimator_arw", "estimator_sigma_st")
    back, believed = split(to_gains(to_params(tuned)))
    np.testing.assert_allclose([*back, *believed.values()], [0.5, 25.0, 1e-6, 3e-5], rtol=1e-14)
    assert type(back) is PDGains and with_estimator(gains, {}) is gains and split(gains) == (gains, {})
    assert tables(tuned) == {"gains": {"k_R": 0.5, "k_Omega": 25.0}, "estimator": {"arw": 1e-6, "sigma_st": 3e-5}}


def test_the_cost_s_derivative_in_the_assumed_noise_matches_central_differences():
    """Forward mode (the tuner's default) through two flight-loop rollouts, T = 3 s."""
    config = _campaign()
    problem = build_problem(config)
    est = problem.loop.estimator
    initial = with_estimator(PDGains(jnp.asarray(0.5714), jnp.asarray(25.0)),
                             {n: jnp.asarray(getattr(est, n)) for n in NAMES})
    refs = CostRefs(jnp.asarray(1e-2), jnp.asarray(0.2), jnp.asarray(1.0))
    controller = config.mission.controller("pd")[0]

    def run(params):
        return cost_and_grad(params, problem.scenario, controller, problem.train, refs, "weighted", "forward", None,
                             None, problem.loop)

    params = to_params(initial)
    _, grad = run(params)
    h = 1e-4
    for i, name in enumerate(initial._fields):
        step = lambda d: type(params)(*(p + d if j == i else p for j, p in enumerate(params)))
        central = (float(run(step(h))[0].cost) - float(run(step(-h))[0].cost)) / (2 * h)
        assert float(grad[i]) == pytest.approx(central, rel=1e-4, abs=1e-9), name
    assert all(float(grad[i]) != 0.0 for i in range(len(params)))


@pytest.mark.slow
def test_dispersed_missions_fly_the_tuned_filter():
    """sample_metrics(estimator=...) equals the mission written with those noise levels."""
    values = {"arw": 2e-6, "sigma_st": 5e-5}
    mission = missions.from_dict({"T": 1.0, "controllers": ["pd"]}, missions.FLIGHT)
    written = missions.from_dict({"T": 1.0, "controllers": ["pd"], "estimator": {"mekf": values}}, missions.FLIGHT)
    parsed, leaves = draw.parse({"seed": "random", "sensors.gyro.arw": 1.5e-6}, mission)
    inputs = batched.inputs(draw.draw(parsed, leaves, 0, 2, 20), jnp.float64)
    gains = PDGains(jnp.asarray(0.5714), jnp.asarray(25.0))
    run = lambda m, **kw: batched.sample_metrics(inputs, gains, controller=m.controller("pd")[0], mission=m, **kw)
    tuned = run(mission, estimator={k: jnp.asarray(v) for k, v in values.items()})
    np.testing.assert_allclose(tuned["attitude_estimation_rms"], run(written)["attitude_estimation_rms"], rtol=1e-12)
    assert not np.allclose(tuned["attitude_estimation_rms"], run(mission)["attitude_estimation_rms"], rtol=1e-6)


@pytest.mark.parametrize(("estimator", "message"), [
    (["theta0"], "no tunable parameter 'theta0'"),
    (["arw", "arw"], "distinct"),
    ("arw", "must be a list"),
    (["bogus"], "no tunable parameter"),
])
def test_bad_estimator_entries_are_refused_in_one_line(estimator, message):
    with pytest.raises(ValueError, match=message):
        _campaign(estimator=estimator)


def test_a_parameter_at_zero_or_a_loop_without_a_filter_is_refused():
    table = {"T": 3.0, "controllers": ["pd"], "estimator": {"kind": "truth"},
             "tune": {"controller": "pd", "iterations": 1, "estimator": ["arw"], "train": {"seeds": [0]},
                      "validation": {"seeds": [5]}}}
    with pytest.raises(ValueError, match="estimator 'truth' has no tunable parameter"):
        parse_config(table, ".", missions.FLIGHT)
    table["estimator"] = {"kind": "mekf", "mekf": {"rrw": 0.0}}
    table["tune"]["estimator"] = ["rrw"]
    with pytest.raises(ValueError, match="rrw is 0 in the mission"):
        parse_config(table, ".", missions.FLIGHT)
