"""The JSON Schema (draft-07) of a mission file and of a ``[dispersions]`` table, generated
from the declarations the parser checks against, so an editor's completion and validation
cannot drift from the parser: the tables the mission parser accepts
(:mod:`so3jax.missions.mission`), the mission's own keys (:data:`so3jax.missions.keys.KEYS`),
the registered components' and controllers' parameters, options and gains, the gain
schedules' keys (:mod:`so3jax.missions.schedule`), the pointing requirements' keys
(:mod:`so3jax.sim.pointing`) and the dispersible leaves (:mod:`so3jax.missions.draw`).

Each :class:`~so3jax.core.params.Param` becomes a value schema (:func:`param`): its type and
shapes, its domain (``minimum``, ``exclusiveMinimum``, ``maximum``), its choices (``enum``), its
doc and unit (``description``) and its default. A table the parser closes is
``additionalProperties: false``. The schema is an editor's aid: the parser remains the
judge of what it cannot say (a horizon that is a whole number of steps, a positive
definite inertia, a phase's name).

The sweep, campaign and comparison files' own tables (layer 9) are added by
:mod:`so3jax.jobs.schema`; ``so3jax schema`` writes them all.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import io
import json
import math
import textwrap
import tokenize

import numpy as np

from so3jax.components import inertias
from so3jax.components import registry as components
from so3jax.controllers import gains as gain_domains
from so3jax.controllers import registry
from so3jax.controllers.scheduled import BY
from so3jax.core.params import Param
from so3jax.missions import distributions, draw, keys
from so3jax.missions import faults as fault_list
from so3jax.missions import mission as missions
from so3jax.missions import schedule as schedules
from so3jax.sim import pointing

DRAFT = "http://json-schema.org/draft-07/schema#"
SETS = {"sensors": "sensor", "environment": "environment"}  # tables of components, each a table or false
CHOSEN = ("estimator", "actuator", "momentum", "filter", "reference")  # tables of one component chosen by ``kind``
# The requirements' values (:func:`so3jax.sim.pointing.parse_requirement`): the keys are
# pointing.KEYS (a key without an entry here takes any value), the choices its constants.
REQUIREMENT_VALUES = {
    "index": lambda: {"enum": list(pointing.INDICES), "description": "the pointing index (ECSS-E-ST-60-10C)"},
    "axis": lambda: {"enum": list(pointing.AXES), "description": "its magnitude on an axis, the angle, or each axis"},
    "level": lambda: {"type": "number", "exclusiveMinimum": 0, "exclusiveMaximum": 1,
                      "description": "the confidence level P_C, in (0, 1)"},
    "limit": lambda: {"type": "number", "minimum": 0, "description": "the requirement's limit [arcsec]"},
    "window": lambda: {"type": "number", "exclusiveMinimum": 0,
                       "description": f"the window Dt [s] of {', '.join(pointing.WINDOWED)}"},
    "separation": lambda: {"type": "number", "exclusiveMinimum": 0,
                           "description": f"the separation Dt_s [s] of {', '.join(pointing.DRIFT)}"},
    "phase": lambda: {"anyOf": [{"type": "integer", "minimum": 0}, {"type": "string", "minLength": 1}],
                      "description": "a phase's name or index, or \"after fault\" (from the mission's first "
                                     "fault) (left out: the whole run)"},
    "interpretation": lambda: {"enum": list(pointing.INTERPRETATIONS), "default": "temporal",
                               "description": "the statistical interpretation (ECSS-E-ST-60-10C)"},
    "name": lambda: {"type": "string", "description": "the requirement's name in reports and goals"},
}
DISPERSION_SEEDS = ("random", "mission")  # dispersions.seed (so3jax.missions.draw.parse)
# dispersions.initial.attitude and .rate: {key: draw.parse's reading} (a distribution or a number [deg])
INITIAL_DISPERSIONS = {"attitude": {"max_angle_deg": "angle"}, "rate": {"norm": "distribution"}}


# --- value schemas ------------------------------------------------------------------------------


def plain(value):
    """A default as JSON data: tuples and arrays as lists, NumPy numbers as Python's; None
    where it holds a non-finite number (JSON has none)."""
    value = np.asarray(value).tolist() if isinstance(value, np.ndarray | np.generic) else value
    if isinstance(value, (list, tuple)):
        items = [plain(v) for v in value]
        return None if any(v is None for v in items) else items
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def with_default(schema: dict, default) -> dict:
    """The schema with its ``default`` (as JSON data), where there is one."""
    value = plain(default) if default is not None else None
    return {**schema, "default": value} if value is not None else schema


def number(low=-math.inf, high=math.inf, integer: bool = False, low_excluded: bool = False) -> dict:
    """A number's schema: its type and its closed domain [low, high] ((low, high] where low is excluded)."""
    out = {"type": "integer" if integer else "number"}
    if low > -math.inf:
        out["exclusiveMinimum" if low_excluded else "minimum"] = _plain_number(low)
    if high < math.inf:
        out["maximum"] = _plain_number(high)
    return out


