"""``so3jax fly``: a mission flown by the closed loop of docs/model.md §8 (sensors, estimator,
sampled-data control, actuators), each controller on the same mission and seed."""

from __future__ import annotations

import functools
import json
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from so3jax.components import registry as components
from so3jax.sim.metrics import cell

PHASE_LABELS = ("capture", "deployment", "detumble")
METRICS = ("rmse", "rmse_unrotated", "effort", "rmse_phase", "effort_phase", "rms_angle_phase", "max_angle_phase",
           "max_torque", "orthogonality_error")
FLIGHT_METRICS = ("attitude_estimation_rms", "attitude_estimation_max", "bias_estimation_rms", "bias_estimation_max",
                  "command_effort", "actuator_effort", "time_at_torque_limit", "time_at_speed_limit",
                  "max_wheel_speed_ratio")
TRAJECTORY = ("t", "R", "Omega", "R_hat", "Omega_hat", "bias", "bias_hat", "tau_cmd", "tau_applied", "wheel_speed")


def register(subparsers) -> None:
    from so3jax.commands import add_memory_argument, add_precision_argument, controllers_help, registered

    p = subparsers.add_parser("fly", help="fly a mission through sensors, estimator, sampled control and wheels",
                              description="A mission flown by each of its controllers through the mission's loop "
                              "(sensors, estimator, sampled control, actuator): a table per controller, "
                              "metrics.json, trajectory.npz, telemetry/ and the figures.",
                              epilog=registered())
    p.add_argument("mission", nargs="?", type=Path,
                   help="mission file (TOML); default: the flight mission (missions/flight.toml)")
    p.add_argument("--T", type=float, help="horizon [s] (default: the mission's)")
    p.add_argument("--seed", type=int, help="disturbance and sensor-noise seed (default: the mission's)")
    p.add_argument("--controllers", help=controllers_help("the mission's"))
    p.add_argument("--record-every", type=int, help="trajectory sampling [steps] (default: the mission's)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a mission entry, e.g. --set control.period=0.05 (repeatable)")
    p.add_argument("--out", type=Path, default=Path("results/fly"), help="output folder (default results/fly)")
    p.add_argument("--json", action="store_true", help="print one JSON object (last line of stdout)")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    add_memory_argument(p)
    add_precision_argument(p)
    p.set_defaults(func=run)


def overrides(args) -> list[str]:
    """The command-line options as mission overrides (after --set's)."""
    items = list(args.set)
    for key, value in (("T", args.T), ("seed", args.seed), ("record_every", args.record_every)):
        if value is not None:
            items.append(f"{key}={value!r}")
    if args.controllers is not None:
        items.append("controllers=" + json.dumps([c.strip() for c in args.controllers.split(",") if c.strip()]))
    return items


def fly(mission, dtype: str = "float64") -> tuple[dict, float]:
    """Every controller of the mission, side by side on the CPU devices
    (:func:`so3jax.parallel.devices.side_by_side`: compilations in parallel). Returns {name:
    Result with NumPy leaves} and the wall time [s], compile included."""
    import jax

    import so3jax as sj
    from so3jax.parallel import devices

    scenario, loop = mission.scenario(dtype), mission.loop(dtype)

    def simulate(name):
        controller, gains = mission.controller(name)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", sj.InertiaWarning)  # reported once, when the mission was read
            result = sj.simulate(scenario, controller, gains, mission.seed, loop=loop,
                                 record_every=mission.record_every)
            return jax.tree.map(np.asarray, result)

    start = time.perf_counter()
    results = devices.side_by_side({name: functools.partial(simulate, name) for name in mission.controllers})
    return results, time.perf_counter() - start


def report(mission, result) -> dict:
    """The metrics of docs/model.md §6 (phases the horizon never reached omitted) and the flight metrics, as
    JSON-ready data: every metric of a diverged run None (null), the run flagged diverged."""
    from so3jax.results.io import to_builtin
    from so3jax.sim.metrics import reached_phases, reported

    m = result.metrics._asdict()
    diverged = bool(m["diverged"])
    reached = sum(reached_phases(mission.scenario().steps_per_phase))
    out = {k: to_builtin(reported(m[k], diverged)[..., :reached] if k.endswith("_phase") else reported(m[k], diverged))
           for k in METRICS}
    out["diverged"] = diverged
    if mission.period_steps is not None:
        f = result.flight._asdict()
        out.update({k: to_builtin(reported(f[k], diverged)) for k in FLIGHT_METRICS})
    return out


