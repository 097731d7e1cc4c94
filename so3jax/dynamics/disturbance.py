"""Disturbance torque d_k, held constant over a step (docs/model.md §4, paper eq. 20)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.ad_checkpoint import checkpoint_name

from so3jax.core import _trig
from so3jax.core._erfinv import erf_inv
from so3jax.core._fusion import materialize
from so3jax.core._threefry import threefry2x32
from so3jax.core.pytree import pytree_dataclass
from so3jax.dynamics import stepped


@pytree_dataclass
class SinusoidPlusNoise:
    """d_k = amplitude sin(frequency t_k) [1, 1, 1] + noise_std eta_k  [N m].

    eta_k = normal(fold_in(key(seed), k), (3,)) in the simulation's dtype, so a seed
    gives the same noise in any implementation that follows docs/model.md §4 (§14).
    """

    amplitude: jax.Array  # N m
    frequency: jax.Array  # rad/s
    noise_std: jax.Array  # N m

    def __call__(self, key, k, t_k):
        """d_k (3, ...) for a key of any batch shape (...) [N m]."""
        return jnp.stack(self.components(key, k, t_k))

    def components(self, key, k, t_k):
        """d_k as its three axes (x, y, z), each of the key's batch shape [N m]: a block of
        steps drawn this way is three loops over the batch, not one that interleaves axes."""
        # vectorized across a sweep's samples
        sine = _trig.sin if stepped.per_trajectory(self.frequency, 0) else jnp.sin
        sinusoid = self.amplitude * sine(self.frequency * t_k)
        return tuple(sinusoid + self.noise_std * eta for eta in noise_components(key, k, jnp.result_type(t_k)))


def noise(key, k, dtype):
    """eta_k = jax.random.normal(jax.random.fold_in(key, k), (3,), dtype) per key,
    as (3, *key.shape) (batch axes last). See :func:`noise_components`."""
    return jnp.stack(noise_components(key, k, dtype))


def noise_components(key, k, dtype):
    """The three components of eta_k = jax.random.normal(jax.random.fold_in(key, k), (3,),
    dtype), each of the key's batch shape.

    For threefry keys (JAX's default) the same bits are computed here on component
    arrays of the key's batch shape: on CPU, JAX lowers Threefry to a rolled loop that
    runs its 20 rounds as separate passes over memory (6x slower in a rollout); written
    out, the hash and the uniform fuse into one loop. The result is ``jax.random.normal``'s
    bit for bit, except for a batch of keys in float64: there the inverse error function is
    :func:`so3jax.core._erfinv.erf_inv`, XLA's algorithm without its scalar ``log`` calls
    (a batched draw ~2x faster on CPU), within 3 ulp of ``jax.random.normal``, the same
    double in ~99.4 % of draws (tests/test_rollout.py). One trajectory (a single key, also
    under vmap) keeps XLA's: its blocks are too short to gain, and it compiles faster.
    """
    dtype = jnp.dtype(dtype)
    if str(jax.random.key_impl(key)) != "threefry2x32" or dtype.itemsize not in (4, 8):
        draw = lambda one: jax.random.normal(jax.random.fold_in(one, k), (3,), dtype)
        eta = draw(key) if key.ndim == 0 else jax.vmap(draw)(key.reshape(-1)).T.reshape((3,) + key.shape)
        return tuple(_named(e) for e in eta)
    data = jax.random.key_data(key)
    zero = jnp.zeros(key.shape, jnp.uint32)
    # fold_in: the key hashed with the counter (0, k); the (3,) draw: counters (0, i).
    folded = _threefry(data[..., 0], data[..., 1], zero, zero + jnp.asarray(k).astype(jnp.uint32))
    uniforms = [_uniform_from_bits(_threefry(*folded, zero, zero + np.uint32(i)), dtype) for i in range(3)]
    inverse = jax.lax.erf_inv if dtype.itemsize == 4 or key.ndim == 0 else erf_inv
    if inverse is erf_inv and data.size:
        # The float64 erf_inv is more than one CPU loop (its divisions are not recomputed):
        # each uniform is computed once, not its hash in every loop (materialize needs a
        # traced scalar: a word of the key).
        uniforms = materialize(uniforms, data.reshape(-1)[-1].astype(dtype))
    return tuple(_named(np.array(np.sqrt(2), dtype) * inverse(u)) for u in uniforms)


NOISE = "noise"


def _named(eta):
    """eta marked NOISE: a checkpoint whose policy saves that name keeps it for the
    backward pass instead of drawing it again (no value changes)."""
    return checkpoint_name(eta, NOISE)


def _threefry(k1, k2, x1, x2):
    """Threefry-2x32 (Salmon et al. 2011) of counters (x1, x2) under key (k1, k2), uint32."""
    return threefry2x32(*jnp.broadcast_arrays(k1, k2, x1, x2))


def _uniform_from_bits(words, dtype):
    """jax.random.normal's map from one element's Threefry output to a uniform in dtype:
    random mantissa bits -> uniform on [nextafter(-1, 0), 1) (then sqrt(2) erfinv)."""
    w1, w2 = words
    if dtype.itemsize == 8:
        uint, bits = jnp.uint64, (w1.astype(jnp.uint64) << np.uint64(32)) | w2.astype(jnp.uint64)
    else:
        uint, bits = jnp.uint32, w1 ^ w2
    nbits, nmant = 8 * dtype.itemsize, jnp.finfo(dtype).nmant
    one = np.array(1.0, dtype).view(uint)
    mantissa = jax.lax.shift_right_logical(bits, uint(nbits - nmant)) | one
    floats = jax.lax.bitcast_convert_type(mantissa, dtype) - np.array(1.0, dtype)
    lo, hi = np.nextafter(np.array(-1.0, dtype), np.array(0.0, dtype)), np.array(1.0, dtype)
    return jnp.maximum(lo, floats * (hi - lo) + lo)


def no_disturbance(dtype=float) -> SinusoidPlusNoise:
    zero = jnp.zeros((), dtype)
    return SinusoidPlusNoise(zero, zero, zero)
