"""The JSON Schemas (draft-07) of so3jax's files, for editors (taplo, Even Better TOML): a
mission (:func:`so3jax.missions.schema.mission`), a sweep, a tuning campaign and a
comparison, each generated from the declarations their parsers check against. A job file
names a mission (``mission = "PATH"``) and may hold mission tables too, so its schema is the
mission's with the job's own tables added:

* a sweep: ``[sweep]`` (the keys :mod:`so3jax.jobs.sweep.config` accepts, typed by the
  default sweep's values) and ``[dispersions]`` (:func:`so3jax.missions.schema.dispersions`);
* a campaign: ``[tune]``, the fields of :class:`so3jax.jobs.tune.config.TuneConfig` and its
  sections (typed by their annotations, described by their comments), ``[[tune.goals]]``
  (:mod:`so3jax.jobs.tune.goals`);
* a comparison: a campaign's ``[tune]`` shared by every law, a sweep's tables and
  ``[compare]`` (:mod:`so3jax.jobs.compare`).

The domains of the job tables' values are those of their parsers' checks
(``checks.number``, ``checks.choice``, ``_positive``, ``_choice``) whose key the call names
(:func:`checked_domains` reads them from the source), so the schema states the bounds the
parser enforces without a second copy of them.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import re
from pathlib import Path

from so3jax.components import registry as components
from so3jax.controllers import registry
from so3jax.jobs import compare as comparisons
from so3jax.jobs.sweep import config as sweeps
from so3jax.jobs.tune import config as campaigns
from so3jax.jobs.tune import goals as design_goals
from so3jax.missions import schema
from so3jax.results import io

FILES = ("mission.json", "sweep.json", "campaign.json", "compare.json")  # what `so3jax schema` writes
_CHECKS = {"number", "choice", "boolean"}  # so3jax.core.checks' calls whose label names the key (argument 2)
_OWN_CHECKS = {"_positive", "_choice"}  # the campaign parser's, whose first argument names the key under [tune]


# --- the domains the parsers check --------------------------------------------------------------


def checked_domains(module, prefix: str = "") -> dict:
    """{dotted key: schema} of the value checks in ``module``'s source whose key the call
    names: ``checks.number(value, "KEY ...", low, high, integer)``, ``checks.choice(value,
    "KEY", CHOICES)``, ``checks.boolean`` (a label built from a loop over a tuple of names, or
    from module-level names, counts; one from a local variable does not), and the campaign
    parser's ``_positive("KEY", value[, integer])`` and ``_choice("KEY", value, CHOICES)``
    (``prefix`` + KEY). The first check of a key wins."""
    tree = ast.parse(inspect.getsource(module))
    namespace = vars(module)
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call) or not node.args:
            continue
        func = node.func
        if (isinstance(func, ast.Attribute) and isinstance(func.value, ast.Name) and func.value.id == "checks"
                and func.attr in _CHECKS and len(node.args) >= 2):
            check, label, rest = func.attr, node.args[1], node.args[2:]
        elif isinstance(func, ast.Name) and func.id in _OWN_CHECKS:
            check, label, rest = func.id, node.args[0], node.args[2:]
        else:
            continue
        for text in _labels(label, tree, node, namespace):
            key = _key(text, prefix if check in _OWN_CHECKS else "")
            domain = _domain(check, rest, node.keywords, namespace)
            if key and domain is not None:
                found.append((node.lineno, node.col_offset, key, domain))
    out = {}
    for *_, key, domain in sorted(found, key=lambda f: f[:2]):
        out.setdefault(key, domain)
    return out


def _key(label: str, prefix: str) -> str | None:
    """The dotted key a check's label names: its first word, or the quoted key of
    "config key 'KEY'"."""
    quoted = re.fullmatch(r"config key '([\w.]+)'", label)
    key = quoted.group(1) if quoted else label.split(" ")[0]
    return prefix + key if re.fullmatch(r"[A-Za-z_][\w.]*", key) else None


def _evaluate(node, namespace):
    """The value of an expression of so3jax's own source in its module's namespace."""
    return eval(compile(ast.Expression(node), "<schema>", "eval"), namespace)  # noqa: S307 (the package's own code)


def _labels(node, tree, call, namespace) -> list:
    """The labels a check's key argument takes: an expression of module-level names, or an
    f-string over a comprehension's variable that runs over a tuple of names."""
    try:
        value = _evaluate(node, namespace)
        return [value] if isinstance(value, str) else []
    except Exception:  # a local variable: the loop's, or not part of the declared schema
        pass
    if not isinstance(node, ast.JoinedStr):
        return []
    loops = _loop_values(tree, call, namespace)
    names = [p.value.id for p in node.values if isinstance(p, ast.FormattedValue) and isinstance(p.value, ast.Name)]
    if len(names) != 1 or names[0] not in loops or not all(
            isinstance(p, ast.Constant) or isinstance(p, ast.FormattedValue) and isinstance(p.value, ast.Name)
            for p in node.values):
        return []
    return ["".join(str(v) if isinstance(p, ast.FormattedValue) else p.value for p in node.values)
            for v in loops[names[0]]]


