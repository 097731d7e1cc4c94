"""Command line: so3jax paper | fly | tune | sweep | compare | identify | margins | crosscheck | schema.

Each command lives in its own module (paper, fly, tune, sweep, compare, identify, margins,
crosscheck, schema), which exposes ``register(subparsers)``, whose parser sets ``func`` to the
module's ``run(args) -> int``; the options the commands share are in :mod:`so3jax.commands.common`.
The jobs the commands run live in :mod:`so3jax.jobs`. JAX is configured here (precision,
one host device per core) before any command runs.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import traceback
import warnings
from pathlib import Path

from so3jax.commands import compare, crosscheck, fly, identify, margins, paper, schema, sweep, tune
from so3jax.commands.common import Parser
from so3jax.parallel import distributed
from so3jax.parallel import xla_flags as _xla_flags

COMMANDS = (paper, fly, tune, sweep, compare, identify, margins, crosscheck, schema)  # in the order --help lists them


DESCRIPTION = (
    "so3jax simulates spacecraft attitude control on SO(3) in JAX: a mission (TOML, --set KEY=VALUE) "
    "names the scenario, the loop's sensors, estimator and actuator, and the controllers, and each command "
    "flies it: paper reproduces the paper's mission and Table II, fly flies any mission through its loop, "
    "tune tunes a controller's gains by gradient descent through the simulator, sweep flies a Monte Carlo "
    "sweep of dispersed missions, compare tunes several laws to one effort budget and pairs them over a "
    "sweep, identify estimates the inertia from telemetry, margins gives the sampled loop's stability margins, "
    "crosscheck flies a mission in Basilisk too and compares the two, schema writes the JSON Schemas an editor "
    "checks mission, sweep, campaign and comparison files with. "
    "'so3jax COMMAND --help' lists a command's "
    "options and the registered components it can choose."
)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="so3jax", description=DESCRIPTION)
    subparsers = parser.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.register(subparsers)
    return parser


CACHE_MAX_BYTES = 2 << 30


def configure_jax(precision: str) -> None:
    """Precision, and a persistent compilation cache: a second ``so3jax paper`` skips
    XLA's compilation (the whole process: ~9 s with an empty cache, ~5 s with a filled one,
    2-core AMD EPYC). The cache lives in $SO3JAX_CACHE_DIR, else
    ~/.cache/so3jax/xla (at most 2 GiB where ``filelock`` is installed, which JAX's
    eviction needs); SO3JAX_CACHE_DIR= (empty) turns it off, and a cache the user
    configured for JAX is left as it is."""
    import jax  # here: configured at run time, after main() sets XLA's flags

    jax.config.update("jax_enable_x64", precision == "float64")
    if jax.config.jax_compilation_cache_dir is None:
        default = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "so3jax" / "xla"
        cache = os.environ.get("SO3JAX_CACHE_DIR", str(default))
        if cache:
            jax.config.update("jax_compilation_cache_dir", cache)
            if jax.config.jax_compilation_cache_max_size == -1 and importlib.util.find_spec("filelock"):
                jax.config.update("jax_compilation_cache_max_size", CACHE_MAX_BYTES)  # JAX's LRU needs filelock


def main(argv=None) -> int:
    _xla_flags.configure_xla(every_core=True)  # before JAX initializes its backend
    args = build_parser().parse_args(argv)
    configure_jax(args.precision)
    with warnings.catch_warnings():
        warnings.showwarning = _warning_printer(args.command)
        # In a multi-process run every process meets the others with its outcome
        # (distributed.agree) and leaves in order (distributed.leave exits the process).
        try:
            code = distributed.agree(args.func(args))
        except ValueError as err:  # bad input (docs/model.md §6): a message, not a traceback
            print(f"so3jax {args.command}: error: {err}", file=sys.stderr)
            code = distributed.agree(2)
        except OSError as err:  # the system refused a file (a full disk, quota, read-only, permission): one line
            print(f"so3jax {args.command}: error: {os_error(err)}", file=sys.stderr)
            code = distributed.agree(2)
        except distributed.PeerFailure as err:  # another process of a multi-process run stopped
            print(f"so3jax {args.command}: error: {err}", file=sys.stderr)
            code = 1
        except KeyboardInterrupt:
            print("interrupted", file=sys.stderr)
            code = distributed.agree(130)
        except Exception:
            if not distributed.active():
                raise
            traceback.print_exc()
            code = distributed.agree(1)
    return distributed.leave(code)


def os_error(err: OSError) -> str:
    """An OSError in one line: what the system said, and of which file."""
    return f"{err.strerror or err}: {err.filename}" if err.filename else f"{err.strerror or err}"


def _warning_printer(command: str):
    """warnings.showwarning for a command: ``so3jax CMD: warning: MESSAGE``, each
    message once, without the source line."""
    shown = set()

    def show(message, category, filename, lineno, file=None, line=None):
        text = str(message)
        if text not in shown:
            shown.add(text)
            print(f"so3jax {command}: warning: {text}", file=sys.stderr if file is None else file)

    return show

