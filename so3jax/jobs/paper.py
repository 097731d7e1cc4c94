"""The paper's capture-and-detumble mission with both controllers (docs/model.md §4), its
Table II and Figs. 1-5: the job ``so3jax paper`` (:mod:`so3jax.commands.paper`) runs."""

from __future__ import annotations

from pathlib import Path

import jax
import numpy as np

from so3jax.missions import mission as missions
from so3jax.results import io, units
from so3jax.sim.metrics import UNREACHED, cell, phase_values, reported

# Table II of the paper (effort in N^2 m^2 s; see docs/model.md §7.5).
PAPER_TABLE = {"pd": {"rmse": 4.024e-3, "effort": 155.61}, "adaptive": {"rmse": 2.776e-3, "effort": 143.10}}
CONTROLLERS = ("pd", "adaptive")  # the paper's experiment (registry names)
METRIC_NAMES = (
    "rmse",
    "rmse_unrotated",
    "effort",
    "rmse_phase",
    "effort_phase",
    "rms_angle_phase",
    "max_angle_phase",
    "max_torque",
    "orthogonality_error",
    "diverged",
)


def load_mission(overrides=()):
    """The paper's mission (:data:`so3jax.missions.mission.PAPER`, missions/paper.toml) with
    ``overrides`` (KEY=VALUE texts); its controllers must be the paper's two."""
    m = missions.load(None, list(overrides), base=missions.PAPER)
    if m.controllers != CONTROLLERS:
        raise ValueError(f"controllers: so3jax paper compares {' and '.join(CONTROLLERS)} (Table II); "
                         "fly other controllers with so3jax fly missions/paper.toml")
    return m


def metrics_dict(result, steps_per_phase=None) -> dict:
    """The metrics of docs/model.md §6 of one rollout: every value NaN when it diverged; per-phase values
    None for the phases the horizon never reached (all reached when steps_per_phase is None)."""
    m = result.metrics._asdict()
    diverged = bool(m["diverged"])
    out = {}
    for k in METRIC_NAMES:
        if k == "diverged":
            out[k] = diverged
        elif k.endswith("_phase") and steps_per_phase is not None:
            out[k] = phase_values(reported(m[k], diverged), steps_per_phase)
        else:
            out[k] = reported(m[k], diverged).tolist()
    return out


def _relative(ours, theirs) -> str:
    """ours against theirs in percent; "—" when either is not a finite number (diverged)."""
    if ours is None or theirs is None or not (np.isfinite(ours) and np.isfinite(theirs)):
        return UNREACHED
    return f"{100.0 * (ours - theirs) / theirs:+.1f} %"


def format_table(metrics: dict) -> str:
    """Our Table II beside the paper's; relative differences computed (docs/model.md §7.5). A
    diverged controller's cells read "diverged" and it enters no comparison; a phase
    never reached reads "—"."""
    pd, ad = metrics["pd"], metrics["adaptive"]
    rows = [f"{'':28s}{'PD':>12s}{'paper PD':>12s}{'adaptive':>12s}{'paper ad.':>12s}"]

    def row(label, key, fmt, paper=True):
        cells = [cell(pd[key], fmt), format(PAPER_TABLE["pd"][key], fmt) if paper else "",
                 cell(ad[key], fmt), format(PAPER_TABLE["adaptive"][key], fmt) if paper else ""]
        rows.append(f"{label:28s}" + "".join(f"{c:>12s}" for c in cells))

    def ours(label, a, b, fmt):
        rows.append(f"{label:28s}{cell(a, fmt):>12s}{'':>12s}{cell(b, fmt):>12s}")

    row("RMSE [rad/s]", "rmse", ".4e")
    row("Effort [N^2 m^2 s]", "effort", ".2f")
    for p in range(len(pd["rmse_phase"])):
        ours(f"  RMSE phase {p + 1} [rad/s]", pd["rmse_phase"][p], ad["rmse_phase"][p], ".4e")
    for p in range(len(pd["effort_phase"])):
        ours(f"  effort phase {p + 1}", pd["effort_phase"][p], ad["effort_phase"][p], ".2f")
    ours("RMSE unrotated [rad/s]", pd["rmse_unrotated"], ad["rmse_unrotated"], ".4e")
    ours("max |tau| [N m]", pd["max_torque"], ad["max_torque"], ".4f")
    ours("|R^T R - I| at end", pd["orthogonality_error"], ad["orthogonality_error"], ".1e")
    rows.append(f"{'diverged':28s}{pd['diverged']!s:>12s}{'':>12s}{ad['diverged']!s:>12s}")
    rows.append("")
    rows.append("adaptive vs PD            ours        paper")
    for key, label in (("rmse", "RMSE"), ("effort", "Effort")):
        theirs = _relative(PAPER_TABLE["adaptive"][key], PAPER_TABLE["pd"][key])
        rows.append(f"  {label:20s}{_relative(ad[key], pd[key]):>12s}{theirs:>12s}")
    rows.append("ours vs paper             PD          adaptive")
    for key, label in (("rmse", "RMSE"), ("effort", "Effort")):
        rows.append(f"  {label:20s}{_relative(pd[key], PAPER_TABLE['pd'][key]):>12s}"
                    f"{_relative(ad[key], PAPER_TABLE['adaptive'][key]):>12s}")
    return "\n".join(rows)


def report(mission, scenario, results: dict, precision: str, wall: float, budget) -> dict:
    """metrics.json: each controller's metrics (:func:`metrics_dict`), their units and the run's
    configuration."""
    out = {name: metrics_dict(r, scenario.steps_per_phase) for name, r in results.items()}
    out["units"] = units.table(out[CONTROLLERS[0]])
    out["config"] = {
        "T": mission.T,
        "dt": mission.dt,
        "n_steps": scenario.n_steps,
        "steps_per_phase": list(scenario.steps_per_phase),
        "seed": mission.seed,
        "precision": precision,
        "tau_J": mission.tau_J,
        "orbital_rate": mission.n,
        "log_derivative": mission.options["adaptive"]["log_derivative"],
        "gains": {name: mission.gains[name]._asdict() for name in CONTROLLERS},
        "mission": mission.describe(),
        "wall_time_s": wall,
        "devices": [str(d) for d in jax.devices("cpu")],  # where fly ran them
        "memory": budget,
    }
    return out


def write_figures(out: Path, results: dict, scenario) -> list[Path]:
    """Figs. 1-5 and the attitude error (:func:`so3jax.viz.paper.figures`) into ``out``."""
    from so3jax.viz import paper as plots  # here: matplotlib only when drawing

    return io.save_figures(out, plots.figures({name: r.history for name, r in results.items()}, scenario))