def _loop_values(tree, call, namespace) -> dict:
    """{variable: names} of the comprehensions around ``call`` that run over a tuple of strings."""
    out = {}
    for comp in ast.walk(tree):
        if isinstance(comp, (ast.ListComp, ast.SetComp, ast.DictComp, ast.GeneratorExp)) and any(
                n is call for n in ast.walk(comp)):
            for gen in comp.generators:
                try:
                    values = _evaluate(gen.iter, namespace)
                except Exception:  # a local variable
                    continue
                if isinstance(gen.target, ast.Name) and isinstance(values, tuple) and all(
                        isinstance(v, str) for v in values):
                    out[gen.target.id] = values
    return out


def _domain(check: str, args: list, keywords: list, namespace) -> dict | None:
    """The schema of a check's domain from its arguments (None where one is a local value)."""
    try:
        given = {k.arg: _evaluate(k.value, namespace) for k in keywords if k.arg}
        if check == "number":
            given.update(zip(("low", "high", "integer"), (_evaluate(a, namespace) for a in args)))
            return schema.number(given.get("low", -float("inf")), given.get("high", float("inf")),
                                 bool(given.get("integer", False)))
        if check in ("choice", "_choice"):
            return {"type": "string", "enum": list(_evaluate(args[0], namespace))}
        if check == "boolean":
            return {"type": "boolean"}
        integer = bool(given.get("integer", _evaluate(args[0], namespace) if args else False))
        return schema.number(0.0, integer=integer, low_excluded=True)
    except Exception:  # an argument that is a local value
        return None


# --- dataclass tables ----------------------------------------------------------------------------------


def annotated(annotation) -> dict:
    """The schema of a field's annotation (a string: ``from __future__ import annotations``):
    int, float, bool, str, dict, a tuple of ints or floats; Any (or another) takes any value."""
    text = annotation.__name__ if isinstance(annotation, type) else str(annotation)
    text = text.replace(" ", "").replace("|None", "")
    simple = {"int": {"type": "integer"}, "float": {"type": "number"}, "bool": {"type": "boolean"},
              "str": {"type": "string"}, "dict": {"type": "object"}, "tuple": {"type": "array"}}
    if text in simple:
        return dict(simple[text])
    element = re.fullmatch(r"tuple\[(int|float),\.\.\.\]", text)
    if element:
        return {"type": "array", "items": simple[element.group(1)]}
    return {}


def valued(value) -> dict:
    """The schema of a default value's type: a boolean, an integer, a number, a string, a list."""
    for kind, name in ((bool, "boolean"), (int, "integer"), (float, "number"), (str, "string"), (list, "array")):
        if isinstance(value, kind):
            return {"type": name}
    return {}


def dataclass_table(cls, prefix: str, domains: dict, special: dict, nested: dict) -> dict:
    """The closed table of a dataclass's fields (but ``mission``): each a ``nested``
    dataclass's own table, a ``special`` schema ({field: a function making it}, in this
    table or a nested one), or its annotation's with the checked ``domains`` of ``prefix`` +
    field; described by the field's comment, with its default."""
    comments = schema.field_comments(cls)
    values = {}
    for f in dataclasses.fields(cls):
        if f.name == "mission":
            continue
        key = f"{prefix}{f.name}"
        if f.name in nested and dataclasses.is_dataclass(nested[f.name]):
            values[f.name] = dataclass_table(nested[f.name], key + ".", domains, special, nested)
        else:
            values[f.name] = special[f.name]() if f.name in special else {**annotated(f.type), **domains.get(key, {})}
        if comments.get(f.name):
            values[f.name]["description"] = comments[f.name]
        default = f.default if f.default is not dataclasses.MISSING else None
        if not dataclasses.is_dataclass(default) and f.name not in nested:
            values[f.name] = schema.with_default(values[f.name], default)
    doc = (cls.__doc__ or "").strip().split("\n\n")[0]
    out = schema.table(values, doc)
    required = [f.name for f in dataclasses.fields(cls) if f.name != "mission" and f.default is dataclasses.MISSING
                and f.default_factory is dataclasses.MISSING]
    return {**out, "required": required} if required else out


# --- the job tables ---------------------------------------------------------------------------------


