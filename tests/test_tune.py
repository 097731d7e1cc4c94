"""Tuning: cost modes, the optax loop's outputs, resume after an interrupt (and its refusal
under another configuration or precision), the non-finite stop, the gradient-free
baseline, campaign files (a mission and a [tune] table), bad configs and the command line.

Every paper-mission run uses T = 20 s and batches of 2 scenarios (as
tests/test_gradients.py), so the compiled rollouts are shared across tests; the flight
mission runs at T = 1 s.
"""

import copy
import csv
import dataclasses
import json
import math
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

import so3jax as sj
from so3jax import commands as cli
from so3jax.jobs import tune
from so3jax.jobs.tune import campaign  # the optimizer loop: where it finds cost_and_grad and population_costs
from so3jax.sim.metrics import Metrics
from tests._host_devices import host_devices_env

ROOT = Path(__file__).parents[1]
BASE = {  # the paper's mission (the default) at T = 20 s, and the campaign
    "T": 20.0,
    "tune": {
        "controller": "pd",
        "iterations": 3,
        "train": {"seeds": [0, 1]},
        "validation": {"seeds": [10, 11]},
        "cost": {"mode": "weighted", "weight": 0.5},
        "optimizer": {"learning_rate": 0.1},
    },
}

pytestmark = pytest.mark.filterwarnings("ignore::so3jax.dynamics.inertia.InertiaWarning")


def table(mission=None, **changes):
    """BASE with changes to its [tune] table (dotted keys written a__b; a value of None
    deletes the key) and mission entries ``mission`` at the top level."""
    t = copy.deepcopy(BASE)
    t.update(mission or {})
    for dotted, value in changes.items():
        *parents, last = dotted.split("__")
        holder = t["tune"]
        for key in parents:
            holder = holder.setdefault(key, {})
        if value is None:
            holder.pop(last, None)
        else:
            holder[last] = value
    return t


def config(mission=None, **changes):
    return tune.parse_config(table(mission, **changes))


def read_history(path):
    with open(path / "history.csv") as f:
        return list(csv.DictReader(f))


def without_wall_time(rows):
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]


# --- cost modes (docs/model.md §6) -------------------------------------------------------------


def fake_metrics(rmse, effort):
    rmse, effort = jnp.asarray(rmse), jnp.asarray(effort)
    zero = jnp.zeros_like(rmse)
    return Metrics(rmse, zero, effort, zero, zero, zero, zero, zero, zero, zero, zero)


def test_weighted_cost():
    refs = tune.CostRefs(jnp.asarray(2e-3), jnp.asarray(100.0), jnp.asarray(0.5))
    costs = tune.scenario_costs(fake_metrics([1e-3, 4e-3], [100.0, 50.0]), refs, "weighted")
    np.testing.assert_allclose(costs, [0.5 + 0.5, 2.0 + 0.25], rtol=1e-15)


def test_equal_effort_cost_penalizes_only_effort_above_the_budget():
    budget = jnp.asarray([100.0, 200.0])  # one per scenario, as taken from another controller's run
    refs = tune.CostRefs(jnp.asarray(1e-3), budget, jnp.asarray(10.0))
    costs = tune.scenario_costs(fake_metrics([1e-3, 2e-3], [90.0, 300.0]), refs, "equal_effort")
    np.testing.assert_allclose(costs, [1.0, 2.0 + 10.0 * 0.5**2], rtol=1e-15)


def test_cost_refs_default_to_the_initial_gains_and_take_the_budget_per_scenario():
    cfg = config(cost={"mode": "equal_effort", "weight": 5.0, "budget_controller": "pd"})
    problem = tune.build_problem(cfg)
    gains = tune.resolve_gains("pd", "paper", jnp.float64)
    metrics = tune.evaluate(problem, gains, problem.train)
    refs = tune.cost_refs(cfg, problem, metrics, problem.train)
    np.testing.assert_allclose(refs.rmse, jnp.mean(metrics.rmse), rtol=1e-15)
    np.testing.assert_allclose(refs.effort, metrics.effort, rtol=1e-15)  # the PD's own effort
    assert float(refs.weight) == 5.0
    np.testing.assert_allclose(tune.scenario_costs(metrics, refs, "equal_effort"), metrics.rmse / refs.rmse, rtol=1e-15)


# --- runs ---------------------------------------------------------------------------


