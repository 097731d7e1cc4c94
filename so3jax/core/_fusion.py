"""A fusion boundary for XLA:CPU: compute a value once instead of in every consumer.

XLA:CPU fuses chains of cheap elementwise operations into each of their consumers,
recomputing them there: in the adaptive law, every element of the 9x3 outer product
Phi z^T would recompute z and Phi from the attitude. A floating-point division counts as
expensive and is never duplicated, so dividing by a 1 that XLA cannot fold makes a
value the output of one fusion, computed once. x / 1 == x exactly, and the derivative
is 1. Other platforms (GPU) fuse by a cost model and get the value unchanged.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def materialize(tree, t):
    """tree, unchanged in value; t: a traced scalar (the time) that makes the 1 opaque."""
    t = jnp.asarray(t)

    def divide_by_one(tree):
        one = (t == t).astype(t.dtype)  # noqa: PLR0124 (on purpose: a 1 that XLA cannot fold)
        return jax.tree.map(lambda x: x / one.astype(x.dtype), tree)

    return jax.lax.platform_dependent(tree, cpu=divide_by_one, default=lambda tree: tree)
