"""Memory a run will need, estimated before anything compiles (``jax.eval_shape`` traces
the computation for its output shapes only), against the memory the machine has free; and
the most steps a rollout can count."""

from __future__ import annotations

import math
import os
import re

import jax
import numpy as np

from so3jax.sim.loop import PAPER_LOOP
from so3jax.sim.rollout import simulate_shapes

# Outputs are held twice at their peak: XLA's result buffer and the NumPy copy made of it.
COPIES = 2
# A rollout counts its steps in int32; a last block may overrun the horizon by up to N steps.
MAX_STEPS = 2**30
_UNITS = {"": 1, "k": 1 << 10, "m": 1 << 20, "g": 1 << 30, "t": 1 << 40}


def available() -> int:
    """Bytes the system can give this process now (MemAvailable, else free pages)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def parse_size(text: str) -> int:
    """'512M', '4G', '1.5GiB', '2e9' -> bytes (binary units); ValueError otherwise."""
    match = re.fullmatch(r"\s*([0-9.eE+]+)\s*([kKmMgGtT]?)(i?[bB])?\s*", str(text))
    try:
        value = float(match.group(1)) * _UNITS[match.group(2).lower()]
    except (AttributeError, ValueError):
        raise ValueError(f"--max-memory must be a size such as 512M or 4G, got {text!r}") from None
    if not value > 0:
        raise ValueError(f"--max-memory must be positive, got {text!r}")
    return int(value)


def fmt(n: int) -> str:
    """Bytes in binary units, three significant digits."""
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024:
            return f"{n:.3g} {unit}"
        n /= 1024
    return f"{n:.3g} TiB"


def nbytes(tree) -> int:
    """Bytes of every array (or ShapeDtypeStruct) leaf of a pytree."""
    return sum(math.prod(x.shape) * np.dtype(x.dtype).itemsize for x in jax.tree.leaves(tree))


def outputs(fn, *args) -> int:
    """Bytes of ``fn(*args)``'s outputs, held COPIES times, from tracing alone."""
    return COPIES * nbytes(jax.eval_shape(fn, *args))


def simulate_bytes(scenario, controller, gains, seed=0, loop=None, record_every=None) -> int:
    """Bytes ``so3jax.simulate`` with these arguments holds at its peak (its results), from
    the trace of its program (:func:`so3jax.sim.rollout.simulate_shapes`), which simulate reuses."""
    shapes = simulate_shapes(scenario, controller, gains, seed, loop=PAPER_LOOP if loop is None else loop,
                             record_every=record_every)
    return COPIES * nbytes(shapes)


def from_args(args) -> int | None:
    """The --max-memory limit of a command's arguments, in bytes (None: what is available)."""
    text = getattr(args, "max_memory", None)
    return None if text is None else parse_size(text)


def check(needed: int, limit: int | None, what: str, advice: str) -> dict:
    """Refuse (ValueError) when ``needed`` bytes exceed ``limit`` (None: the available
    memory). Returns {'estimate_bytes', 'limit_bytes'} for the run's config."""
    source = "available" if limit is None else "allowed by --max-memory"
    limit = available() if limit is None else int(limit)
    if needed > limit:
        raise ValueError(f"{what} needs about {fmt(needed)} of memory, more than the {fmt(limit)} {source}; {advice}")
    return {"estimate_bytes": int(needed), "limit_bytes": limit}


def check_steps(n_steps: int, what: str, advice: str) -> int:
    """Refuse (ValueError) a horizon of more than MAX_STEPS steps, which a rollout cannot
    count; returns ``n_steps``."""
    if n_steps > MAX_STEPS:
        raise ValueError(f"{what} is {n_steps:.3g} steps, more than the {MAX_STEPS} a rollout can count; {advice}")
    return n_steps
