"""``so3jax tune``: the subcommand's arguments, and the campaign they run (the job:
:mod:`so3jax.jobs.tune`)."""

from __future__ import annotations

import sys
from pathlib import Path

from so3jax.commands.common import add_precision_argument, output_folder, registered
from so3jax.jobs import api
from so3jax.jobs.tune import design_report
from so3jax.jobs.tune.optimizers import NonFiniteGradientError
from so3jax.jobs.tune.validation import markdown_table
from so3jax.parallel import distributed

DEFAULT_OUT = Path("results/tune")  # the shipped campaigns' folders are written only when named with --out


def run(args) -> int:
    distributed.initialize(args)  # before anything touches JAX's backend
    out = Path(args.out) if args.out else DEFAULT_OUT / Path(args.config).stem
    try:
        report = api.tune(args.config, out, overrides=args.set, iterations=args.iterations, T=args.T,
                          resume=args.resume)
    except NonFiniteGradientError as err:
        print(f"so3jax tune: {err}", file=sys.stderr)
        return 1
    if "verdict" in report:  # a design campaign: its report, and the held-out verdict
        print(design_report.markdown(report))
        print(f"results in {out}/")
        return 0 if report["verdict"] == "met" else 1
    if distributed.writer():
        print(markdown_table([report]))
        print(f"results in {out}/")
    return 0


def register(subparsers) -> None:
    parser = subparsers.add_parser("tune", help="tune controller gains by gradient descent through the simulator",
                                   description="A tuning campaign: one controller's gains (and optionally the "
                                   "estimator's noise levels) tuned through the mission's rollouts, checkpointed "
                                   "every iteration, validated on held-out scenarios.",
                                   epilog=registered(tunable=True))
    parser.add_argument("config", help="campaign file (TOML): a mission and its [tune] table (every key has a "
                        "default: a mission file alone tunes its first controller), "
                        "e.g. tuning/adaptive_equal_effort.toml")
    parser.add_argument("--iterations", type=int, help="number of iterations (overrides tune.iterations)")
    parser.add_argument("--T", type=float, help="horizon [s] (overrides the mission's T)")
    parser.add_argument("--out", type=output_folder, help=f"run folder (default {DEFAULT_OUT}/NAME for NAME.toml)")
    parser.add_argument("--resume", action="store_true", help="continue the run saved in the run folder")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override an entry with a TOML value: a mission key (T=100.0, gains.pd.k_R=1.0) "
        "or a tune key (tune.optimizer.learning_rate=0.1)",
    )
    distributed.add_arguments(parser)
    add_precision_argument(parser)
    parser.set_defaults(func=run)
