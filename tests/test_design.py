"""Design campaigns ([[tune.goals]], docs/model.md §16.6): a known optimum found, an
infeasible pair of goals reported as such, every goal's derivative against central
differences, and bad input refused in one line before anything compiles."""

import json
import math

import jax.numpy as jnp
import numpy as np
import pytest

from so3jax.jobs.tune import design
from so3jax.jobs.tune.campaign import tune
from so3jax.jobs.tune.config import load_config, parse_config
from so3jax.jobs.tune.gains import resolve_gains, to_gains
from so3jax.jobs.tune.goal_values import UNSTABLE, GoalValues
from so3jax.jobs.tune.goals import parse_goals
from so3jax.jobs.tune.problem import Sampler
from so3jax.missions import draw
from so3jax.missions.mission import gains_file
from so3jax.sim import margins

A, LIMIT = 0.01, 3600.0  # disturbance amplitude per axis [N m]; the hold's APE limit [arcsec]


def hold_campaign(goals, iterations=30):
    """A unit-inertia body held inertially by the PD (k_Omega fixed at 2) under the
    disturbance A sin(f t) [1, 1, 1], f = pi / 400 rad/s, peaking at the end of the hold
    phase [150, 200) s: there the error is quasi-static, k_R sin(theta) = sqrt(3) A sin(f t),
    so the hold's APE at 0.95 (its samples' top 5 %, within 0.02 % of the peak) is at most
    LIMIT exactly where k_R >= sqrt(3) A / sin(LIMIT). The initial error of 0.3 rad costs an
    effort that grows with k_R: the least effort that meets the APE is that k_R."""
    return {"T": 200.0, "dt": 0.05, "seed": 0, "controllers": ["pd"], "record_every": 10,
            "control": {"mode": "continuous"}, "sensors": {"gyro": False, "star_tracker": False},
            "estimator": {"kind": "truth"}, "actuator": {"kind": "ideal"}, "momentum": {"kind": "none"},
            "inertia": {"J": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]},
            "reference": {"kind": "inertial"}, "phases": {"names": ["settle", "hold"], "start": [0.0, 150.0]},
            "disturbance": {"amplitude": A, "frequency": math.pi / 400.0, "noise_std": 0.0},
            "initial": {"attitude": [0.3, 0.0, 0.0], "rate": [0.0, 0.0, 0.0]},
            "gains": {"pd": {"k_R": 0.5, "k_Omega": 2.0}},
            "tune": {"controller": "pd", "iterations": iterations, "fixed": ["k_Omega"],
                     "train": {"seeds": [0], "samples": 1}, "validation": {"seeds": [1], "samples": 1},
                     "dispersions": {},
                     "optimizer": {"learning_rate": 0.1, "schedule": "cosine_decay_schedule",
                                   "schedule_options": {"decay_steps": iterations, "alpha": 0.01}},
                     "goals": goals}}


HOLD = {"index": "APE", "axis": "angle", "level": 0.95, "limit": LIMIT, "phase": "hold", "name": "hold pointing"}


def test_the_least_effort_that_meets_a_pointing_limit_is_the_closed_form_gain(tmp_path):
    config = parse_config(hold_campaign([{**HOLD, "hard": True}, {"budget": "effort", "limit": 1.0, "hard": False}]))
    report = tune(config, tmp_path / "run", progress=False)
    expected = math.sqrt(3.0) * A / math.sin(math.radians(LIMIT / 3600.0))
    assert report["gains"]["best"]["k_R"] == pytest.approx(expected, rel=0.01)
    assert report["gains"]["best"]["k_Omega"] == 2.0  # fixed
    assert report["verdict"] == "met" and report["met_on_training"]
    pointing, effort = report["goals"]
    assert pointing["training"]["initial"] > 1.9 and 0.98 <= pointing["training"]["best"] <= 1.0
    assert effort["training"]["best"] > effort["training"]["initial"]  # what meeting the limit costs
    assert report["binding"] == ["hold pointing", "mean effort"]
    saved = json.loads((tmp_path / "run" / "design.json").read_text())
    assert saved["verdict"] == "met" and (tmp_path / "run" / "design.md").exists()
    assert float(gains_file(tmp_path / "run" / "best_gains.json", "pd").k_R) == report["gains"]["best"]["k_R"]


