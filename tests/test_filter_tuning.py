"""The structural filter's parameters tuned and scheduled like gains ([tune] filter, a
[filter] parameter given per phase): the tuned parameters' layout and the Nyquist bound,
the derivative of the tuning cost with respect to the filter's frequency against central
differences, a short campaign that moves them and records them where the estimator's are,
the config's one-line refusals, and a per-phase frequency switched at the phase's first
tick (all-equal values fly bit for bit as the number)."""

import json
import math

import jax.numpy as jnp
import numpy as np
import pytest

from so3jax.controllers.pd import PDGains
from so3jax.jobs.tune import tune
from so3jax.jobs.tune.config import parse_config
from so3jax.jobs.tune.cost import CostRefs, cost_and_grad
from so3jax.jobs.tune.gains import NYQUIST_SHARE, parts, project, tables, to_gains, to_params, with_estimator
from so3jax.jobs.tune.problem import build_problem
from so3jax.missions import batched, draw
from so3jax.missions import mission as missions
from so3jax.sim import loop as loops
from so3jax.sim.rollout import simulate

pytestmark = pytest.mark.filterwarnings("ignore::so3jax.dynamics.inertia.InertiaWarning")

# A rigid body on an inertial reference, sampled at 0.1 s (Nyquist 5 Hz) through a notch on
# the commanded torque at 0.8 Hz, near the PD loop's crossover so the cost feels it.
PERIOD = 0.1
NOTCH = {"frequency": 0.8, "zeta_zero": 0.05, "zeta_pole": 0.5}
MISSION = {"T": 3.0, "dt": 0.05, "seed": 0, "controllers": ["pd"], "control": {"mode": "sampled", "period": PERIOD},
           "sensors": {"gyro": False, "star_tracker": False}, "estimator": {"kind": "truth"},
           "actuator": {"kind": "ideal"}, "momentum": {"kind": "none"},
           "inertia": {"J": [[1.0, 0.0, 0.0], [0.0, 1.2, 0.0], [0.0, 0.0, 0.9]]}, "reference": {"kind": "inertial"},
           "phases": {"names": ["stowed", "deployed", "docked"], "start": [0.0, 1.0, 2.0]},
           "disturbance": {"amplitude": 0.0, "noise_std": 0.0},
           "initial": {"attitude": [0.3, -0.2, 0.1], "rate": [0.0, 0.0, 0.0]},
           "gains": {"pd": {"k_R": 2.0, "k_Omega": 3.0}},
           "filter": {"kind": "notch", "notch": NOTCH}}


def _campaign(filter_table=None, **tune_keys):
    table = {**MISSION, "filter": filter_table or MISSION["filter"],
             "tune": {"controller": "pd", "iterations": 2, "filter": ["frequency", "zeta_pole"],
                      "train": {"seeds": [0]}, "validation": {"seeds": [5]}, "cost": {"mode": "weighted"},
                      **tune_keys}}
    return parse_config(table, ".", missions.FLIGHT)


def test_the_tuned_parameters_are_the_gains_then_the_filter_s_held_below_nyquist():
    gains = PDGains(jnp.asarray(2.0), jnp.asarray(3.0))
    tuned = with_estimator(gains, {}, {"frequency": jnp.asarray(0.8), "zeta_pole": jnp.asarray(0.5)}, 5.0)
    assert tuned._fields == ("k_R", "k_Omega", "filter_frequency", "filter_zeta_pole")
    back, tuned_parts = parts(to_gains(to_params(tuned)))
    assert type(back) is PDGains and tuned_parts["estimator"] == {}
    np.testing.assert_allclose([*back, *tuned_parts["filter"].values()], [2.0, 3.0, 0.8, 0.5], rtol=1e-14)
    assert tables(tuned) == {"gains": {"k_R": 2.0, "k_Omega": 3.0}, "filter": {"frequency": 0.8, "zeta_pole": 0.5}}
    # a step past the bound: projected back to NYQUIST_SHARE of 5 Hz, and flown there
    params = to_params(tuned)._replace(filter_frequency=jnp.log(jnp.asarray(7.0)))
    assert float(to_gains(params).filter_frequency) == pytest.approx(NYQUIST_SHARE * 5.0, rel=1e-14)
    assert float(project(params).filter_frequency) == pytest.approx(math.log(NYQUIST_SHARE * 5.0), rel=1e-14)
    both = with_estimator(gains, {"arw": jnp.asarray(1e-6)}, {"frequency": jnp.asarray(0.8)}, 5.0)
    assert both._fields[2:] == ("estimator_arw", "filter_frequency")


