"""``so3jax compare``: the subcommand's arguments, and the comparison they run (the job:
:mod:`so3jax.jobs.compare`)."""

from __future__ import annotations

import warnings
from pathlib import Path

from so3jax.commands.common import add_precision_argument, output_folder, registered
from so3jax.dynamics.inertia import InertiaWarning
from so3jax.jobs import compare
from so3jax.missions import config as cfg


def run(args) -> int:
    overrides = [cfg.parse_override(text) for text in args.set]
    with warnings.catch_warnings():
        warnings.simplefilter("once", InertiaWarning)
        config = compare.load_config(args.config, overrides)
    out = Path(args.out) if args.out else Path("results/compare") / Path(args.config).stem
    result = compare.run(config, out, resume=args.resume)
    print(compare.markdown(result))
    print(f"results in {out}/")
    failed = [law for law, e in result["laws"].items() if not all(q["passed"] for q in e.get("requirements", []))]
    return 1 if failed else 0  # a pointing requirement failed (compare.md lists it)


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "compare", help="tune control laws to one effort budget, then pair them over a dispersed sweep",
        description="Control laws side by side: each tuned to one effort budget, judged on held-out seeds and a sweep.",
        epilog=registered(tunable=True))
    parser.add_argument("config", help="comparison file (TOML): a mission whose controllers are compared, [tune], "
                        "[sweep], [dispersions], [compare]; e.g. comparisons/paper.toml")
    parser.add_argument("--out", type=output_folder, help="run folder (default results/compare/NAME for NAME.toml)")
    parser.add_argument("--resume", action="store_true", help="finish the comparison in --out, keeping what it holds")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override an entry with a TOML value: a mission key (T=100.0), tune.*, sweep.*, compare.*")
    add_precision_argument(parser)
    parser.set_defaults(func=run)