def test_goals_that_no_gain_meets_together_are_reported_as_such(tmp_path):
    # the effort of holding against the disturbance alone, 3 A^2 int sin^2(f t) dt ~ 0.03, exceeds 0.01
    goals = [{**HOLD, "hard": True}, {"budget": "effort", "limit": 0.01, "hard": True}]
    config = parse_config(hold_campaign(goals, iterations=12))
    report = tune(config, tmp_path / "run", progress=False)
    assert report["verdict"] == "not met" and not report["met_on_training"]
    assert "mean effort" in report["unmet_hard"]
    assert ["hold pointing", "mean effort"] in report["conflicts"]
    assert "not every hard goal holds" in (tmp_path / "run" / "design.md").read_text()
    # interrupted after 5 iterations and resumed: the same design as the uninterrupted run
    interrupted = hold_campaign(goals, iterations=12)
    interrupted["tune"]["iterations"] = 5
    tune(parse_config(interrupted), tmp_path / "again", progress=False)
    resumed = tune(config, tmp_path / "again", resume=True, progress=False)
    assert resumed["gains"] == report["gains"] and resumed["goals"] == report["goals"]


def test_a_conflict_names_a_goal_held_below_its_limit_by_its_multiplier():
    """Pointing over its limit, a margin under its own but pushed back (its multiplier
    positive) with the opposite gradient: the pair is the conflict; without the multiplier,
    the margin is not active."""
    mission = parse_config(hold_campaign([{**HOLD, "hard": True}])).mission
    goals = parse_goals([{**HOLD, "hard": True}, {"budget": "effort", "limit": 1.0, "hard": True},
                         {"budget": "rmse", "limit": 1.0, "hard": True}], mission)
    hard = np.ones(3, bool)
    g, jac = np.array([2.0, 0.8, 0.5]), np.array([[1.0, 0.0], [-1.0, 0.2], [-1.0, 0.0]])
    assert design.conflicts(g, jac, goals, hard) == []
    pushed = design.conflicts(g, jac, goals, hard, lam=np.array([0.3, 0.1, 0.0]))
    assert pushed == [["hold pointing", "mean effort"]]
    # traded: every iterate that pointed better lost the rms budget, which holds at the design
    rows = [{"g[hold pointing]": 1.5, "g[mean effort]": 0.7, "g[mean rmse]": 3.0},
            {"g[hold pointing]": 2.5, "g[mean effort]": 0.9, "g[mean rmse]": 0.4}]
    assert design.conflicts(g, jac * 0.0, goals, hard, rows=rows) == [["hold pointing", "mean rmse"]]
    rows.append({"g[hold pointing]": 1.9, "g[mean effort]": 0.7, "g[mean rmse]": 0.9})  # one did both
    assert design.conflicts(g, jac * 0.0, goals, hard, rows=rows) == []


# --- each goal's derivative ------------------------------------------------------------------


FLIGHT_GOALS = [
    {"index": "RPE", "axis": "angle", "level": 0.9, "limit": 300.0, "window": 2.0, "interpretation": "ensemble",
     "hard": True},
    {"index": "APE", "axis": "x", "level": 0.5, "limit": 3600.0, "interpretation": "temporal", "hard": True},
    {"index": "AKE", "axis": "each", "level": 0.5, "limit": 5.0, "interpretation": "mixed", "hard": True},
    {"budget": "command_effort", "limit": 1.0, "hard": False},
    {"margin": "disk", "min_db": 6.0, "at": [10.0], "hard": True},
    {"margin": "gain", "min_db": 6.0, "at": [10.0], "hard": True},
    {"margin": "phase", "min_deg": 30.0, "axis": "y", "at": [10.0], "hard": False},
]


