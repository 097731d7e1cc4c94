"""Layer 1: the physics without a loop: the rigid body and inertia profiles (:mod:`~so3jax.dynamics.plant`,
:mod:`~so3jax.dynamics.inertia_timelines`), references, disturbances, the orbit and the space
environment's torques, and the :class:`~so3jax.dynamics.scenario.Scenario` a rollout flies.

May import core only (docs/architecture.md, "Layers")."""