def _plain_number(x):
    return int(x) if isinstance(x, int) or float(x).is_integer() and abs(x) < 2**53 else float(x)


def shaped(shape: tuple, element: dict) -> dict:
    """Nested arrays of ``shape`` (None: any length) of ``element``."""
    if not shape:
        return element
    out = {"type": "array", "items": shaped(shape[1:], element)}
    if shape[0] is not None:
        out["minItems"] = out["maxItems"] = shape[0]
    return out


def one_of(schemas: list) -> dict:
    """The schema of a value that takes one of ``schemas`` (itself where there is one)."""
    return schemas[0] if len(schemas) == 1 else {"anyOf": schemas}


def describe(doc: str, unit: str = "") -> str:
    """A description: the doc on one line, the unit in brackets."""
    doc = " ".join((doc or "").split())
    return f"{doc} [{unit}]" if unit and doc else f"[{unit}]" if unit else doc


def param(p: Param) -> dict:
    """The value schema of a declared parameter: its type, shapes, domain, choices, doc, unit and default."""
    if isinstance(p, keys.ControllerNames):
        name = {"type": "string", "enum": list(registry.names())}
        value = {"anyOf": [name, {"type": "array", "items": name, "minItems": 1, "uniqueItems": True}]}
    elif isinstance(p, keys.Names):
        value = {"type": "array", "items": {"type": "string", "minLength": 1}, "minItems": 1, "uniqueItems": True}
    elif isinstance(p, inertias.Targets):
        value = {"type": "array", "minItems": 1,
                 "items": {"anyOf": [number(0.0, low_excluded=True), shaped((3, 3), number())]}}
    elif p.boolean:
        value = {"type": "boolean"}
    elif p.text:
        value = {"type": "string", "minLength": 1}
    elif p.choices:
        value = {"type": "string", "enum": list(p.choices)}
    else:
        element = number(p.low, p.high, p.integer, p.low_excluded)
        value = one_of([shaped(tuple(shape), element) for shape in p.shapes])
    return with_default({**value, "description": describe(p.doc, p.unit)}, p.default)


def table(properties: dict, description: str = "", closed: bool = True) -> dict:
    """An object of ``properties``; closed: no other key (the parser refuses unknown keys)."""
    out = {"type": "object"}
    if description:
        out["description"] = " ".join(description.split())
    out["properties"] = properties
    if closed:
        out["additionalProperties"] = False
    return out


def params_table(params, description: str = "") -> dict:
    """The table of a component's parameters or a controller's options."""
    return table({p.name: param(p) for p in params}, description)


def field_comments(cls) -> dict:
    """{field: the comment at the end of its line} of a dataclass's or NamedTuple's fields
    (the units and meanings the code states beside each field); {} for a class without source."""
    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):  # made at run time (dataclasses.make_dataclass)
        return {}
    comments = {}
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            text = tok.string.lstrip("#").strip()
            if not text.startswith(("noqa", "type:")):
                comments[tok.start[0]] = text
    body = ast.parse(source).body[0].body
    return {node.target.id: comments[node.end_lineno] for node in body
            if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and node.end_lineno in comments}


# --- the mission's tables ---------------------------------------------------------------------------


def _own_keys(prefix: str) -> dict:
    """{key: schema} of the mission's own keys in the table ``prefix`` (dotted), subtables
    nested (:data:`so3jax.missions.keys.KEYS`)."""
    out = {}
    for name in keys.allowed(prefix):
        full = f"{prefix}.{name}"
        out[name] = param(keys.KEY[full]) if full in keys.KEY else table(_own_keys(full))
    return out


