"""The one device strategy of every command: where rollouts run.

The devices are the ones JAX sees: on a CPU, one host device per core
(:func:`so3jax.configure_xla`, which the command line calls), over several processes
every process's (:mod:`so3jax.parallel.distributed`). Two rules place the work on them:

* A batch of rollouts is split along its leading axis over a :class:`Mesh` of devices
  (:func:`split`, ``jax.shard_map``): each device runs the single-device program on its
  shard, and nothing crosses devices inside the time loop. A batch is split only over as
  many devices as get at least a minimum shard each (:func:`devices_for`): a smaller
  shard costs more CPU time than it saves. ``tune`` splits its scenario batch this way
  (under ``grad``), ``sweep`` each chunk of samples.
* Programs that do not fill the devices and differ from one another (``paper`` and
  ``fly``: one trajectory per controller) run side by side, each on its own device
  (:func:`side_by_side`), so that their compilations and runs overlap.

Inside one device, the batched rollout runs in cache-sized sub-batches
(:data:`so3jax.sim.rollout.CPU_SUB_BATCH`), part of the single-device program.
"""

from __future__ import annotations

import concurrent.futures
from collections.abc import Callable, Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

BATCH = "batch"  # the mesh axis a batch is split along


def mesh(devices: Sequence) -> Mesh:
    """A one-axis mesh (``BATCH``) of the given devices."""
    return Mesh(np.array(list(devices)), (BATCH,))


def devices_for(items: int, available: int, min_shard: int) -> int:
    """How many of ``available`` devices a batch of ``items`` is split over: each gets
    at least ``min_shard`` items, and at least one device is used."""
    return max(1, min(available, items // min_shard))


def place(tree, mesh: Mesh | None):
    """Put tree on every device of the mesh, replicated (:func:`split` takes each
    device's shard itself), so that jit sees the same placement at every call and
    compiles once per shape. Over several processes, every process gives the same values
    as host data. ``mesh`` None: tree unchanged (one device)."""
    if mesh is None:
        return tree
    if jax.process_count() > 1:
        tree = jax.tree.map(np.asarray, tree)
    return jax.device_put(tree, NamedSharding(mesh, PartitionSpec()))


def placed_shapes(tree, mesh: Mesh | None):
    """The ``jax.ShapeDtypeStruct`` leaves of ``place(tree, mesh)`` from shapes alone:
    tracing a jitted function on them traces the program its calls on placed values
    then reuse (jit's trace cache)."""
    sharding = None if mesh is None else NamedSharding(mesh, PartitionSpec())
    return jax.tree.map(lambda x: jax.ShapeDtypeStruct(np.shape(x), x.dtype, sharding=sharding), tree)


def split(fn: Callable, mesh: Mesh | None, batched: Sequence[bool]) -> Callable:
    """``fn`` run with its arguments marked in ``batched`` split along their leading axis
    over the devices of ``mesh`` (the others shared), its outputs concatenated along
    theirs: the values of ``fn`` on the whole batch. The batch is padded to a multiple of
    the mesh size by repeating its last item, and the padding is dropped from the result.
    Traceable: call it under jit (once per mesh), grad or vmap. ``mesh`` None: ``fn``.

    ``check_vma=False``: ``fn``'s loop carries start from shared values and become
    per-device; without the check, the gradient of a shared argument sums over devices.
    """
    if mesh is None:
        return fn
    specs = tuple(PartitionSpec(BATCH) if b else PartitionSpec() for b in batched)
    sharded = jax.shard_map(fn, mesh=mesh, in_specs=specs, out_specs=PartitionSpec(BATCH), check_vma=False)

    def run(*args):
        n = jax.tree.leaves([a for a, b in zip(args, batched) if b])[0].shape[0]
        index = jnp.minimum(jnp.arange(-(-n // mesh.size) * mesh.size), n - 1)
        padded = [jax.tree.map(lambda x: x[index], a) if b else a for a, b in zip(args, batched)]
        return jax.tree.map(lambda x: x[:n], sharded(*padded))

    return run


def side_by_side(jobs: Mapping[str, Callable[[], object]], platform: str = "cpu") -> dict:
    """{name: job()} with job i run on device i (mod the count) of ``platform`` as its
    default device, each in its own thread: independent programs compile and run in
    parallel. A job's results are whatever it returns (convert them to NumPy inside it)."""
    devices = jax.devices(platform)

    def run(i, job):
        with jax.default_device(devices[i % len(devices)]):
            return job()

    with concurrent.futures.ThreadPoolExecutor(max(1, len(jobs))) as pool:
        futures = {name: pool.submit(run, i, job) for i, (name, job) in enumerate(jobs.items())}
        return {name: future.result() for name, future in futures.items()}
