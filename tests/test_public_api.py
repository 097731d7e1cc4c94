"""The public surface: what the commands compute is reachable from ``import so3jax`` under a
name of ``so3jax.__all__`` (every registered component class under its class name, the
margins' and pointing types), the code of the documentation and of examples/ imports
nothing else (``import so3jax`` and ``from so3jax import NAME`` only, ``sj.NAME`` of a public
NAME), and each library call computes what its command does: one short flight (the same as
tests/test_outputs.py's, so the suite compiles it once), its pointing errors, and the
sweep, tune, margins and identify wrappers on what their commands are given (the real runs
are the commands', which call the same functions)."""

import ast
import json
import re
from pathlib import Path

import numpy as np
import pytest

import so3jax as sj
from so3jax import commands as cli
from so3jax.components import registry as components
from so3jax.jobs import margins as margins_job
from so3jax.jobs.identify import regression, telemetry
from so3jax.jobs.identify import report as identify_report
from so3jax.missions import mission as missions
from so3jax.results.io import dumps

ROOT = Path(__file__).resolve().parents[1]
PUBLIC = frozenset(sj.__all__)
FENCE = re.compile(r"^([ \t]*)```(?:python|py)[ \t]*\n(.*?)^\1```", re.M | re.S)


def non_public(sources: list[str]) -> list[str]:
    """What ``sources`` (the Python of one page or file) use of so3jax that is not public: an
    import of a module under so3jax, ``from so3jax import NAME`` or ``alias.NAME`` of a NAME
    outside ``so3jax.__all__`` (alias: a name ``import so3jax`` binds)."""
    trees = [ast.parse(source) for source in sources]
    aliases, out = set(), []
    for tree in trees:
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    if a.name == "so3jax":
                        aliases.add(a.asname or a.name)
                    elif a.name.startswith("so3jax."):
                        out.append(f"import {a.name}")
            elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "so3jax":
                if node.module != "so3jax":
                    out.append(f"from {node.module} import {', '.join(a.name for a in node.names)}")
                else:
                    out += [f"from so3jax import {a.name}" for a in node.names if a.name not in PUBLIC]
    for tree in trees:
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases
                    and node.attr not in PUBLIC):
                out.append(f"{node.value.id}.{node.attr}")
    return out


def _blocks(markdown: str) -> list[str]:
    """The Python code blocks of a Markdown page, unindented."""
    out = []
    for m in FENCE.finditer(markdown):
        indent = m.group(1)
        out.append("\n".join(line[len(indent):] if line.startswith(indent) else line
                             for line in m.group(2).splitlines()))
    return out


def test_the_docs_and_examples_use_only_public_names():
    pages = sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md", ROOT / "examples" / "README.md"]
    found = {str(p.relative_to(ROOT)): non_public(_blocks(p.read_text())) for p in pages}
    found |= {str(p.relative_to(ROOT)): non_public([p.read_text()]) for p in sorted((ROOT / "examples").glob("*.py"))}
    assert {name: used for name, used in found.items() if used} == {}
    assert "import so3jax as sj" in _blocks((ROOT / "docs" / "library.md").read_text())[0]


def test_the_check_sees_a_private_module_and_a_name_outside_all():
    source = ("import so3jax as sj\nimport so3jax.sim.margins\nfrom so3jax.jobs.identify import telemetry\n"
              "from so3jax import fly, _metadata\nsj.missions.draw\nsj.simulate\n")
    assert non_public([source]) == ["import so3jax.sim.margins", "from so3jax.jobs.identify import telemetry",
                                    "from so3jax import _metadata", "sj.missions"]


def test_every_public_name_resolves_and_all_is_sorted():
    """Sorted as ruff's RUF022 sorts: constants, then classes, then the rest."""
    assert all(getattr(sj, name, None) is not None for name in PUBLIC)
    assert set(dir(sj)) >= PUBLIC and len(PUBLIC) == len(sj.__all__)
    assert sj.__all__ == sorted(sj.__all__, key=lambda n: (0 if n.isupper() else 1 if n[0].isupper() else 2, n))
    with pytest.raises(AttributeError, match="no attribute 'missing'"):
        sj.missing  # noqa: B018


def test_every_registered_component_class_is_public():
    for kind in components.KINDS:
        for name in components.names(kind):
            cls = components.get(kind, name).component
            if cls.__module__.startswith("so3jax."):  # not one a test registered
                assert cls.__name__ in PUBLIC and getattr(sj, cls.__name__) is cls, (kind, name)
    for name in ("CircularOrbit", "Environment", "EnvironmentTorque", "IntegratingGyro", "MomentumWarning",
                 "Linearization", "LoopMargins", "DiskMargins", "loop_at_a_time", "disk_margin", "linearize",
                 "Requirement", "Evaluation", "Margins", "Flight", "Telemetry"):
        assert name in PUBLIC, name