@pytest.fixture(scope="module")
def flight_goals():
    config = load_config("missions/flight.toml", [("T", 20.0), ("tune.controller", "pd"),
                                                   ("tune.train", {"seeds": [0], "samples": 2}),
                                                   ("tune.validation", {"seeds": [1], "samples": 2}),
                                                   ("tune.dispersions", {"initial.attitude": {"max_angle_deg": 20.0},
                                                                         "seed": "random"}),
                                                   ("tune.goals", FLIGHT_GOALS)])
    goals = parse_goals(list(config.goals), config.mission)
    initial = resolve_gains("pd", "mission", jnp.float64, mission=config.mission)
    parameters = design.Parameters(config, initial)
    parsed, leaves = draw.parse(config.dispersions, config.mission)
    inputs, _ = design.draw_inputs(Sampler(parsed, leaves, config.mission), 0, 2, jnp.float64)
    values = GoalValues(goals, config.mission, config.mission.controller("pd")[0], parameters.unravel)
    P = np.stack([parameters.p0, parameters.p0 + np.array([0.3, -0.2])])  # two starts at once
    return values, inputs, P


def test_every_goal_derivative_matches_central_differences(flight_goals):
    values, inputs, P = flight_goals
    g, jac, _ = values(P, inputs)
    assert np.all(np.isfinite(g)) and np.all(np.isfinite(jac)) and np.all(g > 0)
    h = 1e-5
    traced = values.traced
    for k in range(P.shape[1]):
        step = np.zeros_like(P)
        step[:, k] = h
        up = np.asarray(values._jacobian(P + step, inputs)[1][0])  # the traced goals' values alone
        down = np.asarray(values._jacobian(P - step, inputs)[1][0])
        fd = (up - down) / (2 * h)
        assert np.all(jac[:, traced, k] != 0.0)
        np.testing.assert_allclose(jac[:, traced, k], fd, rtol=1e-5, atol=1e-7)
    # a margin's derivative holds the linearization's point fixed (docs/model.md §16.6)
    margin = values.goals[-1]
    *_, states = values._margin_points(P[0], inputs, margin.at)
    for p in P:
        _, g_points, d_points, _ = values._margin_points(p, inputs, margin.at, states)
        assert np.all(g_points < UNSTABLE)
        for k in range(P.shape[1]):
            step = np.zeros(P.shape[1])
            step[k] = h
            up = values._margin_points(p + step, inputs, margin.at, states)[1]
            down = values._margin_points(p - step, inputs, margin.at, states)[1]
            np.testing.assert_allclose(d_points[..., k], (up - down) / (2 * h), rtol=1e-5, atol=1e-9)


def test_margin_goals_read_the_disk_margins_the_margins_command_refines(flight_goals):
    """Each margin goal's value on its 256-point grid against the refined disk margins of
    sample_margins (2000 points and bounded Brent): at least as large (the grid can only miss
    the peak of |S - I/2|) and within 1 %; a phase floor reads 2 atan(alpha / 2)."""
    values, inputs, P = flight_goals
    _, _, read = values(P, inputs)  # both starts: the program the derivatives' test ran
    gains = to_gains(values.unravel(jnp.asarray(P[0])))
    refined = design._disks(inputs, gains, values.controller, values.mission, (10.0,))
    for i in values.margins:
        goal = values.goals[i]
        worst = float(np.min(refined[..., list(goal.columns)]))
        exact = math.degrees(2 * math.atan(worst / 2)) if goal.margin == "phase" else margins.db_of_alpha(worst)
        assert exact <= read[0, i] * (1 + 1e-9) and read[0, i] == pytest.approx(exact, rel=0.01)


def test_an_unstable_points_derivative_is_its_spectral_radius(flight_goals):
    """g = UNSTABLE rho at an unstable point: d rho / dp from the closed loop's eigenvectors
    against central differences of the spectral radius of A(p) + BC, A(p) = A0 + p A1."""
    values = flight_goals[0]
    rng = np.random.default_rng(3)
    A0, A1, B, C = rng.normal(size=(6, 6)), rng.normal(size=(6, 6)), rng.normal(size=(6, 3)), rng.normal(size=(3, 6))

    def rho(p):
        return margins.closed_loop_modes(margins.Linearization(A0 + p * A1, B, C, 0.1)).spectral_radius

    assert rho(0.0) > 1.0  # unstable
    value, derivative = values._unstable_point(margins.Linearization(A0, B, C, 0.1), A1[..., None])
    assert value == rho(0.0)
    assert derivative[0] == pytest.approx((rho(1e-6) - rho(-1e-6)) / 2e-6, rel=1e-6)


# --- bad input ---------------------------------------------------------------------------------


