"""Layer 7: mission files: the one TOML parser (:mod:`~so3jax.missions.config`), the keys and
their domains (:mod:`~so3jax.missions.keys`), the validated :class:`~so3jax.missions.mission.Mission`,
the one mission → scenario builder (:mod:`~so3jax.missions.build`), gain schedules,
dispersions drawn (:mod:`~so3jax.missions.draw`, from the distributions of
:mod:`~so3jax.missions.distributions`), then applied to a batch of missions
(:mod:`~so3jax.missions.batched`), and the JSON Schema of a mission file generated from the
keys (:mod:`~so3jax.missions.schema`).

May import core … parallel (docs/architecture.md, "Layers")."""
