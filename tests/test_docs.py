"""The documentation site builds with ``mkdocs build --strict`` (no broken link, no
docstring the API pages cannot render, no key table that fails to generate, no formula
that fails to convert), its generated key tables list every registered component and every
key of the mission schema, its formulas are MathML (no script, no network), the committed
Markdown pages hold their generated blocks up to date (readable unprocessed), and every
command's --help lists the registered names it can choose."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The site built into a temporary folder, strict (every warning is an error)."""
    out = tmp_path_factory.mktemp("site")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, f"mkdocs build --strict failed:\n{run.stdout}\n{run.stderr}"
    return out


def _fresh(expression: str):
    """The value of an expression over docs/schema_docs.py in a fresh interpreter, as mkdocs
    sees the package (no component a test registered in this process)."""
    code = (f"import json, sys; sys.path.insert(0, {str(ROOT / 'docs')!r}); import schema_docs; "
            f"from so3jax.missions import mission; print(json.dumps({expression}))")
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120,
                         check=True)
    return json.loads(run.stdout.strip().splitlines()[-1])


def _page(site: Path, name: str) -> str:
    return (site / name / "index.html").read_text()


def test_site_builds_strict_with_generated_tables(site):
    for page in ("commands/paper", "commands/fly", "commands/tune", "commands/sweep", "commands/compare",
                 "commands/identify", "library", "architecture", "api/rollout"):
        html = _page(site, page)
        assert "<!-- keys:" not in html and "<!-- options:" not in html, page
    assert "sweep.divergence_angle_deg" in _page(site, "commands/sweep")
    assert "tune.optimizer.learning_rate" in _page(site, "commands/tune")
    assert "compare.bootstrap" in _page(site, "commands/compare")
    assert "--initial-inertia" in _page(site, "commands/identify")
    assert (site / "sweeps" / "default" / "cdf.png").exists()  # the recorded results' figures are served


def test_every_registered_component_and_mission_key_is_on_the_fly_page(site):
    html = _page(site, "commands/fly")
    names = _fresh("schema_docs.registered_names()")
    assert set(names) == {"controller", "sensor", "estimator", "actuator", "momentum", "filter", "environment",
                          "reference", "inertia"}
    for kind, registered in names.items():
        assert registered, kind
        for name in registered:
            assert f'id="{name}"' in html or f"<code>{name}</code>" in html, (kind, name)
    chosen = {"controller": ("controller.{}.", "gains.{}."), "sensor": ("[sensors.{}]",),
              "estimator": ('estimator.kind = "{}"',), "actuator": ('actuator.kind = "{}"',),
              "reference": ('reference.kind = "{}"',), "inertia": ('inertia.kind = "{}"',),
              "momentum": ('momentum.kind = "{}"',), "filter": ('filter.kind = "{}"',),
              "environment": ("[environment.{}]",)}
    for kind, registered in names.items():
        for name in registered:  # how a mission names it
            assert any(pattern.format(name) in html for pattern in chosen[kind]), (kind, name)
    # every leaf of the whole schema (the flight mission, every registered component's and
    # controller's parameters at their defaults) and every key the parser checks is listed
    leaves = _fresh("sorted(schema_docs.leaves(mission.default_tree())) + list(schema_docs.mission_keys())")
    missing = [key for key in leaves if f"<code>{key}</code>" not in html and key not in html]
    assert not missing, missing


def test_every_command_help_lists_the_registered_names():
    from so3jax import commands as cli
    from so3jax.components import registry as components
    from so3jax.controllers import registry

    parser = cli.build_parser()
    top = parser.format_help()
    for command in ("paper", "fly", "tune", "sweep", "compare", "identify"):
        assert command in top
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    for command in ("paper", "fly", "sweep", "tune", "compare"):
        text = " ".join(sub.choices[command].format_help().split())
        laws = registry.names(tunable=True) if command in ("tune", "compare") else registry.names()
        for name in laws:
            assert name in text, (command, name)
        for kind in components.KINDS:
            for name in components.names(kind):
                assert name in text, (command, kind, name)
    for command in ("fly", "sweep"):
        text = " ".join(sub.choices[command].format_help().split())
        assert "comma-separated controllers among: " + ", ".join(registry.names()) in text
    identify = " ".join(sub.choices["identify"].format_help().split())
    assert "regression" in identify and "simulation" in identify and "cubic" in identify


_CODE = re.compile(r"<(pre|code)\b.*?</\1>", re.DOTALL)