def _component(kind: str, name: str) -> dict:
    spec = components.get(kind, name)
    return params_table(spec.params, spec.doc)


def _set(table_name: str) -> dict:
    """``[sensors.NAME]`` (or ``[environment.NAME]``): each registered one a table, or false to leave it out."""
    kind = SETS[table_name]
    leave_out = {"const": False, "description": "false: left out"}
    return table({name: {"anyOf": [_component(kind, name), leave_out]} for name in components.names(kind)},
                 f"the {kind}s flown, each its own table (false leaves one out)")


def _kind(kind: str, names: tuple) -> dict:
    docs = "; ".join(f"{name}: {components.get(kind, name).doc}" for name in names)
    return {"type": "string", "enum": list(names), "description": describe(f"the {kind} flown ({docs})")}


def _chosen(kind: str) -> dict:
    """``[KIND] kind`` and a ``[KIND.NAME]`` table per registered component."""
    names = components.names(kind)
    return table({"kind": _kind(kind, names), **{name: _component(kind, name) for name in names}},
                 f"the {kind}: kind names the one flown, [{kind}.NAME] its parameters")


def _inertia() -> dict:
    """``[inertia]``: the paper profile's keys (J, or J0, J1, J2) or another kind's table."""
    names = components.names("inertia")
    others = {name: _component("inertia", name) for name in names if name != "paper"}
    return table({"kind": _kind("inertia", names), **_own_keys("inertia"), **others},
                 "the inertia profile: the paper's (J, or J0, J1, J2) or another kind's [inertia.NAME]")


def gain(spec, field: str, comment: str = "") -> dict:
    """A gain's schema: each shape it may take (its registration's), elements in its domain
    (:mod:`so3jax.controllers.gains`), or a list of them, one per phase or breakpoint (a
    scheduled law's)."""
    domain = gain_domains.gain_domain(spec.gains_type, field)
    schemas = []
    for shape in spec.gain_shapes()[field]:
        if isinstance(domain, gain_domains.Nonnegative):
            element = number(0.0)
        elif isinstance(domain, gain_domains.PositiveDefinite) and len(shape) > 1:
            element = number()  # a matrix: symmetric positive definite, checked by the parser
        else:
            element = number(0.0, low_excluded=True)
        schemas.append(shaped(tuple(shape), element))
    scheduled = {"type": "array", "minItems": 1, "items": one_of(schemas),
                 "description": "one value per phase or breakpoint of its [schedule]"}
    out = {"anyOf": [*schemas, scheduled], "description": comment}
    return with_default(out, np.asarray(getattr(spec.defaults, field)))


def gains(name: str) -> dict:
    """``[gains.NAME]``: the law's gains, or the path of a best_gains.json (``so3jax tune``'s)."""
    spec = registry.get(name)
    comments = field_comments(spec.gains_type)
    own = table({f: gain(spec, f, comments.get(f, "")) for f in spec.gains_type._fields})
    path = {"type": "string", "minLength": 1, "description": "a best_gains.json of so3jax tune, relative to this file"}
    return {"anyOf": [own, path], "description": f"the {spec.label} gains (left out: the registered defaults)"}


def _schedule() -> dict:
    """``[schedule]``: a tunable law's gains per phase, over time or by the declared inertia."""
    values = {"by": {"enum": list(BY), "description": "phase: one set of gains per phase; time: breakpoints [s]; "
                     "inertia: breakpoints [kg m^2] of a moment of the declared inertia"},
              "at": {"type": "array", "items": {"type": "number"}, "minItems": 1,
                     "description": "the breakpoints [s] (by time) or [kg m^2] (by inertia), increasing"},
              "of": {"enum": list(schedules.MOMENTS), "default": "mean",
                     "description": "the moment of the inertia a schedule by inertia reads"}}
    entry = {**table({k: values.get(k, {}) for k in schedules.ENTRY_KEYS}), "required": ["by"]}
    return table({name: entry for name in registry.names(tunable=True)},
                 "gain schedules: one entry per scheduled controller")


