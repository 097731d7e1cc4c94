"""The one configuration parser of every command: TOML files and ``--set KEY=VALUE``
overrides (the values are checked by :mod:`so3jax.core.checks`)."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from so3jax.core import checks

_PREFIX = "v = "  # a value is parsed as the document "v = VALUE"
_LOCATION = re.compile(r"\s*\(at (?:line (\d+), column (\d+)|end of document)\)$")


def meant_as_toml(text: str) -> bool:
    """Whether ``text`` can only be meant as TOML: an array, an inline table or a quoted
    string (it starts with ``[``, ``{``, ``"`` or ``'``), or ``key = value`` inside braces."""
    text = text.strip()
    return text.startswith(("[", "{", '"', "'")) or re.search(r"\{[^}]*=", text) is not None


def _reason(err: tomllib.TOMLDecodeError) -> str:
    """The parse error, located in the value rather than in the document "v = VALUE"."""
    message = str(err)
    found = _LOCATION.search(message)
    what = message[: found.start()] if found else message
    where = ""
    if found and found.group(1) is None:
        where = " at its end"
    elif found:
        line, column = int(found.group(1)), int(found.group(2))
        where = (f" at its character {column - len(_PREFIX)}" if line == 1 else
                 f" at its line {line}, column {column}")
    return what[:1].lower() + what[1:] + where


def parse_value(text: str, key: str = "value"):
    """A TOML value (number, string, array, inline table, boolean); a bare word (a name, a
    path) is a string. Text that does not parse but can only be meant as TOML
    (:func:`meant_as_toml`) is a one-line ValueError naming ``key``, the value and the parse
    error, rather than a string."""
    try:
        return tomllib.loads(f"{_PREFIX}{text}")["v"]
    except tomllib.TOMLDecodeError as err:
        if meant_as_toml(text):
            raise ValueError(f"--set {key}: {checks.short(text)} is not a TOML value: {_reason(err)}") from None
        return text


def parse_override(item: str) -> tuple[str, object]:
    """'table.key=VALUE' -> ('table.key', parsed VALUE) (:func:`parse_value`)."""
    key, sep, value = item.partition("=")
    if not sep or not key.strip():
        raise ValueError(f"override {item!r} must read KEY=VALUE")
    return key.strip(), parse_value(value.strip(), key.strip())


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
