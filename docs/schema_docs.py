"""Markdown tables of the configuration schema, for the documentation site (not part of
the package: ``docs/hooks.py`` imports it for mkdocs, ``tests/test_docs.py`` to check it).

Every table is read from the objects the parsers check against, so the pages cannot drift
from the code: the :class:`~so3jax.core.params.Param` declarations of the mission's own keys
(:mod:`so3jax.missions.keys`), the components' and the controllers', the gains NamedTuples
and the campaign dataclasses (defaults, and the units in their fields' comments), the
sweep's and the comparison's value checks (the ``so3jax.core.checks`` calls of their
parsers: the label names the key, its meaning and unit, the arguments its domain), the
default missions and sweep, and the commands' argparse parsers.

:func:`render` is what ``docs/hooks.py`` calls for a placeholder ``<!-- keys: NAME -->``
(or ``<!-- options: COMMAND -->``) in a page.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import io
import json
import math
import re
import textwrap
import tokenize

_CHECKS = ("number", "array", "choice", "names", "boolean")  # so3jax.core.checks' value checks
_CHECK_MODULES = ("checks", "cfg")  # the names the parsers import it by
_POSITIONAL = {"number": ("low", "high", "integer"), "array": ("shape", "low"), "choice": ("choices",),
               "names": ("choices",), "boolean": ()}


# --- formatting -----------------------------------------------------------------------------


def _cell(text) -> str:
    """Text for a table cell: no newlines, pipes escaped."""
    return " ".join(str(text).split()).replace("|", "\\|")


def _code(value) -> str:
    """A value as inline code, TOML-like (true/false, lists), '—' for None."""
    if value is None:
        return "—"
    if isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, str):
        text = json.dumps(value)
    elif isinstance(value, float):
        text = repr(value)
    else:
        text = json.dumps(_plain(value))
    return f"`{_cell(text)}`"


def _plain(value):
    """Tuples and NumPy values as JSON-ready lists and numbers."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


def _number(x) -> str:
    if isinstance(x, float) and x.is_integer() and abs(x) < 1e15:
        return str(int(x))
    return repr(x)


def _interval(low=-math.inf, high=math.inf, integer=False, low_excluded=False) -> str:
    """'≥ 0', '> 0', '[0, 1]', 'integer ≥ 1', ... ('' for an unbounded real)."""
    kind = "integer " if integer else ""
    has_low, has_high = low is not None and low > -math.inf, high is not None and high < math.inf
    if has_low and has_high:
        return f"{kind}in {'(' if low_excluded else '['}{_number(low)}, {_number(high)}]"
    if has_low:
        return f"{kind}{'>' if low_excluded else '≥'} {_number(low)}"
    if has_high:
        return f"{kind}≤ {_number(high)}"
    return "integer" if integer else ""


def _shape(shape) -> str:
    dims = ", ".join("N" if n is None else str(n) for n in shape)
    return f"({dims},)" if len(shape) == 1 else f"({dims})"


def _table(header: tuple, rows: list) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


_MODEL_REF = re.compile(r"\bdocs/model\.md §(\d+(?:\.\d+)*)")


def _prose(text: str) -> str:
    """A docstring or doc field as table text: section references as 'model §N'."""
    return _cell(_MODEL_REF.sub(r"model §\1", text or ""))


def toml_comments(path) -> dict:
    """{dotted key: comment} of a shipped TOML file's entries (``key = value  # comment``,
    also commented-out entries) and table headers (``[table]  # comment``)."""
    from pathlib import Path

    path = Path(path)
    if not path.exists():
        return {}
    out, table = {}, ""
    for line in path.read_text().splitlines():
        header = re.match(r"^(?:#\s*)?\[([\w.]+)\]\s*(?:#\s*(.*))?$", line)
        if header:
            table = header.group(1) + "."
            if header.group(2):
                out[header.group(1)] = header.group(2)
            continue
        entry = re.match(r"^\s*(?:#\s*)?([A-Za-z_]\w*)\s*=\s*[^#]*?\s#\s*(.*)$", line)
        if entry:
            out.setdefault(table + entry.group(1), entry.group(2))
    return out


