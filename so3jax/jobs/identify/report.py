"""The report of an identification: identification.json's data, the J_hat block of a
mission file, the text table, and residuals.png (:mod:`so3jax.viz.identify`)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from so3jax.controllers import registry
from so3jax.jobs.identify import inertia
from so3jax.results import io
from so3jax.results.io import to_builtin
from so3jax.viz import identify as plots


def summary(fit) -> dict:
    """The estimate as JSON-ready data: J and its entries' covariance, principal moments and
    axes with 1 sigma, the bias and disturbance with theirs, the residuals' RMS."""
    lam, V, lam_std, axis_std = inertia.principal(fit["J"], fit["theta_cov"])
    out = {"J": fit["J"], "J_entries": list(inertia.ENTRIES), "J_entries_std": np.sqrt(np.diag(fit["theta_cov"])),
           "J_entries_covariance": fit["theta_cov"],
           "principal_moments": lam, "principal_moments_std": lam_std,
           "principal_axes": V, "principal_axes_std_deg": np.degrees(axis_std),
           "bias": fit["bias"], "bias_std": None if fit["bias"] is None else np.sqrt(np.diag(fit["bias_cov"])),
           "disturbance": fit["disturbance"],
           "disturbance_std": (None if fit["disturbance"] is None
                               else np.sqrt(np.diag(fit["disturbance_cov"])).reshape(-1, 3)),
           "residual_rms": fit["residual_rms"], "iterations": fit["iterations"], "converged": fit["converged"]}
    for key in ("intervals", "windows", "sigma_gyro", "sigma_star", "sigma_momentum_jump", "warning"):
        if key in fit:
            out[key] = fit[key]
    return to_builtin(out)


def j_hat_toml(J, report) -> str:
    """A [controller.NAME] J_hat block per law that takes a nominal inertia, ready to paste
    into a mission file."""
    rows = ", ".join("[" + ", ".join(f"{x:.10g}" for x in row) + "]" for row in np.asarray(J))
    lines = [f"# J_hat identified by so3jax identify ({report['config']['method']}) "
             f"from {report['config']['telemetry']}",
             f"# principal moments {', '.join(f'{m:.6g}' for m in report['principal_moments'])} kg m^2, "
             f"1 sigma {', '.join(f'{s:.2g}' for s in report['principal_moments_std'])}"]
    for name in registry.names():
        if any(p.name == "J_hat" for p in registry.get(name).options):
            lines += [f"[controller.{name}]", f"J_hat = [{rows}]"]
    return "\n".join(lines) + "\n"


def format_report(r) -> str:
    J, std = np.asarray(r["J"]), r["J_entries_std"]
    lines = ["J [kg m^2] (1 sigma of each entry):"]
    lines += ["  " + "  ".join(f"{x:12.4f}" for x in row) for row in J]
    lines.append("  sigma  " + ", ".join(f"{n} {s:.3g}" for n, s in zip(r["J_entries"], std)))
    lines.append("principal moments [kg m^2]: " + ", ".join(
        f"{m:.4f} +- {s:.3g}" for m, s in zip(r["principal_moments"], r["principal_moments_std"])))
    axes = np.asarray(r["principal_axes"])
    for i in range(3):
        lines.append(f"  axis {i + 1}: [{', '.join(f'{x:+.5f}' for x in axes[:, i])}] "
                     f"+- {r['principal_axes_std_deg'][i]:.3g} deg")
    if r["bias"] is not None:
        lines.append("gyro bias [deg/h]: " + ", ".join(
            f"{math.degrees(b) * 3600:.4f} +- {math.degrees(s) * 3600:.2g}" for b, s in zip(r["bias"], r["bias_std"])))
    if r["disturbance"] is not None:
        for p, (d, s) in enumerate(zip(r["disturbance"], r["disturbance_std"])):
            lines.append(f"disturbance s^{p} [N m]: " + ", ".join(f"{x:+.4g} +- {e:.2g}" for x, e in zip(d, s)))
    lines.append(f"converged: {r['converged']} ({r['iterations']} iterations)")
    return "\n".join(lines)


def write_figures(out: Path, fit) -> list:
    """residuals.png (:func:`so3jax.viz.identify.residuals_figure`) into ``out``."""
    return io.save_figures(out, {"residuals.png": plots.residuals_figure(fit)})
