"""Layer 5: results on disk: atomic writes, JSON and units (:mod:`~so3jax.results.io`,
:mod:`~so3jax.results.units`) and output folders with their lock, manifest, resume and the one
fingerprint (:mod:`~so3jax.results.runfolder`).

May import core … sim (docs/architecture.md, "Layers")."""
