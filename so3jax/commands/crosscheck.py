"""``so3jax crosscheck``: the subcommand's arguments, and the run they start (the job:
:mod:`so3jax.jobs.crosscheck`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from so3jax.commands.common import add_output_arguments, mission_overrides
from so3jax.jobs import crosscheck
from so3jax.jobs.crosscheck import basilisk, representable, statistics
from so3jax.missions import mission as missions
from so3jax.results import runfolder
from so3jax.results.io import dumps, save_npz, write_json

SIMULATORS = ("basilisk",)


def register(subparsers) -> None:
    p = subparsers.add_parser("crosscheck", help="fly a mission in so3jax and in Basilisk and compare them",
                              description="A mission flown by so3jax's loop and by Basilisk's own modules "
                              "(spacecraft hub, reactionWheelStateEffector, rwMotorTorque, simpleNav, inertial3D or "
                              "hillPoint, attTrackingError, mrpFeedback; hingedRigidBodyStateEffector and "
                              "linearSpringMassDamper for [[appendages]] and [[slosh]]), compared at every recorded "
                              "control tick (with navigation errors: as distributions over runs): a table, "
                              "crosscheck.json, differences.npz (runs.npz) and crosscheck.png. Needs the basilisk "
                              f"extra: {basilisk.INSTALL}.")
    p.add_argument("simulator", choices=SIMULATORS, help="the simulator to compare with")
    p.add_argument("mission", type=Path, help="mission file (TOML), e.g. missions/crosscheck.toml")
    p.add_argument("--T", type=float, help="horizon [s] (default: the mission's)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a mission entry, e.g. --set gains.mrp_feedback.K_i=0 (repeatable)")
    p.add_argument("--runs", type=_runs, default=32,
                   help="runs of each side where the mission has navigation errors, compared as distributions "
                        "(default 32)")
    add_output_arguments(p, "results/crosscheck", "the PNG figure")
    p.set_defaults(func=run, precision="float64")  # a comparison at round-off: float64 only


def _runs(text: str) -> int:
    value = int(text) if text.strip().lstrip("+").isdigit() else 0
    if value < 2:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 2, got {text!r}")
    return value


def run(args) -> int:
    mission = missions.load(args.mission, mission_overrides(args, keys=("T",)))
    representable.check(mission)
    basilisk.require()
    with runfolder.claim(args.out, "crosscheck", vars(args)):
        return _crosscheck_into(args, mission)


def _crosscheck_into(args, mission) -> int:
    noisy = representable.navigation_errors(mission)
    runs = f", {args.runs} runs each" if noisy else ""
    print(f"flying {', '.join(mission.controllers)} in so3jax and in Basilisk: {mission.T:g} s at dt = "
          f"{mission.dt:g} s, control period {mission.period:g} s{runs} ...", file=sys.stderr, flush=True)
    config = {**mission.describe(), "precision": args.precision, "mission_file": str(args.mission),
              "simulator": args.simulator}
    if noisy:  # each side's runs compared as distributions (so3jax.jobs.crosscheck.statistics)
        reports, runs = statistics.crosscheck(mission, args.runs, args.precision)
        out = {**reports, "units": statistics.UNITS, "config": {**config, "runs": args.runs}}
        arrays = ("runs.npz", {f"{name}/{side}/{q}": np.array([r[q] for r in getattr(flown, side)])
                               for name, flown in runs.items() for side in ("so3jax", "basilisk")
                               for q, _ in statistics.QUANTITIES})
        table, draw = statistics.format_table(reports), lambda: statistics.write_figures(args.out, mission, runs)
    else:  # tick by tick
        reports, differences, _ = crosscheck.crosscheck(mission, args.precision)
        out = {**reports, "units": crosscheck.UNITS, "config": config}
        arrays = ("differences.npz", {f"{name}/{field}": value for name, d in differences.items()
                                      for field, value in d._asdict().items() if value is not None})
        table, draw = crosscheck.format_table(reports), lambda: crosscheck.write_figures(args.out, mission, differences)
    write_json(args.out / "crosscheck.json", out)
    save_npz(args.out / arrays[0], **arrays[1])
    figures = [] if args.no_figures else draw()
    if args.json:
        print(dumps(out))
    else:
        print(table)
        print(f"\nresults in {args.out}/ (crosscheck.json, {arrays[0]}, {len(figures)} figure)")
    return 0
