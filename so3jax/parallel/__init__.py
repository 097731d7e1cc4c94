"""Layer 6: the one device strategy: how a batch is split over devices and cores
(:mod:`~so3jax.parallel.devices`), over several processes (:mod:`~so3jax.parallel.distributed`),
and the XLA:CPU settings applied before JAX starts (:mod:`~so3jax.parallel.xla_flags`).

May import core … results (docs/architecture.md, "Layers")."""
