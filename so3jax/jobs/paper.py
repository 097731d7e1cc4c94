"""``so3jax paper``: the paper's capture-and-detumble mission with both controllers
(docs/model.md §4), its Table II and Figs. 1-5."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from so3jax.sim.metrics import UNREACHED, cell

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


def register(subparsers) -> None:
    from so3jax.commands import add_memory_argument, add_precision_argument, registered

    p = subparsers.add_parser("paper", help="reproduce the paper's mission with both controllers (table + figures)",
                              description="The paper's capture-and-detumble mission (missions/paper.toml) flown by "
                              "the pd and adaptive controllers: Table II beside the paper's values, metrics.json "
                              "and the figures.",
                              epilog=registered())
    p.add_argument("--T", type=float, help="horizon [s] (default 4000)")
    p.add_argument("--dt", type=float, help="step [s] (default 0.01)")
    p.add_argument("--seed", type=int, help="disturbance seed (default 0)")
    p.add_argument("--tau-J", type=float, help="deployment time constant [s] (default 300)")
    p.add_argument("--log-derivative", choices=("exact", "paper"), help="adaptive law's d/dt log(R_e) (default exact)")
    p.add_argument("--record-every", type=int, help="history sampling [steps] (default 100)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override an entry of the paper's mission (missions/paper.toml), e.g. --set orbit.n=1e-3")
    p.add_argument("--out", type=Path, default=Path("results/paper"), help="output folder (default results/paper)")
    p.add_argument("--json", action="store_true", help="print one JSON object (last line of stdout)")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    add_memory_argument(p)
    add_precision_argument(p)
    p.set_defaults(func=run)


def overrides(args) -> list[str]:
    """The command-line options as overrides of the paper's mission (after --set's)."""
    items = list(args.set)
    for key, value in (("T", args.T), ("dt", args.dt), ("seed", args.seed), ("deployment.tau_J", args.tau_J),
                       ("record_every", args.record_every)):
        if value is not None:
            items.append(f"{key}={value!r}")
    if args.log_derivative is not None:
        items.append(f'controller.adaptive.log_derivative="{args.log_derivative}"')
    return items


def load_mission(args):
    """The paper's mission (:data:`so3jax.missions.mission.PAPER`, missions/paper.toml) with the
    command line's overrides; its controllers must be the paper's two."""
    from so3jax.missions import mission as missions

    m = missions.load(None, overrides(args), base=missions.PAPER)
    if m.controllers != CONTROLLERS:
        raise ValueError(f"controllers: so3jax paper compares {' and '.join(CONTROLLERS)} (Table II); "
                         "fly other controllers with so3jax fly missions/paper.toml")
    return m


def metrics_dict(result, steps_per_phase=None) -> dict:
    """The metrics of docs/model.md §6 of one rollout: every value NaN when it diverged; per-phase values
    None for the phases the horizon never reached (all reached when steps_per_phase is None)."""
    from so3jax.sim.metrics import phase_values, reported

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


def write_figures(out: Path, results: dict, scenario) -> list[Path]:
    from so3jax.viz import plots
    from so3jax.results.io import save_figures

    histories = {name: r.history for name, r in results.items()}
    h = histories["pd"]
    phases, T = scenario.phase_times, scenario.horizon
    t_capture = phases[-1] if phases else T
    figures = {
        "fig1_inertia.png": plots.inertia_figure(h.t, h.J, phases, T),
        "fig2_angular_velocity.png": plots.rate_figure(histories, phases, T),
        "fig3_tracking_error.png": plots.rate_error_figure(histories, phases, t_capture, T),
        "fig4_torque.png": plots.torque_figure(histories, phases, T),
        "fig5_torque_norm.png": plots.torque_norm_figure(histories, phases, T),
        "fig6_attitude_error.png": plots.attitude_error_figure(histories, phases, T),
    }
    return save_figures(out, figures)


def run(args) -> int:
    from so3jax.results import runfolder

    mission = load_mission(args)  # every check before the output folder exists
    with runfolder.claim(args.out, "paper", {"mission": mission.describe(), "precision": args.precision}):
        return _run(args, mission)


def _run(args, mission) -> int:
    import jax

    from so3jax.sim import memory
    from so3jax.jobs.fly import fly
    from so3jax.results.io import dumps, write_json

    scenario = mission.scenario(args.precision)
    needed = sum(memory.simulate_bytes(scenario, *mission.controller(name), mission.seed,
                                       record_every=mission.record_every) for name in CONTROLLERS)
    budget = memory.check(needed, memory.from_args(args), f"--T {mission.T:g} at --record-every {mission.record_every}",
                          "raise --record-every or shorten --T")
    results, wall = fly(mission, args.precision)
    report = {name: metrics_dict(r, scenario.steps_per_phase) for name, r in results.items()}
    report["config"] = {
        "T": mission.T,
        "dt": mission.dt,
        "n_steps": scenario.n_steps,
        "steps_per_phase": list(scenario.steps_per_phase),
        "seed": mission.seed,
        "precision": args.precision,
        "tau_J": mission.tau_J,
        "orbital_rate": mission.n,
        "log_derivative": mission.options["adaptive"]["log_derivative"],
        "gains": {name: mission.gains[name]._asdict() for name in CONTROLLERS},
        "mission": mission.describe(),
        "wall_time_s": wall,
        "devices": [str(d) for d in jax.devices("cpu")],  # where fly ran them
        "memory": budget,
    }
    write_json(args.out / "metrics.json", report)
    figures = [] if args.no_figures else write_figures(args.out, results, scenario)
    diverged = [name for name in CONTROLLERS if report[name]["diverged"]]
    if diverged:
        print(f"warning: diverged rollout(s): {', '.join(diverged)}", file=sys.stderr)
    if args.json:
        print(dumps(report))
    else:
        print(format_table(report))
        print(f"\n{scenario.n_steps} steps x 2 controllers in {wall:.1f} s (compile included); "
              f"results in {args.out}/ (metrics.json, {len(figures)} figures)")
    return 1 if diverged else 0