# --- fly and the pointing errors: one flight, as the command flies it -------------------------

FLY = ("fly", "--T", "1", "--controllers", "pd", "--record-every", "10", "--json")  # tests/test_outputs.py's


@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    """(the library's Flight, the command's exit code, its folder): the same flight."""
    out = tmp_path_factory.mktemp("fly") / "out"
    flight = sj.fly(None, "pd", T=1.0, record_every=10)
    with pytest.MonkeyPatch.context() as mp:  # as tests/conftest.py's cli_env
        mp.setenv("SO3JAX_CACHE_DIR", "")
        mp.setenv("SO3JAX_KEEP_XLA_FLAGS", "1")
        code = cli.main([*FLY, "--no-figures", "--out", str(out)])
    return flight, code, out


def test_fly_returns_what_the_command_writes(flown):
    flight, code, out = flown
    written = json.loads((out / "metrics.json").read_text())
    assert list(flight.reports) == ["pd"] and flight.mission.controllers == ("pd",)
    assert json.loads(dumps(flight.reports))["pd"] == written["pd"]
    assert written["config"]["wall_time_s"] > 0 and flight.wall_s > 0
    with np.load(out / "trajectory.npz") as saved:
        arrays = flight.trajectory
        assert sorted(saved.files) == sorted(arrays)
        for key in saved.files:
            np.testing.assert_array_equal(saved[key], arrays[key], err_msg=key)
    with np.load(out / "telemetry" / "pd.npz") as saved:
        for key, value in flight.telemetry("pd").items():
            np.testing.assert_array_equal(saved[key], value, err_msg=key)
    assert code == (1 if flight.diverged or flight.failed else 0) and flight.diverged == []
    r = flight.results["pd"]
    assert float(r.metrics.rmse) == written["pd"]["rmse"] and r.history.t.shape == arrays["pd/t"].shape
    assert "RMSE [rad/s]" in flight.table()


def test_fly_takes_a_mission_object_and_refuses_overrides_on_it(flown):
    flight = flown[0]
    again = sj.fly(flight.mission, ["pd"])  # compiled already
    assert json.loads(dumps(again.reports)) == json.loads(dumps(flight.reports))
    with pytest.raises(ValueError, match="T apply to a mission file"):
        sj.fly(flight.mission, T=2.0)
    with pytest.raises(ValueError, match=r"controllers must be among the mission's \(pd\), got adaptive"):
        sj.fly(flight.mission, "adaptive")
    with pytest.raises(ValueError, match="needs about .* of memory"):
        sj.fly(flight.mission, max_memory=1024)


def test_pointing_errors_are_the_flights(flown):
    flight = flown[0]
    mission, result = flight.mission, flight.results["pd"]
    expected = {k: flight.reports["pd"][k] for k in ("pointing", "requirements")}
    assert sj.pointing_errors(result, mission) == expected
    assert sj.pointing_errors(result.history, mission.scenario(), window=mission.pointing["window"],
                              levels=mission.pointing["levels"], phase_names=mission.phase_names,
                              requirements=mission.requirements) == expected
    rows = expected["pointing"]["phases"][0]["rows"]
    ape = next(row for row in rows if row["index"] == "APE" and row["level"] == 0.95)
    checked = sj.pointing_errors(result, mission, requirements=[
        {"index": "APE", "axis": "angle", "level": 0.95, "limit": 1e9},
        sj.Requirement("APE", "angle", 0.95, 1.0)])["requirements"]
    assert [q["passed"] for q in checked] == [True, False]
    assert checked[0]["value"] == pytest.approx(ape["angle"], rel=1e-12)
    with pytest.raises(ValueError, match="needs the window"):
        sj.pointing_errors(result, mission.scenario())


# --- margins, sweep, tune, identify: the wrappers on their commands' inputs ------------------


