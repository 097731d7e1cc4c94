"""The JSON Schemas of so3jax's files (``so3jax schema``, schemas/): every shipped TOML file
names its schema on its first line (taplo's ``#:schema PATH``) and validates against it; a
typo'd key, a wrong type and an out-of-range value each fail; the schemas are generated from
the parsers' own tables (a key added there appears in the schema) and the committed files
are what the generator writes now. No JAX compilation."""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import jsonschema
import pytest

from so3jax.commands import schema as command
from so3jax.components import registry as components
from so3jax.controllers import registry
from so3jax.core.params import Param
from so3jax.jobs import schema
from so3jax.jobs.sweep import config as sweeps
from so3jax.jobs.tune import config as campaigns
from so3jax.missions import keys
from so3jax.missions import mission as missions
from so3jax.missions import schema as mission_schema
from so3jax.sim import pointing

ROOT = Path(__file__).resolve().parents[1]
SCHEMAS = ROOT / "schemas"
DIRECTIVE = re.compile(r"#:schema (\S+)\n")


def _shipped() -> list[Path]:
    """The repository's TOML files but pyproject.toml (``git ls-files``; the shipped folders without git)."""
    try:
        listed = subprocess.run(["git", "ls-files", "*.toml"], cwd=ROOT, capture_output=True, text=True, check=True,
                                timeout=60).stdout.split()
    except (OSError, subprocess.SubprocessError):
        listed = [str(p.relative_to(ROOT)) for folder in ("missions", "sweeps", "tuning", "comparisons", "examples")
                  for p in (ROOT / folder).glob("**/*.toml")]
    return [ROOT / name for name in sorted(listed) if name != "pyproject.toml"]


def _committed(name: str) -> dict:
    return json.loads((SCHEMAS / name).read_text(encoding="utf-8"))


def _errors(schema_doc: dict, data: dict) -> list[str]:
    return [f"{list(e.absolute_path)}: {e.message}" for e in jsonschema.Draft7Validator(schema_doc).iter_errors(data)]


def test_every_shipped_file_names_its_schema_on_its_first_line_and_validates():
    files = _shipped()
    folders = {p.relative_to(ROOT).parts[0] for p in files}
    assert {"missions", "sweeps", "tuning", "comparisons"} <= folders
    named = {}
    for path in files:
        text = path.read_text(encoding="utf-8")
        directive = DIRECTIVE.match(text)
        assert directive, f"{path.relative_to(ROOT)}: its first line names no schema (#:schema ../schemas/NAME.json)"
        target = (path.parent / directive.group(1)).resolve()
        assert target.parent == SCHEMAS and target.name in schema.FILES, (path, directive.group(1))
        errors = _errors(_committed(target.name), tomllib.loads(text))
        assert not errors, (path.relative_to(ROOT), errors[:3])
        named.setdefault(target.name, []).append(path.relative_to(ROOT).parts[0])
    # each folder's files name its kind's schema
    assert set(named["mission.json"]) == {"missions"} and set(named["sweep.json"]) == {"sweeps"}
    assert set(named["campaign.json"]) == {"tuning"} and set(named["compare.json"]) == {"comparisons"}


def test_the_schemas_are_draft_07():
    for name in schema.FILES:
        document = _committed(name)
        assert document["$schema"] == "http://json-schema.org/draft-07/schema#"
        jsonschema.Draft7Validator.check_schema(document)


def test_the_committed_schemas_are_what_the_generator_writes_now(tmp_path):
    """A fresh interpreter (no component a test registered in this process): ``so3jax schema
    --check`` on schemas/, then written into a folder, byte for byte the committed files."""
    def cli(*args):
        return subprocess.run([sys.executable, "-m", "so3jax.commands", "schema", *args], cwd=ROOT,
                              capture_output=True, text=True, timeout=300)

    run = cli("--check", "--out", str(SCHEMAS))
    assert run.returncode == 0, f"schemas/ is stale: run `so3jax schema`\n{run.stdout}{run.stderr}"
    run = cli("--out", str(tmp_path))
    assert run.returncode == 0, run.stderr
    for name in schema.FILES:
        assert (tmp_path / name).read_text(encoding="utf-8") == (SCHEMAS / name).read_text(encoding="utf-8"), name


def test_check_names_a_stale_or_missing_file(tmp_path, capsys):
    args = argparse.Namespace(out=tmp_path, check=False)
    assert command.run(args) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(schema.FILES)  # no temporary file left behind
    assert command.run(argparse.Namespace(out=tmp_path, check=True)) == 0
    (tmp_path / "sweep.json").write_text("{}\n")
    (tmp_path / "compare.json").unlink()
    capsys.readouterr()
    assert command.run(argparse.Namespace(out=tmp_path, check=True)) == 1
    assert "sweep.json, compare.json differ" in capsys.readouterr().err


# --- what fails validation -----------------------------------------------------------------------

