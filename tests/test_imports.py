"""Importing so3jax changes nothing outside it: no XLA_FLAGS, no matplotlib backend, no
private JAX module; the CLI's XLA:CPU settings come from an explicit call."""

import os
import subprocess
import sys
from pathlib import Path

import so3jax

PACKAGE = Path(so3jax.__file__).parent

IMPORT_EVERYTHING = """
import os, sys, matplotlib
import so3jax, so3jax.commands, so3jax.viz.plots, so3jax.viz.flight, so3jax.jobs.paper, so3jax.jobs.fly
import so3jax.jobs.tune, so3jax.jobs.sweep, so3jax.jobs.compare, so3jax.jobs.identify.report
import so3jax.viz.paper, so3jax.viz.fly, so3jax.viz.compare, so3jax.viz.identify
import numpy as np
fig = so3jax.viz.plots.inertia_figure(np.zeros(2), np.zeros((2, 3, 3)), (1.0,), T=2.0)
print(os.environ.get("XLA_FLAGS", "<unset>"), matplotlib.get_backend(), "matplotlib.pyplot" in sys.modules)
"""


def _run(code: str, **env) -> str:
    base = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "MPLBACKEND", "SO3JAX_KEEP_XLA_FLAGS")}
    proc = subprocess.run([sys.executable, "-c", code], env={**base, **env}, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.split()


def test_import_sets_no_xla_flags_and_no_matplotlib_backend():
    flags, backend, pyplot = _run(IMPORT_EVERYTHING, MPLBACKEND="pdf")
    assert flags == "<unset>"
    assert backend == "pdf"  # the user's backend, untouched; figures need none
    assert pyplot == "False"


def test_configure_xla_sets_the_commands_settings():
    code = "import os, so3jax; so3jax.configure_xla(every_core=True); print(os.environ['XLA_FLAGS'])"
    flags = " ".join(_run(code))
    assert "xla_cpu_small_while_loop_byte_threshold" in flags
    assert "--xla_force_host_platform_device_count=" in flags


def test_no_private_jax_api():
    offenders = [str(p) for p in PACKAGE.rglob("*.py") if "jax._src" in p.read_text()]
    assert not offenders