def requirement() -> dict:
    """A ``[[requirements]]`` entry (:func:`so3jax.sim.pointing.parse_requirement`)."""
    out = table({k: REQUIREMENT_VALUES[k]() if k in REQUIREMENT_VALUES else {} for k in pointing.KEYS})
    out["required"] = list(pointing.REQUIRED)
    rules = []
    for indices, key in ((pointing.WINDOWED, "window"), (pointing.DRIFT, "separation")):
        takes = {"properties": {"index": {"enum": list(indices)}}, "required": ["index"]}
        rules.append({"if": takes, "then": {"required": [key]}, "else": {"not": {"required": [key]}}})
    out["allOf"] = rules
    return out


def requirements() -> dict:
    return {"type": "array", "items": requirement(),
            "description": "pointing requirements (ECSS-E-ST-60-10C), checked by fly and sweep"}


def faults() -> dict:
    """``[[faults]]``: each entry a time and one target (:mod:`so3jax.missions.faults`)."""
    values = {
        "time": {"type": "number", "minimum": 0, "description": "when the fault acts (from the first control tick "
                 "at or after it) [s]"},
        "end": {"type": "number", "minimum": 0, "description": "a star-tracker outage's end (the outage is "
                "[time, end)) [s]"},
        "wheel": {"type": "integer", "minimum": 1, "description": "the wheel that fails (1-based)"},
        "mode": {"enum": list(fault_list.WHEEL_MODES), "default": "off",
                 "description": "off: a wheel's motor or a thruster delivers no torque; stuck (a wheel's): it "
                 "keeps its speed relative to the body; degraded: its torque limit times factor; friction: its "
                 "bearing friction times factor"},
        "factor": {"type": "number", "minimum": 0,
                   "description": "a degraded wheel's torque limit factor, in [0, 1), or a friction fault's, >= 0"},
        "star_tracker": {"const": fault_list.TARGET_VALUES["star_tracker"],
                         "description": "no star-tracker sample in [time, end)"},
        "gyro": {"const": fault_list.TARGET_VALUES["gyro"], "description": "a step in the gyro's bias from time on"},
        "step": shaped((3,), {"type": "number"}) | {"description": "the gyro bias step [rad/s]"},
        "thruster": {"enum": list(fault_list.THRUSTERS),
                     "description": "the thruster that fails off: of the pair on that body axis, the one firing a "
                     "torque of that sign (momentum.kind = 'thrusters')"},
    }
    entry = {**table({k: values[k] for k in fault_list.KEYS if k in values}), "required": ["time"]}
    entry["oneOf"] = [{"required": [k]} for k in fault_list.TARGETS if k in values]
    return {"type": "array", "items": entry,
            "description": "failures the loop rides through (docs/model.md §8.7), each a time and one target"}


def flexible_entries(name: str) -> dict:
    """``[[appendages]]`` (hinged rigid panels) or ``[[slosh]]`` (spring-mass-damper particles) on
    the hub (docs/model.md §8.9): each entry's keys (:data:`so3jax.missions.keys.APPENDAGE_KEYS`,
    :data:`~so3jax.missions.keys.SLOSH_KEYS`), those without a default required."""
    params = keys.APPENDAGE_KEYS if name == "appendages" else keys.SLOSH_KEYS
    entry = {**params_table(params), "required": [p.name for p in params if p.default is None]}
    what = ("hinged rigid panels on torsional springs" if name == "appendages"
            else "propellant slosh: spring-mass-damper particles")
    return {"type": "array", "items": entry,
            "description": f"{what} on the hub (docs/model.md §8.9), with hub.mass"}


def fdir() -> dict:
    """``[fdir]``: what the loop knows of a wheel that fails off, and when."""
    return table({"detection": {"enum": list(fault_list.DETECTIONS), "default": "never",
                                "description": "never: the loop keeps commanding a failed wheel; latency: it drops "
                                               "it from the distribution fdir.latency after the fault"},
                  "latency": {"type": "number", "minimum": 0,
                              "description": "the time from a wheel's fault to its detection [s]"}},
                 "fault detection, isolation and recovery of the wheels")


def _mission_value(name: str) -> dict:
    """The schema of a top-level key or table the mission parser accepts."""
    if name in keys.TOP:
        return param(keys.KEY[name])
    if name == "requirements":
        return requirements()
    if name == "faults":
        return faults()
    if name == "fdir":
        return fdir()
    if name in ("appendages", "slosh"):
        return flexible_entries(name)
    if name == "inertia":
        return _inertia()
    if name in keys.TABLES:
        return table(_own_keys(name))
    if name in SETS:
        return _set(name)
    if name in CHOSEN:
        return _chosen(name)
    if name == "controller":
        return table({n: params_table(registry.get(n).options, f"the {registry.get(n).label} law's options")
                      for n in registry.names()}, "each controller's options")
    if name == "gains":
        return table({n: gains(n) for n in registry.names()}, "each controller's gains")
    if name == "schedule":
        return _schedule()
    raise ValueError(f"the mission schema has no rule for the mission key {name!r}: add one to so3jax.missions.schema")