def _shipped(name: str):
    """A file of the source tree (missions/, sweeps/)."""
    from pathlib import Path

    return Path(__file__).resolve().parents[1] / name


# --- reading the schema objects ----------------------------------------------------------------


def field_comments(cls) -> dict:
    """{field: the comment at the end of its line} of a dataclass's or NamedTuple's
    annotated fields (the units and meanings the code states beside each field)."""
    source = textwrap.dedent(inspect.getsource(cls))
    comments = {}
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            text = tok.string.lstrip("#").strip()
            if not text.startswith("noqa") and not text.startswith("type:"):
                comments[tok.start[0]] = text
    body = ast.parse(source).body[0].body
    return {node.target.id: comments[node.end_lineno] for node in body
            if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and node.end_lineno in comments}


def _split_label(label: str) -> tuple[str, str, str]:
    """'T (horizon) [s]' -> ('T', 'horizon', 's'): the key, the parenthesized meaning (and
    bracketed layouts such as [w, x, y, z]) and the bracketed unit of a check's label."""
    key, _, rest = label.partition(" ")
    meaning, unit, depth, start = [], "", 0, 0
    for i, ch in enumerate(rest):
        if ch in "([":
            if depth == 0:
                start = i
            depth += 1
        elif ch in ")]":
            depth -= 1
            if depth == 0:
                inner = rest[start + 1:i]
                if ch == "]" and "," not in inner:
                    unit = inner
                else:
                    meaning.append(inner if ch == ")" else f"[{inner}]")
    return key, "; ".join(meaning), unit


def checked_keys(module) -> dict:
    """{key: {"meaning", "unit", "low", "high", "integer", "shape", "choices", "check"}} of
    every ``checks.<check>(value, "label", ...)`` call in ``module`` whose label is a string
    literal, in source order; arguments that are not module-level expressions are left out."""
    tree = ast.parse(inspect.getsource(module))
    namespace = vars(module)
    found = {}
    calls = []
    for n in ast.walk(tree):
        if (isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) and isinstance(n.func.value, ast.Name)
                and n.func.value.id in _CHECK_MODULES and n.func.attr in _CHECKS and len(n.args) >= 2):
            calls += [(n, label) for label in _labels(n.args[1], _loop_values(tree, n, namespace))]
    for call, label in sorted(calls, key=lambda c: (c[0].lineno, c[0].col_offset)):
        key, meaning, unit = _split_label(label)
        entry = {"meaning": meaning, "unit": unit, "check": call.func.attr}
        arguments = dict(zip(_POSITIONAL[call.func.attr], call.args[2:]))
        arguments.update({k.arg: k.value for k in call.keywords if k.arg})
        for name, node in arguments.items():
            try:
                entry[name] = _evaluate(node, namespace)
            except Exception:  # a local variable: not part of the declared schema
                continue
        if key not in found:
            found[key] = entry
    return found


def _evaluate(node, namespace):
    """The value of an expression of so3jax's own source in its module's namespace (a name
    such as ``CONTROL_MODES``, a call such as ``registry.names()``, a literal)."""
    return eval(compile(ast.Expression(node), "<schema>", "eval"), namespace)  # noqa: S307 (the package's own code)


