"""Applying drawn values to a batch of missions: each sample's values (a
:class:`~so3jax.missions.draw.Samples` that :func:`so3jax.missions.draw.draw` gives) become
its scenario (:func:`scenario_values`, :func:`so3jax.missions.build.scenario`) and its loop
(:func:`loop`), and the batch flies as one vmap of rollouts (:func:`sample_metrics`, from
:func:`inputs`). The inputs' shapes and bytes (:func:`input_shapes`, :func:`samples_bytes`)
are known from the leaves alone, before anything is drawn; :func:`pointing_errors` reads a
batch's recorded attitudes.

A sample's reference and inertia are built from its values and its loop's components take
its values as their parameters; the estimator keeps the noise levels the mission's nominal
sensors report: the hardware is dispersed, not what the filter assumes.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.core import so3
from so3jax.dynamics.reference import PiecewiseConstantRate
from so3jax.missions import build
from so3jax.missions.draw import FLEXIBLE_TABLES, PARAM_SHAPES, SCENARIO_TABLES, RolloutParams, Samples
from so3jax.missions.mission import Mission, build_loop
from so3jax.sim import memory
from so3jax.sim.rollout import rollout_batch


def scenario_values(mission: Mission, values: dict) -> Mission:
    """The mission with its reference's, inertia's and flexible body's (appendages.I.k, ...)
    dispersed parameters {key: value} replaced (traceable: only
    :func:`so3jax.missions.build.scenario` reads the result); the mission itself without any."""
    if not values:
        return mission
    tables = {}
    for key, value in values.items():
        table, kind, param = key.split(".")
        if table in FLEXIBLE_TABLES:  # an appendage's or slosh particle's spring or damper, [[table]] entry kind
            entries = tables.setdefault(table, [dict(e) for e in getattr(mission, table)])
            entries[int(kind)][param] = value
            continue
        chosen = tables.setdefault(table, {**getattr(mission, table), kind: dict(getattr(mission, table)[kind])})
        if (kind, param) == ("events", "targets"):
            param = "scales" if jnp.ndim(value) == 1 else "matrices"
        chosen[kind][param] = value
    return dataclasses.replace(mission, **{k: tuple(v) if k in FLEXIBLE_TABLES else v for k, v in tables.items()})


def split(values: dict) -> tuple[dict, dict]:
    """({reference, inertia and flexible body leaf: value}, {component leaf: value}) of a
    sample's dispersed values: the first for :func:`scenario_values`, the second for :func:`loop`."""
    own = {k: v for k, v in values.items() if k.split(".")[0] in SCENARIO_TABLES + FLEXIBLE_TABLES}
    return own, {k: v for k, v in values.items() if k not in own}


def inputs(samples: Samples, dtype) -> tuple:
    """(RolloutParams, {leaf: values}) of the samples, reals in dtype: :func:`sample_metrics`' inputs."""
    as_dtype = lambda x: x.astype(dtype) if x.dtype.kind == "f" else x
    return jax.tree.map(as_dtype, samples.params), {k: as_dtype(v) for k, v in samples.leaves.items()}


def input_shapes(leaves: tuple, n_samples: int, dtype) -> tuple:
    """The shapes and dtypes (``jax.ShapeDtypeStruct``) of :func:`inputs` of n_samples
    samples, from the leaves alone: nothing drawn or compiled."""
    def struct(shape, dtype):
        return jax.ShapeDtypeStruct((n_samples, *shape), dtype)

    params = RolloutParams(*(struct(shape, np.int32 if name == "seed" else dtype)
                             for name, shape in zip(RolloutParams._fields, PARAM_SHAPES)))
    return params, {leaf.key: struct(leaf.shape, dtype) for leaf in leaves}


def samples_bytes(leaves: tuple, n_samples: int, dtype) -> int:
    """Bytes n_samples drawn samples hold: their values in float64
    (:func:`so3jax.missions.draw.draw`) and as a run's inputs in ``dtype`` (:func:`inputs`)."""
    return sum(memory.nbytes(input_shapes(leaves, n_samples, d)) for d in (np.float64, dtype))


# --- a sample's scenario and loop ------------------------------------------------------------