def test_run_writes_its_results_and_every_gradient_is_finite(tmp_path):
    report = tune.tune(config(), tmp_path, progress=False)
    for name in ("best_gains.json", "history.csv", "history.png", "validation.json", "checkpoint.npz"):
        assert (tmp_path / name).is_file(), name
    rows = read_history(tmp_path)
    assert [int(r["iteration"]) for r in rows] == [0, 1, 2]
    assert all(
        math.isfinite(float(r[k])) for r in rows for k in ("cost", "rmse", "effort", "grad_norm", "k_R", "k_Omega")
    )
    assert float(rows[0]["cost"]) == pytest.approx(1.5)  # RMSE_ref, Effort_ref: the initial gains
    assert float(rows[-1]["cost"]) < float(rows[0]["cost"])
    best = json.loads((tmp_path / "best_gains.json").read_text())
    assert best["controller"] == "pd" and best["iteration"] == 2 and set(best["gains"]) == {"k_R", "k_Omega"}
    assert json.loads((tmp_path / "validation.json").read_text()) == json.loads(json.dumps(report))
    assert report["scenarios"]["seeds"] == [10, 11]  # held out
    measured = set(report["tuned"]) | set(report["cost"]) | {"best_cost", "wall_s", "T", "inertia_scale"}
    assert measured - set(report["units"]) == {"gains", "diverged", "diverged_count", "mode", "objective", "initial",
                                               "tuned"}  # each number's unit; gains in the controller's docs
    assert report["tuned"]["gains"] == best["gains"]
    assert report["cost"]["tuned"] < report["cost"]["initial"]
    # a best_gains.json is a valid starting point for another campaign
    assert tune.resolve_gains("pd", str(tmp_path / "best_gains.json"), jnp.float64).k_R == best["gains"]["k_R"]


def test_equal_effort_run_with_the_budget_of_another_controller(tmp_path):
    cfg = config(
        controller="adaptive",
        iterations=2,
        cost={"mode": "equal_effort", "weight": 100.0, "budget_controller": "pd", "budget_gains": "paper"},
    )
    report = tune.tune(cfg, tmp_path, progress=False)
    assert report["budget"]["controller"] == "pd" and report["budget"]["gains"] == {"k_R": 0.5714, "k_Omega": 25.0}
    assert len(report["training"]["refs"]["effort"]) == 2  # one budget per training scenario
    assert set(report["tuned"]["gains"]) == {"K_r", "K_w", "Gamma"}


