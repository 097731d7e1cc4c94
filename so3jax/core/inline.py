"""``@inline``: an array helper traced once per argument shapes and dtypes, its operations
copied into the caller's program at every call (``jax.jit(inline=True)``).

JAX caches a jitted function's jaxpr by its arguments' shapes and dtypes; with
``inline=True`` each call copies that jaxpr into the program being traced. The program is
the one the helper's own operations would make (the same compiled code and values), and a
loop that calls a helper many times (each RK4 stage's rotations) runs its Python once
(docs/performance.md, "Helpers traced once"). Static arguments (flags, functions) are
named in ``static_argnames``.
"""

from __future__ import annotations

import functools

import jax


def inline(fun=None, *, static_argnames=()):
    """``fun`` traced once per argument shapes and dtypes and inlined where it is called;
    ``@inline`` or ``@inline(static_argnames=(...))``."""
    if fun is None:
        return functools.partial(inline, static_argnames=static_argnames)
    return jax.jit(fun, inline=True, static_argnames=static_argnames)
