"""The documentation site builds with ``mkdocs build --strict`` (no broken link, no
docstring the API pages cannot render, no key table that fails to generate), its
generated key tables list every registered component and every key of the mission
schema, and every command's --help lists the registered names it can choose."""

from __future__ import annotations

import json
import os
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
    assert set(names) == {"controller", "sensor", "estimator", "actuator"}
    for kind, registered in names.items():
        assert registered, kind
        for name in registered:
            assert f'id="{name}"' in html or f"<code>{name}</code>" in html, (kind, name)
    chosen = {"controller": ("controller.{}.", "gains.{}."), "sensor": ("[sensors.{}]",),
              "estimator": ('estimator.kind = "{}"',), "actuator": ('actuator.kind = "{}"',)}
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