def test_margins_at_one_time_or_several(monkeypatch):
    """One time: its Margins; several (None: the command's default times): {t: Margins}."""
    monkeypatch.setattr(margins_job, "at", lambda mission, name, t, dtype: (mission.T, name, t, dtype))
    assert sj.margins(None, None, 10.0, T=20.0) == (20.0, "pd", 10.0, "float64")
    assert sj.margins(None, "adaptive", [1.0, 2.0], T=20.0) == {1.0: (20.0, "adaptive", 1.0, "float64"),
                                                                 2.0: (20.0, "adaptive", 2.0, "float64")}
    default = margins_job.default_times(missions.load(None, ["T=20.0"]))
    assert list(sj.margins(None, "pd", T=20.0)) == list(default)
    with pytest.raises(ValueError, match="outside the horizon"):
        sj.margins(None, "pd", 30.0, T=20.0)
    with pytest.raises(ValueError, match="control is continuous"):
        sj.margins(ROOT / "missions" / "paper.toml", "pd", 1.0)
    with pytest.raises(ValueError, match="'sliding_mode' is not flown"):
        sj.margins(None, "sliding_mode", 1.0)


def test_sweep_reads_its_file_and_options_as_the_command_does(monkeypatch, tmp_path):
    from so3jax.jobs.sweep import config_to_dict, engine, load_config

    seen = []
    monkeypatch.setattr(engine, "run_sweep", lambda config, out, **kw: seen.append((config, out, kw)) or {"ok": 1})
    assert sj.sweep(None, tmp_path / "s", samples=8, T=2, controllers="pd, adaptive", seed=3,
                    overrides=["sweep.chunk=16"]) == {"ok": 1}
    (config, out, kw), = seen
    command = load_config(None, ("sweep.chunk=16", "sweep.samples=8", "T=2.0", "sweep.seed=3",
                                 'controllers=["pd", "adaptive"]'))  # what --set, --samples, ... give
    assert config_to_dict(config) == config_to_dict(command) and config.mission == command.mission
    assert (config.samples, config.mission.T, config.mission.controllers, config.seed, config.chunk) == (
        8, 2.0, ("pd", "adaptive"), 3, 16)
    assert out == tmp_path / "s" and kw == {"resume": False, "progress": None, "max_memory": None, "layout": "chunks"}
    assert sj.sweep(config, tmp_path / "s", resume=True) == {"ok": 1} and seen[-1][0] is config
    with pytest.raises(ValueError, match="a sweep configuration is taken as it is"):
        sj.sweep(config, tmp_path / "s", samples=4)


def test_tune_reads_its_campaign_and_options_as_the_command_does(monkeypatch, tmp_path):
    from so3jax.jobs.tune import campaign
    from so3jax.jobs.tune.config import describe, load_config

    seen = []
    monkeypatch.setattr(campaign, "tune", lambda config, out, **kw: seen.append((config, out, kw)) or {"gains": 1})
    path = ROOT / "tuning" / "pd_equal_effort.toml"
    assert sj.tune(path, tmp_path / "t", iterations=2, T=5, overrides=["tune.optimizer.learning_rate=0.01"]) == {
        "gains": 1}
    (config, out, kw), = seen
    command = load_config(path, [("tune.optimizer.learning_rate", 0.01), ("tune.iterations", 2), ("T", 5.0)])
    assert describe(config) == describe(command) and config.mission == command.mission
    assert (config.iterations, config.mission.T) == (2, 5.0)
    assert out == tmp_path / "t" and kw == {"resume": False, "progress": True}
    with pytest.raises(ValueError, match="a campaign configuration is taken as it is"):
        sj.tune(config, tmp_path / "t", T=1.0)


def test_identify_returns_the_commands_report(tmp_path, capsys):
    from tests.test_identify_refusals import manoeuvre  # telemetry integrated in NumPy: no compilation

    data = manoeuvre()
    np.savez(tmp_path / "tm.npz", **data)
    report = sj.identify(data)
    assert cli.main(["identify", str(tmp_path / "tm.npz"), "--no-figures", "--json", "--out", str(tmp_path / "i")]) == 0
    written = json.loads((tmp_path / "i" / "identification.json").read_text())
    assert json.loads(dumps(report)) == {k: v for k, v in written.items() if k != "config"}
    assert sj.identify(tmp_path / "tm.npz") == report
    tm = telemetry.check(data)
    assert isinstance(tm, sj.Telemetry)
    assert json.loads(dumps(sj.identify(tm, disturbance="none", bias=False))) == json.loads(
        dumps(identify_report.summary(regression.identify(tm, bias=False, degree=-1))))
    with pytest.raises(ValueError, match="initial is the simulation method's first guess"):
        sj.identify(data, initial=3000.0)
    with pytest.raises(ValueError, match="disturbance must be one of"):
        sj.identify(data, disturbance="sinusoid")
    with pytest.raises(ValueError, match="interval must be a positive number of seconds"):
        sj.identify(data, interval=0.0)