@pytest.mark.parametrize("method", tune.METHODS)
def test_resume_after_interrupt_equals_an_uninterrupted_run(tmp_path, monkeypatch, method):
    cfg = config(iterations=4, method=method, es={"population": 2})
    straight = tune.tune(cfg, tmp_path / "straight", progress=False)

    # Ctrl-C in the middle of the third iteration
    step = "cost_and_grad" if method == "gradient" else "population_costs"
    original, calls = getattr(campaign, step), []

    def interrupted(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return original(*args, **kwargs)

    monkeypatch.setattr(campaign, step, interrupted)
    with pytest.raises(KeyboardInterrupt):
        tune.tune(cfg, tmp_path / "resumed", progress=False)
    assert len(read_history(tmp_path / "resumed")) == 2  # at most one iteration lost
    monkeypatch.setattr(campaign, step, original)
    with pytest.raises(ValueError, match="--resume"):
        tune.tune(cfg, tmp_path / "resumed", progress=False)
    with pytest.raises(ValueError, match="another configuration"):
        tune.tune(
            config(iterations=4, method=method, es={"population": 2}, seed=None, optimizer={"learning_rate": 0.2}),
            tmp_path / "resumed",
            resume=True,
            progress=False,
        )
    resumed = tune.tune(cfg, tmp_path / "resumed", resume=True, progress=False)

    assert without_wall_time(read_history(tmp_path / "resumed")) == without_wall_time(
        read_history(tmp_path / "straight")
    )
    for name in ("best_gains.json",):
        assert (tmp_path / "resumed" / name).read_text() == (tmp_path / "straight" / name).read_text()
    for report in (straight, resumed):
        report["training"].pop("wall_s")
    assert resumed == straight


def test_a_resume_under_another_precision_is_refused_and_changes_nothing(tmp_path):
    import jax

    cfg = config(iterations=1)
    tune.tune(cfg, tmp_path, progress=False)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    more = dataclasses.replace(cfg, iterations=2)
    jax.config.update("jax_enable_x64", False)
    try:
        with pytest.raises(ValueError) as err:
            tune.tune(more, tmp_path, resume=True, progress=False)
    finally:
        jax.config.update("jax_enable_x64", True)
    message = str(err.value)
    assert "another configuration (precision float64, this run float32)" in message and "\n" not in message
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    with pytest.raises(ValueError, match=r"another configuration \(its mission differ\)"):
        tune.tune(dataclasses.replace(more, mission=config(mission={"seed": 3}).mission), tmp_path, resume=True,
                  progress=False)


def test_the_flight_mission_tunes_through_its_own_loop(tmp_path, monkeypatch):
    """missions/flight.toml (sampled control, gyro and star tracker, MEKF, wheels) at T = 1 s:
    one forward-mode PD iteration through the mission's loop, a finite nonzero gradient."""
    t = {"mission": "../missions/flight.toml", "T": 1.0,
         "tune": {**BASE["tune"], "iterations": 1, "validation": {"seeds": [10, 11]}}}
    cfg = tune.parse_config(t, ROOT / "tuning")
    loops, step = [], campaign.cost_and_grad
    monkeypatch.setattr(campaign, "cost_and_grad", lambda *args, **kw: loops.append(args[-1]) or step(*args, **kw))
    report = tune.tune(cfg, tmp_path, progress=False)
    (loop,) = loops
    assert loop.period_steps == 10 and loop.sensors.rate is not None and loop.sensors.attitude is not None
    assert type(loop.estimator).__name__ == "MEKF" and type(loop.actuator).__name__ == "Wheels"
    (row,) = read_history(tmp_path)
    assert math.isfinite(float(row["grad_norm"])) and float(row["grad_norm"]) > 0
    assert report["training"]["T"] == 1.0 and all(math.isfinite(x) for x in report["tuned"]["rmse"])


def test_the_missions_controller_options_and_gains_are_the_campaigns():
    """[controller.NAME] options configure the tuned law (equal options, equal controllers:
    one jit cache entry per configuration); [gains.NAME] are the initial gains of initial_gains = "mission"."""
    J_hat = [[600.0, 0.0, 0.0], [0.0, 400.0, 0.0], [0.0, 0.0, 900.0]]
    cfg = config(mission={"controller": {"pd": {"J_hat": J_hat}}, "gains": {"pd": {"k_R": 1.5}}})
    same = config(mission={"controller": {"pd": {"J_hat": J_hat}}}).mission
    controller, plain = cfg.mission.controller("pd")[0], config().mission.controller("pd")[0]
    assert controller == same.controller("pd")[0] and hash(controller) == hash(same.controller("pd")[0])
    assert controller != plain
    gains = tune.resolve_gains("pd", cfg.initial_gains, jnp.float64, mission=cfg.mission)
    assert tune.gains_table(gains) == {"k_R": 1.5, "k_Omega": 25.0}
    assert tune.describe(cfg) != tune.describe(config())


def test_non_finite_gradient_stops_with_the_last_good_gains_saved(tmp_path):
    # Almost no effort weight: the gradient asks for larger gains, and Adam's first step moves
    # every log-gain by the learning rate: k_Omega x e^20 makes RK4 blow up.
    cfg = config(cost={"mode": "weighted", "weight": 1e-9}, optimizer={"learning_rate": 20.0})
    with pytest.raises(tune.NonFiniteGradientError, match="non-finite .* iteration 1"):
        tune.tune(cfg, tmp_path, progress=False)
    best = json.loads((tmp_path / "best_gains.json").read_text())
    assert best["last_good"]["iteration"] == 0
    assert best["last_good"]["gains"]["k_Omega"] == pytest.approx(25.0)
    rows = read_history(tmp_path)
    assert len(rows) == 2 and not math.isfinite(float(rows[1]["grad_norm"]))


def test_gradient_free_baseline_never_gets_worse(tmp_path):
    cfg = config(method="es", iterations=3, es={"population": 2, "sigma": 0.3, "seed": 1})
    report = tune.tune(cfg, tmp_path, progress=False)
    rows = read_history(tmp_path)
    costs = [float(r["cost"]) for r in rows]
    assert costs == sorted(costs, reverse=True) and costs[-1] <= 1.5
    assert [int(r["rollouts"]) for r in rows] == [2 + 4, 2 + 8, 2 + 12]  # initial batch + population x batch
    assert report["training"]["method"] == "es" and "sigma" in rows[0]


# --- several host devices ---------------------------------------------------------------


def test_a_batch_is_split_only_where_every_device_gets_enough_rollouts():
    seeds = lambda n: {"seeds": list(range(100, 100 + n))}  # held out: validation has 10, 11
    assert tune.batch_devices(config(), 2) == 1  # 2 scenarios: one device, as the campaigns
    assert tune.batch_devices(config(train=seeds(8)), 2) == 2
    assert tune.batch_devices(config(train=seeds(8)), 16) == 8 // tune.MIN_SHARD
    assert tune.batch_devices(config(train=seeds(64)), 16) == 16
    assert tune.batch_devices(config(train=seeds(64)), 1) == 1
    # ES: every population member runs the batch; never more devices than scenarios
    assert tune.batch_devices(config(method="es", es={"population": 6}), 2) == 2
    assert tune.batch_devices(config(method="es", es={"population": 6}), 16) == 2
    assert tune.batch_devices(config(method="es", es={"population": 1}), 16) == 1


TWO_DEVICE_RUN = """
import json, sys, tempfile, warnings
import jax
jax.config.update("jax_enable_x64", True)
from so3jax.jobs import tune
warnings.simplefilter("ignore")
config = tune.parse_config(json.loads(sys.argv[1]))
problem = tune.build_problem(config)
with tempfile.TemporaryDirectory() as out:
    report = tune.tune(config, out, progress=False)
print(json.dumps({"devices": problem.mesh.size, "tuned": report["tuned"],
                  "compiles": tune.cost_and_grad._cache_size()}))
"""


@pytest.mark.slow
def test_two_host_devices_tune_to_the_gains_of_one(tmp_path):
    """A batch of 8 split over 2 host devices (a child process: the device count is fixed
    when JAX starts) gives the one-device run's gains, at one compilation of the step."""
    import subprocess
    import sys

    t = table(iterations=3, train={"seeds": list(range(8))}, validation={"seeds": [10, 11, 12]})
    env = host_devices_env(2, JAX_PLATFORMS="cpu")
    child = subprocess.Popen(
        [sys.executable, "-c", TWO_DEVICE_RUN, json.dumps(t)], env=env, stdout=subprocess.PIPE, text=True
    )
    one = tune.tune(tune.parse_config(t), tmp_path, progress=False)["tuned"]
    stdout, _ = child.communicate(timeout=900)
    assert child.returncode == 0
    two = json.loads(stdout.strip().splitlines()[-1])
    assert two["devices"] == 2 and two["compiles"] == 1
    for name, value in one["gains"].items():
        assert two["tuned"]["gains"][name] == pytest.approx(value, rel=1e-10), name
    np.testing.assert_allclose(two["tuned"]["rmse"], one["rmse"], rtol=1e-10)


# --- bad configurations: a ValueError naming the key, before any compilation -------------


@pytest.mark.parametrize(
    ("changes", "key"),
    [
        ({"optimizer__name": "adamm"}, "tune.optimizer.name"),
        ({"optimizer__name": "chain"}, "tune.optimizer.name"),
        ({"optimizer__name": "lbfgs"}, "tune.optimizer.name"),
        ({"optimizer__learning_rate": -0.1}, "tune.optimizer.learning_rate"),
        ({"optimizer__learning_rate": float("nan")}, "tune.optimizer.learning_rate"),
        ({"optimizer__options": {"bogus": 1}}, "tune.optimizer.options"),
        ({"optimizer__schedule": "no_such_schedule"}, "tune.optimizer.schedule"),
        ({"optimizer__schedule": "cosine_decay_schedule"}, "tune.optimizer.schedule_options"),
        ({"train__seeds": None}, "tune.train.seeds"),
        ({"controller": "lqr"}, "tune.controller"),
        ({"iterations": 0}, "tune.iterations"),
        ({"iterations": 2.5}, "tune.iterations"),
        ({"gradient": "sideways"}, "tune.gradient"),
        ({"method": "annealing"}, "tune.method"),
        ({"cost__mode": "minimax"}, "tune.cost.mode"),
        ({"cost__weight": -1.0}, "tune.cost.weight"),
        ({"cost__mode": "equal_effort"}, "tune.cost.budget"),
        ({"cost__budget_controller": "lqr", "cost__mode": "equal_effort"}, "tune.cost.budget_controller"),
        ({"cost__lambda": 1.0}, "tune.cost.lambda"),
        ({"validation__seeds": [1, 10]}, "tune.validation.seeds"),
        ({"train__inertia_scales": [1.0, -0.5]}, "tune.train.inertia_scales"),
        ({"record_every": 0}, "tune.record_every"),
        ({"diagonal_gamma": True}, "tune.diagonal_gamma"),
        ({"learning_rate": 0.1}, "tune.learning_rate"),
        ({"initial_gains": {"k_R": 1.0}}, "tune.initial_gains"),
        ({"initial_gains": "missing.json"}, "tune.initial_gains"),
        (
            {
                "cost__mode": "equal_effort",
                "cost__budget_controller": "pd",
                "cost__budget_gains": {"k_R": -1.0, "k_Omega": 1.0},
            },
            "tune.cost.budget_gains",
        ),
    ],
)
def test_bad_config_is_a_one_line_value_error_naming_the_key(changes, key):
    with pytest.raises(ValueError, match=key.replace(".", r"\.")) as err:
        config(**changes)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("campaign", "message"),
    [
        ({**BASE, "tune": 3}, "config key 'tune' must be a table"),
        ({**BASE, "tune": {**BASE["tune"], "mission": "x.toml"}}, "unknown config key 'tune.mission'"),
        ({**BASE, "scenario": {"T": 20.0}}, "unknown config key(s): scenario"),
        ({**BASE["tune"], "T": 20.0}, "unknown config key(s): cost, iterations, optimizer, train, validation"),
        ({**BASE, "T": -1.0}, "T (horizon)"),
        ({**BASE, "mission": 3}, "mission must be the path of a mission file"),
        ({**BASE, "controllers": ["adaptive"]}, "'tune.initial_gains': 'mission' gains: the mission flies no 'pd'"),
    ],
)
def test_bad_campaign_is_a_one_line_value_error(campaign, message):
    with pytest.raises(ValueError) as err:
        tune.parse_config(campaign)
    assert message in str(err.value) and "\n" not in str(err.value)


