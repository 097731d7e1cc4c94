"""The paper scenario's disturbance noise, drawn exactly as docs/model.md §4 prescribes.

    eta_k = jax.random.normal(jax.random.fold_in(jax.random.key(seed), k), (3,), dtype)

for k = 0 .. n_steps-1, with JAX's default PRNG (threefry2x32, partitionable). The
draw runs inside ``jax.enable_x64(True)`` (float64 needs it; float32 draws and the
key of a seed in [0, 2**31) are the same either way), so the caller's global JAX
configuration is left as it is. eta is dimensionless (unit variance per axis).
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cache

import numpy as np


@cache
def _drawer(n_steps: int, dtype_name: str):
    """A jitted map seeds (S,) int64 -> eta (S, n_steps, 3) for one horizon and dtype."""
    import jax
    import jax.numpy as jnp

    def one_seed(seed):
        key = jax.random.key(seed)
        steps = jnp.arange(n_steps, dtype=jnp.uint32)
        return jax.vmap(lambda k: jax.random.normal(jax.random.fold_in(key, k), (3,), dtype_name))(steps)

    return jax.jit(jax.vmap(one_seed))


def paper_noise_batch(seeds: Sequence[int], n_steps: int, dtype=np.float64) -> np.ndarray:
    """eta (len(seeds), n_steps, 3) for several seeds (docs/model.md §4, disturbance row)."""
    import jax

    dtype = np.dtype(dtype)
    if dtype not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ValueError(f"dtype must be float32 or float64, got {dtype}")
    if n_steps < 0 or n_steps >= 2**32:
        raise ValueError(f"n_steps must be in [0, 2**32), got {n_steps}")
    seeds = np.asarray(seeds, dtype=np.int64).reshape(-1)
    with jax.enable_x64(True):
        return np.asarray(_drawer(int(n_steps), dtype.name)(seeds))


def paper_noise(seed: int, n_steps: int, dtype=np.float64) -> np.ndarray:
    """eta (n_steps, 3) for one seed (docs/model.md §4, disturbance row)."""
    return paper_noise_batch([seed], n_steps, dtype)[0]