def test_the_cost_s_derivative_in_the_filter_s_frequency_matches_central_differences():
    """Forward mode (the tuner's default) through a rollout with the notch on the torque, T = 3 s."""
    config = _campaign()
    problem = build_problem(config)
    notch = problem.loop.filter
    initial = with_estimator(PDGains(jnp.asarray(2.0), jnp.asarray(3.0)), {},
                             {"frequency": jnp.asarray(notch.frequency), "zeta_pole": jnp.asarray(notch.zeta_pole)},
                             0.5 / PERIOD)
    refs = CostRefs(jnp.asarray(1e-2), jnp.asarray(0.2), jnp.asarray(1.0))
    controller = config.mission.controller("pd")[0]

    def run(params):
        return cost_and_grad(params, problem.scenario, controller, problem.train, refs, "weighted", "forward", None,
                             None, problem.loop)

    params = to_params(initial)
    _, grad = run(params)
    h = 1e-4
    for name in ("filter_frequency", "filter_zeta_pole"):
        step = lambda d, name=name: params._replace(**{name: getattr(params, name) + d})
        central = (float(run(step(h))[0].cost) - float(run(step(-h))[0].cost)) / (2 * h)
        derivative = float(getattr(grad, name))
        assert derivative != 0.0, name
        assert derivative == pytest.approx(central, rel=1e-5), name


def test_a_campaign_moves_the_filter_and_records_it_where_the_estimator_s_go(tmp_path):
    config = _campaign(optimizer={"learning_rate": 0.2})
    report = tune(config, tmp_path / "run", progress=False)
    initial, tuned = report["initial"]["filter"], report["tuned"]["filter"]
    assert initial == pytest.approx({"frequency": 0.8, "zeta_pole": 0.5}, rel=1e-12)
    assert tuned["frequency"] != pytest.approx(0.8, rel=1e-6) and tuned["zeta_pole"] != pytest.approx(0.5, rel=1e-6)
    assert 0.0 < tuned["frequency"] < NYQUIST_SHARE * 0.5 / PERIOD
    best = json.loads((tmp_path / "run" / "best_gains.json").read_text())
    assert set(best["filter"]) == {"frequency", "zeta_pole"}
    header = (tmp_path / "run" / "history.csv").read_text().splitlines()[0].split(",")
    assert {"filter_frequency", "filter_zeta_pole"} <= set(header)


@pytest.mark.parametrize(("filter_table", "names", "message"), [
    ({"kind": "none"}, ["frequency"], "the mission has no structural filter"),
    (None, ["omega"], "no tunable parameter 'omega'"),
    ({"kind": "lowpass", "lowpass": {"frequency": 1.0}}, ["zeta_zero"], "no tunable parameter 'zeta_zero'"),
    (None, ["frequency", "frequency"], "distinct"),
    (None, "frequency", "must be a list"),
    ({"kind": "notch", "notch": {**NOTCH, "zeta_zero": 0.0}}, ["zeta_zero"], "zeta_zero is 0 in the mission"),
    ({"kind": "notch", "notch": {**NOTCH, "frequency": 4.999}}, ["frequency"], "must start below 4.95 Hz"),
])
def test_bad_filter_entries_are_refused_in_one_line(filter_table, names, message):
    with pytest.raises(ValueError, match=message) as err:
        _campaign(filter_table, filter=names)
    assert "\n" not in str(err.value)


def test_a_filter_with_tuned_parameters_and_a_margin_constraint_is_refused():
    with pytest.raises(ValueError, match="cannot be combined with tune.filter"):
        _campaign(constraints={"disk_margin": {"min_db": 3.0}})


# --- a per-phase filter ---------------------------------------------------------------------------


def _mission(frequency):
    return missions.from_dict({**MISSION, "filter": {"kind": "notch", "notch": {**NOTCH, "frequency": frequency}}},
                              missions.FLIGHT)


