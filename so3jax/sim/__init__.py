"""Layer 4: the closed loop and what is read from it: the wiring of one tick and one step
(:mod:`~so3jax.sim.loop`), the scan over a mission (:mod:`~so3jax.sim.rollout`), the metrics,
flight metrics, pointing errors and requirements, stability margins and batched gradients.

May import core, dynamics, components and controllers (docs/architecture.md, "Layers")."""