def _labels(node, loops: dict) -> list:
    """The labels a check's ``where`` argument takes: a string literal, or an f-string over a
    comprehension's variable that runs over a literal tuple of names (``f"sweep.{key}"``)."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [node.value]
    if isinstance(node, ast.JoinedStr):
        parts = node.values
        names = [p.value.id for p in parts if isinstance(p, ast.FormattedValue) and isinstance(p.value, ast.Name)]
        simple = all(isinstance(p, (ast.Constant, ast.FormattedValue)) for p in parts)
        if len(names) == 1 and names[0] in loops and simple:
            return ["".join(str(v) if isinstance(p, ast.FormattedValue) else p.value for p in parts)
                    for v in loops[names[0]]]
    return []


def _loop_values(tree, call, namespace) -> dict:
    """{variable: values} of the comprehensions around ``call`` that iterate over a tuple of
    strings the module can evaluate."""
    out = {}
    for comp in ast.walk(tree):
        if isinstance(comp, (ast.ListComp, ast.SetComp, ast.DictComp, ast.GeneratorExp)) and any(
                n is call for n in ast.walk(comp)):
            for gen in comp.generators:
                if isinstance(gen.target, ast.Name):
                    try:
                        values = _evaluate(gen.iter, namespace)
                    except Exception:
                        continue
                    if isinstance(values, tuple) and all(isinstance(v, str) for v in values):
                        out[gen.target.id] = values
    return out


def _domain_of_check(entry: dict) -> str:
    if entry.get("choices"):
        return "one of " + ", ".join(f"`{c}`" for c in entry["choices"])
    if entry["check"] == "boolean":
        return "true or false"
    parts = []
    if entry["check"] == "array" and "shape" in entry:
        parts.append("array " + _shape(entry["shape"]))
    interval = _interval(entry.get("low", -math.inf), entry.get("high", math.inf), entry.get("integer", False))
    if interval:
        parts.append(interval)
    if entry["check"] == "names":
        parts.append("names")
    return ", ".join(parts) or "number"


def _dotted(tree: dict, key: str):
    node = tree
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node


def _param_domain(p) -> str:
    if hasattr(p, "domain"):  # a declaration that states its own (e.g. registered names)
        return p.domain()
    if p.boolean:
        return "true or false"
    if p.text:
        return "a string"
    if p.choices:
        return "one of " + ", ".join(f"`{c}`" for c in p.choices)
    shapes = " or ".join("number" if s == () else "array " + _shape(s) for s in p.shapes)
    interval = _interval(p.low, p.high, p.integer, p.low_excluded)
    return f"{shapes}, {interval}" if interval else shapes


def _param_rows(params, prefix: str) -> list:
    return [(f"`{prefix}{p.name}`", _cell(p.unit), _param_domain(p), _code(p.default), _prose(p.doc)) for p in params]


_HEADER = ("key", "unit", "domain", "default", "meaning")


# --- the tables -------------------------------------------------------------------------------


def mission_table(base: str = "flight") -> str:
    """The mission's own keys (:data:`so3jax.missions.keys.KEYS`: horizon, loop timing,
    controllers, inertias, orbit, disturbance, initial state), with the defaults of the
    flight mission or of the paper's (``base``)."""
    from so3jax.missions import keys, mission

    tree = {"flight": mission.FLIGHT, "paper": mission.PAPER}[base]
    rows = [(f"`{p.name}`", _cell(p.unit), _param_domain(p), _code(_dotted(tree, p.name)), _prose(p.doc))
            for p in keys.KEYS]
    return _table(_HEADER, rows)


def entries_table(name: str) -> str:
    """The keys of an ``[[appendages]]`` or ``[[slosh]]`` entry (:data:`so3jax.missions.keys.APPENDAGE_KEYS`,
    :data:`~so3jax.missions.keys.SLOSH_KEYS`); a ``—`` default: required."""
    from so3jax.missions import keys

    params = {"appendages": keys.APPENDAGE_KEYS, "slosh": keys.SLOSH_KEYS}[name]
    return _table(_HEADER, _param_rows(params, ""))


def mission_keys() -> tuple:
    """The keys :func:`mission_table` lists."""
    from so3jax.missions import keys

    return tuple(p.name for p in keys.KEYS)