def test_a_per_phase_frequency_switches_at_the_phase_s_first_tick():
    mission = _mission([0.8, 1.6, 2.4])
    scenario, loop = mission.scenario(jnp.float64), mission.loop(jnp.float64)
    assert loop.filter.phases == 3
    sections = [loop.filter.at_phase(p).coefficients(jnp.float64) for p in range(3)]
    scalar = [_mission(f).loop(jnp.float64).filter.coefficients(jnp.float64) for f in (0.8, 1.6, 2.4)]
    np.testing.assert_array_equal(np.asarray(sections), np.asarray(scalar))
    m = loop.period_steps
    for start, before, after in ((1.0, 0, 1), (2.0, 1, 2)):
        first = round(start / PERIOD)  # the phase's first tick
        def at(j):
            return np.asarray(loop.filter.at_phase(loops.phase(scenario, jnp.asarray(j * m))).coefficients(jnp.float64))

        np.testing.assert_array_equal(at(first - 1), np.asarray(sections[before]))
        np.testing.assert_array_equal(at(first), np.asarray(sections[after]))
    with pytest.raises(ValueError, match=r"filter.notch.frequency has 2 values: give one number, or one per phase"):
        _mission([0.8, 1.6])


def test_a_per_phase_filter_of_equal_values_flies_bit_for_bit_as_the_number():
    def fly(frequency):
        mission = _mission(frequency)
        return simulate(mission.scenario(jnp.float64), mission.controller("pd")[0], mission.gains["pd"], 0,
                        loop=mission.loop(jnp.float64))

    scalar, listed, switched = fly(0.8), fly([0.8, 0.8, 0.8]), fly([0.8, 1.6, 1.6])
    np.testing.assert_array_equal(np.asarray(listed.history.Omega), np.asarray(scalar.history.Omega))
    np.testing.assert_array_equal(np.asarray(listed.metrics.rmse), np.asarray(scalar.metrics.rmse))
    # another frequency from the second phase on: the same flight until its first tick, then not
    t = np.asarray(scalar.history.t)
    early, late = t <= 1.0, t > 1.0 + PERIOD
    np.testing.assert_array_equal(np.asarray(switched.history.Omega)[early], np.asarray(scalar.history.Omega)[early])
    assert not np.allclose(np.asarray(switched.history.Omega)[late], np.asarray(scalar.history.Omega)[late])


def test_dispersed_missions_fly_the_tuned_filter():
    """sample_metrics(filter=...) equals the mission written with those values (T = 1 s)."""
    short = {**MISSION, "T": 1.0}
    mission = missions.from_dict(short, missions.FLIGHT)
    written = missions.from_dict({**short, "filter": {"kind": "notch", "notch": {**NOTCH, "frequency": 1.3}}},
                                 missions.FLIGHT)
    parsed, leaves = draw.parse({"seed": "random", "filter.notch.zeta_pole": 0.5}, mission)
    inputs = batched.inputs(draw.draw(parsed, leaves, 0, 2, 20), jnp.float64)
    gains = PDGains(jnp.asarray(2.0), jnp.asarray(3.0))
    run = lambda m, **kw: batched.sample_metrics(inputs, gains, controller=m.controller("pd")[0], mission=m, **kw)
    tuned = run(mission, filter={"frequency": jnp.asarray(1.3)})
    np.testing.assert_allclose(tuned["rmse"], run(written)["rmse"], rtol=1e-12)
    assert not np.allclose(tuned["rmse"], run(mission)["rmse"], rtol=1e-6)


def test_a_per_phase_filter_is_tuned_one_value_per_phase(tmp_path):
    per_phase = {"kind": "notch", "notch": {**NOTCH, "frequency": [0.8, 0.8, 1.2]}}
    config = _campaign(per_phase, filter=["frequency"], optimizer={"learning_rate": 0.2})
    report = tune(config, tmp_path / "run", progress=False)
    assert report["initial"]["filter"]["frequency"] == pytest.approx([0.8, 0.8, 1.2], rel=1e-12)
    tuned = report["tuned"]["filter"]["frequency"]
    assert len(tuned) == 3 and all(abs(t - f) > 1e-6 for t, f in zip(tuned, [0.8, 0.8, 1.2]))
    header = (tmp_path / "run" / "history.csv").read_text().splitlines()[0].split(",")
    assert {"filter_frequency_0", "filter_frequency_1", "filter_frequency_2"} <= set(header)
