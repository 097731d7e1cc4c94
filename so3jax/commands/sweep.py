"""``so3jax sweep``: the subcommand's arguments, and the run they start (the job:
:mod:`so3jax.jobs.sweep`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from so3jax.commands.common import (
    add_memory_argument,
    add_precision_argument,
    controllers_help,
    output_folder,
    registered,
)
from so3jax.jobs import api
from so3jax.jobs.sweep import pointing
from so3jax.jobs.sweep.engine import LAYOUTS
from so3jax.jobs.sweep.summary import format_summary
from so3jax.parallel import distributed
from so3jax.sim import memory


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "sweep",
        help="Monte Carlo robustness sweep of a mission (sharded over all devices)",
        description="Monte Carlo robustness sweep: a mission dispersed on its own leaves x its controllers, "
                    "paired by sample.",
        epilog=registered(),
    )
    p.add_argument("config", nargs="?", type=Path,
                   help="sweep file: a mission, [sweep] and [dispersions] "
                        "(default: the built-in one, = sweeps/default.toml)")
    p.add_argument("--samples", type=int, help="number of samples")
    p.add_argument("--T", type=float, help="horizon [s] (the mission's T)")
    p.add_argument("--controllers", help=controllers_help("the mission's"))
    p.add_argument("--chunk", type=int,
                   help="samples per batch on the host (at least 8 per device, a multiple of the device count; "
                        "an accelerator runs the largest batch its memory holds)")
    p.add_argument("--seed", type=int, help="sampling seed")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override an entry with a TOML value: a mission key (T=100.0), sweep.KEY or dispersions.LEAF, "
        "e.g. --set 'dispersions.deployment.tau_J={dist=\"normal\", mean=300, std=30}'",
    )
    p.add_argument("--out", type=output_folder, default=Path("results/sweep"),
                   help="output folder (default results/sweep)")
    p.add_argument("--resume", action="store_true", help="finish the sweep in --out, keeping its finished chunks")
    group = distributed.add_arguments(p)
    group.add_argument("--layout", choices=LAYOUTS, default="chunks",
                       help="how processes share the sweep: whole chunks per process (default), "
                            "or each chunk over every process's devices")
    add_memory_argument(p)
    add_precision_argument(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    distributed.initialize(args)
    summary = api.sweep(args.config, args.out, overrides=args.set, samples=args.samples, T=args.T,
                        controllers=args.controllers, chunk=args.chunk, seed=args.seed, resume=args.resume,
                        max_memory=memory.from_args(args), layout=args.layout)
    if distributed.writer():
        print(format_summary(summary))
        run = summary["run"]
        if run["computed_samples"]:
            print(
                f"{run['computed_samples']} rollouts in {run['wall_s']:.1f} s on {run['devices']} device(s): "
                f"{run['samples_per_s']:.3g} samples/s, {run['trajectory_steps_per_s'] / 1e6:.3g} M trajectory-steps/s "
                f"(compile included); results in {args.out}/",
                file=sys.stderr,
            )
    failed = pointing.failed(summary)
    if failed and distributed.writer():
        print(f"pointing requirements FAILED: {'; '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0
