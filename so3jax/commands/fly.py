"""``so3jax fly``: the subcommand's arguments, and the run they start (the job:
:mod:`so3jax.jobs.fly`)."""

from __future__ import annotations

import sys
from pathlib import Path

from so3jax.commands.common import (
    add_memory_argument,
    add_output_arguments,
    add_precision_argument,
    controllers_help,
    mission_overrides,
    registered,
)
from so3jax.jobs import fly
from so3jax.missions import mission as missions
from so3jax.results import runfolder, units
from so3jax.results.io import dumps, save_npz, write_json
from so3jax.sim import memory


def register(subparsers) -> None:
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
    add_output_arguments(p, "results/fly")
    add_memory_argument(p)
    add_precision_argument(p)
    p.set_defaults(func=run)


def run(args) -> int:
    mission = missions.load(args.mission, mission_overrides(args))
    with runfolder.claim(args.out, "fly", vars(args)):
        return _fly_into(args, mission)


def _fly_into(args, mission) -> int:
    budget = fly.check_memory(mission, args.precision, memory.from_args(args))
    print(f"flying {', '.join(mission.controllers)}: {mission.T:g} s at dt = {mission.dt:g} s"
          + (f", control period {mission.period:g} s" if mission.period else ", continuous control")
          + " ...", file=sys.stderr, flush=True)
    flight = fly.flight(mission, args.precision)
    reports = dict(flight.reports)
    reports["units"] = units.table(reports[mission.controllers[0]])
    reports["config"] = {**mission.describe(), "precision": args.precision, "wall_time_s": flight.wall_s,
                         "memory": budget, "mission_file": None if args.mission is None else str(args.mission)}
    write_json(args.out / "metrics.json", reports)
    save_npz(args.out / "trajectory.npz", **flight.trajectory)
    telemetry = fly.write_telemetry(args.out, mission, flight.results)
    figures = [] if args.no_figures else fly.write_figures(args.out, mission, flight.results)
    diverged, failed = flight.diverged, flight.failed
    if diverged:
        print(f"warning: diverged: {', '.join(diverged)}", file=sys.stderr)
    if failed:
        print(f"warning: requirements failed: {', '.join(failed)}", file=sys.stderr)
    if args.json:
        print(dumps(reports))
    else:
        print(flight.table())
        if mission.requirements:
            print("\n" + flight.requirements_table())
        print(f"\n{mission.scenario().n_steps} steps x {len(flight.results)} controllers in {flight.wall_s:.1f} s "
              f"(compile included); results in {args.out}/ (metrics.json, trajectory.npz{telemetry}, "
              f"{len(figures)} figures)")
    return 1 if diverged or failed else 0