def components_table(kind: str, heading: str = "###") -> str:
    """One section per registered component of ``kind`` (sensor, estimator, actuator,
    reference, inertia): what it is, and a row per parameter (``[sensors.NAME]``,
    ``[estimator.NAME]``, ``[actuator.NAME]``, ``[reference.NAME]``, ``[inertia.NAME]``)."""
    from so3jax.components import registry as components

    table = {"sensor": "sensors", "estimator": "estimator", "actuator": "actuator", "reference": "reference",
             "inertia": "inertia", "momentum": "momentum", "filter": "filter", "environment": "environment"}[kind]
    out = []
    for name in components.names(kind):
        spec = components.get(kind, name)
        facts = []
        if spec.provides:
            facts.append(f"measures the {spec.provides}")
        if spec.needs:
            facts.append("reads the " + " and the ".join(spec.needs) + " measurements")
        if spec.truth:
            facts.append("reads the true state")
        select = f"`[{table}.{name}]`" if kind in ("sensor", "environment") else f"`{table}.kind = \"{name}\"`"
        out.append(f"{heading} `{name}`\n\n{_prose(spec.doc)}. Chosen by {select}"
                   + (f"; {', '.join(facts)}" if facts else "") + ".\n")
        if spec.params:
            out.append(_table(_HEADER, _param_rows(spec.params, f"{table}.{name}.")) + "\n")
        else:
            out.append("No parameters.\n")
    return "\n".join(out)


def controllers_table(heading: str = "###") -> str:
    """One section per registered controller: its options (``[controller.NAME]``) and its
    gains (``[gains.NAME]``, the defaults being the registration's)."""
    import sys

    from so3jax.controllers import registry

    out = []
    for name in registry.names():
        spec = registry.get(name)
        module = sys.modules[spec.factory.__module__]
        summary = (module.__doc__ or "").strip().split("\n\n")[0]
        tunable = "its gains are tunable (`tune`, `compare`)" if spec.tunable else "it has no gains to tune"
        out.append(f"{heading} `{name}` ({spec.label})\n\n{_prose(summary)}\n\n"
                   f"`{spec.factory.__module__}`; {tunable}.\n")
        if spec.options:
            out.append(_table(_HEADER, _param_rows(spec.options, f"controller.{name}.")) + "\n")
        fields = spec.gains_type._fields
        if fields:
            comments = field_comments(spec.gains_type)
            shapes = spec.gain_shapes()
            rows = [(f"`gains.{name}.{f}`", " or ".join("number" if s == () else _shape(s) for s in shapes[f]),
                     _code(getattr(spec.defaults, f)), _prose(comments.get(f, ""))) for f in fields]
            out.append(_table(("gain", "shape", "default", "unit, meaning"), rows) + "\n")
    return "\n".join(out)


def dataclass_table(cls, prefix: str, defaults: dict | None = None, checks: dict | None = None,
                    nested: dict | None = None) -> str:
    """A row per field of a dataclass (nested dataclasses as their own rows under
    ``prefix.field.``): default (``defaults`` where given), type, and the field's comment;
    ``checks``: {key: checked_keys entry} for the domains."""
    rows = []

    def add(cls, prefix, defaults):
        comments = field_comments(cls)
        for f in dataclasses.fields(cls):
            if f.name == "mission":
                continue
            sub = (nested or {}).get(f.name)
            if sub is not None and dataclasses.is_dataclass(sub):
                add(sub, f"{prefix}{f.name}.", None)
                continue
            if defaults is not None and f.name in defaults:
                default = defaults[f.name]
            elif f.default is not dataclasses.MISSING:
                default = f.default
            elif f.default_factory is not dataclasses.MISSING:
                default = f.default_factory()
            else:
                default = "(required)"
            key = f"{prefix}{f.name}"
            entry = (checks or {}).get(key)
            domain = _domain_of_check(entry) if entry else _cell(_annotation(f.type))
            shown = "required" if default == "(required)" else _code(default)
            rows.append((f"`{key}`", domain, shown, _prose(comments.get(f.name, ""))))

    add(cls, prefix, defaults)
    return _table(("key", "type or domain", "default", "meaning"), rows)