# What the shipped campaigns meant as a flat file with a [scenario] table (T = 4000 s,
# dt = 0.01 s, default controllers): their [tune] tables, every field.
_EQUAL_EFFORT = {"mode": "equal_effort", "weight": 1000.0, "rmse_ref": None, "effort_ref": None, "budget": None,
                 "budget_controller": "pd", "budget_gains": "paper"}
_ADAM = {"name": "adam", "learning_rate": 0.3, "options": {}, "schedule": "cosine_decay_schedule", "clip_norm": 1.0}
_DEFAULT_OPTIMIZER = {"name": "adam", "learning_rate": 0.05, "options": {}, "schedule": None, "schedule_options": {},
                      "clip_norm": 1.0}
_COMMON = {"train": {"seeds": [0], "inertia_scales": [0.9, 1.1]},
           "validation": {"seeds": [100, 101], "inertia_scales": [0.9, 1.0, 1.1]},
           "cost": _EQUAL_EFFORT, "gradient": "forward", "record_every": None, "diagonal_gamma": False}
SHIPPED = {
    "pd_equal_effort": {**_COMMON, "controller": "pd", "iterations": 16, "method": "gradient",
                        "optimizer": {**_ADAM, "schedule_options": {"decay_steps": 16, "alpha": 0.1}},
                        "es": {"population": 8, "sigma": 0.2, "seed": 0}},
    "pd_equal_effort_es": {**_COMMON, "controller": "pd", "iterations": 16, "method": "es",
                           "optimizer": _DEFAULT_OPTIMIZER, "es": {"population": 6, "sigma": 0.3, "seed": 0}},
    "adaptive_equal_effort": {**_COMMON, "controller": "adaptive", "iterations": 7, "method": "gradient",
                              "optimizer": {**_ADAM, "schedule_options": {"decay_steps": 7, "alpha": 0.1}},
                              "es": {"population": 8, "sigma": 0.2, "seed": 0}},
    "adaptive_equal_effort_es": {**_COMMON, "controller": "adaptive", "iterations": 7, "method": "es",
                                 "optimizer": _DEFAULT_OPTIMIZER, "es": {"population": 10, "sigma": 0.3, "seed": 0}},
    "pd_flight": {**_COMMON, "controller": "pd", "iterations": 8, "method": "gradient",
                  "optimizer": {**_ADAM, "schedule_options": {"decay_steps": 8, "alpha": 0.1}},
                  "es": {"population": 8, "sigma": 0.2, "seed": 0}},
}
SHIPPED["pd_flight_margin"] = {**SHIPPED["pd_flight"],  # pd_flight with a 20 dB disk-margin floor at the last tick
                               "constraints": {"disk_margin": {"min_db": 20.0, "at": [3999.9], "weight": 100.0}}}
