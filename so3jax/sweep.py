"""``so3jax sweep``: Monte Carlo robustness sweeps of the paper's mission.

Samples (:mod:`so3jax.dispersions`) run with every chosen controller, so results pair
sample by sample. Rollouts run in chunks; each chunk is split into one shard per device
JAX sees (every process's), and each shard runs the same single-device executable (a
natively batched rollout, :func:`so3jax.rollout.rollout_batch`), rather than one
SPMD-partitioned program. Over several processes, each takes whole chunks as it becomes
free (a claim file per chunk in the shared output folder) and runs their shards on its
own devices; with ``--layout mesh`` every chunk runs over all processes' devices at once.
Results are reproducible bit for bit for a given chunk size and total device count,
whatever the number of processes or the layout (so a resumed sweep equals an
uninterrupted one); another chunking
changes them at round-off only (~1e-15 relative, tested): the batched step is vectorized
across the shard, and how XLA vectorizes depends on the shard's size. A shard holds at
least 8 samples.
A rollout keeps no history (record_every = N): about 2 kB of device memory per sample,
so the chunk size sets progress and resume granularity rather than memory. Finished
chunks are saved at once under ``OUT/chunks``; an interrupted sweep resumes
(``--resume``) without recomputing them, and resuming with more --samples extends it.

Output folder: samples.csv / samples.npz (parameters and metrics per sample),
summary.json and summary.md (statistics, diverged samples, paired comparison),
cdf.png, histograms.png, rmse_vs_inertia_scale.png.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import functools
import io
import math
import operator
import os
import re
import shutil
import sys
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec, SingleDeviceSharding

from so3jax import config as cfg
from so3jax import dispersions as disp
from so3jax import distributed
from so3jax import runfolder
from so3jax.controllers import registry
from so3jax.io import save_figure, save_npz, write_json, write_text
from so3jax.metrics import Metrics, cell, finite_values, reported
from so3jax.rollout import rollout_batch
from so3jax.scenario import (
    PAPER_J0,
    PAPER_J2,
    InertiaWarning,
    Scenario,
    check_gains,
    paper_scenario,
    steps_for_horizon,
)

CONTROLLERS = {n: (registry.get(n).factory, registry.get(n).gains_type) for n in registry.names(tunable=True)}
PAPER_GAINS = {n: registry.get(n).defaults for n in CONTROLLERS}
PHASE_NAMES = ("capture", "deployment", "detumble")
STAT_NAMES = ("mean", "std", "p50", "p95", "p99", "max")
BATCH = "batch"
MIN_SHARD = 8  # samples per device and batch, at least
LAYOUTS = ("chunks", "mesh")  # how several processes share a sweep (run_sweep)

# The default sweep (sweeps/default.toml); a config file's missing entries take these values.
DEFAULT_DISPERSIONS = disp.Dispersions(
    J0=disp.InertiaDispersion(
        nominal=PAPER_J0,
        scale=disp.LogNormal(1.0, 0.1),
        axis_scale=disp.Uniform(0.9, 1.1),
        rotation_deg=10.0,
        products=disp.Normal(0.0, 10.0),
    ),
    J1=disp.InertiaDispersion(scale=disp.Uniform(1.8, 2.2), products=disp.Normal(0.0, 10.0)),
    J2=disp.InertiaDispersion(
        nominal=PAPER_J2,
        scale=disp.LogNormal(1.0, 0.1),
        axis_scale=disp.Uniform(0.9, 1.1),
        rotation_deg=10.0,
        products=disp.Normal(0.0, 20.0),
    ),
    tau_J=disp.Uniform(200.0, 400.0),
    n=disp.Uniform(1.0381e-3, 1.1314e-3),
    amplitude=disp.Uniform(0.05, 0.15),
    noise_std=disp.Uniform(0.0125, 0.0375),
    initial_angle_deg=30.0,
    initial_rate=disp.Uniform(0.0, 0.005),
)


# --- configuration ----------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class SweepConfig:
    """A sweep: samples 0 .. samples-1 of ``dispersions`` (seed ``seed``), horizon T [s],
    step dt [s], with each of ``controllers`` at ``gains``. Defaults: sweeps/default.toml.

    chunk: samples per batch (at least 8 per device, a multiple of the device count);
    max_draws: attempts at a positive definite sample before it is rejected; a sample
    diverged when its state is non-finite or its attitude error exceeds
    divergence_angle_deg [deg].
    """

    samples: int = 1024
    seed: int = 0
    T: float = 4000.0
    dt: float = 0.01
    controllers: tuple = ("pd", "adaptive")
    chunk: int = 128
    max_draws: int = 20
    divergence_angle_deg: float = 150.0
    gains: dict = dataclasses.field(default_factory=lambda: dict(PAPER_GAINS))
    dispersions: disp.Dispersions = DEFAULT_DISPERSIONS


_TOP_KEYS = ("samples", "seed", "T", "dt", "controllers", "chunk", "max_draws", "divergence_angle_deg")
_TABLES = ("inertia", "deployment", "orbit", "disturbance", "initial", "gains")


def _inertia(t: dict, where: str, default: disp.InertiaDispersion) -> disp.InertiaDispersion:
    fields = {}
    if "nominal" in t:
        if default.nominal is None:
            raise ValueError(f"[{where}] takes no nominal: J1's nominal is the sample's J0 (scale is the growth J1/J0)")
        nominal = cfg.array(t["nominal"], f"{where}.nominal (a 3x3 matrix)", (3, 3))
        fields["nominal"] = tuple(map(tuple, nominal.tolist()))
    for name in ("scale", "axis_scale", "products"):
        if name in t:
            fields[name] = _distribution(t[name], f"{where}.{name}")
    if "rotation_deg" in t:
        fields["rotation_deg"] = cfg.number(t["rotation_deg"], f"{where}.rotation_deg", low=0.0, high=180.0)
    return dataclasses.replace(default, **fields)


def _distribution(value, where: str) -> disp.Distribution:
    """disp.parse_distribution, after checking that a table's ``dist`` is a name (a string)."""
    if isinstance(value, dict) and "dist" in value and not isinstance(value["dist"], str):
        cfg.choice(value["dist"], f"{where}.dist", tuple(disp.DISTRIBUTIONS))
    return disp.parse_distribution(value, where)