def _annotation(annotation) -> str:
    text = annotation if isinstance(annotation, str) else getattr(annotation, "__name__", str(annotation))
    return text.replace("typing.", "")


def tune_table() -> str:
    """The ``[tune]`` table of a campaign (``TuneConfig`` and its sections)."""
    from so3jax.jobs.tune import config

    domains = _tune_domains()
    rows_table = dataclass_table(config.TuneConfig, "tune.", nested={**config.SECTIONS, **config.CONSTRAINTS})
    lines = rows_table.split("\n")
    for i, line in enumerate(lines[2:], start=2):
        key = line.split("`")[1].removeprefix("tune.")
        if key in domains:
            cells = line.split(" | ")
            cells[1] = domains[key]
            lines[i] = " | ".join(cells)
    return "\n".join(lines)


def _tune_domains() -> dict:
    """{tune key: domain} of the campaign's ``_choice(KEY, value, CHOICES)`` and
    ``_positive(KEY, value[, integer])`` checks."""
    from so3jax.jobs.tune import config

    tree = ast.parse(inspect.getsource(config.validate))
    out = {}
    for n in ast.walk(tree):
        if not (isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.args
                and isinstance(n.args[0], ast.Constant) and isinstance(n.args[0].value, str)):
            continue
        key = n.args[0].value
        if n.func.id == "_choice" and len(n.args) == 3:
            try:
                choices = _evaluate(n.args[2], vars(config))
            except Exception:
                continue
            out[key] = "one of " + ", ".join(f"`{c}`" for c in choices)
        elif n.func.id == "_positive":
            integer = any(k.arg == "integer" and getattr(k.value, "value", False) for k in n.keywords)
            integer = integer or (len(n.args) > 2 and getattr(n.args[2], "value", False) is True)
            out.setdefault(key, "integer > 0" if integer else "> 0")
    return out


def sweep_table() -> str:
    """The ``[sweep]`` table: the default sweep's values and the parser's domains."""
    from so3jax.jobs.sweep import config

    checks = checked_keys(config)
    comments = {k.removeprefix("sweep."): v for k, v in toml_comments(_shipped("sweeps/default.toml")).items()}
    rows = []
    for key, default in config.DEFAULT["sweep"].items():
        entry = checks.get(f"sweep.{key}")
        rows.append((f"`sweep.{key}`", _domain_of_check(entry) if entry else _annotation(
            config.SweepConfig.__dataclass_fields__[key].type), _code(default), _prose(comments.get(key, ""))))
    return _table(("key", "domain", "default", "meaning"), rows)


def distributions_table() -> str:
    """The distributions a ``[dispersions]`` leaf takes."""
    from so3jax.missions import distributions

    rows = [("a number", "—", "fixed at that value")]
    for name, cls in distributions.DISTRIBUTIONS.items():
        fields = ", ".join(f.name for f in dataclasses.fields(cls))
        rows.append((f'`{{dist = "{name}", ...}}`', fields, _prose((cls.__doc__ or "").strip())))
    return _table(("value", "parameters", "meaning"), rows)


def default_dispersions_table() -> str:
    """The default sweep's ``[dispersions]``, leaf by leaf."""
    from so3jax.jobs.sweep import config

    def flatten(table, prefix=""):
        for key, value in table.items():
            path = f"{prefix}{key}"
            if isinstance(value, dict) and "dist" not in value and not (set(value) & {"max_angle_deg", "norm"}):
                yield from flatten(value, path + ".")
            else:
                yield path, value

    rows = [(f"`dispersions.{k}`", _code(v)) for k, v in flatten(config.DEFAULT["dispersions"])]
    return _table(("leaf", "default sweep's value"), rows)