def test_formulas_are_mathml_with_no_script(site):
    """Every formula of every page is MathML rendered at build time: no TeX left to a
    script, no script or stylesheet loaded from the network, the equation numbers kept."""
    pages = sorted(site.rglob("*.html"))
    assert len(pages) > 30
    for path in pages:
        html = path.read_text()
        name = path.relative_to(site).as_posix()
        text = _CODE.sub("", html)
        assert "\\(" not in text and "\\[" not in text, (name, text[text.find("\\"):][:200])
        assert 'class="arithmatex"' not in html, name
        assert not re.search(r"<script[^>]*\bsrc=[\"']?(https?:)?//", html), name
        assert "mathjax" not in html.lower() and "katex" not in html.lower(), name
    model = _page(site, "model")
    source = (ROOT / "docs" / "model.md").read_text()
    assert model.count("<math ") >= source.count("$$") // 2 > 20
    tags = re.findall(r"\\tag\{([^}]*)\}", source)
    assert tags and "(1.1)" in tags[0].join("()")
    labels = re.findall(r'<span class="math-tag">\(([^)<]*)\)</span></div>', model)
    assert labels == tags  # every equation number, in order, as a label beside its formula
    assert "<mtext>(1.1)</mtext>" not in model
    for page in ("commands/tune", "commands/sweep"):
        assert "<math " in _page(site, page), page


def _hooks(monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "docs"))
    import hooks

    return hooks


def test_a_formula_that_does_not_convert_fails_the_build_naming_page_and_formula(monkeypatch):
    from mkdocs.exceptions import PluginError

    hooks = _hooks(monkeypatch)
    page = type("Page", (), {"file": type("File", (), {"src_uri": "model.md"})()})()
    good = hooks.on_page_content('<p><span class="arithmatex">\\(\\hat\\beta = \\arg\\min x &lt; 1\\)</span></p>'
                                 '<div class="arithmatex">\\[\n\\dot R = R\\,\\hat\\Omega,\\\na\n\\tag{2.3}\n\\]</div>',
                                 page, None, None)
    assert "<math " in good and "\\" not in good and "&#x0003C;" in good
    assert '<span class="math-tag">(2.3)</span></div>' in good and "2.3" not in good.split("math-tag")[0]
    aligned = hooks.mathml("\\begin{aligned} a &= b, & c &= d\\\\ e &= f \\end{aligned}", True)
    assert "<mtable" in aligned and aligned.count("<mtr>") == 2
    broken = ("\\unknowncommand x", "\\frac{1}{2", "x}", "a \\tag{1} = b \\tag{2}", "\\begin{foo} a \\end{foo}",
              "a & b", "a \\\\ b", "x^")
    for tex in broken:  # each one latex2mathml would take silently or with an error of its own
        with pytest.raises(PluginError, match=r"^model\.md: cannot convert the formula ") as error:
            hooks.on_page_content(f'<p><span class="arithmatex">\\({tex}\\)</span></p>', page, None, None)
        assert repr(f"\\({tex}\\)") in str(error.value), tex


def test_committed_pages_hold_their_generated_blocks():
    """The Markdown pages read as they are where nothing processes them (the repository
    host): no bare placeholder, no mkdocstrings directive, every generated block as the code
    generates it now (``python docs/generated.py --write`` rewrites them)."""
    run = subprocess.run([sys.executable, "docs/generated.py", "--check"], cwd=ROOT, capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    readme = (ROOT / "README.md").read_text()
    linked = {ROOT / link for link in re.findall(r"\]\((docs/[^)#\s]+\.md)", readme)}
    assert ROOT / "docs" / "commands" / "fly.md" in linked
    for path in sorted((ROOT / "docs").rglob("*.md")) + sorted(linked):
        text = path.read_text()
        assert not re.search(r"^\s*:::", text, re.MULTILINE), path
        opened = re.findall(r"^[ \t]*<!--\s*(?:keys|options|api):", text, re.MULTILINE)
        closed = re.findall(r"^[ \t]*<!--\s*end:", text, re.MULTILINE)
        assert len(opened) == len(closed), path
    paper = (ROOT / "docs" / "commands" / "paper.md").read_text()
    assert "| `--json` |" in paper and "| `orbit.n` |" in paper
    so3 = (ROOT / "docs" / "api" / "so3.md").read_text()
    assert "(../../so3jax/core/so3.py)" in so3 and "- `hat()`: " in so3


def test_generated_blocks_are_one_implementation_for_pages_and_site(monkeypatch):
    """``expand`` fills a bare marker, replaces a stale block, keeps its indentation and
    what follows; for the site it leaves no marker and makes an API block the directive."""
    _hooks(monkeypatch)
    import generated

    page = "intro\n\n  <!-- options: paper -->\n\n  stale\n\n  <!-- end: old -->\nafter\n<!-- options: fly -->\nend"
    written = generated.expand(page, "commands/x.md")
    assert "stale" not in written and "end: old" not in written
    assert written.startswith("intro\n\n  <!-- options: paper -->\n\n  | option |")
    assert "\n  | `--json` |" in written and "\nafter\n<!-- options: fly -->\n" in written
    assert written.count("<!-- end: generated by python docs/generated.py --write -->") == 2
    assert generated.expand(written, "commands/x.md") == written
    site = generated.expand(written, "commands/x.md", markers=False)
    assert "<!--" not in site and "| `--json` |" in site and site.endswith("\nend")
    api = generated.expand("<!-- api: so3jax.core.so3 heading_level=1 -->\nold\n<!-- end: x -->", "api/so3.md",
                           markers=False)
    assert api == "::: so3jax.core.so3\n    options:\n      heading_level: 1"
