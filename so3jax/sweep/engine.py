"""Running a sweep: each sample's mission, the batched single-device executables, a
chunk split into one shard per device, and the chunk loop (run_sweep)."""

from __future__ import annotations

import functools
import operator
import shutil
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec, SingleDeviceSharding

from so3jax import dispersed, distributed, runfolder
from so3jax import dispersions as disp
from so3jax.io import save_npz
from so3jax.metrics import Metrics
from so3jax.rollout import rollout, rollout_batch
from so3jax.scenario import steps_for_horizon
from so3jax.sweep.config import SweepConfig, config_to_dict
from so3jax.sweep.storage import _chunk_path, _prepare_out, _take, load_chunks, write_outputs
from so3jax.sweep.summary import summarize

BATCH = "batch"
MIN_SHARD = 8  # samples per device and batch, at least
LAYOUTS = ("chunks", "mesh")  # how several processes share a sweep (run_sweep)


_MISSIONS: dict = {}  # fingerprint -> Mission: the static key that names a mission to simulate_batch


def mission_key(mission) -> str:
    """A hashable name of the mission (its fingerprint), for simulate_batch's ``mission``."""
    key = runfolder.fingerprint(mission.describe())
    _MISSIONS[key] = mission
    return key


@functools.partial(jax.jit, static_argnames=("controller", "mission"))
def simulate_batch(inputs, gains, *, controller: str, mission: str) -> Metrics:
    """Metrics of a batch of samples: inputs = (RolloutParams, {dispersed component
    parameter: values}), leading batch axis. Their scenarios share the mission's loop and
    run natively batched (:func:`so3jax.rollout.rollout_batch`, the values of a vmap of
    rollouts); with dispersed component parameters, each sample's loop is its own (a vmap
    of rollouts)."""
    params, leaves = inputs
    m = _MISSIONS[mission]
    law, dtype = m.controller(controller)[0], params.J0.dtype
    scenarios = jax.vmap(lambda p: dispersed.scenario(m, p))(params)
    n = scenarios.n_steps
    if not leaves:
        return rollout_batch(scenarios, law, gains, params.seed, loop=m.loop(dtype), record_every=n).metrics

    def one(scenario, seed, values):
        return rollout(scenario, law, gains, seed, loop=dispersed.loop(m, values, dtype), record_every=n).metrics

    return jax.vmap(one)(scenarios, params.seed, leaves)


def batch_mesh() -> Mesh:
    """A Mesh of every device JAX sees (all processes), over the batch axis."""
    return Mesh(np.array(jax.devices()), (BATCH,))