FLIGHT = {"pd_flight", "pd_flight_margin"}  # flown through missions/flight.toml's loop; the others the paper's


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_shipped_campaigns_parse_to_their_recorded_meaning(name):
    """The paper's mission at T = 4000 s, dt = 0.01 s (the scenario paper_scenario built,
    leaf for leaf, in both precisions), its continuous loop, the default control laws and
    the paper's gains; the [tune] table field for field."""
    import jax

    from so3jax.controllers import registry
    from so3jax.dynamics.scenario import paper_scenario
    from so3jax.sim.loop import PAPER_LOOP

    gradient = {p.stem for p in (ROOT / "tuning").glob("*.toml") if not p.stem.startswith("design_")}
    assert gradient == set(SHIPPED)  # the design campaigns: tests/test_design.py
    cfg = tune.load_config(ROOT / "tuning" / f"{name}.toml")
    assert json.loads(json.dumps(tune.tune_table(cfg))) == {**SHIPPED[name], "initial_gains": "mission"}
    if name in FLIGHT:
        assert cfg.mission == sj.load_mission(ROOT / "missions" / "flight.toml")
        _check_recorded_checkpoint(name, cfg)
        return
    for dtype in (jnp.float64, jnp.float32):
        built, recorded = cfg.mission.scenario(dtype), paper_scenario(4000.0, 0.01, dtype=dtype)
        assert jax.tree.structure(built) == jax.tree.structure(recorded)
        for a, b in zip(jax.tree.leaves(built), jax.tree.leaves(recorded)):
            assert a.dtype == b.dtype and np.array_equal(a, b)
    assert cfg.mission.loop(jnp.float64) == PAPER_LOOP
    assert cfg.mission.options["pd"] == {} and cfg.mission.options["adaptive"] == {"log_derivative": "exact"}
    for controller in ("pd", "adaptive"):  # the mission's gains and the budget's "paper": the registered defaults
        gains = tune.resolve_gains(controller, "mission", jnp.float64, mission=cfg.mission)
        assert tune.gains_table(gains) == tune.gains_table(registry.get(controller).defaults)
    _check_recorded_checkpoint(name, cfg)


