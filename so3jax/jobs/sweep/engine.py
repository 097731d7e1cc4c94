"""Running a sweep: each sample's mission, a chunk of samples split over the devices
(:mod:`so3jax.parallel.devices`), and the chunk loop (run_sweep)."""

from __future__ import annotations

import dataclasses
import functools
import operator
import shutil
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh

from so3jax.dynamics.scenario import steps_for_horizon
from so3jax.jobs.sweep import margins as sweep_margins
from so3jax.jobs.sweep.config import SweepConfig, config_to_dict
from so3jax.jobs.sweep.storage import chunk_path, claim_chunk, load_chunks, prepare_out, write_outputs
from so3jax.jobs.sweep.summary import summarize
from so3jax.missions import batched, draw
from so3jax.missions.draw import MAX_SAMPLES
from so3jax.missions.mission import Mission
from so3jax.parallel import chunks, devices, distributed
from so3jax.results import runfolder
from so3jax.results.io import save_npz
from so3jax.sim import memory

MIN_SHARD = chunks.MIN_SHARD  # samples per device and batch, at least
LAYOUTS = ("chunks", "mesh")  # how several processes share a sweep (run_sweep)


@functools.partial(jax.jit, static_argnames=("controller", "mission", "mesh", "pointing"))
def simulate_batch(inputs, gains, *, controller: str, mission: Mission, mesh: Mesh | None = None,
                   pointing: bool = False) -> dict:
    """:func:`so3jax.missions.batched.sample_metrics` of a batch of samples by controller
    name, the batch split over the devices of ``mesh`` (:func:`so3jax.parallel.devices.split`;
    None: one device): without histories, or with ``pointing`` the attitude errors recorded
    every ``mission.record_every`` steps."""
    every = mission.record_every if pointing else steps_for_horizon(mission.T, mission.dt)  # else no history
    shard = functools.partial(batched.sample_metrics, controller=mission.controller(controller)[0], mission=mission,
                              record_every=every, pointing=pointing)
    return devices.split(shard, mesh, batched=(True, False))(inputs, gains)


def batch_mesh(layout: str = "mesh") -> Mesh:
    """The devices one chunk runs over: every device JAX sees (all processes) with layout
    "mesh", this process's own with layout "chunks" (the same in one process)."""
    return devices.mesh(jax.devices() if layout == "mesh" else jax.local_devices())


def padded_chunk(chunk: int, n_devices: int) -> int:
    """Samples per chunk on the host: a multiple of the device count, at least MIN_SHARD per
    device (:func:`so3jax.parallel.chunks.host_chunk`)."""
    return chunks.host_chunk(chunk, n_devices)


def device_chunk(config: SweepConfig, mesh: Mesh) -> tuple[int, float | None]:
    """(samples per chunk, the bytes a sample was taken to need, None on the host): on the
    host the configured chunk, padded (:func:`padded_chunk`); on an accelerator the largest
    chunk whose samples fit its memory (:func:`so3jax.parallel.chunks.chunk_on`), each
    needing its chunk program's inputs and outputs and :data:`~so3jax.parallel.chunks.WORKING_BYTES`."""
    chunk = padded_chunk(config.chunk, mesh.size)
    if chunks.device_memory(mesh.devices.flat[0]) is None:
        return chunk, None
    per_sample = chunks.WORKING_BYTES + memory_needed(dataclasses.replace(config, samples=0), chunk, mesh) / chunk
    return chunks.chunk_on(mesh.devices.flat, per_sample, config.samples, config.chunk), per_sample


def run_chunk(inputs, gains, controller: str, mission: Mission, mesh: Mesh, pointing: bool = False) -> dict:
    """{metric: values} (numpy) of a chunk whose size is a multiple of the mesh size, split over
    the mesh's devices (:func:`simulate_batch`). Over several processes with a mesh of
    every process's devices, each process runs its devices' shards and the processes
    exchange their results. inputs: (RolloutParams, dispersed component values)."""
    out = simulate_batch(*devices.place((inputs, gains), mesh), controller=controller, mission=mission, mesh=mesh,
                         pointing=pointing)
    if not out["rmse"].is_fully_addressable:  # a mesh of several processes
        out = multihost_utils.process_allgather(out, tiled=True)
    return {k: np.asarray(v) for k, v in out.items()}


def run_sweep(
    config: SweepConfig, out: Path, *, resume: bool = False, progress: bool | None = None,
    max_memory: int | None = None, layout: str = "chunks",
) -> dict:
    """Run (or finish, with resume) a sweep; write the output folder; return the summary.
    ``max_memory`` [bytes] (default: the memory available) bounds the run's estimate.
    Over several processes, ``layout`` "chunks" gives each process whole chunks (the next
    unclaimed one whenever it is free), run over its own devices, and "mesh" runs every
    chunk over all processes' devices. The files are those of one process with as many
    devices as a chunk runs over (:func:`batch_mesh`), bit for bit: each device runs the
    same program on a shard of the same samples."""
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {', '.join(LAYOUTS)}, got {layout!r}")
    mesh = batch_mesh(layout)
    chunk = device_chunk(config, mesh)[0]
    budget = check_size(config, chunk, max_memory, mesh)
    settings = dict(config_to_dict(config), mission=config.mission.describe())
    with runfolder.claim(out, "sweep", settings, resume=resume, lock=distributed.writer()) as run:
        if jax.process_count() > 1:
            run.start()  # the folder every process must see (distributed.check_shared)
        return _run_sweep(config, run.out, resume, progress, layout, mesh, chunk, budget)


