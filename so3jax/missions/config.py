"""The one configuration parser of every command: TOML files and ``--set KEY=VALUE``
overrides (the values are checked by :mod:`so3jax.core.checks`)."""

from __future__ import annotations

import tomllib
from pathlib import Path


def parse_value(text: str):
    """A TOML value (number, string, array, inline table, boolean); a bare word is a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def parse_override(item: str) -> tuple[str, object]:
    """'table.key=VALUE' -> ('table.key', parsed VALUE)."""
    key, sep, value = item.partition("=")
    if not sep or not key.strip():
        raise ValueError(f"override {item!r} must read KEY=VALUE")
    return key.strip(), parse_value(value.strip())


def set_dotted(table: dict, dotted: str, value) -> None:
    """table[a][b][c] = value for dotted = 'a.b.c', creating the tables on the way."""
    *parents, last = dotted.split(".")
    for key in parents:
        table = table.setdefault(key, {})
        if not isinstance(table, dict):
            raise ValueError(f"config key {dotted!r}: {key!r} is not a table")  # noqa: TRY004 (bad input)
    table[last] = value


def read_toml(path) -> dict:
    """A TOML file's tables (UTF-8, a byte-order mark allowed); ValueError (not a traceback)
    for a missing or unreadable file."""
    path = Path(path)
    if path.suffix != ".toml":
        raise ValueError(f"config file {path} must be a .toml file")
    try:
        return tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except FileNotFoundError:
        raise ValueError(f"config file {path} does not exist") from None
    except (IsADirectoryError, PermissionError) as err:
        raise ValueError(f"config file {path} cannot be read: {err.strerror or err}") from None
    except UnicodeDecodeError as err:
        raise ValueError(f"config file {path} is not UTF-8 text (byte {err.start}: {err.reason})") from None
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"config file {path} is not valid TOML: {err}") from None


def override(d: dict, overrides=()) -> dict:
    """d (changed in place) with ``KEY=VALUE`` overrides applied (dotted keys)."""
    for item in overrides:
        set_dotted(d, *parse_override(item))
    return d
