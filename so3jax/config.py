"""The one configuration parser of every command: TOML files, ``--set KEY=VALUE``
overrides, and the checks of their values (one-line ValueErrors, before any compilation)."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np


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
    """A TOML file's tables; ValueError (not a traceback) for a missing or unreadable file."""
    path = Path(path)
    if path.suffix != ".toml":
        raise ValueError(f"config file {path} must be a .toml file")
    try:
        return tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"config file {path} does not exist") from None
    except (IsADirectoryError, PermissionError, UnicodeDecodeError) as err:
        raise ValueError(f"config file {path} cannot be read: {err.strerror or err}") from None
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"config file {path} is not valid TOML: {err}") from None


def load(path=None, overrides=()) -> dict:
    """The tables of ``path`` (or {}), with ``KEY=VALUE`` overrides applied (dotted keys)."""
    d = read_toml(path) if path is not None else {}
    for item in overrides:
        set_dotted(d, *parse_override(item))
    return d


def table(d: dict, key: str, allowed, where: str = "") -> dict:
    """d[key] (a table, {} when absent) after checking that it has only ``allowed`` keys."""
    t = d.get(key, {})
    if not isinstance(t, dict):
        raise ValueError(f"{where}{key} must be a table")  # noqa: TRY004 (bad input: ValueError, as the CLI expects)
    unknown = set(t) - set(allowed)
    if unknown:
        raise ValueError(f"unknown key(s) in [{where}{key}]: {', '.join(sorted(unknown))}; allowed: {', '.join(allowed)}")
    return t


def number(value, where: str, low=-math.inf, high=math.inf, integer=False):
    """A number in [low, high] (an int if ``integer``), else ValueError naming ``where``."""
    ok = isinstance(value, int) if integer else isinstance(value, (int, float))
    if isinstance(value, bool) or not ok or not math.isfinite(value) or not (low <= value <= high):
        kind = "an integer" if integer else "a finite number"
        raise ValueError(f"{where} must be {kind} in [{low}, {high}], got {value!r}")
    return value if integer else float(value)


def array(value, where: str, shape: tuple, low=-math.inf) -> np.ndarray:
    """A numeric array of ``shape`` (None: any length on that axis), every entry finite and >= low."""
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{where} must be a numeric array of shape {shape}, got {value!r}") from None
    if a.ndim != len(shape) or any(s is not None and n != s for n, s in zip(a.shape, shape)):
        raise ValueError(f"{where} must have shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)) or np.any(a < low):
        raise ValueError(f"{where} must be finite{f' and >= {low}' if low > -math.inf else ''}, got {a.tolist()}")
    return a


def names(value, where: str, known) -> tuple[str, ...]:
    """A list of distinct names among ``known``; a single string is a one-element list."""
    items = (value,) if isinstance(value, str) else value
    if not isinstance(items, (list, tuple)) or not items or not all(isinstance(x, str) for x in items):
        raise ValueError(f"{where} must be a name or a list of names among {', '.join(known)}, got {value!r}")
    items = tuple(x.strip() for x in items)
    bad = [x for x in items if x not in known]
    if bad or len(set(items)) != len(items):
        raise ValueError(f"{where} must be distinct names among {', '.join(known)}, got {list(items)}")
    return items
