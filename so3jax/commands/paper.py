"""``so3jax paper``: the subcommand's arguments, and the run they start (the job:
:mod:`so3jax.jobs.paper`)."""

from __future__ import annotations

import sys

from so3jax.commands.common import add_memory_argument, add_output_arguments, add_precision_argument, registered
from so3jax.jobs import paper
from so3jax.jobs.fly import fly, memory_needed
from so3jax.results import runfolder
from so3jax.results.io import dumps, write_json
from so3jax.sim import memory


def register(subparsers) -> None:
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
    add_output_arguments(p, "results/paper")
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


def run(args) -> int:
    mission = paper.load_mission(overrides(args))  # every check before the output folder exists
    with runfolder.claim(args.out, "paper", {"mission": mission.describe(), "precision": args.precision}):
        return _run(args, mission)


def _run(args, mission) -> int:
    scenario = mission.scenario(args.precision)
    budget = memory.check(memory_needed(mission, args.precision), memory.from_args(args),
                          f"--T {mission.T:g} at --record-every {mission.record_every}",
                          "raise --record-every or shorten --T")
    results, wall = fly(mission, args.precision)
    report = paper.report(mission, scenario, results, args.precision, wall, budget)
    write_json(args.out / "metrics.json", report)
    figures = [] if args.no_figures else paper.write_figures(args.out, results, scenario)
    diverged = [name for name in paper.CONTROLLERS if report[name]["diverged"]]
    if diverged:
        print(f"warning: diverged rollout(s): {', '.join(diverged)}", file=sys.stderr)
    if args.json:
        print(dumps(report))
    else:
        print(paper.format_table(report))
        print(f"\n{scenario.n_steps} steps x 2 controllers in {wall:.1f} s (compile included); "
              f"results in {args.out}/ (metrics.json, {len(figures)} figures)")
    return 1 if diverged else 0
