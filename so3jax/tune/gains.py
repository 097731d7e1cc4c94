"""Tunable controllers and their gains: reading gains ("paper", a table, a
best_gains.json), the log-gain parameters p = log g, and gains as tables and columns."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from so3jax import config as cfg
from so3jax import runfolder
from so3jax.controllers import registry
from so3jax.scenario import check_gains

# One instance per controller, so that jit caches hit across runs in one process.
CONTROLLERS = {n: registry.get(n).factory() for n in registry.names(tunable=True)}


GAIN_TYPES = {n: registry.get(n).gains_type for n in CONTROLLERS}
PAPER_GAINS = {n: registry.get(n).defaults for n in CONTROLLERS}


def resolve_gains(controller: str, spec, dtype, diagonal_gamma=False):
    """Gains from "paper", a table {name: value}, or a best_gains.json path; checked (SPEC 6)."""
    cls = GAIN_TYPES[controller]
    if spec == "paper":
        table = PAPER_GAINS[controller]._asdict()
    elif isinstance(spec, str):
        saved = json.loads(Path(spec).read_text())
        if runfolder.incomplete(Path(spec).parent):
            warnings.warn(f"gains file {spec} is from a so3jax run that did not finish (its manifest says incomplete)")
        held = saved.get("controller") if isinstance(saved, dict) else None
        if held != controller or not isinstance(saved.get("gains"), dict):
            raise ValueError(f"gains file {spec} holds no table of {controller!r} gains ({held!r} gains)")
        table = saved["gains"]
    elif isinstance(spec, dict):
        table = spec
    else:
        raise ValueError(f"gains must be 'paper', a table or a .json path, got {cfg.short(spec)}")
    for name in table:
        if name not in cls._fields:
            raise ValueError(f"unknown gain {name!r} for the {controller} controller ({', '.join(cls._fields)})")
    missing = [name for name in cls._fields if name not in table]
    if missing:
        raise ValueError(f"missing gain {missing[0]!r} for the {controller} controller")
    registered = registry.get(controller)
    shapes = {name: tuple(s for s in allowed if len(s) < 2)  # tuning: a scalar or a (9,) diagonal Gamma
              for name, allowed in registered.gain_shapes().items()}
    table = cfg.gains(table, registered.defaults, shapes, "gains")._asdict()
    gains = cls(**{name: jnp.asarray(table[name], dtype) for name in cls._fields})
    if controller == "adaptive":
        if gains.Gamma.ndim > 1:
            raise ValueError("tuning supports a scalar or (9,) diagonal Gamma")
        if diagonal_gamma:
            gains = gains._replace(Gamma=jnp.broadcast_to(gains.Gamma, (9,)))
    check_gains(gains)
    return gains


def to_params(gains):
    """Log-gains, the tuned parameters."""
    return jax.tree.map(jnp.log, gains)


def to_gains(params):
    return jax.tree.map(jnp.exp, params)


def gains_table(gains) -> dict:
    return {name: np.asarray(value).tolist() for name, value in gains._asdict().items()}


def gain_columns(gains) -> dict:
    """Flat {column: value}: Gamma_0 .. Gamma_8 for a diagonal Gamma."""
    columns = {}
    for name, value in gains._asdict().items():
        value = np.asarray(value)
        if value.ndim == 0:
            columns[name] = float(value)
        else:
            columns.update({f"{name}_{i}": float(v) for i, v in enumerate(value)})
    return columns