def config_from_dict(d: dict) -> SweepConfig:
    """A SweepConfig from the TOML structure (see sweeps/default.toml); ValueError on bad input."""
    if not isinstance(d, dict):
        raise ValueError(f"a sweep config must be a table, got {cfg.short(d)}")  # noqa: TRY004 (bad input)
    unknown = set(d) - set(_TOP_KEYS) - set(_TABLES)
    if unknown:
        raise ValueError(f"unknown config key(s): {', '.join(sorted(unknown))}")
    base = SweepConfig()
    top = {}
    for key in ("samples", "chunk", "max_draws"):
        if key in d:
            top[key] = cfg.number(d[key], key, low=1, integer=True)
    if "seed" in d:
        top["seed"] = cfg.number(d["seed"], "seed", low=0, high=2**32 - 1, integer=True)
    for key in ("T", "dt"):
        if key in d:
            top[key] = cfg.number(d[key], key, low=0.0)
    if "divergence_angle_deg" in d:
        top["divergence_angle_deg"] = cfg.number(d["divergence_angle_deg"], "divergence_angle_deg", 0.0, 180.0)
    if "controllers" in d:
        top["controllers"] = cfg.names(d["controllers"], "controllers", tuple(CONTROLLERS))
    config = dataclasses.replace(base, **top)
    steps_for_horizon(config.T, config.dt)

    inertia = cfg.table(d, "inertia", ("J0", "J1", "J2"), "")
    inertia_keys = ("nominal", "scale", "axis_scale", "rotation_deg", "products")
    base_d = base.dispersions
    fields = {
        name: _inertia(cfg.table(inertia, name, inertia_keys, "inertia."), f"inertia.{name}", getattr(base_d, name))
        for name in ("J0", "J1", "J2")
    }
    for table, keys in (("deployment", ("tau_J",)), ("orbit", ("n",)), ("disturbance", ("amplitude", "frequency", "noise_std"))):
        t = cfg.table(d, table, keys + (("seed",) if table == "disturbance" else ()), "")
        fields.update({k: _distribution(t[k], f"{table}.{k}") for k in keys if k in t})
    seed = cfg.table(d, "disturbance", ("seed", "amplitude", "frequency", "noise_std"), "").get("seed", "random")
    if seed != "random":
        fields["disturbance_seed"] = cfg.number(seed, "disturbance.seed ('random' or a seed)", 0, 2**31 - 1, integer=True)
    initial = cfg.table(d, "initial", ("max_angle_deg", "rate"), "")
    if "max_angle_deg" in initial:
        fields["initial_angle_deg"] = cfg.number(initial["max_angle_deg"], "initial.max_angle_deg", 0.0, 180.0)
    if "rate" in initial:
        fields["initial_rate"] = _distribution(initial["rate"], "initial.rate")
    dispersions = dataclasses.replace(base_d, **fields)
    if not dispersions.initial_angle_deg < config.divergence_angle_deg:
        raise ValueError(
            f"divergence_angle_deg ({config.divergence_angle_deg}) must exceed initial.max_angle_deg "
            f"({dispersions.initial_angle_deg}), or every large initial error would count as diverged"
        )

    gains = dict(base.gains)
    gain_tables = cfg.table(d, "gains", tuple(CONTROLLERS), "")
    for name, t in gain_tables.items():
        spec = registry.get(name)
        gains[name] = cfg.gains(t, gains[name], spec.gain_shapes(), f"gains.{name}")
    for name, g in gains.items():
        try:
            check_gains(g)
        except (TypeError, ValueError) as err:
            raise ValueError(f"[gains.{name}]: {err}") from None
    disp.check(dispersions)
    return dataclasses.replace(config, gains=gains, dispersions=dispersions)


