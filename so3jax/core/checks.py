"""The value checks of every parameter a user gives: one-line ValueErrors (TypeErrors for
wrong types) naming the key, before anything compiles."""

from __future__ import annotations

import math

import numpy as np


def table(d: dict, key: str, allowed, where: str = "") -> dict:
    """d[key] (a table, {} when absent) after checking that it has only ``allowed`` keys."""
    t = d.get(key, {})
    if not isinstance(t, dict):
        raise ValueError(f"{where}{key} must be a table, got {short(t)}")  # noqa: TRY004 (bad input)
    unknown = set(t) - set(allowed)
    if unknown:
        raise ValueError(f"unknown key(s) in [{where}{key}]: {', '.join(sorted(unknown))}; "
                         f"allowed: {', '.join(allowed)}")
    return t


def number(value, where: str, low=-math.inf, high=math.inf, integer=False):
    """A number in [low, high] (an int if ``integer``), else ValueError naming ``where``."""
    ok = isinstance(value, int) if integer else isinstance(value, (int, float))
    if isinstance(value, bool) or not ok or not finite(value) or not (low <= value <= high):
        kind = "an integer" if integer else "a finite number"
        raise ValueError(f"{where} must be {kind} in [{low}, {high}], got {short(value)}")
    return value if integer else float(value)


def finite(x) -> bool:
    """math.isfinite, False for an integer too large for a float."""
    try:
        return math.isfinite(x)
    except OverflowError:
        return False


def _numeric(value) -> bool:
    """Whether value is a number (not a bool), a NumPy real array, or nested lists of numbers."""
    if isinstance(value, (list, tuple)):
        return all(_numeric(x) for x in value)
    if isinstance(value, np.ndarray):
        return value.dtype.kind in "fiu"
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def short(value, limit: int = 80) -> str:
    """repr(value) on one line, cut to ``limit`` characters."""
    text = " ".join(repr(value).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def array(value, where: str, shape: tuple, low=-math.inf) -> np.ndarray:
    """A numeric array of ``shape`` (None: any length on that axis), every entry finite and >= low."""
    if not _numeric(value):
        raise ValueError(f"{where} must be a numeric array of shape {shape}, got {short(value)}")
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):  # ragged nested lists
        raise ValueError(f"{where} must be a numeric array of shape {shape}, got {short(value)}") from None
    if a.ndim != len(shape) or any(s is not None and n != s for n, s in zip(a.shape, shape)):
        raise ValueError(f"{where} must have shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)) or np.any(a < low):
        bound = f" and >= {low}" if low > -math.inf else ""
        raise ValueError(f"{where} must be finite{bound}, got {short(a.tolist())}")
    return a


def concrete(value, where: str) -> np.ndarray | None:
    """A library parameter's values as a float NumPy array, or None where it is traced
    (under jit, vmap or grad: its values are checked where they are concrete). ValueError
    naming ``where`` for a value that is not real numbers: a string, a bool, a table."""
    import jax  # here: the commands import this module before JAX is configured

    if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(value)):
        return None
    dtype = getattr(value, "dtype", None)
    ok = dtype.kind in "fiu" if dtype is not None else _numeric(value)
    try:
        a = np.asarray(value, dtype=float) if ok else None
    except (TypeError, ValueError):  # ragged
        a = None
    if a is None:
        raise ValueError(f"{where} must be real numbers, got {short(value)}")
    return a


def values(where: str, x, shape, positive: bool = False, nonnegative: bool = False) -> np.ndarray | None:
    """A parameter's values (NumPy, None where traced): one-line ValueError unless x has
    ``shape`` and, where concrete, is finite (positive / non-negative)."""
    v = concrete(x, where)
    if np.shape(x) != shape:
        raise ValueError(f"{where} must have shape {shape}, got {np.shape(x)}")
    if v is None:
        return None
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{where} must be finite, got {v.tolist()}")
    if positive and np.any(v <= 0):
        raise ValueError(f"{where} must be positive, got {v.tolist()}")
    if nonnegative and np.any(v < 0):
        raise ValueError(f"{where} must be non-negative, got {v.tolist()}")
    return v


def boolean(value, where: str) -> bool:
    """true or false, else ValueError naming ``where``."""
    if not isinstance(value, bool):
        raise ValueError(f"{where} must be true or false, got {short(value)}")
    return value


def choice(value, where: str, choices) -> str:
    """One of the names ``choices``, else ValueError naming ``where``."""
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"{where} must be one of {', '.join(choices)}, got {short(value)}")
    return value


def gains(given, defaults, shapes: dict, where: str):
    """``defaults`` (a NamedTuple of gains) with the entries of the table ``given``
    replaced, each checked against its default before use: a number where the default is
    a number (and that shape is allowed), else a numeric array of one of the shapes
    ``shapes[field]`` (the default's shape for a field not listed). Numbers stay as
    given; arrays become float arrays."""
    if not isinstance(given, dict):
        raise ValueError(f"[{where}] must be a table, got {short(given)}")  # noqa: TRY004 (bad input)
    fields = type(defaults)._fields
    unknown = set(given) - set(fields)
    if unknown:
        raise ValueError(f"unknown key(s) in [{where}]: {', '.join(sorted(map(str, unknown)))}; "
                         f"allowed: {', '.join(fields) or 'none (a law without gains)'}")
    values = {}
    for name, value in given.items():
        allowed = tuple(tuple(s) for s in shapes.get(name, (np.shape(getattr(defaults, name)),)))
        key = f"{where}.{name}"
        kinds = " or ".join("a number" if s == () else f"a numeric array of shape {s}" for s in allowed)
        if not _numeric(value):
            raise ValueError(f"{key} must be {kinds}, got {short(value)}")
        try:
            a = np.asarray(value, dtype=float)
        except ValueError:  # ragged nested lists
            raise ValueError(f"{key} must be {kinds}, got {short(value)}") from None
        if a.shape not in allowed:
            raise ValueError(f"{key} must be {kinds}, got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{key} must be finite, got {short(a.tolist())}")
        values[name] = value if a.ndim == 0 and not isinstance(value, (list, tuple, np.ndarray)) else a
    return defaults._replace(**values)


def names(value, where: str, known) -> tuple[str, ...]:
    """A list of distinct names among ``known``; a single string is a one-element list."""
    items = (value,) if isinstance(value, str) else value
    if not isinstance(items, (list, tuple)) or not items or not all(isinstance(x, str) for x in items):
        raise ValueError(f"{where} must be a name or a list of names among {', '.join(known)}, got {short(value)}")
    items = tuple(x.strip() for x in items)
    bad = [x for x in items if x not in known]
    if bad or len(set(items)) != len(items):
        raise ValueError(f"{where} must be distinct names among {', '.join(known)}, got {short(list(items))}")
    return items
