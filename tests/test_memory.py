"""Memory estimates: sizes parsed, the estimate equal to what a run returns, and runs that
cannot fit refused (one line, exit code 2) before anything compiles."""

import importlib
import os
import subprocess
import sys

import jax
import numpy as np
import pytest

import so3jax as sj
from so3jax.sim import memory


@pytest.mark.parametrize(("text", "expected"),
                         [("512", 512), ("4K", 4096), ("1.5G", 3 << 29), ("2GiB", 2 << 30), ("3mb", 3 << 20)])
def test_sizes(text, expected):
    assert memory.parse_size(text) == expected


@pytest.mark.parametrize("text", ["lots", "-1G", "0", "4X", ""])
def test_bad_sizes_are_one_line_errors(text):
    with pytest.raises(ValueError, match="--max-memory"):
        memory.parse_size(text)


def test_available_memory_is_positive_and_at_most_the_machine_total():
    total = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    assert 0 < memory.available() <= total


def test_the_estimate_is_the_bytes_of_what_simulate_returns_held_twice(monkeypatch):
    """The estimate traces the program simulate then runs, once (a horizon no other test flies)."""
    scenario = sj.paper_scenario(2.0, 0.01)
    controller, gains = sj.controllers.get("pd").factory(), sj.controllers.get("pd").defaults
    module = importlib.import_module("so3jax.sim.rollout")
    traced, rollout = [], module._rollout
    monkeypatch.setattr(module, "_rollout", lambda *a, **k: traced.append(1) or rollout(*a, **k))
    for record_every in (1, 10):
        estimate = memory.simulate_bytes(scenario, controller, gains, 0, record_every=record_every)
        result = sj.simulate(scenario, controller, gains, 0, record_every=record_every)
        assert len(traced) == (1 if record_every == 1 else 2)  # simulate reused the estimate's trace
        measured = sum(np.asarray(x).nbytes for x in jax.tree.leaves(result))
        assert estimate == memory.COPIES * measured


def test_the_check_refuses_above_the_limit_and_reports_both():
    assert memory.check(10, 100, "run", "advice") == {"estimate_bytes": 10, "limit_bytes": 100}
    with pytest.raises(ValueError,
                       match=r"run needs about 1 KiB of memory, more than the 100 B allowed by --max-memory; advice"):
        memory.check(1024, 100, "run", "advice")


@pytest.mark.parametrize(
    "args",
    [
        ("paper", "--T", "200000", "--record-every", "1"),  # histories larger than any machine here has free
        ("paper", "--T", "100", "--max-memory", "10K"),
        ("fly", "--T", "100", "--record-every", "1", "--max-memory", "1M"),
        ("sweep", "--samples", "8", "--T", "10", "--max-memory", "1K"),
    ],
)
def test_a_run_that_cannot_fit_is_refused_before_compiling(tmp_path, args):
    env = {**os.environ, "JAX_LOG_COMPILES": "1"}  # logged when lowered, so also for a persistent-cache hit
    proc = subprocess.run([sys.executable, "-m", "so3jax.commands", *args, "--out", str(tmp_path / "out")],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    compiled = [line for line in proc.stderr.splitlines() if line.startswith("Compiling ")]
    assert not [line for line in compiled if "simulate" in line or "rollout" in line], compiled  # only tiny array ops
    error = proc.stderr.strip().splitlines()[-1]
    assert error.startswith(f"so3jax {args[0]}: error: ") and "of memory, more than the" in error
    assert not (tmp_path / "out" / "metrics.json").exists() and not (tmp_path / "out" / "chunks").exists()