def config_to_dict(config: SweepConfig) -> dict:
    """The TOML structure of a config (config_from_dict inverts it)."""
    d = {k: getattr(config, k) for k in _TOP_KEYS}
    d["controllers"] = list(config.controllers)
    ds = config.dispersions

    def inertia(x: disp.InertiaDispersion) -> dict:
        t = {} if x.nominal is None else {"nominal": [list(r) for r in x.nominal]}
        t.update(scale=disp.describe(x.scale), axis_scale=disp.describe(x.axis_scale), rotation_deg=x.rotation_deg)
        t["products"] = disp.describe(x.products)
        return t

    d["inertia"] = {name: inertia(getattr(ds, name)) for name in ("J0", "J1", "J2")}
    d["deployment"] = {"tau_J": disp.describe(ds.tau_J)}
    d["orbit"] = {"n": disp.describe(ds.n)}
    d["disturbance"] = {
        "seed": "random" if ds.disturbance_seed is None else ds.disturbance_seed,
        **{k: disp.describe(getattr(ds, k)) for k in ("amplitude", "frequency", "noise_std")},
    }
    d["initial"] = {"max_angle_deg": ds.initial_angle_deg, "rate": disp.describe(ds.initial_rate)}
    d["gains"] = {name: {k: np.asarray(v).tolist() for k, v in g._asdict().items()} for name, g in config.gains.items()}
    return d


def load_config(path: Path | None = None, overrides: tuple = ()) -> SweepConfig:
    """Config from a TOML file (or the defaults), then ``KEY=VALUE`` overrides (dotted keys)."""
    d = cfg.load(path, overrides)
    return config_from_dict(d)


# --- running ----------------------------------------------------------------------------


def mission(p: disp.RolloutParams, T: float, dt: float) -> Scenario:
    """The paper's mission (SPEC 4) with one sample's parameters; traceable (vmap)."""
    scenario = paper_scenario(
        T,
        dt,
        tau_J=p.tau_J,
        n=p.n,
        J0=p.J0,
        J1=p.J1,
        J2=p.J2,
        disturbance_amplitude=p.amplitude,
        disturbance_frequency=p.frequency,
        noise_std=p.noise_std,
        dtype=p.J0.dtype,
    )
    return dataclasses.replace(scenario, R0=p.R0, Omega0=p.Omega0)


@functools.partial(jax.jit, static_argnames=("controller", "T", "dt"))
def simulate_batch(params: disp.RolloutParams, gains, *, controller: str, T: float, dt: float) -> Metrics:
    """Metrics of a batch of samples (leading axis): their missions, natively batched
    (:func:`so3jax.rollout.rollout_batch`, the values of a vmap of rollouts)."""
    law = CONTROLLERS[controller][0]()
    scenarios = jax.vmap(lambda p: mission(p, T, dt))(params)
    return rollout_batch(scenarios, law, gains, params.seed, record_every=scenarios.n_steps).metrics


def batch_mesh() -> Mesh:
    """A Mesh of every device JAX sees (all processes), over the batch axis."""
    return Mesh(np.array(jax.devices()), (BATCH,))


