"""Disturbance torque d_k, held constant over a step (SPEC 4, paper eq. 20)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from so3jax._pytree import pytree_dataclass


@pytree_dataclass
class SinusoidPlusNoise:
    """d_k = amplitude sin(frequency t_k) [1, 1, 1] + noise_std eta_k  [N m].

    eta_k = normal(fold_in(key(seed), k), (3,)) in the simulation's dtype, so a seed
    gives the same noise in any implementation that follows SPEC 4.
    """

    amplitude: jax.Array  # N m
    frequency: jax.Array  # rad/s
    noise_std: jax.Array  # N m

    def __call__(self, key, k, t_k):
        """d_k (3, ...) for a key of any batch shape (...) [N m]."""
        eta = noise(key, k, jnp.result_type(t_k))
        return self.amplitude * jnp.sin(self.frequency * t_k) * jnp.ones_like(eta) + self.noise_std * eta


def noise(key, k, dtype):
    """eta_k = normal(fold_in(key, k), (3,)) per key; (3, *key.shape) (batch axes last)."""
    draw = lambda one: jax.random.normal(jax.random.fold_in(one, k), (3,), dtype)
    if key.ndim == 0:
        return draw(key)
    flat = jax.vmap(draw)(key.reshape(-1))
    return flat.T.reshape((3,) + key.shape)


def no_disturbance(dtype=float) -> SinusoidPlusNoise:
    zero = jnp.zeros((), dtype)
    return SinusoidPlusNoise(zero, zero, zero)
