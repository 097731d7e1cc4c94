"""Tests run in float64 with strict dtype promotion (no silent float32 <-> float64 mixing)."""

import jax

from so3jax import configure_xla

configure_xla()  # the so3jax command's XLA:CPU settings, before JAX's first computation
jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
