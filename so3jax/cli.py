"""Command line: ``so3jax paper | tune | sweep``.

Each command lives in its own module, which exposes ``register(subparsers)``; the
parser it adds sets ``func(args) -> int``. JAX is configured here (precision, one
host device per core) before any command imports it.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from so3jax import _xla_flags

COMMAND_MODULES = ("so3jax.paper", "so3jax.tune", "so3jax.sweep")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="so3jax", description=__doc__.splitlines()[0])
    subparsers = parser.add_subparsers(dest="command", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(subparsers)
    return parser


def add_precision_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--precision",
        choices=("float64", "float32"),
        default="float64",
        help="floating-point precision (default float64)",
    )


def configure_jax(precision: str) -> None:
    import jax

    jax.config.update("jax_enable_x64", precision == "float64")


def main(argv=None) -> int:
    _xla_flags.use_every_core()  # before JAX initializes its backend
    args = build_parser().parse_args(argv)
    configure_jax(args.precision)
    try:
        return args.func(args)
    except ValueError as err:  # bad input (SPEC 6): a message, not a traceback
        print(f"so3jax {args.command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