@pytest.mark.parametrize("change, message", [
    ({"goals": [{**HOLD, "phase": "cruise", "hard": True}]}, "unknown phase 'cruise'"),
    ({"goals": [{**HOLD, "index": "XPE", "hard": True}]}, "unknown index 'XPE'"),
    ({"goals": [{"requirement": "nadir pointing", "hard": True}]}, "has no requirement 'nadir pointing'"),
    ({"goals": [{**HOLD, "level": 1.0, "hard": True}]}, "tune.goals[0].level"),
    ({"goals": [{**HOLD}]}, "tune.goals[0].hard: missing"),
    ({"goals": [{**HOLD, "index": "AKE", "hard": True}]},  # the campaign's estimator reads the truth
     "tune.goals[0].index: AKE reads the knowledge error, and the mission's estimator (estimator.kind = 'truth') "
     "reads the true state"),
    ({"goals": [{**HOLD, "index": "RPE", "window": 0.1, "hard": True}]},  # records every 10 steps of 0.05 s
     "tune.goals[0].window: 0.1 s is shorter than the recording interval, 0.5 s"),
    ({"goals": [{"margin": "disk", "min_db": 0.0, "hard": True}]}, "tune.goals[0].min_db"),
    ({"goals": [{"margin": "phase", "min_deg": 95.0, "hard": True}]}, "tune.goals[0].min_deg"),
    ({"goals": [{"margin": "phase", "min_db": 6.0, "hard": True}]}, "[tune.goals[0]]: min_db; allowed"),
    ({"goals": [{"margin": "phase", "hard": True}]}, "tune.goals[0].min_deg: missing"),
    ({"goals": [{"margin": "gain", "min_db": 6.0, "axis": "w", "hard": True}]}, "tune.goals[0].axis"),
    ({"goals": [{"margin": "disk", "min_db": 6.0, "axis": "x", "hard": True}]}, "axis"),
    ({"goals": [{"margin": "delay", "min_db": 6.0, "hard": True}]}, "tune.goals[0].margin"),
    ({"goals": [{"budget": "effort", "limit": 1.0, "statistic": "median", "hard": False}]}, "statistic"),
    ({"bounds": {"k_R": [1.0, 0.5]}}, "tune.bounds.k_R"),
    ({"bounds": {"k_X": [0.1, 1.0]}}, "no gain 'k_X'"),
    ({"starts": 0}, "tune.starts"),
    ({"dispersions": {"bogus": 1.0}}, "tune.dispersions.bogus cannot be dispersed"),
    ({"fixed": ["k_R", "k_Omega"]}, "nothing is left to tune"),
    ({"dispersions": None}, "needs a [tune.dispersions] table"),
])
def test_bad_design_input_is_a_one_line_error(change, message):
    campaign = hold_campaign([{**HOLD, "hard": True}])
    campaign["tune"].update(change)
    if campaign["tune"].get("dispersions", 0) is None:
        del campaign["tune"]["dispersions"], campaign["tune"]["train"]["samples"]
        del campaign["tune"]["validation"]["samples"]
    with pytest.raises(ValueError, match=None) as err:
        parse_config(campaign)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_a_margin_goal_needs_a_sampled_loop():
    campaign = hold_campaign([{"margin": "disk", "min_db": 6.0, "hard": True}])
    with pytest.raises(ValueError, match="needs a sampled loop"):
        parse_config(campaign)


def test_a_schedule_on_a_law_the_mission_does_not_fly_is_refused():
    campaign = hold_campaign([{**HOLD, "hard": True}])
    campaign["schedule"] = {"adaptive": {"by": "phase"}}
    with pytest.raises(ValueError, match="schedule.adaptive"):
        parse_config(campaign)


