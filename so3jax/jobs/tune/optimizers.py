"""Optimizer steps on the tuned parameters (log-gains; a nonnegative gain scaled, kept >= 0):
an optax update, and the gradient-free (1+lambda)-ES
baseline."""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from jax.flatten_util import ravel_pytree

from so3jax.jobs.tune.cost import Evaluation
from so3jax.jobs.tune.gains import project


class GradientState(NamedTuple):
    params: Any
    opt_state: Any


class ESState(NamedTuple):
    params: Any
    cost: jax.Array
    rmse: jax.Array
    effort: jax.Array
    sigma: jax.Array


@functools.partial(jax.jit, static_argnames=("tx",))
def optax_step(tx, state: GradientState, grad, value):
    with jax.numpy_dtype_promotion("standard"):  # optax mixes int32 step counts with floats
        updates, opt_state = tx.update(grad, state.opt_state, state.params, value=value)
    return GradientState(project(optax.apply_updates(state.params, updates)), opt_state)


def es_candidates(params, sigma, key, population):
    """population log-gain vectors params + sigma * N(0, I) (leading axis)."""
    flat, unravel = ravel_pytree(params)
    noise = jax.random.normal(key, (population,) + flat.shape, flat.dtype)
    return jax.vmap(unravel)(flat + sigma * noise)


def es_select(state: ESState, candidates, evaluation: Evaluation) -> ESState:
    """Keep the best candidate if it beats the parent; sigma by the 1/5th success rule."""
    costs = jnp.where(jnp.isfinite(evaluation.cost), evaluation.cost, jnp.inf)
    best = jnp.argmin(costs)
    better = costs[best] < state.cost
    success = jnp.mean((costs < state.cost).astype(state.sigma.dtype))

    def pick(new, old):
        return jnp.where(better, new, old)

    return ESState(
        jax.tree.map(lambda c, p: pick(c[best], p), candidates, state.params),
        pick(costs[best], state.cost),
        pick(evaluation.rmse[best], state.rmse),
        pick(evaluation.effort[best], state.effort),
        state.sigma * jnp.exp((success - 0.2) / 0.8),
    )


class NonFiniteGradientError(FloatingPointError):
    """A cost or gradient became NaN/inf; the run stopped with its last good gains saved."""