def _cell(x, fmt):
    """None here is a diverged run's metric (phases never reached are left out)."""
    return "diverged" if x is None else cell(x, fmt)


def format_table(mission, reports: dict) -> str:
    """One column per controller."""
    names = list(reports)
    width = max(14, *(len(n) + 2 for n in names))
    lines = [f"{'':34s}" + "".join(f"{n:>{width}s}" for n in names)]

    def row(label, fn, fmt):
        lines.append(f"{label:34s}" + "".join(f"{_cell(fn(reports[n]), fmt):>{width}s}" for n in names))

    row("RMSE [rad/s]", lambda r: r["rmse"], ".4e")
    row("effort (delivered) [N^2 m^2 s]", lambda r: r["effort"], ".2f")
    for p in range(len(reports[names[0]]["rmse_phase"])):
        label = PHASE_LABELS[p] if p < len(PHASE_LABELS) else f"phase {p + 1}"
        row(f"  RMSE {label} [rad/s]", lambda r, p=p: r["rmse_phase"][p], ".4e")
        row(f"  max attitude error {label} [deg]", lambda r, p=p: None if r["max_angle_phase"][p] is None
            else math.degrees(r["max_angle_phase"][p]), ".3f")
    row("max |tau| delivered [N m]", lambda r: r["max_torque"], ".4f")
    if mission.period_steps is not None:
        row("command effort [N^2 m^2 s]", lambda r: r["command_effort"], ".2f")
        label = components.get("actuator", mission.actuator["kind"]).effort_label
        row(f"{label} [N^2 m^2 s]", lambda r: r["actuator_effort"], ".2f")
        row("attitude estimation RMS [arcsec]", lambda r: _arcsec(r["attitude_estimation_rms"]), ".2f")
        row("attitude estimation max [arcsec]", lambda r: _arcsec(r["attitude_estimation_max"]), ".2f")
        row("bias estimation RMS [deg/h]", lambda r: _deg_h(r["bias_estimation_rms"]), ".4f")
        row("bias estimation max [deg/h]", lambda r: _deg_h(r["bias_estimation_max"]), ".4f")
        row("max wheel speed / limit", lambda r: r["max_wheel_speed_ratio"], ".3f")
        row("time at a torque limit [s]", lambda r: r["time_at_torque_limit"], ".1f")
        row("time at a speed limit [s]", lambda r: r["time_at_speed_limit"], ".1f")
    lines.append(f"{'diverged':34s}" + "".join(f"{str(reports[n]['diverged']):>{width}s}" for n in names))
    return "\n".join(lines)


def _arcsec(x):
    return None if x is None else math.degrees(x) * 3600.0


def _deg_h(x):
    return None if x is None else math.degrees(x) * 3600.0


def recorded(x, otherwise):
    """A History field, or ``otherwise`` where the wiring does not record it (``()``)."""
    return otherwise if isinstance(x, tuple) and x == () else x


def trajectory_arrays(results: dict) -> dict:
    """{controller/quantity: array} of the recorded histories (t shared). A wiring without
    an estimate (continuous: the law reads the true state) stores the truth as R_hat,
    Omega_hat and zero biases, and a zero covariance without a filter; wheel_speed is
    (M, 0) without wheels."""
    arrays = {}
    for name, r in results.items():
        h = r.history
        values = {"t": h.t, "R": h.R, "Omega": h.Omega, "R_hat": recorded(h.R_hat, h.R),
                  "Omega_hat": recorded(h.Omega_hat, h.Omega), "bias": recorded(h.bias, np.zeros_like(h.Omega)),
                  "bias_hat": recorded(h.bias_hat, np.zeros_like(h.Omega)), "tau_cmd": h.tau_cmd, "tau_applied": h.tau,
                  "wheel_speed": h.actuator if np.ndim(h.actuator) == 2 else np.zeros((len(h.t), 0)),
                  "disturbance": h.disturbance, "covariance": recorded(h.covariance, np.zeros((len(h.t), 6, 6)))}
        arrays.update({f"{name}/{k}": np.asarray(v) for k, v in values.items()})
    return arrays


