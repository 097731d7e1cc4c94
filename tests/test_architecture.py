"""The package's layers (docs/architecture.md): every import of so3jax, at module level or
inside a function, goes to the same layer or one below, and the module graph has no circle."""

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
