"""Layer 8: every figure and line style: the controllers' colours by name
(:mod:`~so3jax.viz.styles`) and each result's matplotlib figures.

May import core … missions (docs/architecture.md, "Layers")."""
