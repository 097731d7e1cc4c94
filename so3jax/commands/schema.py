"""``so3jax schema``: the subcommand's arguments, and the JSON Schemas it writes (the job:
:mod:`so3jax.jobs.schema`)."""

from __future__ import annotations

import sys
from pathlib import Path

from so3jax.jobs import schema


def register(subparsers) -> None:
    p = subparsers.add_parser("schema", help="the JSON Schemas of mission, sweep, campaign and comparison files",
                              description="Writes the JSON Schemas (draft-07) of so3jax's TOML files, generated "
                              "from the keys and domains the parsers check: " + ", ".join(schema.FILES) + ". "
                              "An editor that reads taplo's '#:schema PATH' first line (Even Better TOML, "
                              "taplo, tombi) then completes, describes and checks a file's keys as it is typed.")
    p.add_argument("--out", type=Path, default=Path("schemas"),
                   help="folder the schemas are written into (default schemas/)")
    p.add_argument("--check", action="store_true",
                   help="write nothing; exit with 1, naming them, where the files in --out differ from what "
                   "the parsers' tables generate now")
    p.set_defaults(func=run, precision="float64")


def run(args) -> int:
    if args.check:
        stale = schema.stale(args.out)
        if stale:
            print(f"{args.out}: {', '.join(stale)} differ from the parsers' tables: run so3jax schema --out "
                  f"{args.out}", file=sys.stderr)
            return 1
        print(f"{args.out}: {', '.join(schema.FILES)} up to date")
        return 0
    paths = schema.write(args.out)
    print(f"wrote {', '.join(str(p) for p in paths)}")
    return 0
