"""Every script in examples/ runs as ``python examples/<name>.py`` does (in-process, by
runpy, with its command line and SO3JAX_EXAMPLE_T set for a short horizon) and computes
what it prints: the numbers it leaves in its module-level ``results``. A component an
example registers is unregistered afterwards, so no other test sees it.

Compilation dominates: horizons are seconds and batches two samples; the actuator and
gradient examples fly the flight loop without its sensors and filter (``--set``; with the
MEKF the reverse-mode program takes about three times as long to compile), the gradient
through the same wheels and checkpointing."""

import math
import runpy
import sys
from pathlib import Path

import numpy as np
import pytest

from so3jax.components import registry as components
from so3jax.controllers import registry

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
NO_FILTER = ["--set", "estimator.kind=truth", "--set", "sensors.gyro=false", "--set", "sensors.star_tracker=false"]


@pytest.fixture
def example(monkeypatch):
    """run(name, *argv, T=seconds) -> the example's ``results``; registrations it made are removed after the test."""
    components.names("sensor")  # the built-in components registered before the snapshot
    before = set(registry.names()), {kind: set(components.names(kind)) for kind in components.KINDS}

    def run(name, *argv, T):
        monkeypatch.setattr(sys, "argv", [f"examples/{name}.py", *argv])
        monkeypatch.setenv("SO3JAX_EXAMPLE_T", repr(float(T)))
        monkeypatch.setenv("SO3JAX_KEEP_XLA_FLAGS", "1")  # sj.configure_xla() leaves XLA_FLAGS alone here
        return runpy.run_path(str(EXAMPLES / f"{name}.py"), run_name="__main__")["results"]

    yield run
    for name in set(registry.names()) - before[0]:
        registry.unregister(name)
    for kind in components.KINDS:
        for name in set(components.names(kind)) - before[1][kind]:
            components.unregister(kind, name)


def test_every_example_is_tested():
    tested = {"custom_controller", "custom_actuator", "gradient_through_flight", "vmapped_sweep", "identify_inertia"}
    assert {p.stem for p in EXAMPLES.glob("*.py")} == tested
    readme = (EXAMPLES / "README.md").read_text()
    assert all(f"{name}.py" in readme for name in tested)


def test_custom_controller(example):
    """The saturated PD without feedforward flies the paper's mission next to the PD: both
    RMSEs of the PD's order (6e-3 rad/s over the first 20 s), not the same law's."""
    r = example("custom_controller", T=20.0)
    (pd, _), (saturated, effort) = r["pd"], r["example_saturated_pd"]
    assert 1e-3 < pd < 1e-2 and math.isfinite(effort) and effort > 0
    assert 0.5 < saturated / pd < 2.0 and saturated != pd


def test_custom_actuator(example):
    """The lag delays the torque: the RMSE grows with its time constant (ideal < 0.5 s < 5 s)."""
    r = example("custom_actuator", *NO_FILTER, T=10.0)
    rmse = [r[k][0] for k in ("ideal", "lag 0.5 s", "lag 5 s")]
    assert all(math.isfinite(x) for x in rmse)
    assert rmse[0] < rmse[1] < rmse[2], rmse


def test_gradient_through_flight(example):
    """jax.grad through the loop with the wheels agrees with central differences."""
    r = example("gradient_through_flight", *NO_FILTER, T=5.0)
    assert np.all(np.abs(r["central"]) > 1e-3)
    assert r["relative_difference"] < 1e-6, (r["grad"], r["central"])


def test_vmapped_sweep(example):
    """Two dispersed samples per law: finite, different RMSEs of the paper's order; the
    adaptive law ahead of the PD on each."""
    r = example("vmapped_sweep", "--samples", "2", T=10.0)
    for rmse in r.values():
        assert rmse.shape == (2,) and np.all((1e-3 < rmse) & (rmse < 5e-2)) and rmse[0] != rmse[1]
    assert np.all(r["adaptive"] < r["pd"])


def test_identify_inertia(example):
    """120 s of the noisy manoeuvre identify J2 to 1 %, each entry within 4 sigma."""
    from so3jax.jobs.identify import inertia

    r = example("identify_inertia", T=120.0)
    assert r["relative_error"] < 0.01, r["relative_error"]
    z = (inertia.entries(r["J"]) - inertia.entries(r["J_true"])) / r["sigma"]
    assert np.all(np.abs(np.asarray(z)) < 4.0), z