def mission_properties() -> dict:
    """{key: schema} of every top-level key and table a mission accepts (the parser's own
    list: ``so3jax.missions.mission``'s keys and tables)."""
    return {name: _mission_value(name) for name in missions.TOP_KEYS + missions.MISSION_TABLES}


def document(title: str, description: str, properties: dict, shared: dict | None = None) -> dict:
    """A schema document: a closed table of ``properties``; shared: its definitions
    ({name: schema}, which :func:`ref` refers to)."""
    return {"$schema": DRAFT, "title": title, **table(properties, description),
            **({"definitions": shared} if shared else {})}


def mission() -> dict:
    """The schema of a mission file (missions/*.toml)."""
    return document("so3jax mission", "A mission flown by so3jax fly, paper, margins and crosscheck: every entry "
                    "left out keeps the flight mission's (docs/commands/fly.md).", mission_properties())


# --- dispersions ------------------------------------------------------------------------------------


def ref(name: str, description: str = "") -> dict:
    """A reference to the document's definition ``name`` (:data:`DEFINITIONS`), with a description of its own."""
    target = {"$ref": f"#/definitions/{name}"}
    return {"allOf": [target], "description": description} if description else target


def distribution(relative: bool = False, description: str = "") -> dict:
    """A number (fixed) or a distribution table ``{dist = NAME, ...}``
    (:data:`so3jax.missions.distributions.DISTRIBUTIONS`); relative: with an optional
    ``relative`` (an offset from or a scale of the mission's value)."""
    return ref("relative_distribution" if relative else "distribution", description)


def _distribution(relative: bool) -> dict:
    tables = []
    for name, cls in distributions.DISTRIBUTIONS.items():
        fields = [f.name for f in dataclasses.fields(cls)]
        number = {"type": "number"}
        properties = {"dist": {"const": name},
                      **{f: {"type": "array", "items": number, "minItems": 1} if f == "values" else number
                         for f in fields}}
        if relative:
            properties["relative"] = {"enum": list(draw.RELATIVE),
                                      "description": "offset: the mission's value plus the draw; scale: times it"}
        tables.append({**table(properties, (cls.__doc__ or "").strip()), "required": ["dist", *fields]})
    return {"anyOf": [{"type": "number", "description": "fixed at this value"}, *tables]}


def _inertia_dispersion() -> dict:
    """An inertia matrix's dispersion (:class:`so3jax.missions.draw.InertiaDispersion`)."""
    types = {f.name: f.type for f in dataclasses.fields(draw.InertiaDispersion)}
    values = {key: distribution() if "Distribution" in str(types[key]) else {"type": "number"}
              for key in draw.INERTIA_KEYS}
    return table(values, (draw.InertiaDispersion.__doc__ or "").strip().split("\n\n")[0])


def _leaves(kind: str, name: str) -> dict:
    """The dispersible (real-valued) parameters of a component: a distribution each."""
    params = components.get(kind, name).params
    return table({p.name: distribution(True, describe(p.doc, p.unit)) for p in params
                  if not (p.integer or p.boolean or p.choices or p.text)})


def dispersions(description: str = "") -> dict:
    """A ``[dispersions]`` table (:func:`so3jax.missions.draw.parse`): the mission's
    dispersible leaves, each a number or a distribution (a reference to the document's definition)."""
    return ref("dispersions", description)


