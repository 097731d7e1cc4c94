"""so3jax crosscheck basilisk: the refusals (one line, before anything is compiled or
Basilisk is imported) and, where Basilisk is installed, the agreement of so3jax's loop with
Basilisk's own modules on short flights of missions/crosscheck.toml."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from so3jax import commands as cli
from so3jax.jobs.crosscheck import basilisk

MISSIONS = Path(__file__).resolve().parent.parent / "missions"
CROSSCHECK = str(MISSIONS / "crosscheck.toml")
ONLY_MRP = 'controllers=["mrp_feedback"]'


@pytest.mark.parametrize(("mission", "sets", "message"), [
    ("flight.toml", [ONLY_MRP], "the inertia profile inertia.kind = paper"),
    ("flight.toml", [], "controller pd, adaptive"),
    ("paper.toml", [ONLY_MRP], "continuous control"),
    ("leo.toml", [ONLY_MRP], "the disturbance torque"),
    ("nadir.toml", [ONLY_MRP], "the disturbance torque"),
    ("crosscheck.toml", ['reference.kind="lvlh"', "orbit.n=0.0"], 'reference.kind = "lvlh" at orbit.n = 0'),
    ("identify.toml", [], "controller open_loop"),
    ("crosscheck.toml", ["sensors.gyro={}"], "sensors (gyro)"),
    ("crosscheck.toml", ['estimator.kind="raw"', "sensors.gyro={}", "sensors.star_tracker={}"], "sensors"),
    ("crosscheck.toml", ['momentum.kind="thrusters"'], "momentum management"),
    ("crosscheck.toml", ["environment.gravity_gradient={}"], "environment torques (environment.gravity_gradient)"),
    ("crosscheck.toml", ["actuator.wheels.momentum_compensation=true"], "compensation with law_type 0"),
    ("crosscheck.toml", ["actuator.wheels.spin_inertia_error=0.1"], "spin_inertia_error"),
    ("crosscheck.toml", ['actuator.kind="saturated"'], 'actuator.kind = "saturated"'),
    ("crosscheck.toml", ['reference.kind="slews"', "reference.slews.attitudes=[[0.1, 0.0, 0.0]]",
                         "reference.slews.times=[10.0]"], 'reference.kind = "slews"'),
    ("crosscheck.toml", ["gains.mrp_feedback.K_i=-1.0"], "K_i = -1, use 0"),
    ("crosscheck.toml", ["inertia.events.time_constants=[5.0]"], "an inertia event's blend"),
    ("crosscheck.toml", ["inertia.events.times=[60.004]"], "an inertia step at 60.004 s"),
    ("crosscheck.toml", ['estimator.kind="raw"', "sensors.gyro={}", "sensors.star_tracker={}",
                         'faults=[{time=10.0, star_tracker="outage", end=20.0}]'], "a star-tracker outage"),
    ("crosscheck.toml", ['estimator.kind="raw"', "sensors.gyro={}", "sensors.star_tracker={}",
                         'faults=[{time=10.0, gyro="bias step", step=[1e-5, 0.0, 0.0]}]'], "a gyro bias step"),
    ("crosscheck.toml", ['faults=[{time=10.0, wheel=2, mode="stuck"}]'], "a wheel stuck at its speed"),
])
def test_what_basilisk_cannot_fly_is_one_line(mission, sets, message, in_process, capsys, monkeypatch):
    """Named in one line, exit 2, with Basilisk's import refused (nothing reaches it)."""
    monkeypatch.setitem(sys.modules, "Basilisk", None)
    argv = ["crosscheck", "basilisk", str(MISSIONS / mission), "--out", str(in_process / "out")]
    code = cli.main([*argv, *(x for s in sets for x in ("--set", s))])
    err = [line for line in capsys.readouterr().err.splitlines() if ": warning: " not in line]
    assert code == 2 and len(err) == 1 and err[0].startswith("so3jax crosscheck: error: "), err
    assert message in err[0], err
    assert not (in_process / "out").exists()