FLIGHT = tomllib.loads((ROOT / "missions" / "flight.toml").read_text(encoding="utf-8"))


def _with(base: dict, dotted: str, value) -> dict:
    data = copy.deepcopy(base)
    *tables, last = dotted.split(".")
    node = data
    for t in tables:
        node = node.setdefault(t, {})
    node[last] = value
    return data


@pytest.mark.parametrize(("key", "value", "message"), [
    # a typo'd key: at the top, in a table, in a component's table, a component's name, a gain
    ("dtt", 0.1, "'dtt' was unexpected"),
    ("control.perod", 0.1, "'perod' was unexpected"),
    ("actuator.wheels.max_sped", 600.0, "'max_sped' was unexpected"),
    ("sensors.gyroo", {}, "'gyroo' was unexpected"),
    ("gains.pd.kR", 1.0, "not valid under any"),
    ("schedule.pd", {"by": "phase", "att": [0.0]}, "'att' was unexpected"),
    # a wrong type
    ("T", "long", "is not of type 'number'"),
    ("seed", 1.5, "is not of type 'integer'"),
    ("controllers", [1, 2], "not valid under any"),
    ("actuator.wheels.momentum_compensation", "yes", "is not of type 'boolean'"),
    ("inertia.J0.nominal", [[1.0, 0.0, 0.0]], "is too short"),
    # a value out of its domain, or not among the choices
    ("seed", -1, "less than the minimum of 0"),
    ("orbit.inclination", 200.0, "greater than the maximum of 180"),
    ("pointing.levels", [0.5, 1.5], "greater than the maximum of 1"),
    ("sensors.star_tracker.every", 0, "not valid under any"),
    ("actuator.wheels.spin_inertia", 0.0, "not valid under any"),  # (0, inf): 0 excluded
    ("estimator.kind", "ukf", "is not one of"),
    ("controllers", ["pd", "lqr"], "not valid under any"),
    ("gains.pd.k_R", -1.0, "not valid under any"),
])
def test_a_typo_a_wrong_type_or_an_out_of_range_value_fails_the_mission_schema(key, value, message):
    document = _committed("mission.json")
    assert _errors(document, FLIGHT) == []
    errors = _errors(document, _with(FLIGHT, key, value))
    assert errors and any(message in e for e in errors), errors


@pytest.mark.parametrize(("entry", "message"), [
    ({"index": "RPE", "axis": "x", "level": 0.95, "limit": 5.0}, "'window' is a required property"),
    ({"index": "APE", "axis": "x", "level": 0.95, "limit": 5.0, "window": 10.0}, "should not be valid"),
    ({"index": "APE", "axis": "x", "level": 1.5, "limit": 5.0}, "greater than or equal to the maximum of 1"),
    ({"index": "APE", "axis": "q", "level": 0.95, "limit": 5.0}, "is not one of"),
    ({"index": "APE", "axis": "x", "level": 0.95}, "'limit' is a required property"),
    ({"index": "APE", "axis": "x", "level": 0.95, "limit": 5.0, "phse": 1}, "'phse' was unexpected"),
])
def test_a_bad_requirement_fails(entry, message):
    errors = _errors(_committed("mission.json"), {"requirements": [entry]})
    assert any(message in e for e in errors), errors


def test_the_job_files_own_tables_fail_on_a_typo_a_wrong_type_or_an_out_of_range_value():
    sweep = tomllib.loads((ROOT / "sweeps" / "flight.toml").read_text(encoding="utf-8"))
    campaign = tomllib.loads((ROOT / "tuning" / "design_pd.toml").read_text(encoding="utf-8"))
    comparison = tomllib.loads((ROOT / "comparisons" / "flight_cvar.toml").read_text(encoding="utf-8"))
    cases = [
        ("sweep.json", sweep, "sweep.sampels", 8, "'sampels' was unexpected"),
        ("sweep.json", sweep, "sweep.samples", 0, "less than the minimum of 1"),
        ("sweep.json", sweep, "sweep.pointing", "yes", "is not of type 'boolean'"),
        ("sweep.json", sweep, "sweep.divergence_angle_deg", 200.0, "greater than the maximum of 180"),
        ("sweep.json", sweep, "dispersions.seed", "rand", "is not one of"),
        ("sweep.json", sweep, "dispersions.sensors.gyro.arww", 1e-6, "'arww' was unexpected"),
        ("sweep.json", sweep, "dispersions.orbit.n", {"dist": "uniform", "low": 1e-3}, "not valid under any"),
        ("sweep.json", sweep, "dispersions.orbit.n", {"dist": "uniform", "low": 0, "high": 1, "relative": "scale"},
         "not valid under any"),  # a structured leaf takes no relative
        ("campaign.json", campaign, "tune.iteration", 3, "'iteration' was unexpected"),
        ("campaign.json", campaign, "tune.iterations", 0, "less than or equal to the minimum of 0"),
        ("campaign.json", campaign, "tune.method", "adam", "is not one of"),
        ("campaign.json", campaign, "tune.optimizer.learning_rate", "fast", "is not of type 'number'"),
        ("campaign.json", campaign, "tune.train.seds", [0], "'seds' was unexpected"),
        ("campaign.json", campaign, "tune.goals", [{"margin": "disk", "min_db": 6.0, "axis": "x", "hard": True}],
         "not valid under any"),  # the disk margin has no axis
        ("campaign.json", campaign, "tune.goals", [{"budget": "effort", "limit": -1.0, "hard": False}],
         "not valid under any"),
        ("campaign.json", campaign, "tune.bounds", {"k_RR": [0.1, 1.0]}, "is not one of"),
        ("compare.json", comparison, "compare.bootstrap", 10, "less than the minimum of 100"),
        ("compare.json", comparison, "compare.candidates.pd_mean.controler", "pd", "'controler' was unexpected"),
        ("compare.json", comparison, "tune.controller", "pd", "'controller' was unexpected"),
    ]
    for name, base, key, value, message in cases:
        document = _committed(name)
        assert _errors(document, base) == [], name
        errors = _errors(document, _with(base, key, value))
        assert any(message in e for e in errors), (name, key, value, errors)