def write_telemetry(out: Path, mission, results: dict) -> str:
    """OUT/telemetry/NAME.npz per controller (:mod:`so3jax.jobs.identify.telemetry`'s format),
    where the loop has a gyro and a star tracker; what the summary line lists."""
    from so3jax.jobs.identify import telemetry
    from so3jax.results.io import save_npz

    if not telemetry.recorded(mission):
        return ""
    for name, r in results.items():
        save_npz(out / "telemetry" / f"{name}.npz", **telemetry.from_run(mission, r.history, mission.seed))
    return ", telemetry/"


def write_figures(out: Path, mission, results: dict) -> list[Path]:
    from so3jax.viz import flight as flight_plots, plots
    from so3jax.results.io import save_figures

    phases = mission.scenario().phase_times
    histories = {name: r.history for name, r in results.items()}
    if mission.period_steps is None:
        figures = {"attitude_error.png": plots.attitude_error_figure(histories, phases, mission.T),
                   "torque.png": plots.torque_figure(histories, phases, mission.T)}
    else:
        figures = {
            "attitude.png": flight_plots.attitude_figure(histories, phases, mission.T),
            "bias.png": flight_plots.bias_figure(histories, phases, mission.T),
            "torque.png": flight_plots.torque_figure(histories, phases, mission.T),
        }
        kind = mission.actuator["kind"]
        figures.update(flight_plots.actuator_figures(kind, histories, phases, mission.T, mission.actuator[kind]))
    return save_figures(out, figures)


def run(args) -> int:
    from so3jax.missions import mission as missions
    from so3jax.results import runfolder

    mission = missions.load(args.mission, overrides(args))
    with runfolder.claim(args.out, "fly", vars(args)):
        return _fly_into(args, mission)


def _fly_into(args, mission) -> int:
    from so3jax.sim import memory
    from so3jax.results.io import dumps, save_npz, write_json

    scenario, loop = mission.scenario(args.precision), mission.loop(args.precision)
    needed = sum(memory.simulate_bytes(scenario, *mission.controller(name), mission.seed, loop, mission.record_every)
                 for name in mission.controllers)
    budget = memory.check(needed, memory.from_args(args), f"T = {mission.T:g} s at record_every = {mission.record_every}",
                          "raise --record-every or shorten --T")
    print(f"flying {', '.join(mission.controllers)}: {mission.T:g} s at dt = {mission.dt:g} s"
          + (f", control period {mission.period:g} s" if mission.period else ", continuous control")
          + " ...", file=sys.stderr, flush=True)
    results, wall = fly(mission, args.precision)
    reports = {name: report(mission, r) for name, r in results.items()}
    reports["config"] = {**mission.describe(), "precision": args.precision, "wall_time_s": wall, "memory": budget,
                         "mission_file": None if args.mission is None else str(args.mission)}
    write_json(args.out / "metrics.json", reports)
    save_npz(args.out / "trajectory.npz", **trajectory_arrays(results))
    telemetry = write_telemetry(args.out, mission, results)
    figures = [] if args.no_figures else write_figures(args.out, mission, results)
    diverged = [n for n in mission.controllers if reports[n]["diverged"]]
    if diverged:
        print(f"warning: diverged: {', '.join(diverged)}", file=sys.stderr)
    if args.json:
        print(dumps(reports))
    else:
        print(format_table(mission, {n: reports[n] for n in mission.controllers}))
        print(f"\n{mission.scenario().n_steps} steps x {len(results)} controllers in {wall:.1f} s (compile included); "
              f"results in {args.out}/ (metrics.json, trajectory.npz{telemetry}, {len(figures)} figures)")
    return 1 if diverged else 0