def _check_recorded_checkpoint(name, cfg):
    """The recorded run's checkpoint belongs to this campaign: --resume --iterations N extends it."""
    from so3jax.results import io, runfolder

    description = io.to_builtin(tune.describe(dataclasses.replace(cfg, iterations=0)))
    tune.check_fingerprint(ROOT / "tuning" / name / tune.CHECKPOINT, runfolder.fingerprint(description), description)


def test_bad_initial_gains_name_the_gain():
    with pytest.raises(ValueError, match="K_w"):
        tune.resolve_gains("adaptive", {"K_r": 0.1, "Gamma": 1.0}, jnp.float64)
    with pytest.raises(ValueError, match="k_R"):
        tune.resolve_gains("pd", {"k_R": -1.0, "k_Omega": 1.0}, jnp.float64)


# --- command line --------------------------------------------------------------------


def test_cli_overrides_and_resume(tmp_path, capsys):
    path = tmp_path / "campaign.toml"
    path.write_text(
        f'mission = "{ROOT / "missions" / "paper.toml"}"\nT = 4000.0\n[tune]\ncontroller = "pd"\niterations = 5\n'
        '[tune.train]\nseeds = [0, 1]\n[tune.validation]\nseeds = [10, 11]\n[tune.cost]\nmode = "weighted"\n'
    )
    out = tmp_path / "run"
    args = [
        "tune",
        str(path),
        "--set",
        "T=20.0",
        "--iterations",
        "1",
        "--out",
        str(out),
        "--set",
        "tune.optimizer.learning_rate=0.2",
    ]
    assert cli.main(args) == 0
    assert "| pd (tuned) | pd |" in capsys.readouterr().out
    more = args[:5] + ["2"] + args[6:]
    assert cli.main(more) == 2  # the run exists: --resume or another --out
    assert "--resume" in capsys.readouterr().err
    assert cli.main([*more, "--resume"]) == 0
    rows = read_history(out)
    assert len(rows) == 2 and json.loads((out / "validation.json").read_text())["training"]["T"] == 20.0
    assert (
        cli.main(["tune", str(path), "--T", "20", "--set", "tune.optimizer.name=adamm", "--out", str(tmp_path / "x")])
        == 2
    )
    assert "tune.optimizer.name" in capsys.readouterr().err
    assert cli.main(["tune", str(path), "--set", "optimizer.name=adam", "--out", str(tmp_path / "x")]) == 2
    assert "unknown config key(s): optimizer" in capsys.readouterr().err


