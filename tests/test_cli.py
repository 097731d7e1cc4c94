"""``so3jax paper`` end to end, as a user runs it (a subprocess with its own JAX)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def run_cli(*args, cwd, **env_vars):
    """``so3jax ARGS`` in a fresh interpreter (works installed or from the source tree)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]), **env_vars}
    return subprocess.run(
        [sys.executable, "-m", "so3jax.cli", *args], cwd=cwd, capture_output=True, text=True, timeout=600, env=env
    )


def test_paper_json_and_figures(tmp_path):
    out = tmp_path / "paper"
    proc = run_cli("paper", "--T", "40", "--json", "--out", str(out), "--record-every", "50", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    assert set(report) == {"pd", "adaptive", "config"}
    for name in ("pd", "adaptive"):
        m = report[name]
        assert set(m) >= {"rmse", "rmse_unrotated", "effort", "rmse_phase", "effort_phase", "rms_angle_phase",
                          "max_angle_phase", "max_torque", "orthogonality_error", "diverged"}
        assert len(m["rmse_phase"]) == 3 and m["diverged"] is False
        # only phase 1 is reached in 40 s: the others have no value
        assert m["rmse_phase"][0] > 0 and m["rmse_phase"][1] is None and m["effort_phase"][1:] == [None, None]
        np.testing.assert_allclose(m["effort"], m["effort_phase"][0], rtol=1e-12)
    assert report["config"]["n_steps"] == 4000 and report["config"]["precision"] == "float64"
    assert json.loads((out / "metrics.json").read_text())["pd"] == report["pd"]
    for fig in ("fig1_inertia", "fig2_angular_velocity", "fig3_tracking_error", "fig4_torque", "fig5_torque_norm"):
        assert (out / f"{fig}.png").stat().st_size > 10_000
    assert "triangle inequality" in proc.stderr


def test_paper_table_and_float32(tmp_path):
    proc = run_cli("paper", "--T", "10", "--precision", "float32", "--no-figures", "--out", str(tmp_path), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "paper PD" in proc.stdout and "-31.0 %" in proc.stdout  # the paper's own RMSE ratio, recomputed
    assert json.loads((tmp_path / "metrics.json").read_text())["config"]["precision"] == "float32"


def test_paper_rejects_a_bad_horizon(tmp_path):
    proc = run_cli("paper", "--T", "10.005", "--no-figures", "--out", str(tmp_path), cwd=tmp_path)
    assert proc.returncode != 0
    assert "not a multiple of dt" in proc.stderr


def test_compilations_are_cached_and_reused(tmp_path):
    """The second identical run loads its executables from the persistent cache: same
    results, and the cache holds one entry per compiled program."""
    cache = tmp_path / "cache"
    args = ("paper", "--T", "2", "--json", "--no-figures", "--out", str(tmp_path / "p"))
    env = {"SO3JAX_CACHE_DIR": str(cache), "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0"}
    first = run_cli(*args, cwd=tmp_path, **env)
    assert first.returncode == 0, first.stderr
    entries = sorted(p.name for p in cache.iterdir())
    assert any(name.startswith("jit__simulate_jit") for name in entries)
    second = run_cli(*args, cwd=tmp_path, **env)
    assert second.returncode == 0, second.stderr
    assert sorted(p.name for p in cache.iterdir()) == entries  # nothing compiled anew
    strip = lambda out: {k: v for k, v in json.loads(out.strip().splitlines()[-1]).items() if k != "config"}
    assert strip(second.stdout) == strip(first.stdout)