def test_the_command_refuses_bad_goals_before_compiling(in_process, capsys):
    from so3jax import commands as cli

    (in_process / "c.toml").write_text('mission = "x.toml"\n')
    campaign = in_process / "design.toml"
    campaign.write_text('T = 20.0\n[tune]\ncontroller = "pd"\nstarts = 2\n[tune.train]\nseeds = [0]\nsamples = 2\n'
                        '[tune.validation]\nseeds = [1]\nsamples = 2\n[tune.dispersions]\nseed = "random"\n'
                        '[[tune.goals]]\nindex = "APE"\naxis = "angle"\nlevel = 0.95\nlimit = 10.0\n'
                        'phase = "deployment"\nhard = true\n[[tune.goals]]\nmargin = "disk"\nmin_db = -1.0\n'
                        'hard = true\n')
    assert cli.main(["tune", str(campaign), "--out", "o"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("so3jax tune: error: ") and "tune.goals[1].min_db" in err and "\n" not in err
    assert not (in_process / "o").exists()


def test_a_scheduled_law_is_designed_with_one_set_of_gains_per_phase():
    campaign = hold_campaign([{**HOLD, "hard": True}])
    campaign["schedule"] = {"pd": {"by": "phase"}}
    campaign["gains"]["pd"] = {"k_R": [0.5, 0.6], "k_Omega": 2.0}
    campaign["tune"]["bounds"] = {"k_R": [0.1, 10.0]}
    config = parse_config(campaign)
    initial = resolve_gains("pd", config.initial_gains, jnp.float64, mission=config.mission)
    np.testing.assert_array_equal(initial.k_R, [0.5, 0.6])
    np.testing.assert_array_equal(initial.k_Omega, [2.0, 2.0])  # one number: every phase
    parameters = design.Parameters(config, initial)
    assert list(parameters.columns(parameters.p0)) == ["k_R_0", "k_R_1", "k_Omega_0", "k_Omega_1"]
    np.testing.assert_array_equal(parameters.free, [True, True, False, False])
    np.testing.assert_allclose(np.exp(parameters.low), [0.1, 0.1, 0.2, 0.2])  # k_Omega: a decade either side
    np.testing.assert_allclose(np.exp(parameters.high), [10.0, 10.0, 20.0, 20.0])
    starts = np.exp(parameters.starts(64, 0))
    assert np.all((starts[:, :2] >= 0.1) & (starts[:, :2] <= 10.0)) and np.all(starts[:, 2:] == 2.0)
    np.testing.assert_allclose(starts[0], [0.5, 0.6, 2.0, 2.0])
    paper = resolve_gains("pd", "paper", jnp.float64, mission=config.mission)
    np.testing.assert_array_equal(paper.k_R, [0.5714, 0.5714])


def test_a_margin_before_the_loop_is_formed_is_refused():
    """At tick 0 the rate-integrating gyro has no reading: the loop lacks its rate feedback."""
    for key, value in (("tune.constraints.disk_margin", {"min_db": 6.0, "at": [0.0]}),):
        with pytest.raises(ValueError, match="before t = 0.1 s, the first tick at which the loop is formed"):
            load_config("tuning/pd_flight_margin.toml", [(key, value)])
    with pytest.raises(ValueError, match=r"tune.goals\[0\].at: t = 0 s is before t = 0.1 s"):
        load_config("tuning/design_pd.toml", [("tune.goals", [{"margin": "disk", "min_db": 6.0, "at": [0.0],
                                                                "hard": True}])])


DESIGNS = ("design_pd", "design_pd_scheduled", "design_adaptive", "design_mrp_feedback")


@pytest.mark.parametrize("name", DESIGNS)
def test_shipped_design_campaigns_parse_and_their_records_are_theirs(name):
    """The sign-off mission's four requirements and a 6 dB disk margin, hard, and the effort,
    soft, over 32 dispersed flight missions, held out on 256; the recorded run's checkpoint
    belongs to the file (--resume continues it) and its report to the law."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    config = load_config(root / "tuning" / f"{name}.toml")
    goals = parse_goals(list(config.goals), config.mission)
    assert [g.kind for g in goals] == ["requirement"] * 4 + ["margin", "budget"]
    assert [g.hard for g in goals] == [True] * 5 + [False] and goals[4].min_db == 6.0
    assert (config.train.samples, config.validation.samples) == (32, 256)
    assert ("schedule" in name) == bool(config.mission.schedule)
    record = root / "tuning" / name
    report = json.loads((record / "design.json").read_text())
    assert report["controller"] == config.controller and report["held_out"]["samples"] >= 250
    assert [g["name"] for g in report["goals"]] == [g.name for g in goals]
    with np.load(record / design.CHECKPOINT) as data:
        assert str(data["fingerprint"]) == design.campaign_fingerprint(config)
