"""Threefry-2x32 (Salmon et al. 2011, 20 rounds), the hash behind JAX's default PRNG,
written out round by round in ``jax.lax`` integer ops.

JAX's CPU lowering of ``threefry2x32`` runs the rounds as a rolled loop, each a separate
pass over memory; written out, the hash and what consumes it fuse into one loop. The
words are the same by construction (tests/test_rollout.py checks them against
``jax.random``).
"""

from __future__ import annotations

import jax
import numpy as np

_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))
_PARITY = np.uint32(0x1BD11BDA)


def _rotate_left(x, d: int):
    return jax.lax.shift_left(x, np.uint32(d)) | jax.lax.shift_right_logical(x, np.uint32(32 - d))


# jitted, not inlined: one equation that the caller's derivatives and batching pass as a whole; its
# words are integers, so the call XLA inlines computes the same values
@jax.jit
def threefry2x32(k1, k2, x1, x2):
    """The two uint32 output words of Threefry-2x32 of counters (x1, x2) under key (k1, k2);
    arguments uint32 arrays of one shape."""
    ks = (k1, k2, k1 ^ k2 ^ _PARITY)
    x = [x1 + ks[0], x2 + ks[1]]
    for i in range(5):
        for r in _ROTATIONS[i % 2]:
            x[0] = x[0] + x[1]
            x[1] = x[0] ^ _rotate_left(x[1], r)
        x[0] = x[0] + ks[(i + 1) % 3]
        x[1] = x[1] + ks[(i + 2) % 3] + np.uint32(i + 1)
    return x[0], x[1]