def _gains_given() -> dict:
    return {"anyOf": [{"type": "string", "minLength": 1},
                      {"type": "object", "additionalProperties": {"anyOf": [{"type": "number"}, {"type": "array"}]}}],
            "description": '"mission", "paper", a best_gains.json path, or a table of gains'}


def _gain_names() -> list:
    return list(dict.fromkeys(f for n in registry.names(tunable=True) for f in registry.get(n).gains_type._fields))


def _bounds() -> dict:
    pair = {"type": "array", "items": {"type": "number", "minimum": 0}, "minItems": 2, "maxItems": 2}
    return {"type": "object", "propertyNames": {"enum": _gain_names()}, "additionalProperties": pair}


def _fixed() -> dict:
    return {"type": "array", "items": {"enum": _gain_names()}, "uniqueItems": True}


def _estimator() -> dict:
    names = dict.fromkeys(p.name for n in components.names("estimator") for p in components.get("estimator", n).params)
    return {"type": "array", "items": {"enum": list(names)}, "uniqueItems": True}


def goal() -> dict:
    """A ``[[tune.goals]]`` entry: a requirement (the mission's, by name or index, or one of
    its own), a margin floor or a budget (:func:`so3jax.jobs.tune.goals.parse_goal`)."""
    values = {
        "hard": {"type": "boolean", "description": "true: a hard goal (g < 1 required); false: a soft one (minimized)"},
        "name": {"type": "string", "description": "the goal's name in reports"},
        "requirement": {"anyOf": [{"type": "string"}, {"type": "integer", "minimum": 0}],
                        "description": "a [[requirements]] entry of the mission, by name or index"},
        "margin": {"enum": list(design_goals.MARGINS)},
        "min_db": {**schema.number(0.0, design_goals.MAX_DB, low_excluded=True), "description": "the floor [dB]"},
        "min_deg": {**schema.number(0.0, design_goals.MAX_DEG, low_excluded=True), "description": "the floor [deg]"},
        "at": {"anyOf": [{"type": "array", "items": {"type": "number", "minimum": 0}, "minItems": 1},
                         {"const": design_goals.PHASE_ENDS}],
               "description": f'times [s], whole control periods, or "{design_goals.PHASE_ENDS}"'},
        "axis": {"enum": list(design_goals.AXES)},
        "budget": {"enum": list(design_goals.BUDGETS),
                   "description": "; ".join(f"{k} [{u}]" for k, u in design_goals.BUDGETS.items())},
        "limit": {**schema.number(0.0, low_excluded=True), "description": "the budget, in its metric's unit"},
        "statistic": {"enum": list(design_goals.STATISTICS), "default": "mean"},
    }
    common = {k: values.get(k, {}) for k in design_goals.COMMON_KEYS}
    inline = schema.requirement()
    kinds = [{**schema.table({**common, "requirement": values["requirement"]}), "required": ["hard", "requirement"]},
             {**inline, "properties": {**inline["properties"], **common},
              "required": ["hard", *inline["required"]]}]
    for margin, names in design_goals.MARGIN_KEYS.items():
        own = {"margin": {"const": margin}, **{k: values.get(k, {}) for k in names}}
        kinds.append({**schema.table({**common, **own}), "required": ["hard", "margin", names[0]]})
    own = {"budget": values["budget"], **{k: values.get(k, {}) for k in design_goals.BUDGET_KEYS}}
    kinds.append({**schema.table({**common, **own}), "required": ["hard", "budget", "limit"]})
    return {"type": "object", "anyOf": kinds, "description": "a goal: a requirement, a margin floor or a budget"}


def tune(shared: bool = False) -> dict:
    """``[tune]`` (:class:`so3jax.jobs.tune.config.TuneConfig`); shared: a comparison's, whose
    ``controller`` is each law's and whose ``dispersions`` may be the comparison's own."""
    domains = checked_domains(campaigns, campaigns.TUNE + ".")
    dispersions = schema.dispersions
    if shared:
        def dispersions():
            own = {"const": comparisons.SWEEP_DISPERSIONS, "description": "the comparison's own [dispersions]"}
            return {"anyOf": [schema.dispersions(), own]}
    special = {"dispersions": dispersions, "goals": lambda: {"type": "array", "items": goal(), "minItems": 1},
               "bounds": _bounds, "fixed": _fixed, "estimator": _estimator, "initial_gains": _gains_given,
               "budget_gains": _gains_given}
    nested = {**campaigns.SECTIONS, **campaigns.CONSTRAINTS}
    fields = {f.name for cls in (campaigns.TuneConfig, *nested.values()) for f in dataclasses.fields(cls)}
    if set(special) - fields:
        raise ValueError(f"the campaign schema names no field {', '.join(sorted(set(special) - fields))} of [tune]")
    out = dataclass_table(campaigns.TuneConfig, campaigns.TUNE + ".", domains, special, nested)
    if shared:
        del out["properties"]["controller"]
    out["description"] = ("the campaign every law's tuning shares (tune.controller: each law in turn)" if shared
                          else "the tuning campaign (every key has a default)")
    return out


