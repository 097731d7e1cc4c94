"""``so3jax margins``: the subcommand's arguments, and the run they start (the job:
:mod:`so3jax.jobs.margins`)."""

from __future__ import annotations

import sys
from pathlib import Path

from so3jax.commands.common import add_output_arguments, add_precision_argument, mission_overrides, registered
from so3jax.jobs import margins
from so3jax.missions import mission as missions
from so3jax.results import runfolder
from so3jax.results.io import dumps


def register(subparsers) -> None:
    p = subparsers.add_parser("margins", help="stability margins of a mission's sampled loop, broken at the actuator",
                              description="Each controller's sampled loop linearized over one control period by "
                              "automatic differentiation about its noise-free flight, broken at the actuator "
                              "input: per-axis gain, phase and delay margins (the other axes closed), disk "
                              "margins per axis and for all axes at once; margins.json, a table, and Bode and "
                              "Nichols figures. With [[appendages]] or [[slosh]], the structural modes at each time "
                              "(frequency, damping ratio), marked on the figures.",
                              epilog=registered())
    p.add_argument("mission", nargs="?", type=Path,
                   help="mission file (TOML) with a sampled loop; default: the flight mission (missions/flight.toml)")
    p.add_argument("--at", type=float, nargs="+", metavar="T",
                   help="times [s] to linearize at, each a whole number of control periods (repeatable: the "
                   "times accumulate; default: the last tick of each phase)")
    p.add_argument("--T", type=float, help="horizon [s] (default: the mission's)")
    p.add_argument("--controllers", help="comma-separated controllers (default: the mission's)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a mission entry, e.g. --set gains.pd.k_Omega=40.0 (repeatable)")
    add_output_arguments(p, "results/margins")
    add_precision_argument(p)
    p.set_defaults(func=run)


def run(args) -> int:
    mission = missions.load(args.mission, mission_overrides(args, ("T",)))
    times = margins.check_times(mission, args.at)
    with runfolder.claim(args.out, "margins", vars(args)):
        print(f"margins of {', '.join(mission.controllers)} at t = {', '.join(f'{t:g}' for t in times)} s ...",
              file=sys.stderr, flush=True)
        reports, linearizations, wall = margins.run(mission, times, args.precision)
        config = {**mission.describe(), "precision": args.precision, "wall_time_s": wall,
                  "mission_file": None if args.mission is None else str(args.mission)}
        figures = margins.write(args.out, reports, linearizations, config, not args.no_figures)
        unstable = [n for n, r in reports.items() if not r["stable"]]
        if unstable:
            print(f"warning: closed loop unstable: {', '.join(unstable)}", file=sys.stderr)
        if args.json:
            print(dumps({**reports, "config": config}))
        else:
            print(margins.format_table(reports))
            print(f"\n{len(times)} linearizations x {len(reports)} controllers in {wall:.1f} s (compile included); "
                  f"results in {args.out}/ (margins.json, {len(figures)} figures)")
        return 1 if unstable else 0
