"""Pointing requirements in a mission ([[requirements]], docs/model.md §18) through ``so3jax fly``:
checked on the run's recorded history, reported in metrics.json and on the terminal, a
failed one making the exit code 1; a bad one a one-line error before anything compiles.
In process, with the tiny fly of tests/test_outputs.py (the same compiled program)."""

import json
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from so3jax import commands as cli

FLY = ("fly", "--T", "1", "--controllers", "pd", "--record-every", "10", "--json", "--no-figures",
       # a mission of its own phases: a constant inertia, an inertial reference
       "--set", "inertia.J=[[1200.0, 0.0, 0.0], [0.0, 1000.0, 0.0], [0.0, 0.0, 800.0]]",
       "--set", "reference.kind='inertial'", "--set", "phases.names=['acquire', 'hold']",
       "--set", "phases.start=[0.0, 0.5]")
MET = '{index = "AKE", axis = "angle", level = 0.5, limit = 1e7}'  # the median knowledge error: far below 1e7 arcsec
MISSED = '{index = "AKE", axis = "x", level = 0.5, limit = 0.0}'  # no estimate is exact
HOLD = '{index = "APE", axis = "angle", level = 0.5, limit = 1e7, phase = "hold"}'  # a phase by its name


def test_requirements_are_checked_reported_and_set_the_exit_code(tmp_path, capsys):
    out = tmp_path / "fly"
    code = cli.main([*FLY, "--out", str(out), "--set", f"requirements = [{MET}, {MISSED}, {HOLD}]"])
    assert code == 1
    assert "requirements failed: pd" in capsys.readouterr().err
    saved = json.loads((out / "metrics.json").read_text())
    report = saved["pd"]
    assert saved["units"]["attitude_estimation_rms"] == "rad" and saved["units"]["max_angle_phase"] == "rad"
    assert set(saved["units"]) == {k for k in report if k not in ("pointing", "requirements")}
    assert report["pointing"]["unit"] == "arcsec"
    met, missed, hold = report["requirements"]
    assert hold["passed"] and hold["samples"] == 5 and hold["requirement"].endswith("hold: <= 1e+07 arcsec")
    assert (met["passed"], missed["passed"]) == (True, False)
    # independently: scipy's rotation vectors of R_hat^T R, the 5th smallest of the 10 samples (level 0.5)
    saved = np.load(out / "trajectory.npz")
    e_K = Rotation.from_matrix(np.swapaxes(saved["pd/R_hat"], -1, -2) @ saved["pd/R"]).as_rotvec()
    arcsec = 180 / math.pi * 3600
    assert len(e_K) == 10 and met["samples"] == 10 and met["resolved"]
    assert met["value"] == pytest.approx(np.sort(np.linalg.norm(e_K, axis=1))[4] * arcsec, rel=1e-9)
    assert missed["value"] == pytest.approx(np.sort(np.abs(e_K[:, 0]))[4] * arcsec, rel=1e-9)
    phases = report["pointing"]["phases"]
    assert [p["name"] for p in phases] == ["acquire", "hold"] and [p["samples"] for p in phases] == [5, 5]
    assert len(report["max_angle_phase"]) == 2
    assert {r["index"] for r in phases[0]["rows"]} == {"APE", "MPE", "RPE", "AKE", "MKE", "RKE"}