def sweep_table() -> dict:
    """``[sweep]``: the keys the sweep parser accepts, typed by the default sweep's values."""
    domains = checked_domains(sweeps)
    values = {}
    for key in sweeps.SWEEP_KEYS:
        default = sweeps.DEFAULT["sweep"].get(key)
        field = sweeps.SweepConfig.__dataclass_fields__.get(key)
        typed = valued(default) or (annotated(field.type) if field is not None else {})
        values[key] = schema.with_default({**typed, **domains.get(f"sweep.{key}", {})}, default)
    comments = schema.field_comments(sweeps.SweepConfig)
    for key, text in comments.items():
        if key in values:
            values[key]["description"] = text
    return schema.table(values, "the sweep's samples, batches and checks (left out: the default sweep's)")


def compare_table() -> dict:
    """``[compare]`` (:func:`so3jax.jobs.compare.parse`) with its candidates."""
    domains = checked_domains(comparisons)
    fields = {f.name: f for f in dataclasses.fields(comparisons.CompareConfig)}
    comments = schema.field_comments(comparisons.CompareConfig)
    candidate_values = {"controller": {"enum": list(registry.names(tunable=True)),
                                       "description": "the law (default: the candidate's name)"},
                        "gains": {**_gains_given(), "description": "fixed gains, flown as given (not tuned)"},
                        "tune": {"type": "object", "description": "the entries of [tune] this candidate's campaign "
                                 "changes"},
                        "against": {"type": "string", "description": "the candidate it is paired with"}}
    candidate = schema.table({k: candidate_values.get(k, {}) for k in comparisons.CANDIDATE_KEYS})
    values = {}
    for key in comparisons.COMPARE_KEYS:
        if key == "candidates":
            values[key] = {"type": "object", "additionalProperties": candidate,
                           "description": "what is compared instead of the mission's laws, a table per candidate"}
            continue
        field = fields.get(key)
        values[key] = {**(annotated(field.type) if field is not None else {}), **domains.get(f"compare.{key}", {})}
        if comments.get(key):
            values[key]["description"] = comments[key]
        if field is not None and field.default is not dataclasses.MISSING:
            values[key] = schema.with_default(values[key], field.default)
    return schema.table(values, "the comparison: its reference candidate and bootstrap")


def _job(title: str, description: str, tables: dict) -> dict:
    mission = {"mission": {"type": "string", "minLength": 1,
                           "description": "the mission file flown (relative to this file); this file's mission "
                           "keys and tables change its entries"}}
    return schema.document(title, description, {**mission, **schema.mission_properties(), **tables},
                           schema.definitions())


def sweep() -> dict:
    return _job("so3jax sweep", "A Monte Carlo sweep (so3jax sweep): a mission, [sweep] and [dispersions].",
                {"sweep": sweep_table(), "dispersions": schema.dispersions()})


def campaign() -> dict:
    return _job("so3jax tuning campaign", "A tuning campaign (so3jax tune): a mission and [tune].",
                {campaigns.TUNE: tune()})


def compare() -> dict:
    tables = {"tune": tune(shared=True), "sweep": sweep_table(), "dispersions": schema.dispersions(),
              "compare": compare_table()}
    missing = set(comparisons.JOBS) - set(tables)
    if missing:
        raise ValueError(f"the comparison schema has no rule for its table(s) {', '.join(sorted(missing))}")
    return _job("so3jax comparison", "Control laws compared (so3jax compare): a mission, the [tune] every law "
                "shares, a sweep's [sweep] and [dispersions], and [compare].", tables)


def generate() -> dict:
    """{file name: its text} of every schema (:data:`FILES`)."""
    made = {"mission.json": schema.mission, "sweep.json": sweep, "campaign.json": campaign, "compare.json": compare}
    return {name: schema.dumps(made[name]()) for name in FILES}


def write(folder) -> list:
    """Write every schema into ``folder``, each file atomically; the paths written."""
    paths = []
    for name, text in generate().items():
        path = Path(folder) / name
        io.write_text(path, text)
        paths.append(path)
    return paths


def stale(folder) -> list:
    """The schema files of ``folder`` that differ from what :func:`generate` writes now (or are missing)."""
    folder = Path(folder)
    return [name for name, text in generate().items()
            if not (folder / name).is_file() or (folder / name).read_text(encoding="utf-8") != text]