# --- diverged rollouts: reported as diverged, never as a number ----------------------


def strict_json(path):
    return json.loads(Path(path).read_text(), parse_constant=lambda c: pytest.fail(f"{c} in {path}"))


def test_a_diverged_validation_scenario_is_null_and_left_out_of_the_means(tmp_path):
    """A held-out scenario at 1e-4 of the inertia: k_Omega dt / J far beyond RK4's
    stability, it diverges with any gains; the other one does not."""
    cfg = config(iterations=1, validation={"seeds": [10], "inertia_scales": [1.0, 1e-4]})
    report = tune.tune(cfg, tmp_path, progress=False)
    assert strict_json(tmp_path / "validation.json") == report
    for label in ("initial", "tuned"):
        entry = report[label]
        assert entry["diverged"] == [False, True] and entry["diverged_count"] == 1
        assert entry["rmse"][1] is None and entry["effort"][1] is None and entry["rmse"][0] > 0
        assert entry["mean_rmse"] == entry["rmse"][0] and entry["mean_effort"] == entry["effort"][0]
        assert report["cost"][label] is None  # the batch's cost is not a number
    table = tune.markdown_table([report])
    assert f"| {report['tuned']['mean_rmse']:.4e} (1 of 2 diverged) |" in table and "nan" not in table.lower()
    strict_json(tmp_path / "best_gains.json")


def test_markdown_table_reads_diverged_when_every_scenario_diverged():
    entry = {"gains": {"k_R": 1.0, "k_Omega": 2.0}, "rmse": [None, None], "effort": [None, None],
             "diverged": [True, True], "diverged_count": 2, "mean_rmse": None, "mean_effort": None}
    table = tune.markdown_table([{"controller": "pd", "initial": entry, "tuned": entry}])
    assert table.splitlines()[-1].endswith("| diverged | diverged |")


def test_es_stops_when_the_initial_gains_diverge_in_training(tmp_path):
    """Training at 1e-4 of the inertia: every rollout diverges; the baseline stops at once
    and its history counts the diverged rollouts, with no cost as a number."""
    cfg = config(method="es", iterations=2, es={"population": 2}, train={"seeds": [0, 1], "inertia_scales": [1e-4]})
    with pytest.raises(tune.NonFiniteGradientError, match="2 of 2 training rollouts diverged"):
        tune.tune(cfg, tmp_path, progress=False)
    (row,) = read_history(tmp_path)
    assert row["diverged"] == "2" and not math.isfinite(float(row["cost"])) and not math.isfinite(float(row["rmse"]))
    assert not (tmp_path / "validation.json").exists()


def test_best_row_is_the_lowest_finite_cost():
    rows = [{"cost": float("nan")}, {"cost": 2.0}, {"cost": 1.5}, {"cost": float("inf")}]
    assert tune.best_history_row(rows) == {"cost": 1.5}


def test_a_mission_alone_is_a_campaign_with_the_defaults():
    """Every [tune] key has a default: the mission's first controller, 16 iterations, seed 0
    to train on and seeds 100 and 101 held out."""
    cfg = tune.parse_config({"T": 20.0})
    assert (cfg.controller, cfg.iterations) == (cfg.mission.controllers[0], 16) == ("pd", 16)
    assert (cfg.train.seeds, cfg.validation.seeds) == ((0,), (100, 101))
    flight = tune.load_config(ROOT / "missions" / "flight.toml")
    assert flight.controller == flight.mission.controllers[0] and flight.mission.period is not None
    with pytest.raises(ValueError, match="tune.controller") as err:
        tune.parse_config({"controllers": ["open_loop"]})
    assert "\n" not in str(err.value)