def _dispersions() -> dict:
    tree = {"seed": {"enum": list(DISPERSION_SEEDS), "default": "mission",
                     "description": "random: a disturbance and sensor-noise seed per sample; mission: the mission's"}}
    for table_name, key in draw.STRUCTURED:
        declared = keys.KEY[f"{table_name}.{key}"]
        tree.setdefault(table_name, {})[key] = distribution(False, describe(declared.doc, declared.unit))
    tree.setdefault("inertia", {}).update({J: ref("inertia_dispersion") for J in ("J0", "J1", "J2")})
    readings = {"angle": {"type": "number", "description": "[deg]"}, "distribution": distribution()}
    tree.setdefault("initial", {}).update({name: table({k: readings[v] for k, v in values.items()})
                                           for name, values in INITIAL_DISPERSIONS.items()})
    for table_name in draw.LOOP_TABLES:
        kind = SETS.get(table_name, table_name)
        tree[table_name] = {name: _leaves(kind, name) for name in components.names(kind)}
    for (table_name, kind), leaves in draw.SCENARIO_LEAVES.items():
        declared = {p.name: p for p in components.get(table_name, kind).params}
        values = {}
        for name, domain in leaves.items():
            p = declared.get(name)
            text = describe(p.doc, p.unit) if p is not None else ""
            if domain == draw.INERTIA:
                values[name] = ref("inertia_dispersion", text)
            elif isinstance(p, inertias.Targets):  # scales (a distribution) or inertias (an inertia's dispersion)
                values[name] = {"anyOf": [distribution(True), ref("inertia_dispersion")], "description": text}
            else:
                values[name] = distribution(True, text)
        tree.setdefault(table_name, {})[kind] = table(values)
    out = _tables(tree, "what varies from sample to sample: the mission's leaves, each a number (fixed) or a "
                  "distribution")
    out["properties"]["faults"] = _fault_dispersions()
    out["properties"].update({name: _flexible_dispersions(name) for name in draw.FLEXIBLE_LEAVES})
    return out


def _fault_dispersions() -> dict:
    """``faults.I``: the numeric values of the mission's [[faults]] entry I (0-based), each
    a distribution (:data:`so3jax.missions.draw.FAULT_LEAVES`)."""
    described = {k: v["description"] for k, v in faults()["items"]["properties"].items()}
    params = dict.fromkeys(p for leaves in draw.FAULT_LEAVES.values() for p in leaves)
    entry = table({p: distribution(True, described[p]) for p in params},
                  "the values of the mission's [[faults]] entry of this 0-based index")
    return {"type": "object", "description": "the mission's faults' times, outage ends, degraded wheels' factors "
            "and gyro bias steps, by the 0-based index of their [[faults]] entry",
            "patternProperties": {"^[0-9]+$": entry}, "additionalProperties": False}


def _flexible_dispersions(name: str) -> dict:
    """``appendages.I`` or ``slosh.J``: the spring and damper of the mission's ``[[name]]``
    entry of that 0-based index, each a distribution (:data:`so3jax.missions.draw.FLEXIBLE_LEAVES`)."""
    params = {p.name: p for p in (keys.APPENDAGE_KEYS if name == "appendages" else keys.SLOSH_KEYS)}
    entry = table({p: distribution(True, describe(params[p].doc, params[p].unit)) for p in draw.FLEXIBLE_LEAVES[name]},
                  f"the values of the mission's [[{name}]] entry of this 0-based index")
    what = "hinged panels'" if name == "appendages" else "slosh particles'"
    return {"type": "object", "description": f"the mission's {what} springs and dampers (docs/model.md §8.9), by "
            f"the 0-based index of their [[{name}]] entry; one given per phase draws each phase's value on its own",
            "patternProperties": {"^[0-9]+$": entry}, "additionalProperties": False}


# The definitions a job file's schema holds (its [dispersions] and its distributions), by name.
DEFINITIONS = {"dispersions": _dispersions, "distribution": lambda: _distribution(False),
               "relative_distribution": lambda: _distribution(True), "inertia_dispersion": _inertia_dispersion}


def definitions() -> dict:
    """{name: schema} of :data:`DEFINITIONS`, for a document that refers to them."""
    return {name: make() for name, make in DEFINITIONS.items()}


def _tables(tree: dict, description: str = "") -> dict:
    """A nested {key: schema or subtree} as closed tables."""
    return table({k: v if _is_schema(v) else _tables(v) for k, v in tree.items()}, description)


def _is_schema(value: dict) -> bool:
    return any(k in value for k in ("type", "anyOf", "allOf", "enum", "const", "$ref"))


def dumps(schema: dict) -> str:
    """A schema as the text of its file: indented JSON, a newline at the end."""
    return json.dumps(schema, indent=2, ensure_ascii=False) + "\n"
