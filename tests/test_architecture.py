"""The package's layers (docs/architecture.md): every import of so3jax, at module level or
inside a function, goes to the same layer or one below, and the module graph has no circle;
no module reaches for another module's private (underscore) names."""

import ast
from pathlib import Path

import so3jax

PACKAGE = Path(so3jax.__file__).parent

# bottom to top; a module may import its own layer and the layers below it
LAYERS = ("core", "dynamics", "components", "controllers", "sim", "results", "parallel", "missions", "viz", "jobs",
          "commands")


def _name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_name(p): p for p in PACKAGE.rglob("*.py")}


def _imports(path: Path) -> set[str]:
    """The so3jax modules a file imports (a name imported from a package counts as its module where it is one)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.split(".")[0] == "so3jax"}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").split(".")[0] == "so3jax":
            for a in node.names:
                full = f"{node.module}.{a.name}"
                found.add(full if full in MODULES else node.module)
    return found


GRAPH = {name: _imports(path) - {name} for name, path in MODULES.items()}


def _layer(module: str) -> int | None:
    parts = module.split(".")
    return LAYERS.index(parts[1]) if len(parts) > 1 and parts[1] in LAYERS else None


def upward_imports() -> list[str]:
    out = []
    for module, deps in GRAPH.items():
        if module == "so3jax":
            continue  # the public API re-exports every layer
        own = _layer(module)
        for dep in deps:
            if own is None or _layer(dep) is None or _layer(dep) > own:
                out.append(f"{module} -> {dep}")
    return sorted(out)


def circles() -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in GRAPH.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in GRAPH:
        if v not in index:
            visit(v)
    return out


def test_every_module_sits_in_a_layer():
    assert [m for m in MODULES if m != "so3jax" and _layer(m) is None] == []


def test_no_import_goes_up_a_layer():
    assert upward_imports() == []


def test_the_import_graph_has_no_circle():
    assert circles() == []


def test_the_checks_see_an_upward_import_and_a_circle():
    GRAPH["so3jax.core.so3"].add("so3jax.sim.loop")
    try:
        assert "so3jax.core.so3 -> so3jax.sim.loop" in upward_imports()
        assert any("so3jax.core.so3" in c and "so3jax.sim.loop" in c for c in circles())
    finally:
        GRAPH["so3jax.core.so3"].discard("so3jax.sim.loop")


def _private_uses(module: str, source: str) -> list[str]:
    """Another so3jax module's underscore names ``source`` uses: ``from M import _x`` and
    ``alias._x`` where ``alias`` names a so3jax module (dunder names aside)."""
    tree = ast.parse(source)
    aliases, out = {}, []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").split(".")[0] == "so3jax":
            for a in node.names:
                full = f"{node.module}.{a.name}"
                if full in MODULES:
                    aliases[a.asname or a.name] = full
                elif a.name.startswith("_") and node.module != module:
                    out.append(f"{module}: {node.module}.{a.name}")
        elif isinstance(node, ast.Import):
            aliases.update({a.asname: a.name for a in node.names if a.asname and a.name in MODULES})
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases
                and node.attr.startswith("_") and not node.attr.startswith("__") and aliases[node.value.id] != module):
            out.append(f"{module}: {aliases[node.value.id]}.{node.attr}")
    return out


def test_no_module_uses_another_modules_private_names():
    found = [use for name, path in MODULES.items() for use in _private_uses(name, path.read_text())]
    assert found == []


def test_the_check_sees_a_private_import_and_a_private_attribute():
    source = "from so3jax.core.so3 import _axis_terms\nfrom so3jax.core import checks\nchecks._hidden(1)\n"
    assert _private_uses("so3jax.sim.loop", source) == ["so3jax.sim.loop: so3jax.core.so3._axis_terms",
                                                        "so3jax.sim.loop: so3jax.core.checks._hidden"]