def sample_metrics(inputs, gains, *, controller, mission: Mission, record_every: int | None = None,
                   estimator=None, pointing: bool = False, filter=None) -> dict:  # noqa: A002
    """{metric: values} of a batch of samples of ``mission`` (hashable by its fingerprint: a
    static argument of jit) flown by ``controller`` at ``gains``: the docs/model.md §6 metrics, and the
    flight metrics of a sampled loop. inputs = (RolloutParams, {dispersed component
    parameter: values}), leading batch axis. The samples share the mission's loop and run
    natively batched (:func:`so3jax.sim.rollout.rollout_batch`, the values of a vmap of
    rollouts); with dispersed component parameters, each sample flies its own loop (the
    components' parameters with a batch axis). record_every: the rollouts' checkpoint blocks [steps] (reverse-mode
    memory; the horizon's steps: none). estimator: {parameter: value} of the mission's
    estimator that every sample shares (the noise levels the filter assumes, tuned); filter:
    {parameter: value} of the mission's structural filter that every sample shares (tuned).
    pointing: also the attitude errors at the start of every block of ``record_every``
    steps, ``pointing_performance`` e_P and, where the loop estimates the attitude,
    ``pointing_knowledge`` e_K ((batch, M, 3) rad, :func:`pointing_errors`).
    Pure: jit, grad and :func:`so3jax.parallel.devices.split` compose with it."""
    params, leaves = inputs
    m, dtype = mission, params.J0.dtype
    shared = {f"estimator.{m.estimator['kind']}.{k}": v for k, v in (estimator or {}).items()}
    shared.update({f"filter.{m.filter['kind']}.{k}": v for k, v in (filter or {}).items()})
    own, leaves = split(leaves)
    scenarios = jax.vmap(lambda p, v: build.scenario(scenario_values(m, v), p))(params, own)  # own: its own
    dispersed_tables = {k.split(".")[0] for k in own}
    shared_parts = [name for name, shared_part in (
        ("reference", "reference" not in dispersed_tables  # a constant rate depends on the sample's orbit rate
         and not isinstance(scenarios.reference, PiecewiseConstantRate)),
        ("inertia", "inertia" not in dispersed_tables and m.inertia["kind"] != "paper"),  # the paper's: per sample
        # the appendages and slosh: the mission's own, unless their springs or dampers are dispersed
        ("flexible", m.flexible and not dispersed_tables & set(FLEXIBLE_TABLES)),
        ("flexible_initial", m.flexible),
    ) if shared_part]
    axes = 0
    if shared_parts:  # one for the batch: the mission's own
        nominal = build.scenario(m, dtype=dtype)
        scenarios = dataclasses.replace(scenarios, **{name: getattr(nominal, name) for name in shared_parts})
        axes = dataclasses.replace(jax.tree.map(lambda _: 0, scenarios), **dict.fromkeys(shared_parts))
        if m.flexible and "flexible" not in shared_parts:  # (flexible_initial is always shared)
            body, body_axes = _own_springs(nominal.flexible, scenarios.flexible)
            scenarios = dataclasses.replace(scenarios, flexible=body)
            axes = dataclasses.replace(axes, flexible=body_axes)
    if leaves:  # each sample's loop: its components' parameters with a batch axis
        loops, loop_axes = jax.vmap(lambda values: loop(m, {**shared, **values}, dtype))(leaves), 0
    else:
        loops, loop_axes = (loop(m, shared, dtype) if shared else m.loop(dtype)), None
    return _results(rollout_batch(scenarios, controller, gains, params.seed, scenario_axes=axes, loop=loops,
                                  loop_axes=loop_axes, record_every=record_every), pointing)


def _own_springs(nominal, bodies):
    """(body, its vmap axes): the mission's flexible body ``nominal`` with each sample's springs
    and dampers (k, c) from ``bodies`` (batch axis 0), the only leaves a sweep disperses
    (:data:`~so3jax.missions.draw.FLEXIBLE_LEAVES`); the rest shared by the batch, so that the
    body's geometry is computed once per stage, not per sample."""
    def with_springs(body, source):  # body with the k and c of source's panels and particles
        swap = lambda parts, own: tuple(dataclasses.replace(x, k=y.k, c=y.c) for x, y in zip(parts, own))
        return dataclasses.replace(body, panels=swap(body.panels, source.panels), slosh=swap(body.slosh, source.slosh))

    return with_springs(nominal, bodies), with_springs(jax.tree.map(lambda _: None, nominal),
                                                       jax.tree.map(lambda _: 0, nominal))


def _results(result, pointing: bool = False) -> dict:
    """A rollout's docs/model.md §6 metrics and, in the sampled wiring, its flight metrics, by
    name; with ``pointing``, its recorded attitude errors (:func:`pointing_errors`)."""
    flight = {} if result.flight is None else result.flight._asdict()
    return {**result.metrics._asdict(), **flight, **(pointing_errors(result.history) if pointing else {})}


def pointing_errors(history) -> dict:
    """{"pointing_performance": e_P, "pointing_knowledge": e_K (where the history holds an
    estimate)}: log(R_ref^T R)^vee [rad] of the recorded attitudes R (M, 3, 3) against R_d and
    R_hat, (..., M, 3) of records (..., M, 3, 3), in the run's precision (the signals of
    :mod:`so3jax.sim.pointing`)."""
    def error(R_ref):
        R_e = jnp.einsum("...mji,...mjk->ik...m", R_ref, history.R)  # R_ref^T R, (3, 3, ..., M)
        return jnp.moveaxis(so3.log(R_e, select=True), 0, -1)

    out = {"pointing_performance": error(history.R_d)}
    if history.R_hat is not None:
        out["pointing_knowledge"] = error(history.R_hat)
    return out


def loop(mission: Mission, values: dict, dtype):
    """The mission's loop with component and fault leaves {key: value} replaced (traceable);
    the estimator assumes the nominal sensors' noise levels."""
    faults = [dict(f) for f in mission.faults]
    tables = {"sensors": {k: dict(v) for k, v in mission.sensors.items()},
              **{table: {k: (dict(v) if isinstance(v, dict) else v) for k, v in getattr(mission, table).items()}
                 for table in ("estimator", "actuator", "momentum", "filter")}}
    for key, value in values.items():
        table, name, param = key.split(".")
        if table == "faults":
            faults[int(name)][param] = value
        else:
            tables[table][name][param] = value
    changed = dataclasses.replace(mission, **tables, faults=tuple(faults))
    return build_loop(changed, lambda x: jnp.asarray(x, dtype), noise_of=mission)