def inertia_dispersion_table() -> str:
    """The structured dispersion of an inertia leaf (``inertia.J0``, ``J1``, ``J2``)."""
    from so3jax.missions import draw

    doc = inspect.getdoc(draw.InertiaDispersion) or ""
    rows = []
    for key in draw.INERTIA_KEYS:
        match = re.search(rf"\b{key}: (.*?)(?=; \w+: |\.\s|$)", " ".join(doc.split()))
        rows.append((f"`{key}`", _prose(match.group(1) if match else "")))
    return _table(("key", "meaning"), rows)


def compare_table() -> str:
    """The ``[compare]`` table's keys and domains (its parser's checks)."""
    from so3jax.jobs import compare

    checks = {k: v for k, v in checked_keys(compare).items() if k.startswith("compare.")}
    comments = field_comments(compare.CompareConfig)
    defaults = {f.name: f.default for f in dataclasses.fields(compare.CompareConfig)}
    rows = []
    for k, v in checks.items():
        name = k.removeprefix("compare.")
        default = defaults.get(name, dataclasses.MISSING)
        rows.append((f"`{k}`", _domain_of_check(v) if v["check"] != "choice" else "a candidate's name",
                     "—" if default is dataclasses.MISSING else _code(default), _prose(comments.get(name, ""))))
    return _table(("key", "domain", "default", "meaning"), rows)


def options_table(command: str) -> str:
    """The options of ``so3jax COMMAND`` from its argparse parser."""
    from so3jax import commands as cli

    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    rows = []
    for action in sub.choices[command]._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        name = ", ".join(action.option_strings) or action.dest.upper()
        if action.option_strings and action.nargs != 0:
            name += " " + (action.metavar or action.dest.upper())
        choices = ", ".join(f"`{c}`" for c in action.choices) if action.choices else ""
        default = action.default
        shown = "—" if default in (None, [], False) or default is argparse.SUPPRESS else f"`{_cell(default)}`"
        rows.append((f"`{name}`", choices, shown, _cell(action.help or "")))
    return _table(("option", "choices", "default", "meaning"), rows)


def leaves(tree: dict, prefix: str = "") -> list:
    """The dotted keys of a nested table's leaves (e.g. of ``so3jax.missions.mission.default_tree()``)."""
    out = []
    for key, value in tree.items():
        if isinstance(value, dict) and value:
            out += leaves(value, f"{prefix}{key}.")
        elif not isinstance(value, dict):
            out.append(f"{prefix}{key}")
    return out


def registered_names() -> dict:
    """{kind: registered names} of controllers, sensors, estimators and actuators."""
    from so3jax.components import registry as components
    from so3jax.controllers import registry

    return {"controller": registry.names(), **{kind: components.names(kind) for kind in components.KINDS}}


def render(what: str, args: tuple = ()) -> str:
    """The Markdown of a placeholder: ``keys: NAME [ARG]`` or ``options: COMMAND``."""
    if what == "options":
        return options_table(args[0])
    name, rest = args[0], args[1:]
    tables = {
        "mission": lambda: mission_table(*rest),
        "sensors": lambda: components_table("sensor", *rest),
        "estimators": lambda: components_table("estimator", *rest),
        "actuators": lambda: components_table("actuator", *rest),
        "references": lambda: components_table("reference", *rest),
        "inertias": lambda: components_table("inertia", *rest),
        "momentum": lambda: components_table("momentum", *rest),
        "filters": lambda: components_table("filter", *rest),
        "environment": lambda: components_table("environment", *rest),
        "controllers": lambda: controllers_table(*rest),
        "appendages": lambda: entries_table("appendages"),
        "slosh": lambda: entries_table("slosh"),
        "tune": tune_table,
        "sweep": sweep_table,
        "distributions": distributions_table,
        "dispersions": default_dispersions_table,
        "inertia-dispersion": inertia_dispersion_table,
        "compare": compare_table,
    }
    if name not in tables:
        raise ValueError(f"unknown schema table {name!r}; known: {', '.join(tables)}")
    return tables[name]()
