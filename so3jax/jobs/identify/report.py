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


def _std(covariance) -> np.ndarray:
    """The 1 sigma of each variable of a covariance (a variance below zero by round-off: 0)."""
    return np.sqrt(np.maximum(np.diag(covariance), 0.0))


# identification.json's units (so3jax.results.units); a standard deviation has its value's unit.
UNITS = {"J": "kg m^2", "J_entries_std": "kg m^2", "J_entries_covariance": "kg^2 m^4", "principal_moments": "kg m^2",
         "principal_moments_std": "kg m^2", "principal_axes": "-", "principal_axes_std_deg": "deg", "bias": "rad/s",
         "bias_std": "rad/s", "disturbance": "N m / s^k (row k: the coefficient of t^k)",
         "disturbance_std": "N m / s^k", "sigma_gyro": "rad/s",
         "sigma_star": "rad", "sigma_momentum_jump": "N m s",
         "constancy": "- (split_s: s)"}


def summary(fit) -> dict:
    """The estimate as JSON-ready data: J and its entries' covariance, principal moments and
    axes with 1 sigma, the bias and disturbance with theirs, the residuals' RMS, and the
    test of a constant inertia."""
    lam, V, lam_std, axis_std = inertia.principal(fit["J"], fit["theta_cov"])
    out = {"J": fit["J"], "J_entries": list(inertia.ENTRIES), "J_entries_std": _std(fit["theta_cov"]),
           "J_entries_covariance": fit["theta_cov"],
           "principal_moments": lam, "principal_moments_std": lam_std,
           "principal_axes": V, "principal_axes_std_deg": np.degrees(axis_std),
           "bias": fit["bias"], "bias_std": None if fit["bias"] is None else _std(fit["bias_cov"]),
           "disturbance": fit["disturbance"],
           "disturbance_std": None if fit["disturbance"] is None else _std(fit["disturbance_cov"]).reshape(-1, 3),
           "residual_rms": fit["residual_rms"], "iterations": fit["iterations"], "converged": fit["converged"]}
    for key in ("intervals", "windows", "sigma_gyro", "sigma_star", "sigma_momentum_jump", "constancy", "warning"):
        if key in fit:
            out[key] = fit[key]
    # residual_rms: the momentum equation's [N m s] (regression), or the measurements' residuals
    # in their noise's standard deviations (simulation, which fits over windows)
    out["units"] = {**UNITS, "residual_rms": "-" if "windows" in fit else "N m s"}
    return to_builtin(out)


def j_hat_toml(J, report) -> str:
    """A [controller.NAME] J_hat block per law that takes a nominal inertia, ready to paste
    into a mission file."""
    rows = ", ".join("[" + ", ".join(f"{x:.10g}" for x in row) + "]" for row in np.asarray(J))
    lines = [f"# J_hat identified by so3jax identify ({report['config']['method']}) "
             f"from {report['config']['telemetry']}",
             f"# principal moments {', '.join(_number(m, '.6g') for m in report['principal_moments'])} kg m^2, "
             f"1 sigma {', '.join(_number(s, '.2g') for s in report['principal_moments_std'])}"]
    if "warning" in report:
        lines.append(f"# warning: {report['warning']}")
    for name in registry.names():
        if any(p.name == "J_hat" for p in registry.get(name).options):
            lines += [f"[controller.{name}]", f"J_hat = [{rows}]"]
    return "\n".join(lines) + "\n"


def _number(x, spec: str) -> str:
    """x formatted by ``spec``; None (JSON's null: a value that is not finite) as "n/a"."""
    return "n/a" if x is None else format(x, spec)


def format_report(r) -> str:
    """The text table of a report (:func:`summary`: its values that are not finite are None)."""
    lines = ["J [kg m^2] (1 sigma of each entry):"]
    lines += ["  " + "  ".join(_number(x, "12.4f") for x in row) for row in r["J"]]
    lines.append("  sigma  " + ", ".join(
        f"{n} {_number(s, '.3g')}" for n, s in zip(r["J_entries"], r["J_entries_std"])))
    lines.append("principal moments [kg m^2]: " + ", ".join(
        f"{_number(m, '.4f')} +- {_number(s, '.3g')}"
        for m, s in zip(r["principal_moments"], r["principal_moments_std"])))
    for i in range(3):
        axis = [row[i] for row in r["principal_axes"]]
        lines.append(f"  axis {i + 1}: [{', '.join(_number(x, '+.5f') for x in axis)}] "
                     f"+- {_number(r['principal_axes_std_deg'][i], '.3g')} deg")
    deg_h = lambda x: None if x is None else math.degrees(x) * 3600  # rad/s -> deg/h
    if r["bias"] is not None:
        lines.append("gyro bias [deg/h]: " + ", ".join(
            f"{_number(deg_h(b), '.4f')} +- {_number(deg_h(s), '.2g')}" for b, s in zip(r["bias"], r["bias_std"])))
    if r["disturbance"] is not None:
        for p, (d, s) in enumerate(zip(r["disturbance"], r["disturbance_std"])):
            lines.append(f"disturbance s^{p} [N m]: " + ", ".join(
                f"{_number(x, '+.4g')} +- {_number(e, '.2g')}" for x, e in zip(d, s)))
    test = r.get("constancy")
    if test is not None and not test["tested"]:
        lines.append(f"constant inertia (J on the record's two halves): not tested: {test['reason']}")
    elif test is not None:
        verdict = "REJECTED" if test["rejected"] else "not rejected"
        lines.append(f"constant inertia (J on the record's two halves): score statistic {test['statistic']:.4g}, "
                     f"{test['dof']} dof, p = {test['p_value']:.3g}: {verdict} at {test['significance']:g}")
    lines.append(f"converged: {r['converged']} ({r['iterations']} iterations)")
    return "\n".join(lines)


def write_figures(out: Path, fit) -> list:
    """residuals.png (:func:`so3jax.viz.identify.residuals_figure`) into ``out``."""
    return io.save_figures(out, {"residuals.png": plots.residuals_figure(fit)})
