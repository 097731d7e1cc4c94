"""Bad values of every config entry, generated from the schemas: the default mission's
tree (so3jax.missions.mission.default_tree(): the flight mission with every registered
component, option and gain), the sweep
defaults (sweep.config_to_dict(sweep.load_config())) and a shipped tune campaign with its
dataclass defaults. For every leaf: a wrong-type value (a string for a number, a bool for
a number, a number for a string, a table for a leaf, ...), and for every array a
wrong-shape one. Each must be a ValueError from the parser, one line, naming the key:
parser level, nothing compiled. A few checks through so3jax.commands.main close the file."""

from __future__ import annotations

import dataclasses
import importlib
import json
from pathlib import Path

import numpy as np
import pytest

from so3jax import commands as cli
from so3jax.controllers import registry
from so3jax.jobs import sweep, tune
from so3jax.missions import config as cfg
from so3jax.missions import mission
from so3jax.sim.loop import check_loop

ROOT = Path(__file__).resolve().parents[1]
TUNE_FILE = ROOT / "tuning" / "pd_equal_effort.toml"
TABLE = {"x": 1.0}  # a table where a value belongs


# --- the trees ------------------------------------------------------------------------


def mission_tree() -> dict:
    """The mission schema's tree: the flight mission with every registered component's
    parameters, controller options and default gains."""
    return json.loads(json.dumps(mission.default_tree()))


def sweep_tree() -> dict:
    return json.loads(json.dumps(sweep.config_to_dict(sweep.load_config())))


def tune_base() -> dict:
    return cfg.read_toml(TUNE_FILE)


def tune_tree() -> dict:
    """The shipped campaign's [tune] table, every field of its TuneConfig (defaults
    included); its mission's entries are the mission tree's."""
    return json.loads(json.dumps({tune.TUNE: tune.tune_table(tune.load_config(TUNE_FILE))}))


def _annotation(path) -> str:
    """The dataclass annotation of a [tune] field (the schema of a None default)."""
    cls = tune.TuneConfig
    for key in path[1:-1]:
        cls = tune.SECTIONS.get(key)
        if cls is None:
            return ""
    return next((str(f.type) for f in dataclasses.fields(cls) if f.name == path[-1]), "")


def leaves(tree: dict, prefix=()):
    """(path, value) of every leaf; an empty table is a leaf."""
    for key, value in tree.items():
        if isinstance(value, dict) and value:
            yield from leaves(value, prefix + (key,))
        else:
            yield prefix + (key,), value


def _numeric(value) -> bool:
    if isinstance(value, list):
        return bool(value) and all(_numeric(x) for x in value)
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _drop_last(value):
    """value with the last element of its innermost axis dropped."""
    return [_drop_last(x) for x in value] if isinstance(value[0], list) else value[:-1]


def _first_to_string(value):
    """value with its first number written as a string."""
    return [_first_to_string(value[0]) if isinstance(value[0], list) else str(value[0]), *value[1:]]


def _first_to_bool(value):
    """value with its first number replaced by true."""
    return [_first_to_bool(value[0]) if isinstance(value[0], list) else True, *value[1:]]


def bad_values(value, annotation: str = ""):
    """(what, bad value) pairs for a leaf of default ``value`` (``annotation``: the
    schema's type where the default is None)."""
    if value is None:
        value = 1.0 if ("float" in annotation or "int" in annotation) else "name"
    if isinstance(value, bool):
        return [("string for a bool", "yes"), ("number for a bool", 1.0), ("table for a bool", TABLE)]
    if isinstance(value, (int, float)):
        return [("string for a number", "big"), ("bool for a number", True), ("table for a number", TABLE),
                ("array for a number", [value, value])]
    if isinstance(value, str):
        return [("number for a string", 1.5), ("bool for a string", True), ("table for a string", TABLE)]
    if isinstance(value, dict):  # an empty table
        return [("number for a table", 1.5), ("string for a table", "big"), ("bool for a table", True)]
    assert isinstance(value, list), value
    out = [("string for an array", "big"), ("bool for an array", True), ("table for an array", TABLE),
           ("extra axis", [value])]
    if _numeric(value):
        out.append(("a string in an array", _first_to_string(value)))
        out.append(("a bool in an array", _first_to_bool(value)))
        if "..." not in annotation:  # a fixed shape (not a tuple[float, ...] of any length)
            out.append(("an element short", _drop_last(value)))
    else:
        out.append(("number in a list of names", [*value[:-1], 1.5]))
    return out


