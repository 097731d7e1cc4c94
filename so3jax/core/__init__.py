"""Layer 0: the arithmetic everything rests on: SO(3) (:mod:`~so3jax.core.so3`), the RK4 step
on SO(3) (:mod:`~so3jax.core.integrate`), ``pytree_dataclass``, the checks of user input
(:mod:`~so3jax.core.checks`), the one schema primitive ``Param`` and the table reader
(:mod:`~so3jax.core.tables`), a loop's carry seeded with the tangents its derivative reaches
(:mod:`~so3jax.core.tangents`), helpers traced once and inlined
(:mod:`~so3jax.core.inline`); the underscore modules are its private numerics.

Imports nothing of so3jax (docs/architecture.md, "Layers")."""
