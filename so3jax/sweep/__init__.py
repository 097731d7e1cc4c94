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

Modules: config (SweepConfig, TOML parsing, defaults), engine (batched executables,
chunks over devices, run_sweep), storage (output folder, chunk files, resume, outputs),
summary (per-sample table, statistics), plots (figures), cli (the subcommand).
"""

from so3jax.metrics import Metrics
from so3jax.sweep.config import (
    DEFAULT,
    SweepConfig,
    config_from_dict,
    config_to_dict,
    load_config,
)
from so3jax.sweep.engine import (
    BATCH,
    LAYOUTS,
    MIN_SHARD,
    batch_mesh,
    memory_needed,
    mission_key,
    padded_chunk,
    run_chunk,
    run_sweep,
    simulate_batch,
)
from so3jax.sweep.storage import _take  # noqa: F401 (benchmarks/sweep.py shares chunks as run_sweep does)
from so3jax.sweep.storage import load_chunks, write_csv, write_outputs
from so3jax.sweep.summary import PHASE_NAMES, STAT_NAMES, columns, diverged, format_summary, summarize
from so3jax.sweep.plots import figures
from so3jax.sweep.cli import main, register

__all__ = [
    "BATCH",
    "DEFAULT",
    "LAYOUTS",
    "MIN_SHARD",
    "Metrics",
    "PHASE_NAMES",
    "STAT_NAMES",
    "SweepConfig",
    "batch_mesh",
    "columns",
    "config_from_dict",
    "config_to_dict",
    "diverged",
    "figures",
    "format_summary",
    "load_chunks",
    "load_config",
    "main",
    "memory_needed",
    "mission_key",
    "padded_chunk",
    "register",
    "run_chunk",
    "run_sweep",
    "simulate_batch",
    "summarize",
    "write_csv",
    "write_outputs",
]