# --- one source: the parsers' tables --------------------------------------------------------------


def _properties(document: dict, *path: str) -> dict:
    node = document
    for key in path:
        node = node["properties"][key]
    return node["properties"]


def test_a_key_added_to_the_parsers_tables_appears_in_the_schema(monkeypatch):
    extra = Param("pointing.settle", 30.0, "s", low=0.0, doc="a key added to the mission's table")
    monkeypatch.setattr(keys, "KEYS", (*keys.KEYS, extra))
    monkeypatch.setattr(keys, "KEY", {**keys.KEY, extra.name: extra})
    monkeypatch.setattr(pointing, "KEYS", (*pointing.KEYS, "owner"))
    monkeypatch.setattr(sweeps, "SWEEP_KEYS", (*sweeps.SWEEP_KEYS, "extra_draws"))
    monkeypatch.setitem(sweeps.DEFAULT["sweep"], "extra_draws", 3)
    tracker = components.get("sensor", "star_tracker")
    sensor = dataclasses.replace(tracker, name="test_tracker",
                                 params=(*tracker.params, Param("blur", 1e-5, "rad", low=0.0, doc="image blur")))
    law = dataclasses.replace(registry.get("pd"), name="test_pd")
    components.register(sensor)
    registry.register(law)
    try:
        mission = mission_schema.mission()
        sweep = schema.sweep()
    finally:
        components.unregister("sensor", "test_tracker")
        registry.unregister("test_pd")
    settle = _properties(mission, "pointing")["settle"]
    assert settle["minimum"] == 0 and settle["default"] == 30.0 and "[s]" in settle["description"]
    assert "owner" in mission["properties"]["requirements"]["items"]["properties"]
    blur = _properties(mission, "sensors")["test_tracker"]["anyOf"][0]["properties"]["blur"]
    assert blur["minimum"] == 0 and "image blur" in blur["description"]
    assert "test_pd" in _properties(mission, "controller") and "test_pd" in _properties(mission, "gains")
    assert "test_pd" in _properties(mission, "schedule")  # a tunable law can be scheduled
    assert "test_pd" in mission["properties"]["controllers"]["anyOf"][0]["enum"]
    assert _properties(sweep, "sweep")["extra_draws"] == {"type": "integer", "default": 3}
    dispersions = sweep["definitions"]["dispersions"]
    assert "blur" in _properties(dispersions, "sensors", "test_tracker")  # a real-valued parameter is dispersible
    assert "test_tracker" not in _properties(mission_schema.mission(), "sensors")  # unregistered: gone


def test_a_campaign_field_added_appears_in_the_schema(monkeypatch):
    grown = dataclasses.make_dataclass("TuneConfig", [("patience", int, dataclasses.field(default=4))],
                                       bases=(campaigns.TuneConfig,), frozen=True)
    monkeypatch.setattr(campaigns, "TuneConfig", grown)
    assert _properties(schema.campaign(), "tune")["patience"] == {"type": "integer", "default": 4}


def test_a_table_the_parser_accepts_without_a_rule_is_refused(monkeypatch):
    monkeypatch.setattr(missions, "MISSION_TABLES", (*missions.MISSION_TABLES, "telemetry"))
    with pytest.raises(ValueError, match="no rule for the mission key 'telemetry'"):
        mission_schema.mission()


def test_the_value_rules_name_only_keys_the_parsers_declare():
    assert set(mission_schema.REQUIREMENT_VALUES) <= set(pointing.KEYS)
    assert set(mission_schema.SETS) | set(mission_schema.CHOSEN) <= set(missions.MISSION_TABLES)