def nested(path, value) -> dict:
    d = value
    for key in reversed(path):
        d = {key: d}
    return d


def toml(value) -> str:
    """value as a TOML inline value (what --set KEY=VALUE reads)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(map(toml, value)) + "]"
    return "{" + ", ".join(f"{k} = {toml(v)}" for k, v in value.items()) + "}"


def cases(tree, annotate=lambda path: ""):
    return [(".".join(path), what, bad)
            for path, value in leaves(tree) for what, bad in bad_values(value, annotate(path))]


def _mission_annotation(path) -> str:
    """A mission key of any length (a shape with None, e.g. pointing.levels) reads as tuple[float, ...]."""
    from so3jax.missions import keys

    param = keys.KEY.get(".".join(path))
    return "tuple[float, ...]" if param is not None and any(None in shape for shape in param.shapes) else ""


MISSION_CASES = cases(mission_tree(), _mission_annotation)
SWEEP_CASES = cases(sweep_tree())
TUNE_CASES = cases(tune_tree(), _annotation)
ids = lambda cases: [f"{key}: {what}" for key, what, _ in cases]


def assert_one_line_naming(err: pytest.ExceptionInfo, key: str) -> None:
    message = str(err.value)
    assert "\n" not in message, message
    assert key in message, f"{key!r} not named in: {message}"


@pytest.fixture(autouse=True)
def nothing_compiled(monkeypatch):
    """A bad value must stop the parser before any rollout is built."""

    def compiled(*args, **kwargs):
        raise AssertionError("reached a rollout")

    monkeypatch.setattr(importlib.import_module("so3jax.sim.rollout"), "_rollout", compiled)


# --- generated: parser level --------------------------------------------------------------


def test_every_leaf_has_cases():
    """The generators walk whole trees: every table of the schemas contributes."""
    assert len(MISSION_CASES) > 100 and len(SWEEP_CASES) > 100 and len(TUNE_CASES) > 60
    keys = {key for key, _, _ in MISSION_CASES}
    assert {"gains.adaptive.Gamma", "gains.pd.k_R", "gains.open_loop", "actuator.wheels.axes", "T"} <= keys


@pytest.mark.parametrize("key,what,bad", MISSION_CASES, ids=ids(MISSION_CASES))
def test_mission_bad_value(key, what, bad):
    with pytest.raises(ValueError) as err:
        mission.from_dict(nested(key.split("."), bad))
    assert_one_line_naming(err, key)
    with pytest.raises(ValueError) as err:
        mission.load(None, [f"{key}={toml(bad)}"])
    assert_one_line_naming(err, key)


@pytest.mark.parametrize("key,what,bad", SWEEP_CASES, ids=ids(SWEEP_CASES))
def test_sweep_bad_value(key, what, bad):
    table = sweep_tree()  # whole: a distribution table given replaces the default one
    cfg.set_dotted(table, key, bad)
    with pytest.raises(ValueError) as err:
        sweep.config_from_dict(table)
    assert_one_line_naming(err, key)
    with pytest.raises(ValueError) as err:
        sweep.load_config(ROOT / "sweeps" / "default.toml", (f"{key}={toml(bad)}",))
    assert_one_line_naming(err, key)


@pytest.mark.parametrize("key,what,bad", TUNE_CASES, ids=ids(TUNE_CASES))
def test_tune_bad_value(key, what, bad):
    table = tune_base()
    cfg.set_dotted(table, key, bad)
    with pytest.raises(ValueError) as err:
        tune.parse_config(table, TUNE_FILE.parent)
    assert_one_line_naming(err, key)
    with pytest.raises(ValueError) as err:
        tune.load_config(TUNE_FILE, [cfg.parse_override(f"{key}={toml(bad)}")])
    assert_one_line_naming(err, key)


@pytest.mark.parametrize(
    "override",
    ["gains.adaptive.Gamma=[1.0, 2.0, 3.0]", "gains.adaptive.Gamma=[[1.0, 2.0], [3.0, 4.0]]", 'gains.pd.k_R="big"',
     "gains.pd.k_Omega=true", "gains.adaptive.K_w=[75.0]", "gains.open_loop.k=1.0"],
)
def test_gains_are_checked_per_field_against_the_registration(override):
    """Scalar gains take numbers; Gamma a number, a (9,) diagonal or a (9, 9) matrix."""
    with pytest.raises(ValueError) as err:
        mission.load(None, [override])
    assert_one_line_naming(err, override.partition("=")[0].rpartition(".")[0])


def test_gains_of_every_registered_shape_are_accepted():
    spec = registry.get("adaptive")
    assert spec.gain_shapes()["Gamma"] == ((), (9,), (9, 9)) and registry.get("pd").gain_shapes()["k_R"] == ((),)
    diagonal = mission.load(None, ["gains.adaptive.Gamma=[1e8, 1e8, 1e8, 1e8, 1e8, 1e8, 1e8, 1e8, 1e8]"])
    assert diagonal.gains["adaptive"].Gamma.shape == (9,)
    full = mission.from_dict({"gains": {"adaptive": {"Gamma": (1e8 * np.eye(9)).tolist()}}})
    assert full.gains["adaptive"].Gamma.shape == (9, 9)
    assert mission.load().gains == {n: registry.get(n).defaults for n in ("pd", "adaptive")}


# --- generated: the library's components ----------------------------------------------------


def _component_cases():
    """(loop, component path, field, what, bad value) for every parameter of every
    component of the flight loop (gyro, star tracker, MEKF, wheels) and the saturated
    actuator, from their dataclass fields."""
    flight = mission.load()
    loops = [mission.build_loop(flight, np.asarray),
             mission.build_loop(mission.load(None, ['actuator.kind="saturated"']), np.asarray)]
    out = []
    for loop in loops:
        for path in (("sensors", "rate"), ("sensors", "attitude"), ("estimator",), ("actuator",)):
            part = loop
            for name in path:
                part = getattr(part, name)
            for field in dataclasses.fields(part):
                value = getattr(part, field.name)
                value = value.tolist() if isinstance(value, np.ndarray) else value
                for what, bad in bad_values(value, "..." if field.name == "axes" else ""):  # any number of wheels
                    out.append((loop, path, field.name, what, bad))
    return out


COMPONENT_CASES = _component_cases()


def _replace(loop, path, field, value):
    if len(path) == 1:
        return dataclasses.replace(loop, **{path[0]: dataclasses.replace(getattr(loop, path[0]), **{field: value})})
    return dataclasses.replace(loop, sensors=_replace(loop.sensors, path[1:], field, value))


@pytest.mark.parametrize("loop,path,field,what,bad", COMPONENT_CASES,
                         ids=[f"{type(c[0].actuator).__name__}-{'.'.join(c[1])}.{c[2]}: {c[3]}"
                              for c in COMPONENT_CASES])
def test_component_bad_parameter(loop, path, field, what, bad):
    """A library component with a parameter of the wrong type or shape: the loop's check
    (what rollout and simulate run first) raises one line naming the parameter."""
    bad_loop = _replace(loop, path, field, bad)
    with pytest.raises(ValueError) as err:
        check_loop(bad_loop, {"J0": np.diag([600.0, 400.0, 900.0])})
    assert_one_line_naming(err, field)


# --- cross-field checks -------------------------------------------------------------------


@pytest.mark.parametrize(
    "overrides,message",
    [
        (["actuator.wheels.initial_speed=700.0"], "initial_speed [rad/s] must not exceed actuator.wheels.max_speed"),
        (["actuator.wheels.initial_speed=[0.0, -628.5, 0.0, 0.0]"], "(wheel 2: -628.5 against 628)"),
        (["T=0.05"], "control.period = 0.1 s is longer than the horizon T = 0.05 s"),
        (["T=0.25"], "T (horizon) = 0.25 s is not a whole number of control periods"),
        (["T=4000.05"], "not a whole number of control periods"),
    ],
)
def test_cross_field_checks(overrides, message):
    with pytest.raises(ValueError) as err:
        mission.load(None, overrides)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_cross_field_limits_are_inclusive():
    """A wheel at its speed limit and a horizon of one control period are accepted; the
    shipped missions (T = 4000 s, 40000 periods of 0.1 s) pass."""
    mission.load(None, ["actuator.wheels.initial_speed=628.0", "T=0.1"])
    mission.load(ROOT / "missions" / "flight.toml")
    mission.load(ROOT / "missions" / "paper.toml", ["T=0.25"])  # continuous: no control period


def test_library_wheels_refuse_an_initial_speed_over_the_limit():
    from so3jax.components.actuators import Wheels, pyramid_axes

    wheels = Wheels(pyramid_axes(), np.full(4, 0.16), np.full(4, 0.25), np.full(4, 100.0), np.r_[0.0, 150.0, 0.0, 0.0])
    message = r"initial_speed .* must not exceed .*max_speed .*\(wheel 2: 150 against 100\)"
    with pytest.raises(ValueError, match=message):
        wheels.check()


# --- the command line ---------------------------------------------------------------------


def _non_utf8(tmp_path) -> str:
    path = tmp_path / "latin1.toml"
    path.write_bytes("T = 20.0  # \u00e9t\u00e9\n".encode("latin-1"))
    return str(path)


def _tune_copy(tmp_path) -> str:
    """The shipped campaign elsewhere, its mission file named by an absolute path."""
    path = tmp_path / "campaign.toml"
    text = TUNE_FILE.read_text()
    mission_line = next(line for line in text.splitlines() if line.startswith("mission = "))
    mission_path = (TUNE_FILE.parent / cfg.parse_override(mission_line)[1]).resolve()
    path.write_text(text.replace(mission_line, f"mission = {json.dumps(str(mission_path))}"))
    return str(path)


@pytest.mark.parametrize(
    "argv,message",
    [
        (["fly", "--set", 'gains.adaptive.Gamma="big"'], "gains.adaptive.Gamma must be"),
        (["fly", "--set", "gains.pd.k_R=true"], "gains.pd.k_R must be a number, got True"),
        (["fly", "--set", "gains.adaptive.Gamma=[1,2,3]"], "gains.adaptive.Gamma must be"),
        (["fly", _non_utf8], "is not UTF-8 text"),
        (["paper", "--T", "nan"], "T (horizon) [s] must be a finite number"),
        (["paper", "--set", "controllers=pd"], "so3jax paper compares pd and adaptive"),
        (["paper", "--set", "sensors.gyro={}"], "continuous"),
        (["sweep", "--set", "dispersions.sensors.gyro.arw=1e-6"], "the mission flies no sensors 'gyro'"),
        (["fly", "--T", "0.25"], "not a whole number of control periods"),
        (["fly", "--set", "actuator.wheels.initial_speed=-700.0"], "actuator.wheels.initial_speed"),
        (["sweep", "--set", "dispersions.deployment.tau_J={dist=[1]}"],
         "dispersions.deployment.tau_J.dist must be one of"),
        (["sweep", "--set", "gains.adaptive.Gamma={a=1}"], "gains.adaptive.Gamma must be"),
        (["tune", _tune_copy, "--set", "tune.optimizer.options=1.5"], "'tune.optimizer.options' must be a table"),
        (["tune", _tune_copy, "--set", "tune.train.seeds=3"], "'tune.train.seeds' must be a non-empty list"),
        (["tune", _tune_copy, "--set", "tune.initial_gains={k_R=true, k_Omega=25.0}"], "gains.k_R must be a number"),
        (["tune", _tune_copy, "--set", "gains.pd.k_R=true"], "gains.pd.k_R must be a number"),
        (["tune", _tune_copy, "--set", "optimizer.name=1"], "unknown config key(s): optimizer"),
    ],
    ids=lambda x: x if isinstance(x, str) else None,
)
def test_cli_bad_values_are_one_line(argv, message, cli_env, capsys):
    argv = [a(cli_env) if callable(a) else a for a in argv]
    out = ["--out", str(cli_env / "out")] + (["--no-figures"] if argv[0] in ("paper", "fly") else [])
    code = cli.main([*argv, *out])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if ": warning: " not in line]
    assert code == 2, err
    assert "Traceback" not in err
    assert len(lines) == 1 and lines[0].startswith(f"so3jax {argv[0]}: error: ") and message in lines[0], err


@pytest.mark.parametrize(("text", "value"), [
    ("pd", "pd"), ("raw", "raw"), ("pd,adaptive", "pd,adaptive"), ("random", "random"),
    ("results/tune/best_gains.json", "results/tune/best_gains.json"),
    ("../missions/flight.toml", "../missions/flight.toml"), ("[1.0, 2.0]", [1.0, 2.0]),
    ("{dist = 'uniform', low = 0.0, high = 1.0}", {"dist": "uniform", "low": 0.0, "high": 1.0}),
    ("'inertial'", "inertial"), ('"a b"', "a b"), ("1e-3", 1e-3), ("true", True),
])
def test_set_reads_a_toml_value_or_a_bare_word(text, value):
    """--set VALUE is TOML; a bare word (a name, a path, a list of names) that is not is a string."""
    assert cfg.parse_override(f"key={text}") == ("key", value)


@pytest.mark.parametrize(("argv", "message"), [
    (["sweep", str(ROOT / "sweeps" / "flight.toml"), "--set", "sweep.dispersions=[{bad"],
     "--set sweep.dispersions: '[{bad' is not a TOML value: expected '=' after a key in a key/value pair at its end"),
    (["fly", "--set", 'requirements=[{index="APE", limit=}]'],
     "--set requirements: '[{index=\"APE\", limit=}]' is not a TOML value: invalid value at its character 22"),
    (["fly", "--set", 'requirements=[\n{index="APE", axis="x", level=0.9, limit=1.0},\n{index="APE", limit=}]'],
     "is not a TOML value: invalid value at its line 3, column 21"),
    (["fly", "--set", "reference.kind='inertial"], "--set reference.kind: \"'inertial\" is not a TOML value: "),
    (["fly", "--set", "initial.rate=[0.0, 0.0"], "--set initial.rate: '[0.0, 0.0' is not a TOML value: unclosed array"),
    (["tune", _tune_copy, "--set", "tune.bounds={k_R=[0.1, 1.0]"],
     "--set tune.bounds: '{k_R=[0.1, 1.0]' is not a TOML value: "),
    (["fly", "--set", "requirements=x{index=APE}"], "--set requirements: 'x{index=APE}' is not a TOML value: "),
], ids=lambda x: x if isinstance(x, str) else None)
def test_a_toml_syntax_error_in_set_is_one_line_naming_key_value_and_error(argv, message, in_process, capsys):
    """Text that can only be meant as TOML (an array, an inline table, a quoted string, key =
    value in braces) and does not parse is refused as such, not read as a string."""
    argv = [a(in_process) if callable(a) else a for a in argv]
    assert cli.main([*argv, "--out", "out"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith(f"so3jax {argv[0]}: error: "), err
    assert message in err and "Traceback" not in err, err
    assert not (in_process / "out").exists()