def padded_chunk(chunk: int, n_devices: int) -> int:
    """Samples per chunk: a multiple of the device count, at least MIN_SHARD per device."""
    return n_devices * max(MIN_SHARD, -(-chunk // n_devices))


_EXECUTABLES: dict = {}  # (controller, T, dt, device, argument shapes) -> compiled simulate_batch


def _executables(controller: str, T: float, dt: float, devices, args) -> list:
    """simulate_batch compiled for each device (args: one shard's (params, gains), arrays);
    the missing ones are lowered one by one and compiled in parallel."""
    signature = tuple((x.shape, x.dtype) for x in jax.tree.leaves(args))
    keys = [(controller, T, dt, device, signature) for device in devices]
    missing = list(dict.fromkeys(key for key in keys if key not in _EXECUTABLES))
    if missing:

        def lower(device):
            spec = lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=SingleDeviceSharding(device))
            return simulate_batch.lower(*jax.tree.map(spec, args), controller=controller, T=T, dt=dt)

        lowered = [lower(key[3]) for key in missing]
        with ThreadPoolExecutor(len(lowered)) as pool:
            _EXECUTABLES.update(zip(missing, pool.map(lambda low: low.compile(), lowered)))
    return [_EXECUTABLES[key] for key in keys]


def _run_shards(shards: list, gains, controller: str, T: float, dt: float, devices) -> list:
    """Metrics of each shard (equal sizes), shard j on devices[j]; dispatched before any is read."""
    executables = _executables(controller, T, dt, devices, (shards[0], gains))
    return [f(*jax.device_put((shard, gains), device)) for f, shard, device in zip(executables, shards, devices)]


def run_chunk(params: disp.RolloutParams, gains, controller: str, T: float, dt: float, mesh: Mesh,
              layout: str = "chunks") -> dict:
    """Metrics (numpy) of a chunk whose size is a multiple of the mesh size, in mesh.size
    equal shards, each run by ``simulate_batch`` on one device: the same shard programs, so
    the same bits, whichever devices run them. Layout "chunks": this process runs every
    shard on its own devices in turn. Layout "mesh": each process runs the shards of its
    devices in the mesh, and the processes exchange their results."""
    n = len(params.seed)
    if layout == "mesh" and jax.process_count() > 1:
        from jax.experimental import multihost_utils

        sharding = NamedSharding(mesh, PartitionSpec(BATCH))
        index_map = sharding.addressable_devices_indices_map((n,))
        shards = [jax.tree.map(operator.itemgetter(index), params) for index in index_map.values()]
        outputs = _run_shards(shards, gains, controller, T, dt, list(index_map))
        out = jax.tree.map(
            lambda *parts: jax.make_array_from_single_device_arrays((n,) + parts[0].shape[1:], sharding, list(parts)),
            *outputs,
        )
        out = multihost_utils.process_allgather(out, tiled=True)
        return {k: np.asarray(v) for k, v in out._asdict().items()}
    size, local = n // mesh.size, jax.local_devices()
    shards = [jax.tree.map(lambda x: x[j * size : (j + 1) * size], params) for j in range(mesh.size)]
    outputs = _run_shards(shards, gains, controller, T, dt, [local[j % len(local)] for j in range(mesh.size)])
    return {k: np.concatenate([np.asarray(getattr(o, k)) for o in outputs]) for k in Metrics._fields}


def _take(claims: Path, controller: str, first: int) -> bool:
    """Whether this process takes the chunk (controller, first): the first process to create
    its claim file in the folder ``claims`` does (O_EXCL, atomic on a shared filesystem)."""
    try:
        os.close(os.open(claims / f"{controller}-{first:09d}", os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return False
    return True


def _chunk_path(out: Path, controller: str, first: int) -> Path:
    return out / "chunks" / f"{controller}-{first:09d}.npz"


def load_chunks(out: Path, controllers, n_samples: int, fingerprint: str) -> dict:
    """{controller: {field: array (n_samples, ...)}, plus 'done' (bool)} from OUT/chunks; every
    chunk must carry this sweep's fingerprint."""
    results = {}
    pattern = re.compile(r"(\w+)-(\d{9})\.npz")
    remedy = "delete it and rerun with --resume to recompute it"
    for path in sorted((out / "chunks").glob("*.npz")):
        match = pattern.fullmatch(path.name)
        if not match or match.group(1) not in controllers:
            continue
        try:
            with np.load(path) as f:
                chunk = {key: f[key] for key in ("fingerprint", "index", *Metrics._fields)}
        except Exception as err:  # a truncated or foreign file: zip, pickle or key errors
            raise runfolder.corrupt(path, err, remedy) from None
        if str(chunk["fingerprint"]) != fingerprint:
            raise ValueError(f"{path} belongs to another sweep (fingerprint {chunk['fingerprint']}, this one {fingerprint}); use another --out")
        keep = chunk["index"] < n_samples
        index = chunk["index"][keep]
        r = results.setdefault(match.group(1), {"done": np.zeros(n_samples, bool)})
        for field in Metrics._fields:
            value = chunk[field][keep]
            if field not in r:
                r[field] = np.full((n_samples,) + value.shape[1:], np.nan)
            r[field][index] = value
        r["done"][index] = True
    return results


def _fingerprint(config: SweepConfig) -> dict:
    """What fixes each sample's results (chunk size, controller subset, sample count do not)."""
    d = config_to_dict(config)
    for key in ("chunk", "controllers", "samples"):
        d.pop(key)
    d["precision"] = str(jnp.dtype(jnp.result_type(float)))
    return d


def _prepare_out(out: Path, config: SweepConfig, resume: bool) -> str:
    """Check the run description in OUT/sweep.json against this sweep's; returns its fingerprint."""
    from so3jax.io import to_builtin

    description = to_builtin(_fingerprint(config))
    description["fingerprint"] = runfolder.fingerprint(description)
    stamp = out / "sweep.json"
    has_chunks = any((out / "chunks").glob("*.npz"))
    if resume and stamp.exists():
        import json

        try:
            previous = json.loads(stamp.read_text())
        except (OSError, ValueError) as err:
            raise runfolder.corrupt(stamp, err, "delete the folder or choose another --out") from None
        changed = sorted(k for k in set(previous) | set(description) if k != "fingerprint" and previous.get(k) != description.get(k))
        if changed:
            raise ValueError(f"--resume: {out} holds a sweep with other settings ({', '.join(changed)}); use another --out")
    elif resume and has_chunks:
        raise ValueError(f"--resume: {stamp} is missing, so the chunks in {out} cannot be matched to this sweep; use another --out")
    elif not resume and has_chunks:
        if runfolder.incomplete(out) is None and (out / "summary.json").exists():
            raise ValueError(f"{out} holds a finished sweep; choose another --out, or delete {out} to run it again")
        raise ValueError(f"{out} holds an unfinished sweep: pass --resume to finish it, or choose another --out")
    if distributed.writer():
        write_json(stamp, description)
    return description["fingerprint"]


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
    with runfolder.claim(out, "sweep", config_to_dict(config), resume=resume, lock=distributed.writer()) as run:
        if jax.process_count() > 1:
            run.start()  # the folder every process must see (distributed.check_shared)
        return _run_sweep(config, run.out, resume, progress, max_memory, layout)


def memory_needed(config: SweepConfig, params, chunk: int) -> int:
    """Bytes a sweep holds at its peak: one chunk's inputs and outputs, and the results table."""
    from so3jax import memory

    dtype = jnp.result_type(float)
    first = jax.tree.map(lambda x: x[:1], params)
    per_sample = 0
    for controller in config.controllers:
        gains = jax.tree.map(lambda g: np.asarray(g, dtype), config.gains[controller])
        run = functools.partial(simulate_batch, controller=controller, T=config.T, dt=config.dt)
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
    params = jax.tree.map(lambda x: x.astype(dtype) if x.dtype.kind == "f" else x, samples.params)
    valid = np.flatnonzero(samples.valid)
    n_steps = steps_for_horizon(config.T, config.dt)
    mesh = batch_mesh()
    chunk = padded_chunk(config.chunk, mesh.size)
    budget = memory.check(memory_needed(config, params, chunk), max_memory, f"--chunk {chunk} of {config.samples} samples",
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
            chunk_params = jax.tree.map(operator.itemgetter(padded), params)
            with distributed.collective(f"{controller} samples {index[0]}-{index[-1]}"):
                metrics = run_chunk(chunk_params, gains, controller, config.T, config.dt, mesh, layout)
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


# --- results ----------------------------------------------------------------------------


def _phases(config: SweepConfig) -> list[tuple[int, str]]:
    """(index, name) of the phases the horizon reaches."""
    steps = paper_scenario(config.T, config.dt).steps_per_phase
    return [(p, PHASE_NAMES[p]) for p, k in enumerate(steps) if k > 0]


def diverged(config: SweepConfig, r: dict) -> np.ndarray:
    """Non-finite state, or attitude error beyond divergence_angle_deg (NaN counts as beyond)."""
    active = [p for p, _ in _phases(config)]
    angle = r["max_angle_phase"][:, active].max(axis=1)
    return (r["diverged"] == 1) | ~(angle <= math.radians(config.divergence_angle_deg))


def columns(config: SweepConfig, samples: disp.Samples, results: dict) -> dict:
    """Per-sample table: parameters, then each controller's metrics: NaN where not
    simulated, and every metric NaN where the state became non-finite (``nonfinite``)."""
    p = samples.params
    cols: dict[str, Any] = {
        "index": np.arange(len(p.seed)),
        "status": np.where(samples.valid, "simulated", "rejected"),
        "draws": samples.draws,
        "disturbance_seed": p.seed,
    }
    entries = {"xx": (0, 0), "yy": (1, 1), "zz": (2, 2), "xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}
    for i, name in enumerate(("J0", "J1", "J2")):
        J = getattr(p, name)
        cols[f"{name}_scale"] = samples.scale[:, i]
        cols.update({f"{name}_{e}": J[:, a, b] for e, (a, b) in entries.items()})
    nominal = {name: np.trace(np.asarray(getattr(config.dispersions, name).nominal)) for name in ("J0", "J2")}
    cols["J0_trace_ratio"] = np.trace(p.J0, axis1=1, axis2=2) / nominal["J0"]
    cols["J2_trace_ratio"] = np.trace(p.J2, axis1=1, axis2=2) / nominal["J2"]
    moments = [np.linalg.eigvalsh(getattr(p, name)) for name in ("J0", "J1", "J2")]
    cols["physical"] = np.all([m[:, 0] + m[:, 1] >= m[:, 2] * (1 - 1e-9) for m in moments], axis=0)
    cols.update(tau_J=p.tau_J, n=p.n, amplitude=p.amplitude, frequency=p.frequency, noise_std=p.noise_std)
    cols["initial_angle_deg"] = np.degrees(np.linalg.norm(samples.attitude_error, axis=1))
    cols.update({f"attitude_error_{a}": samples.attitude_error[:, i] for i, a in enumerate("xyz")})
    cols.update({f"Omega0_{a}": p.Omega0[:, i] for i, a in enumerate("xyz")})
    phases = _phases(config)
    n = len(p.seed)
    for c in config.controllers:
        r = results.get(c, {})
        done = r.get("done", np.zeros(n, bool))
        nonfinite = done & (r.get("diverged", np.zeros(n)) == 1)
        for field in Metrics._fields:
            if field == "diverged":
                continue
            value = r.get(field, np.full((n, len(PHASE_NAMES)) if field.endswith("_phase") else n, np.nan))
            value = reported(value, nonfinite)
            if field.endswith("_phase"):
                cols.update({f"{c}_{field.removesuffix('_phase')}_{name}": value[:, i] for i, name in phases})
            else:
                cols[f"{c}_{field}"] = value
        cols[f"{c}_nonfinite"] = np.where(done, r.get("diverged", np.zeros(n)) == 1, np.nan)
        cols[f"{c}_diverged"] = np.where(done, diverged(config, r) if r else False, np.nan)
    return cols


def _stats(x) -> dict:
    """Statistics over the finite values of x (None without any), and their number."""
    x, _ = finite_values(x)
    if not len(x):
        return {**dict.fromkeys(STAT_NAMES), "samples": 0}
    p50, p95, p99 = np.percentile(x, [50, 95, 99])
    return {"mean": x.mean(), "std": x.std(), "p50": p50, "p95": p95, "p99": p99, "max": x.max(), "samples": len(x)}


def _row(cols: dict, i: int) -> dict:
    return {k: (v[i].item() if hasattr(v[i], "item") else v[i]) for k, v in cols.items()}


def summarize(config: SweepConfig, samples: disp.Samples, results: dict) -> dict:
    """Statistics of RMSE [rad/s] and effort [N^2 m^2 s] per controller and phase over the
    samples that did not diverge (each with its number of samples; None where there is
    none); counts and parameters of diverged and rejected samples; paired comparisons (every
    pair of controllers in config order, on the samples where neither diverged)."""
    cols = columns(config, samples, results)
    phases = _phases(config)
    summary: dict[str, Any] = {
        "config": config_to_dict(config),
        "precision": str(jnp.dtype(jnp.result_type(float))),
        "samples": {
            "requested": config.samples,
            "simulated": int(samples.valid.sum()),
            "rejected": int((~samples.valid).sum()),
            "rejected_indices": np.flatnonzero(~samples.valid).tolist(),
            "redraws": int((samples.draws[samples.valid] - 1).sum()),
            "nonphysical_inertia": int((samples.valid & ~cols["physical"]).sum()),
        },
        "controllers": {},
        "paired": {},
    }
    simulated = {c: ~np.isnan(cols[f"{c}_diverged"]) for c in config.controllers}
    bad = {c: cols[f"{c}_diverged"] == 1 for c in config.controllers}
    for c in config.controllers:
        good = simulated[c] & ~bad[c]
        entry = {
            "simulated": int(simulated[c].sum()),
            "diverged": int(bad[c].sum()),
            "nonfinite": int((cols[f"{c}_nonfinite"] == 1).sum()),
            "diverged_samples": [_row(cols, i) for i in np.flatnonzero(bad[c])],
        }
        for metric in ("rmse", "effort"):
            entry[metric] = {"mission": _stats(cols[f"{c}_{metric}"][good])}
            entry[metric].update({name: _stats(cols[f"{c}_{metric}_{name}"][good]) for _, name in phases})
        summary["controllers"][c] = entry
    for j, b in enumerate(config.controllers):
        for a in config.controllers[:j]:
            paired = simulated[a] & simulated[b]
            both = paired & ~bad[a] & ~bad[b]
            pair = {
                "samples": int(both.sum()),
                f"diverged_only_{a}": int((paired & bad[a] & ~bad[b]).sum()),
                f"diverged_only_{b}": int((paired & bad[b] & ~bad[a]).sum()),
            }
            for metric in ("rmse", "effort"):
                x, y = cols[f"{a}_{metric}"][both], cols[f"{b}_{metric}"][both]
                pair[metric] = {
                    f"{b}_better_fraction": float(np.mean(y < x)) if len(x) else None,
                    "relative_change": dict(zip(("mean", "p5", "p50", "p95"), _quantiles((y - x) / x))),
                }
            summary["paired"][f"{b}_vs_{a}"] = pair
    return summary


def _quantiles(x):
    x, _ = finite_values(x)
    if not len(x):
        return (None,) * 4
    return (float(np.mean(x)), *map(float, np.percentile(x, [5, 50, 95])))


def format_summary(summary: dict) -> str:
    """Markdown tables of the summary."""
    lines = []
    s = summary["samples"]
    lines.append(
        f"{s['requested']} samples: {s['simulated']} simulated, {s['rejected']} rejected "
        f"(not positive definite after {summary['config']['max_draws']} draws), {s['redraws']} redraws, "
        f"{s['nonphysical_inertia']} with a non-physical inertia (triangle inequality)"
    )
    for metric, label in (("rmse", "RMSE [rad/s]"), ("effort", "effort [N^2 m^2 s]")):
        lines += ["", f"| {label} | phase | " + " | ".join(STAT_NAMES) + " | samples |",
                  "|---|---|" + "---:|" * (len(STAT_NAMES) + 1)]
        for c, entry in summary["controllers"].items():
            for phase, st in entry[metric].items():
                none = "diverged" if entry["diverged"] else "—"  # no sample left: all diverged, or none simulated
                cells = [none if st[k] is None else cell(st[k], ".4g") for k in STAT_NAMES]
                lines.append(f"| {c} | {phase} | " + " | ".join(cells) + f" | {st.get('samples', '')} |")
    lines += ["", "| controller | simulated | diverged | non-finite |", "|---|---:|---:|---:|"]
    for c, e in summary["controllers"].items():
        lines.append(f"| {c} | {e['simulated']} | {e['diverged']} | {e['nonfinite']} |")
    for name, pair in summary["paired"].items():
        b, a = name.split("_vs_")
        lines.append("")
        lines.append(f"{b} vs {a} on {pair['samples']} paired samples (neither diverged):")
        for metric in ("rmse", "effort"):
            frac = pair[metric][f"{b}_better_fraction"]
            q = pair[metric]["relative_change"]
            if frac is None:
                continue
            lines.append(
                f"- {metric}: {b} lower in {100 * frac:.1f} % of samples; change {b}/{a} - 1: "
                f"median {100 * q['p50']:+.1f} %, 5-95 % [{100 * q['p5']:+.1f} %, {100 * q['p95']:+.1f} %], mean {100 * q['mean']:+.1f} %"
            )
    return "\n".join(lines) + "\n"


def write_csv(path: Path, cols: dict) -> None:
    """One row per sample: an empty cell where a value does not exist (a rejected sample's
    metrics, a controller not simulated), "nan" for a diverged rollout's metrics."""
    flags = sorted((k for k in cols if k.endswith("_nonfinite")), key=len, reverse=True)  # NaN where not simulated
    owner = {k: next((f for f in flags if k.startswith(f.removesuffix("nonfinite"))), None) for k in cols}
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow(cols)
    for i in range(len(cols["index"])):
        row = _row(cols, i)

        def text(key, v):
            if not (isinstance(v, float) and math.isnan(v)):
                return v
            flag = owner[key]
            return "nan" if flag is not None and not math.isnan(row[flag]) else ""

        writer.writerow([text(k, v) for k, v in row.items()])
    write_text(path, buffer.getvalue())


def write_outputs(out: Path, config: SweepConfig, samples: disp.Samples, results: dict, summary: dict) -> None:
    cols = columns(config, samples, results)
    write_csv(out / "samples.csv", cols)
    save_npz(out / "samples.npz", **cols)
    write_json(out / "summary.json", summary)
    write_text(out / "summary.md", format_summary(summary))
    for name, fig in figures(config, cols).items():
        save_figure(fig, out / name)


def _log_if_wide(ax, axis: str, values) -> None:
    """Log scale where the values span more than a decade (else log ticks crowd)."""
    if len(values) and values.min() > 0 and values.max() > 10 * values.min():
        getattr(ax, f"set_{axis}scale")("log")


def figures(config: SweepConfig, cols: dict) -> dict:
    """CDFs and histograms of RMSE and effort per controller; RMSE against inertia scale."""
    from matplotlib.figure import Figure

    from so3jax.controllers.registry import style

    names = config.controllers
    color = {c: {"color": style(c)["color"], "label": style(c)["label"]} for c in names}
    good = {c: cols[f"{c}_diverged"] == 0 for c in names}
    title = f"{len(cols['index'])} samples, T = {config.T:g} s (diverged samples left out)"
    cdf, hist = Figure(figsize=(10, 3.8), layout="constrained"), Figure(figsize=(10, 3.8), layout="constrained")
    for fig, kind in ((cdf, "cdf"), (hist, "hist")):
        axes = fig.subplots(1, 2)
        for ax, (metric, label) in zip(axes, (("rmse", "RMSE [rad/s]"), ("effort", "effort [N$^2$ m$^2$ s]"))):
            values = {c: np.sort(cols[f"{c}_{metric}"][good[c]]) for c in names}
            pooled = np.concatenate(list(values.values()))
            if not len(pooled):
                continue
            _log_if_wide(ax, "x", pooled)
            low, high = pooled.min(), pooled.max()
            bins = np.geomspace(low, high, 40) if ax.get_xscale() == "log" else np.linspace(low, high, 40)
            for c, v in values.items():
                if kind == "cdf":
                    ax.step(v, np.arange(1, len(v) + 1) / max(len(v), 1), where="post", **color[c])
                else:
                    ax.hist(v, bins=bins, histtype="step", **color[c])
            ax.set_xlabel(label)
            ax.set_ylabel("fraction of samples" if kind == "cdf" else "samples")
            ax.grid(alpha=0.3)
            ax.legend()
        fig.suptitle(title)
    panels = [("J0_trace_ratio", "rmse", "capture inertia scale tr(J0)/tr(J0 nominal)", "mission RMSE [rad/s]")]
    if any(name == "detumble" for _, name in _phases(config)):
        panels.append(("J2_trace_ratio", "rmse_detumble", "docked inertia scale tr(J2)/tr(J2 nominal)", "detumble RMSE [rad/s]"))
    scatter = Figure(figsize=(5 * len(panels), 3.8), layout="constrained")
    for ax, (x, y, xlabel, ylabel) in zip(scatter.subplots(1, len(panels), squeeze=False)[0], panels):
        for c in names:
            ax.scatter(cols[x][good[c]], cols[f"{c}_{y}"][good[c]], s=6, alpha=0.6, **color[c])
        _log_if_wide(ax, "y", np.concatenate([cols[f"{c}_{y}"][good[c]] for c in names]))
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        ax.legend()
    scatter.suptitle(title)
    return {"cdf.png": cdf, "histograms.png": hist, "rmse_vs_inertia_scale.png": scatter}


# --- command line -----------------------------------------------------------------------


def register(subparsers) -> None:
    from so3jax.cli import add_memory_argument, add_precision_argument

    p = subparsers.add_parser(
        "sweep",
        help="Monte Carlo robustness sweep of the paper's mission (sharded over all devices)",
        description="Monte Carlo robustness sweep: dispersed missions x controllers, paired by sample.",
    )
    p.add_argument("config", nargs="?", type=Path, help="TOML config (default: the built-in one, = sweeps/default.toml)")
    p.add_argument("--samples", type=int, help="number of samples")
    p.add_argument("--T", type=float, help="horizon [s]")
    p.add_argument("--controllers", help="comma-separated subset of: " + ", ".join(CONTROLLERS))
    p.add_argument("--chunk", type=int, help="samples per batch (at least 8 per device, a multiple of the device count)")
    p.add_argument("--seed", type=int, help="sampling seed")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config entry with a TOML value, e.g. --set 'inertia.J0.scale={dist=\"normal\", mean=1, std=0.1}'",
    )
    p.add_argument("--out", type=Path, default=Path("results/sweep"), help="output folder (default results/sweep)")
    p.add_argument("--resume", action="store_true", help="finish the sweep in --out, keeping its finished chunks")
    group = distributed.add_arguments(p)
    group.add_argument("--layout", choices=LAYOUTS, default="chunks",
                       help="how processes share the sweep: whole chunks per process (default), or each chunk over every process's devices")
    add_memory_argument(p)
    add_precision_argument(p)
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    distributed.initialize(args)
    overrides = list(args.set)
    for key in ("samples", "T", "chunk", "seed"):
        if getattr(args, key) is not None:
            overrides.append(f"{key}={getattr(args, key)}")
    if args.controllers is not None:
        overrides.append("controllers=" + str([c.strip() for c in args.controllers.split(",")]).replace("'", '"'))
    with warnings.catch_warnings():
        warnings.simplefilter("once", InertiaWarning)
        config = load_config(args.config, tuple(overrides))
    from so3jax import memory

    summary = run_sweep(config, args.out, resume=args.resume, max_memory=memory.from_args(args), layout=args.layout)
    if distributed.writer():
        print(format_summary(summary))
        run = summary["run"]
        if run["computed_samples"]:
            print(
                f"{run['computed_samples']} rollouts in {run['wall_s']:.1f} s on {run['devices']} device(s): "
                f"{run['samples_per_s']:.3g} samples/s, {run['trajectory_steps_per_s'] / 1e6:.3g} M trajectory-steps/s "
                f"(compile included); results in {args.out}/",
                file=sys.stderr,
            )
    return 0
