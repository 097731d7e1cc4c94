"""Monte Carlo robustness sweeps of a mission: the job ``so3jax sweep`` (:mod:`so3jax.commands.sweep`) runs.

Samples (:mod:`so3jax.missions.draw`) run with every chosen controller, so results pair
sample by sample. Rollouts run in chunks, each split over the devices one chunk runs
over (:mod:`so3jax.parallel.devices`): every device runs the same program (a natively batched
rollout, :func:`so3jax.sim.rollout.rollout_batch`) on its shard. Over several processes,
each takes whole chunks as it becomes free (a claim file per chunk in the shared output
folder) and runs them over its own devices; with ``--layout mesh`` every chunk runs over
all processes' devices at once. Results are reproducible bit for bit for a given chunk
size and count of devices a chunk runs over, whatever the number of processes (so a
resumed sweep equals an uninterrupted one); another chunking or device count changes them
at round-off only (~1e-15 relative, tested): the batched step is vectorized across the
shard, and how XLA vectorizes depends on the shard's size and on the program's
partitioning. A shard holds at least 8 samples.
A rollout keeps no history (record_every = N): about 2 kB of device memory per sample,
so the chunk size sets progress and resume granularity rather than memory. Finished
chunks are saved at once under ``OUT/chunks``; an interrupted sweep resumes
(``--resume``) without recomputing them, and resuming with more --samples extends it.

Output folder: samples.csv / samples.npz (parameters and metrics per sample),
summary.json and summary.md (statistics, diverged samples, paired comparison),
cdf.png, histograms.png, rmse_vs_inertia_scale.png.

Modules: config (SweepConfig, TOML parsing, defaults), engine (a chunk's shards over
the devices, run_sweep), storage (output folder, chunk files, resume, outputs),
summary (per-sample table, statistics); the figures are drawn by :mod:`so3jax.viz.sweep`.
"""

from so3jax.dynamics.paper import PHASE_NAMES
from so3jax.jobs.sweep.config import (
    DEFAULT,
    SweepConfig,
    config_from_dict,
    config_to_dict,
    load_config,
)
from so3jax.jobs.sweep.engine import (
    LAYOUTS,
    MIN_SHARD,
    batch_mesh,
    check_size,
    memory_needed,
    padded_chunk,
    run_chunk,
    run_sweep,
    simulate_batch,
)
from so3jax.jobs.sweep.storage import (
    claim_chunk,  # noqa: F401 (benchmarks/sweep.py shares chunks as run_sweep does)
    load_chunks,
    write_csv,
    write_outputs,
)
from so3jax.jobs.sweep.summary import STAT_NAMES, columns, diverged, format_summary, summarize
from so3jax.sim.metrics import Metrics
from so3jax.viz.sweep import figures

__all__ = [
    "DEFAULT",
    "LAYOUTS",
    "MIN_SHARD",
    "Metrics",
    "PHASE_NAMES",
    "STAT_NAMES",
    "SweepConfig",
    "batch_mesh",
    "check_size",
    "columns",
    "config_from_dict",
    "config_to_dict",
    "diverged",
    "figures",
    "format_summary",
    "load_chunks",
    "load_config",
    "memory_needed",
    "padded_chunk",
    "run_chunk",
    "run_sweep",
    "simulate_batch",
    "summarize",
    "write_csv",
    "write_outputs",
]
