"""What the commands' parsers share: the one-line-error parser, the --precision and
--max-memory options, and the registered names a command's --help lists."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from so3jax.components import registry as components
from so3jax.controllers import registry


class _Given(argparse._StoreAction):
    """An option's value (argparse's default action, in every so3jax parser and its groups):
    given again, a list option's values accumulate (``--at 1.0 --at 5.0``: both), any other
    is a one-line error, never the last value kept silently."""

    def __call__(self, parser, namespace, values, option_string=None):
        given = getattr(parser, "given", set())
        if self.dest in given and option_string is not None:
            if self.nargs not in ("+", "*"):
                parser.error(f"{option_string} is given twice: give it once")
            values = list(getattr(namespace, self.dest)) + list(values)
        given.add(self.dest)
        setattr(namespace, self.dest, values)


class Parser(argparse.ArgumentParser):
    """argparse with a one-line error (``so3jax CMD: error: ...``, exit 2); ``--help`` shows the
    usage; an option given twice accumulates or is refused (:class:`_Given`)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.register("action", None, _Given)
        self.register("action", "store", _Given)

    def parse_known_args(self, args=None, namespace=None):
        self.given = set()  # the options given in this parse
        return super().parse_known_args(args, namespace)

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def registered(tunable: bool = False) -> str:
    """The registered names a mission chooses among (a command's --help epilog), read from
    the registries; ``tunable``: the controllers whose gains ``tune`` can tune."""
    laws = ", ".join(registry.names(tunable=True) if tunable else registry.names())
    return (f"registered {'tunable controllers (tune.controller)' if tunable else 'controllers'}: {laws}; "
            f"sensors ([sensors.NAME]): {', '.join(components.names('sensor'))}; "
            f"estimators (estimator.kind): {', '.join(components.names('estimator'))}; "
            f"actuators (actuator.kind): {', '.join(components.names('actuator'))}; "
            f"momentum management (momentum.kind): {', '.join(components.names('momentum'))}; "
            f"structural filters (filter.kind): {', '.join(components.names('filter'))}; "
            f"environment torques ([environment.NAME]): {', '.join(components.names('environment'))}; "
            f"references (reference.kind): {', '.join(components.names('reference'))}; "
            f"inertias (inertia.kind): {', '.join(components.names('inertia'))}.")


def controllers_help(default: str) -> str:
    """--controllers' help: the registered controller names."""
    return f"comma-separated controllers among: {', '.join(registry.names())} (default: {default})"


def add_precision_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--precision",
        choices=("float64", "float32"),
        default="float64",
        help="floating-point precision (default float64)",
    )


def add_memory_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--max-memory",
        metavar="SIZE",
        help="refuse a run estimated to need more memory than SIZE, e.g. 4G (default: the memory available)",
    )


def output_folder(text: str) -> Path:
    """--out's type: a folder's path; an empty one is refused (it would name the current directory)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("must name a folder; an empty path would be the current directory")
    return Path(text)


def add_output_arguments(parser: argparse.ArgumentParser, folder: str, figures: str = "the PNG figures") -> None:
    """--out (default ``folder``), --json and --no-figures, as the commands that write one run's folder take them."""
    parser.add_argument("--out", type=output_folder, default=Path(folder), help=f"output folder (default {folder})")
    parser.add_argument("--json", action="store_true", help="print one JSON object (last line of stdout)")
    parser.add_argument("--no-figures", action="store_true", help=f"skip {figures}")


def mission_overrides(args, keys=("T", "seed", "record_every")) -> list[str]:
    """The mission overrides of a command's arguments: --set's, then ``KEY=VALUE`` for each of
    ``keys`` (a mission key and its option) given, then --controllers."""
    items = list(args.set)
    for key in keys:
        value = getattr(args, key, None)
        if value is not None:
            items.append(f"{key}={value!r}")
    if getattr(args, "controllers", None) is not None:
        items.append("controllers=" + json.dumps([c.strip() for c in args.controllers.split(",") if c.strip()]))
    return items
