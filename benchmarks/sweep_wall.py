"""Wall time of ``so3jax sweep`` on a sweep file as a user runs it: cold (an empty
compilation cache) and warm (the cache the cold run filled), each in its own process.

    python benchmarks/sweep_wall.py                       # sweeps/default.toml, cold then warm, one run each
    python benchmarks/sweep_wall.py --runs 2 --config sweeps/default.toml
    python benchmarks/sweep_wall.py --sweep-args --samples 8 --T 0.2      # a tiny sweep (a smoke test)

Each run is ``SO3JAX_CACHE_DIR=CACHE so3jax sweep CONFIG --out OUT`` in a fresh
interpreter (the installed command), timed from the outside; the sweep's own timing of its
loop over chunks (``summary.json``'s ``run``, compilation of the first chunks included)
beside it. Prints one JSON object and
writes it to ``benchmarks/results/sweep-<config>-wall-cpu-<cores>core-<cpu>.json``
(the CPU model from ``lscpu``), with the machine's float64 matmul peak measured before
and after the runs: machines that ``lscpu`` names alike can differ severalfold in speed per
core, and the peak tells them apart.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if __package__ in (None, ""):  # run as a script: the repository root on the path (benchmarks.throughput)
    sys.path.insert(0, str(ROOT))


def cpu_model() -> str:
    """lscpu's model name (platform.processor() where lscpu is missing)."""
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
        return next(line.split(":", 1)[1].strip() for line in out.splitlines() if line.startswith("Model name"))
    except (OSError, subprocess.CalledProcessError, StopIteration):
        return platform.processor() or "unknown"


def cpu_flags() -> list[str]:
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return []
    flags = next((line.split(":", 1)[1].split() for line in text.splitlines() if line.startswith("flags")), [])
    return sorted(f for f in flags if f.startswith(("avx", "fma")))


def slug(text: str) -> str:
    words = re.sub(r"\(.*?\)", " ", text).lower().split()
    keep = [w for w in words if w not in ("processor", "cpu", "@") and not w.endswith("ghz")]
    return "-".join(re.sub(r"[^a-z0-9]+", "", w) for w in keep if re.sub(r"[^a-z0-9]+", "", w))


def _matmul_peak_gflops() -> float:
    from benchmarks.throughput import _matmul_peak  # the peak every benchmark here reports

    return round(_matmul_peak(2048) / 1e9, 1)


def one_run(config: Path, cache: str, label: str, extra: list) -> dict:
    """One ``so3jax sweep`` in its own process: wall time, peak RSS, its stderr's timing lines."""
    out = Path(tempfile.mkdtemp(prefix="sweep-wall-")) / "out"
    env = dict(os.environ, SO3JAX_CACHE_DIR=cache)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    load = os.getloadavg()
    start = time.perf_counter()
    proc = subprocess.run([shutil.which("so3jax") or "so3jax", "sweep", str(config), "--out", str(out), *extra],
                          env=env, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    try:
        run = json.loads((out / "summary.json").read_text())["run"]  # the sweep's own timing of its loop
    except (OSError, KeyError, ValueError):
        run = {}
    shutil.rmtree(out.parent, ignore_errors=True)
    if proc.returncode != 0:
        raise SystemExit(f"so3jax sweep failed ({proc.returncode}): {proc.stderr.strip().splitlines()[-1:]}")
    return {"cache": label, "wall_s": round(wall, 2), "sweep_loop_s": run.get("wall_s"),
            "trajectory_steps_per_s": run.get("trajectory_steps_per_s"), "devices": run.get("devices"),
            "cpu_s": round((after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), 2),
            "max_rss_kb": after.ru_maxrss, "load_avg_start": [round(x, 2) for x in load],
            "load_avg_end": [round(x, 2) for x in os.getloadavg()]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=ROOT / "sweeps" / "default.toml")
    parser.add_argument("--runs", type=int, default=1, help="cold-then-warm pairs")
    parser.add_argument("--out", type=Path, default=None, help="the JSON record (default: benchmarks/results/...)")
    parser.add_argument("--sweep-args", nargs=argparse.REMAINDER, default=[],
                        help="further arguments of so3jax sweep (last on the line)")
    args = parser.parse_args(argv)
    import jax  # the version only: the runs are separate processes

    peak_before = _matmul_peak_gflops()
    runs = []
    for _ in range(args.runs):
        cache = tempfile.mkdtemp(prefix="so3jax-cache-")
        try:
            runs.append(one_run(args.config, cache, "cold", args.sweep_args))
            runs.append(one_run(args.config, cache, "warm", args.sweep_args))
        finally:
            shutil.rmtree(cache, ignore_errors=True)
    cpus = len(os.sched_getaffinity(0))
    model = cpu_model()
    record = {
        "command": (f"XLA_FLAGS='{os.environ['XLA_FLAGS']}' " if os.environ.get("XLA_FLAGS") else "")
        + "python benchmarks/sweep_wall.py " + " ".join(sys.argv[1:] if argv is None else argv),
        "what": f"so3jax sweep {args.config.name} {' '.join(args.sweep_args)} from the installed command, each run "
                "in a fresh process: cold (an empty compilation cache: compilation included), then warm (the cache "
                "the cold run filled)",
        "cpu": model, "cpu_flags": cpu_flags(), "cpus": cpus, "python": platform.python_version(),
        "jax": jax.__version__,
        "float64_matmul_peak_gflops": {"before": peak_before, "after": _matmul_peak_gflops(),
                                       "what": "numpy 2048 x 2048 matmul on every BLAS thread, best of 3"},
        "runs": runs,
    }
    print(json.dumps(record))
    name = f"sweep-{args.config.stem}-wall-cpu-{cpus}core-{slug(model)}.json"
    out = args.out or ROOT / "benchmarks" / "results" / name
    out.write_text(json.dumps(record, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