def test_a_bad_requirement_is_one_line_before_compiling(in_process, capsys):
    bad = '{index = "RPE", axis = "angle", level = 0.95, limit = 5.0}'  # a relative error needs its window
    assert cli.main([*FLY, "--out", "o", "--set", f"requirements = [{bad}]"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "so3jax fly: error: requirements[0].window: missing (the window Dt [s] of RPE)"
    assert not (in_process / "o").exists()


RECORDED = ("the recording interval, 0.1 s (record_every = 10 steps of dt = 0.01 s): "
            "a window must hold a recorded sample")


@pytest.mark.parametrize(("setting", "refused"), [
    (f'requirements = [{MET}, {{index = "RPE", axis = "angle", level = 0.5, limit = 1e7, window = 0.05}}]',
     "requirements[1].window: 0.05 s"),
    ('requirements = [{index = "MKE", axis = "x", level = 0.5, limit = 1e7, window = 0.09}]',
     "requirements[0].window: 0.09 s"),
    ('requirements = [{index = "PDE", axis = "x", level = 0.5, limit = 1e7, window = 0.05, separation = 0.1}]',
     "requirements[0].window: 0.05 s"),
    ("pointing.window = 0.05", "pointing.window: 0.05 s"),
])
def test_a_window_shorter_than_the_recording_interval_is_refused_before_compiling(in_process, capsys, setting,
                                                                                   refused):
    """A window shorter than the time between recorded samples would hold no sample somewhere:
    refused with the mission's other checks, naming the key, its value and the interval."""
    assert cli.main([*FLY, "--out", "o", "--set", setting]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"so3jax fly: error: {refused} is shorter than {RECORDED}"
    assert not (in_process / "o").exists()


def test_the_recording_interval_is_record_every_on_whole_control_periods():
    """record_every rounds up to whole control periods (the flight mission's: 10 steps) and
    down to the horizon; a window of exactly one interval is accepted."""
    from so3jax.missions import mission

    window = '[{index = "RPE", axis = "angle", level = 0.5, limit = 1e7, window = 0.1}]'
    m = mission.load(None, ["T=1.0", "record_every=1", f"requirements={window}", "pointing.window=0.1"])
    assert m.recording == (0.1, "record_every = 1 step of dt = 0.01 s, rounded up to whole control periods of 10 steps")
    assert m.requirements[0].window == 0.1
    assert mission.load(None, ["T=1.0", "record_every=1000", "pointing.window=1.0"]).recording == (
        1.0, "record_every = 1000 steps of dt = 0.01 s, at most the horizon T = 1 s")
    short = window.replace("0.1", "0.5")
    with pytest.raises(ValueError, match=r"^requirements\[0\]\.window: 0\.5 s is shorter than the recording interval"):
        mission.load(None, ["T=1.0", "record_every=1000", "pointing.window=1.0", f"requirements={short}"])


TRUTH = ("--set", "estimator.kind='truth'", "--set", "sensors.gyro=false", "--set", "sensors.star_tracker=false")
NO_ESTIMATE = ("reads the knowledge error, and the mission's estimator (estimator.kind = 'truth') reads the true "
               "state (an estimator that estimates: raw, mekf): there is no estimate to be wrong, so it would pass at "
               "0 arcsec")


@pytest.mark.parametrize(("requirement", "refused"), [
    ('{name = "knowledge", index = "AKE", axis = "x", level = 0.5, limit = 1.0}', "AKE ('knowledge')"),
    ('{index = "MKE", axis = "x", level = 0.5, limit = 1.0, window = 0.5}', "MKE"),
    ('{index = "RKE", axis = "angle", level = 0.5, limit = 1.0, window = 0.5}', "RKE"),
    ('{index = "KDE", axis = "x", level = 0.5, limit = 1.0, window = 0.2, separation = 0.2}', "KDE"),
])
def test_a_knowledge_requirement_without_an_estimate_is_refused_before_compiling(in_process, capsys, requirement,
                                                                                  refused):
    """An estimator that reads the true state has no estimate to be wrong (e_K = 0): a
    knowledge requirement would pass at 0 arcsec whatever it asks. Refused as the mission is
    read, naming the requirement; the performance ones are flown."""
    assert cli.main([*FLY, *TRUTH, "--out", "o", "--set", f"requirements = [{HOLD}, {requirement}]"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"so3jax fly: error: requirements[1].index: {refused} {NO_ESTIMATE}"
    assert not (in_process / "o").exists()


def test_the_paper_mission_takes_no_knowledge_requirement():
    """The paper's continuous wiring reads the truth: a knowledge requirement is refused there too."""
    from pathlib import Path

    from so3jax.missions import mission

    paper = Path(__file__).parents[1] / "missions" / "paper.toml"
    assert mission.load(paper).no_estimate is not None and mission.load(None).no_estimate is None
    with pytest.raises(ValueError, match=r"^requirements\[0\]\.index: AKE reads the knowledge error"):
        mission.load(paper, [f"requirements = [{MET}]"])


def test_the_shipped_sign_off_mission_names_its_requirements_and_phases():
    """missions/signoff.toml (docs/signoff.md): the flight mission with four requirements,
    each line naming the requirement and its phase by name."""
    from pathlib import Path

    from so3jax.missions import mission

    m = mission.load(Path(__file__).parents[1] / "missions" / "signoff.toml")
    assert m.controllers == ("pd", "adaptive") and m.period_steps == 10  # the flight mission's
    lines = [r.describe() for r in m.requirements]
    assert lines[0] == "deployment pointing: APE angle at 0.95 (temporal), deployment: <= 7200 arcsec"
    assert [r.phase for r in m.requirements] == [1, 1, None, None] and "whole run" in lines[2]