def padded_chunk(chunk: int, n_devices: int) -> int:
    """Samples per chunk: a multiple of the device count, at least MIN_SHARD per device."""
    return n_devices * max(MIN_SHARD, -(-chunk // n_devices))


_EXECUTABLES: dict = {}  # (controller, mission, device, argument shapes) -> compiled simulate_batch


def _executables(controller: str, mission: str, devices, args) -> list:
    """simulate_batch compiled for each device (args: one shard's (inputs, gains), arrays);
    the missing ones are lowered one by one and compiled in parallel."""
    signature = tuple((x.shape, x.dtype) for x in jax.tree.leaves(args))
    keys = [(controller, mission, device, signature) for device in devices]
    missing = list(dict.fromkeys(key for key in keys if key not in _EXECUTABLES))
    if missing:

        def lower(device):
            spec = lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=SingleDeviceSharding(device))
            return simulate_batch.lower(*jax.tree.map(spec, args), controller=controller, mission=mission)

        lowered = [lower(key[2]) for key in missing]
        with ThreadPoolExecutor(len(lowered)) as pool:
            _EXECUTABLES.update(zip(missing, pool.map(lambda low: low.compile(), lowered)))
    return [_EXECUTABLES[key] for key in keys]


def _run_shards(shards: list, gains, controller: str, mission: str, devices) -> list:
    """Metrics of each shard (equal sizes), shard j on devices[j]; dispatched before any is read."""
    executables = _executables(controller, mission, devices, (shards[0], gains))
    return [f(*jax.device_put((shard, gains), device)) for f, shard, device in zip(executables, shards, devices)]


def run_chunk(inputs, gains, controller: str, mission: str, mesh: Mesh, layout: str = "chunks") -> dict:
    """Metrics (numpy) of a chunk whose size is a multiple of the mesh size, in mesh.size
    equal shards, each run by ``simulate_batch`` on one device: the same shard programs, so
    the same bits, whichever devices run them. Layout "chunks": this process runs every
    shard on its own devices in turn. Layout "mesh": each process runs the shards of its
    devices in the mesh, and the processes exchange their results. inputs: (RolloutParams,
    dispersed component values), see :func:`simulate_batch`."""
    n = len(inputs[0].seed)
    if layout == "mesh" and jax.process_count() > 1:
        from jax.experimental import multihost_utils

        sharding = NamedSharding(mesh, PartitionSpec(BATCH))
        index_map = sharding.addressable_devices_indices_map((n,))
        shards = [jax.tree.map(operator.itemgetter(index), inputs) for index in index_map.values()]
        outputs = _run_shards(shards, gains, controller, mission, list(index_map))
        out = jax.tree.map(
            lambda *parts: jax.make_array_from_single_device_arrays((n,) + parts[0].shape[1:], sharding, list(parts)),
            *outputs,
        )
        out = multihost_utils.process_allgather(out, tiled=True)
        return {k: np.asarray(v) for k, v in out._asdict().items()}
    size, local = n // mesh.size, jax.local_devices()
    shards = [jax.tree.map(lambda x: x[j * size : (j + 1) * size], inputs) for j in range(mesh.size)]
    outputs = _run_shards(shards, gains, controller, mission, [local[j % len(local)] for j in range(mesh.size)])
    return {k: np.concatenate([np.asarray(getattr(o, k)) for o in outputs]) for k in Metrics._fields}


def run_sweep(
    config: SweepConfig, out: Path, *, resume: bool = False, progress: bool | None = None, max_memory: int | None = None,
    layout: str = "chunks",
) -> dict:
    """Run (or finish, with resume) a sweep; write the output folder; return the summary.
    ``max_memory`` [bytes] (default: the memory available) bounds the run's estimate.
    Over several processes, ``layout`` "chunks" gives each process whole chunks (the next
    unclaimed one whenever it is free) and "mesh" runs every chunk over all processes'
    devices; both write the same files (see :func:`run_chunk`)."""
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {', '.join(LAYOUTS)}, got {layout!r}")
    settings = dict(config_to_dict(config), mission=config.mission.describe())
    with runfolder.claim(out, "sweep", settings, resume=resume, lock=distributed.writer()) as run:
        if jax.process_count() > 1:
            run.start()  # the folder every process must see (distributed.check_shared)
        return _run_sweep(config, run.out, resume, progress, max_memory, layout)


def memory_needed(config: SweepConfig, inputs, chunk: int) -> int:
    """Bytes a sweep holds at its peak: one chunk's inputs and outputs, and the results table."""
    from so3jax import memory

    dtype = jnp.result_type(float)
    first = jax.tree.map(lambda x: x[:1], inputs)
    per_sample, key = 0, mission_key(config.mission)
    for controller in config.controllers:
        gains = jax.tree.map(lambda g: np.asarray(g, dtype), config.gains[controller])
        run = functools.partial(simulate_batch, controller=controller, mission=key)
        per_sample = max(per_sample, memory.outputs(run, first, gains) + memory.nbytes(first))
    table = config.samples * len(config.controllers) * (per_sample + memory.nbytes(first))
    return chunk * per_sample + table


def _run_sweep(config: SweepConfig, out: Path, resume: bool, progress, max_memory, layout: str) -> dict:
    from tqdm import tqdm

    from so3jax import memory

    distributed.check_shared(out)  # every process reads the finished chunks; with layout "chunks", writes its own
    # every check before the first file (sweep.json): a refused sweep writes nothing
    dtype = jnp.result_type(float)
    samples = disp.draw_samples(config.dispersions, config.seed, config.samples, config.max_draws)
    leaves, in_domain = dispersed.draw_leaves(config.leaves, config.seed, config.samples)
    samples = samples._replace(valid=samples.valid & in_domain, leaves=leaves)
    as_dtype = lambda x: x.astype(dtype) if x.dtype.kind == "f" else x
    inputs = (jax.tree.map(as_dtype, samples.params), {k: as_dtype(v) for k, v in leaves.items()})
    key = mission_key(config.mission)
    valid = np.flatnonzero(samples.valid)
    n_steps = steps_for_horizon(config.T, config.dt)
    mesh = batch_mesh()
    chunk = padded_chunk(config.chunk, mesh.size)
    budget = memory.check(memory_needed(config, inputs, chunk), max_memory, f"--chunk {chunk} of {config.samples} samples",
                          "lower --chunk or --samples")
    fingerprint = _prepare_out(out, config, resume)
    processes = jax.process_count()
    share = processes > 1 and layout == "chunks"  # processes take whole chunks, claiming each
    claims = out / "chunks" / ".claims"  # a file per chunk a process has taken
    if distributed.writer():
        shutil.rmtree(claims, ignore_errors=True)  # an interrupted run's claims: its unfinished chunks are free
        if share:
            claims.mkdir(parents=True)
    distributed.barrier("sweep: output folder checked")
    done = load_chunks(out, config.controllers, config.samples, fingerprint)
    jobs = []  # (controller, sample indices) of every chunk left, in one order for every process
    for controller in config.controllers:
        todo = valid[~done[controller]["done"][valid]] if controller in done else valid
        jobs += [(controller, todo[first : first + chunk]) for first in range(0, len(todo), chunk)]
    total = len(valid) * len(config.controllers)
    held = total - sum(len(index) for _, index in jobs)  # samples whose chunks OUT already holds
    bar = tqdm(
        total=total,
        initial=held,
        unit="sample",
        desc=f"sweep, process 0 of {processes}" if share else "sweep",
        disable=not distributed.writer() or (None if progress is None else not progress),
        dynamic_ncols=True,
    )
    start = time.perf_counter()
    with bar:
        for controller, index in jobs:
            if share and not _take(claims, controller, int(index[0])):
                continue  # another process computes it
            gains = jax.tree.map(lambda g: np.asarray(g, dtype), config.gains[controller])
            padded = np.concatenate([index, np.full(chunk - len(index), index[-1])])
            chunk_inputs = jax.tree.map(operator.itemgetter(padded), inputs)
            with distributed.collective(f"{controller} samples {index[0]}-{index[-1]}"):
                metrics = run_chunk(chunk_inputs, gains, controller, key, mesh, layout)
            if distributed.writer() or share:
                save_npz(_chunk_path(out, controller, int(index[0])), fingerprint=np.array(fingerprint), index=index, **{k: v[: len(index)] for k, v in metrics.items()})
            if share:  # count every process's saved chunks
                saved = {path.name for path in (out / "chunks").glob("*.npz")}
                bar.n = total - sum(len(i) for c, i in jobs if _chunk_path(out, c, int(i[0])).name not in saved)
            else:
                bar.n += len(index)
            rate = (bar.n - held) / (time.perf_counter() - start)
            bar.set_postfix_str(f"{controller}, {rate * n_steps / 1e6:.3g} M steps/s", refresh=False)
            bar.refresh()
    distributed.barrier("sweep: waiting for every process's chunks")
    wall, computed = time.perf_counter() - start, sum(len(index) for _, index in jobs)
    if share and distributed.writer():
        shutil.rmtree(claims, ignore_errors=True)
    results = load_chunks(out, config.controllers, config.samples, fingerprint)
    summary = summarize(config, samples, results)
    summary["run"] = {
        "devices": mesh.size,
        "processes": processes,
        "layout": layout,
        "chunk": chunk,
        "memory": budget,
        "computed_samples": computed,
        "wall_s": wall,
        "samples_per_s": computed / wall if computed else None,
        "trajectory_steps_per_s": computed * n_steps / wall if computed else None,
    }
    if distributed.writer():
        write_outputs(out, config, samples, results, summary)
    return summary