def check_size(config: SweepConfig, chunk: int, max_memory: int | None, mesh: Mesh | None = None) -> dict:
    """Refuse (ValueError) a sweep whose samples and chunks need more memory than
    ``max_memory`` [bytes] (None: what is available), before anything is drawn, compiled or
    written (the horizon's step count is the mission loader's check); returns the memory budget."""
    if config.samples > MAX_SAMPLES:
        raise ValueError(f"sweep.samples = {config.samples} is more than the {MAX_SAMPLES} samples a sampling seed "
                         "numbers; lower --samples")
    return memory.check(memory_needed(config, chunk, mesh), max_memory, f"--chunk {chunk} of {config.samples} samples",
                        "lower --chunk or --samples")


def memory_needed(config: SweepConfig, chunk: int, mesh: Mesh | None = None) -> int:
    """Bytes a sweep holds at its peak, from shapes alone (nothing drawn or compiled): the
    drawn samples, one chunk's inputs and outputs, and the results table. Each
    controller's chunk program is traced as the chunks call it (``chunk`` samples placed
    on ``mesh``), so that the chunks reuse this trace."""
    dtype = jnp.result_type(float)
    first = batched.input_shapes(config.leaves, 1, dtype)
    per_sample = 0
    for controller in config.controllers:
        gains = jax.tree.map(lambda g: np.asarray(g, dtype), config.gains[controller])
        args = devices.placed_shapes((batched.input_shapes(config.leaves, chunk, dtype), gains), mesh)
        run = functools.partial(simulate_batch, controller=controller, mission=config.mission, mesh=mesh,
                                pointing=config.pointing)
        per_sample = max(per_sample, -(-memory.outputs(run, *args) // chunk) + memory.nbytes(first))
    table = config.samples * len(config.controllers) * per_sample
    return chunk * per_sample + table + batched.samples_bytes(config.leaves, config.samples, dtype)


def _run_sweep(config: SweepConfig, out: Path, resume: bool, progress, layout: str, mesh: Mesh, chunk: int,
               budget: dict) -> dict:
    from tqdm import tqdm  # here: only a run that shows progress needs it

    distributed.check_shared(out)  # every process reads the finished chunks; with layout "chunks", writes its own
    # every check before the first file (sweep.json): a refused sweep writes nothing
    dtype = jnp.result_type(float)
    samples = draw.draw(config.dispersions, config.leaves, config.seed, config.samples, config.max_draws,
                        mission=config.mission)
    inputs = batched.inputs(samples, dtype)
    valid = np.flatnonzero(samples.valid)
    if not len(valid):
        reasons = "; ".join(f"{n} for {why}" for why, n in draw.rejections(samples).items())
        raise ValueError(f"[dispersions]: every one of the {config.samples} samples is rejected ({reasons}): "
                         "narrow the dispersions")
    n_steps = steps_for_horizon(config.T, config.dt)
    fingerprint = prepare_out(out, config, resume)
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

    def compute(controller, index):
        gains = jax.tree.map(lambda g: np.asarray(g, dtype), config.gains[controller])
        padded = np.concatenate([index, np.full(chunk - len(index), index[-1])])
        chunk_inputs = jax.tree.map(operator.itemgetter(padded), inputs)
        metrics = run_chunk(chunk_inputs, gains, controller, config.mission, mesh, config.pointing)
        if config.margins_at:
            law = config.mission.controller(controller)[0]
            values = sweep_margins.sample_margins(chunk_inputs, gains, controller=law, mission=config.mission,
                                                  times=config.margins_at)
            metrics.update({f"{sweep_margins.PREFIX}{k}": v for k, v in values.items()})
        return metrics

    # In one process, each controller's first chunk starts at once: their programs compile side by side.
    firsts = {} if processes > 1 else {c: i for i, (c, _) in reversed(list(enumerate(jobs)))}
    pool = ThreadPoolExecutor(max(1, len(firsts)))
    early = {i: pool.submit(compute, *jobs[i]) for i in firsts.values()} if len(firsts) > 1 else {}
    with bar:
        try:
            for i, (controller, index) in enumerate(jobs):
                if share and not claim_chunk(claims, controller, int(index[0])):
                    continue  # another process computes it
                with distributed.collective(f"{controller} samples {index[0]}-{index[-1]}"):
                    metrics = early.pop(i).result() if i in early else compute(controller, index)
                if distributed.writer() or share:
                    save_npz(chunk_path(out, controller, int(index[0])), fingerprint=np.array(fingerprint),
                             index=index, **{k: v[: len(index)] for k, v in metrics.items()})
                if share:  # count every process's saved chunks
                    saved = {path.name for path in (out / "chunks").glob("*.npz")}
                    bar.n = total - sum(len(i) for c, i in jobs if chunk_path(out, c, int(i[0])).name not in saved)
                else:
                    bar.n += len(index)
                rate = (bar.n - held) / (time.perf_counter() - start)
                bar.set_postfix_str(f"{controller}, {rate * n_steps / 1e6:.3g} M steps/s", refresh=False)
                bar.refresh()
        finally:
            pool.shutdown(wait=False, cancel_futures=True)  # an interrupted run does not wait for another first chunk
    distributed.barrier("sweep: waiting for every process's chunks")
    wall, computed = time.perf_counter() - start, sum(len(index) for _, index in jobs)
    if share and distributed.writer():
        shutil.rmtree(claims, ignore_errors=True)
    results = load_chunks(out, config.controllers, config.samples, fingerprint)
    summary = summarize(config, samples, results)
    summary["run"] = {
        "devices": jax.device_count(),
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
