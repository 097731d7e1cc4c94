"""A best_gains.json (``so3jax tune``'s) wherever gains are read: a mission's
``[gains.NAME]`` (in its file, relative to the file's folder; with ``--set``, relative to
the current directory), and tune's and compare's gains, through the one reader
(``so3jax.missions.mission.gains_file``). Nothing here compiles."""

import json
import types

import jax.numpy as jnp
import numpy as np
import pytest

import so3jax
from so3jax import commands as cli
from so3jax.controllers.adaptive import AdaptiveGains
from so3jax.controllers.pd import PDGains
from so3jax.jobs import tune
from so3jax.jobs.tune import storage
from so3jax.missions import mission as missions


def write_best(folder, controller, gains):
    """best_gains.json of a one-iteration campaign at ``gains``, written by tune's own writer."""
    folder.mkdir(parents=True, exist_ok=True)
    row = {"iteration": 0, "cost": 1.0, "rmse": 1e-3, "effort": 10.0, **tune.gain_columns(gains)}
    storage.write_best_gains(folder, types.SimpleNamespace(controller=controller, dispersions=None), [row], gains)
    return folder / "best_gains.json"


def assert_gains_equal(gains, path):
    saved = json.loads(path.read_text())["gains"]
    assert set(gains._fields) == set(saved)
    for name, value in saved.items():
        np.testing.assert_array_equal(np.asarray(getattr(gains, name)), np.asarray(value))


def test_a_tuned_file_given_with_set_is_the_missions_gains(tmp_path, monkeypatch):
    path = write_best(tmp_path / "results" / "tune", "pd", PDGains(1.25, 31.0))
    monkeypatch.chdir(tmp_path)  # a path given with --set is relative to the current directory
    mission = so3jax.load_mission(None, ['gains.pd="results/tune/best_gains.json"', "gains.adaptive.K_w=60.0"])
    assert_gains_equal(mission.gains["pd"], path)
    assert mission.gains["pd"] != PDGains(0.5714, 25.0)  # not the defaults
    assert mission.gains["adaptive"].K_w == 60.0


def test_a_diagonal_gamma_is_read_as_tuned(tmp_path):
    gains = AdaptiveGains(0.01, 60.0, jnp.arange(1.0, 10.0) * 1e7)
    path = write_best(tmp_path, "adaptive", gains)
    mission = so3jax.load_mission(None, [f"gains.adaptive={json.dumps(str(path))}"])
    assert mission.gains["adaptive"].Gamma.shape == (9,)
    assert_gains_equal(mission.gains["adaptive"], path)


def test_a_mission_file_names_a_gains_file_relative_to_itself(tmp_path, monkeypatch):
    path = write_best(tmp_path / "missions" / "tuned", "pd", PDGains(1.25, 31.0))
    (tmp_path / "missions" / "m.toml").write_text('controllers = ["pd"]\n[gains]\npd = "tuned/best_gains.json"\n')
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert_gains_equal(so3jax.load_mission(tmp_path / "missions" / "m.toml").gains["pd"], path)
    # a job file's mission: the mission file's gains relative to it, the job's own to the job's folder
    mission, _ = missions.load_job({"mission": "missions/m.toml"}, tmp_path, ())
    assert_gains_equal(mission.gains["pd"], path)
    other = write_best(tmp_path / "jobs", "pd", PDGains(2.0, 40.0))
    mission, _ = missions.load_job({"mission": "../missions/m.toml", "gains": {"pd": "best_gains.json"}},
                                   tmp_path / "jobs", ())
    assert_gains_equal(mission.gains["pd"], other)


def bad_files(tmp_path):
    """{case: (path, what the error says)}."""
    adaptive = write_best(tmp_path / "adaptive", "adaptive", AdaptiveGains(0.01, 60.0, 1e8))
    (tmp_path / "broken.json").write_text('{"controller": "pd", "gains": {"k_R": 1.0,')
    (tmp_path / "table.json").write_text('{"k_R": 1.0, "k_Omega": 25.0}')
    (tmp_path / "partial.json").write_text('{"controller": "pd", "gains": {"k_R": 1.0}}')
    (tmp_path / "negative.json").write_text('{"controller": "pd", "gains": {"k_R": -1.0, "k_Omega": 25.0}}')
    return {
        "another law": (adaptive, "tuned for the 'adaptive' controller, not 'pd'"),
        "missing": (tmp_path / "nowhere.json", "does not exist"),
        "not JSON": (tmp_path / "broken.json", "is not JSON"),
        "not tune's": (tmp_path / "table.json", "is not a best_gains.json"),
        "a gain missing": (tmp_path / "partial.json", "misses the pd gain 'k_Omega'"),
        "a bad gain": (tmp_path / "negative.json", "k_R must be positive"),
        "a folder": (tmp_path, "cannot be read"),
    }


@pytest.mark.parametrize("case", ["another law", "missing", "not JSON", "not tune's", "a gain missing", "a bad gain",
                                  "a folder"])
def test_a_bad_gains_file_is_a_one_line_error(case, tmp_path):
    path, message = bad_files(tmp_path)[case]
    with pytest.raises(ValueError) as mission_error:
        so3jax.load_mission(None, [f"gains.pd={json.dumps(str(path))}"])
    text = str(mission_error.value)
    assert len(text.splitlines()) == 1 and text.startswith(f"gains.pd: gains file {path}") and message in text, text
    with pytest.raises(ValueError) as tune_error:  # tune and compare: the same reader, the same words
        tune.resolve_gains("pd", str(path), jnp.float64)
    assert str(tune_error.value) == text.removeprefix("gains.pd: ")


def test_a_gains_file_of_a_law_not_flown_is_checked(tmp_path):
    path = write_best(tmp_path, "adaptive", AdaptiveGains(0.01, 60.0, 1e8))
    with pytest.raises(ValueError, match="tuned for the 'adaptive' controller, not 'pd'"):
        so3jax.load_mission(None, ["controllers=adaptive", f"gains.pd={json.dumps(str(path))}"])


@pytest.mark.parametrize("value", ["missing.json", "adaptive/best_gains.json"])
def test_fly_refuses_a_bad_gains_file_before_any_folder(value, in_process, capsys):
    write_best(in_process / "adaptive", "adaptive", AdaptiveGains(0.01, 60.0, 1e8))
    out = in_process / "out"
    code = cli.main(["fly", "--set", f"gains.pd={value}", "--out", str(out), "--no-figures"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(f"so3jax fly: error: gains.pd: gains file {value} "), err
    assert len(err.strip().splitlines()) == 1 and not out.exists(), err