def test_without_basilisk_the_error_says_how_to_install(in_process, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "Basilisk", None)
    code = cli.main(["crosscheck", "basilisk", CROSSCHECK, "--out", str(in_process / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == [f"so3jax crosscheck: error: Basilisk is not installed: {basilisk.INSTALL}"]


# Round-off, not modelling: both sides integrate the same equations with RK4 at dt = 0.01 s
# (so3jax on SO(3), Basilisk on MRPs), whose truncation errors differ by (|Omega| dt)^5 ~ 1e-22
# per step; measured over 600 s: 2e-15 rad, 3e-17 rad/s, 2e-13 rad/s in wheel speeds (about
# 50 rad/s: 1e3 ulps accumulated), torque 1e-14 relative. A one-dynamics-step offset in the
# wiring (the task order reversed) gives 6e-10 rad/s, the torque's first-tick integral 7e-3
# relative: the bounds sit 100x above round-off and 1e4x below either.
BOUNDS = {"max_attitude": 1e-13, "max_rate": 1e-15, "max_wheel_speed": 1e-11, "max_torque_relative": 1e-12}


@pytest.mark.parametrize("sets", [
    ["T=100.0"],  # the shipped mission: wheels, law_type 0 with the wheels' momentum in the law, integral on,
    # its inertia's step at 60 s
    ["T=20.0", "actuator.wheels.momentum_compensation=true", "controller.mrp_feedback.law_type=1",
     "controller.mrp_feedback.known_torque=[0.01, -0.02, 0.005]",  # the compensation is law_type 1's term
     'reference.kind="lvlh"', "reference.lvlh={offset=[0.2, -0.1, 0.15]}"],  # hillPoint on Basilisk's orbit
    ["T=65.0", 'actuator.kind="ideal"'],  # extForceTorque, the hub alone, across the step
], ids=["wheels", "compensated-lvlh", "ideal"])
def test_so3jax_and_basilisk_agree_at_round_off(sets, cli_env, capsys):
    pytest.importorskip("Basilisk")
    out = cli_env / "out"
    code = cli.main(["crosscheck", "basilisk", CROSSCHECK, "--out", str(out), "--json",
                     *(x for s in sets for x in ("--set", s))] + ([] if sets == ["T=100.0"] else ["--no-figures"]))
    assert code == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["mrp_feedback"]
    for key, bound in BOUNDS.items():
        assert report[key] <= bound, (key, report[key])
    assert report["ticks_compared"] == round(float(sets[0][2:]) / 0.1)
    assert report["max_torque_command"] > 0.01  # a manoeuvre, not a rest
    assert {"crosscheck.json", "differences.npz"} <= {p.name for p in out.iterdir()}
    assert sets != ["T=100.0"] or (out / "crosscheck.png").stat().st_size > 0


# Wheel 1 fails off at 5.03 s, acting from the tick at 5.1 s, and is dropped from the
# distribution 2 s later (the tick at 7.1 s); wheel 2 is degraded to 0.1 of its limit from
# 3 s, where its clip binds. Basilisk without the faults is 1.8 rad/s apart in wheel speed,
# without the drop 1.4 rad/s, without the degraded limit 0.16 rad/s; either event a tick
# early or late 2e-2 rad/s. The wheels rub (Coulomb and viscous friction), wheel 3's friction
# tripled from 4 s: Basilisk without that fault is 0.13 rad/s apart in wheel speed, with it a
# tick late 1.1e-3 rad/s. The round-off bounds tell each apart.
FAULTS = ["T=20.0", 'faults=[{time=5.03, wheel=1, mode="off"}, {time=3.0, wheel=2, mode="degraded", factor=0.1}, '
          '{time=4.0, wheel=3, mode="friction", factor=3.0}]', "fdir.latency=2.0",
          "actuator.wheels.coulomb_friction=5e-4", "actuator.wheels.viscous_friction=2e-5"]


def test_a_wheel_that_fails_off_is_flown_by_both_at_round_off(cli_env, capsys, monkeypatch):
    """The bounds of the flights without faults, with the wheels' friction and wheel 3's
    friction fault; in Basilisk's run wheel 1, failed off, is slowed by its friction alone
    from its fault's tick on: its axial spin g_1^T Omega + Omega_w,1 falls at
    -(f_c + c_v Omega_w,1) / J_s (it changed otherwise before)."""
    pytest.importorskip("Basilisk")
    from so3jax.missions import mission as missions

    flown, honest = [], basilisk.fly
    monkeypatch.setattr(basilisk, "fly", lambda *args, **kwargs: flown.append(honest(*args, **kwargs)) or flown[-1])
    code = cli.main(["crosscheck", "basilisk", CROSSCHECK, "--out", str(cli_env / "out"), "--json", "--no-figures",
                     *(x for s in FAULTS for x in ("--set", s))])
    assert code == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["mrp_feedback"]
    for key, bound in BOUNDS.items():
        assert report[key] <= bound, (key, report[key])
    assert report["ticks_compared"] == 200
    g = missions.load(CROSSCHECK, FAULTS).actuator["wheels"]["axes"][0]
    (run,) = flown
    spin = run.Omega @ g + run.wheel_speed[:, 0]  # [rad/s], at the ticks 0, 0.1, ... s
    speed = run.wheel_speed[51:, 0]  # about 40 rad/s: the friction's Coulomb and viscous terms
    friction = -(5e-4 + 2e-5 * (speed[1:] + speed[:-1]) / 2) / 0.16 * 0.1  # its change over a tick, trapezoidal
    coasting = np.diff(spin[51:]) - friction
    assert np.max(np.abs(coasting)) <= 1e-9, np.max(np.abs(coasting))  # the trapezoid's error ~1e-12
    assert abs(spin[51] - spin[0]) > 1e-3 and abs(spin[50] - spin[51]) > 1e-6, (spin[0], spin[50], spin[51])


NAVIGATION = ["T=10.0", 'estimator.kind="raw"', "sensors.nav_attitude={sigma=1e-5, bound=3e-5}",
              "sensors.nav_rate={sigma=1e-6}"]


def test_with_navigation_errors_the_two_agree_as_distributions(cli_env, capsys):
    """simpleNav's walks and so3jax's (each side its own draws): 8 runs each, every
    quantity's means equal by Welch's t (p > 1e-3); the files of one run."""
    pytest.importorskip("Basilisk")
    out = cli_env / "out"
    code = cli.main(["crosscheck", "basilisk", CROSSCHECK, "--out", str(out), "--json", "--runs", "8", "--no-figures",
                     *(x for s in NAVIGATION for x in ("--set", s))])
    assert code == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert report["config"]["runs"] == 8 and report["units"]["rate_knowledge"] == "rad/s"
    result = report["mrp_feedback"]
    assert result["agree"] and result["runs"] == 8, result
    knowledge = result["quantities"]["attitude_knowledge"]
    assert 1e-4 < knowledge["so3jax_mean"] < 2e-4  # an MRP walk bounded at 3e-5 per axis: about 4 x 3e-5 x sqrt(3)
    assert sorted(p.name for p in out.iterdir()) == ["crosscheck.json", "manifest.json", "runs.npz"]


def test_a_walk_that_differs_is_told_apart(monkeypatch):
    """Basilisk's attitude walk bounded at twice the mission's: its knowledge error's mean
    differs by far more than the runs' spread (p < 1e-3), so the comparison can fail."""
    pytest.importorskip("Basilisk")
    from so3jax.jobs.crosscheck import statistics
    from so3jax.missions import mission as missions

    mission = missions.load(CROSSCHECK, NAVIGATION)
    honest = basilisk.navigation_errors

    def looser(m):
        P, bounds = honest(m)
        return P, [2.0 * b for b in bounds]

    monkeypatch.setattr(basilisk, "navigation_errors", looser)
    reports, _ = statistics.crosscheck(mission, 8)
    assert not reports["mrp_feedback"]["agree"]
    assert reports["mrp_feedback"]["quantities"]["attitude_knowledge"]["p"] < 1e-3


def test_a_quantity_neither_side_draws_agrees():
    """Without nav_rate the rate knowledge is 0 in every run of both sides: t = 0, p = 1 (not
    Welch's NaN, which would fail the verdict), the other quantities' tests as before."""
    from so3jax.jobs.crosscheck import statistics

    ours = [{"attitude_knowledge": 1e-5 * (1 + 0.1 * i), "rate_knowledge": 0.0, "pointing": 0.2 + 1e-3 * i}
            for i in range(4)]
    theirs = [{**r, "attitude_knowledge": r["attitude_knowledge"] * 1.01} for r in ours]
    result = statistics.compare(ours, theirs)
    assert (result["rate_knowledge"]["t"], result["rate_knowledge"]["p"]) == (0.0, 1.0)
    assert 0 < result["attitude_knowledge"]["p"] < 1 and result["pointing"]["p"] == 1.0
