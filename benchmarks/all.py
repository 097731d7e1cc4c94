"""Run the benchmark set and collect it: throughput (so3jax beside the NumPy and Numba
baselines, FLOPs and the machine's peak, ``so3jax paper`` wall time), multi-device
scaling of the sweep path and of a tuning step, and gradient cost and memory against the
horizon.

    python -m benchmarks.all [--quick] [--out benchmarks/results] [--tag TAG] [--limit-scale 1]

Each benchmark runs as a subprocess with its own time limit; the limits add up to 19
minutes (``--quick``: 8); on 2 cores at a load average of ~1-2 the set without the tuning
step took 12.5-13.5 minutes (the adaptive reverse-mode compilations take ~5
of them). On a loaded
machine the throughput script skips its lowest-priority work once past its budget (it
lists what it skipped), a benchmark out of time is recorded with its error (the
gradients benchmark keeps the runs it finished), and ``--limit-scale`` stretches every
limit. The combined JSON object is written atomically to ``<out>/<tag>.json``
(``<tag>-quick.json`` with --quick), the throughput plot beside it as
``<tag>-throughput.png``, and printed as the last line of stdout.

The tag names the machine: ``cpu-<cores>core-<model>`` or ``gpu-<device kind>``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import resource
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.throughput import cpu_model

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

# name: (script, arguments, time limit [s]); the limits add up to 19 minutes (quick: 8).
# Each limit leaves room over the benchmark's time on 2 cores at a load average of 1-2
# (throughput ~260-290 s, sweep 76-95 s, gradients ~105 s + ~300 s; benchmarks/results/).
GRADIENTS = ["--batch", "2", "--modes", "reverse", "--jobs", "2"]
PLAN = {
    "throughput": ("throughput", [], 310),
    "sweep": ("sweep", ["--devices", "1,2,4", "--T", "50", "--samples", "128", "--chunk", "64"], 110),
    "gradients_pd": (
        "gradients",
        ["--controllers", "pd", "--horizons", "10000", "100000", "--fd-horizon", "10000", *GRADIENTS],
        130,
    ),
    "gradients_adaptive": (
        "gradients",
        ["--controllers", "adaptive", "--horizons", "10000", "100000", "--fd-horizon", "10000", *GRADIENTS],
        350,
    ),
    # compilations dominate (four, 15-45 s each on 2 loaded cores); the steps take seconds
    "tune": ("tune", ["--T", "20", "--batches", "0,64", "--rounds", "7", "--calls", "5"], 240),
}
QUICK_PLAN = {
    "throughput": ("throughput", ["--quick"], 130),
    "sweep": ("sweep", ["--devices", "1,2", "--T", "10", "--samples", "32", "--chunk", "16"], 110),
    "gradients_pd": (
        "gradients",
        ["--controllers", "pd", "--horizons", "10000", "30000", "--fd-horizon", "0", *GRADIENTS],
        120,
    ),
    "tune": ("tune", ["--T", "5", "--batches", "64", "--rounds", "3", "--calls", "3"], 120),
}
THROUGHPUT_RESERVE = 45  # s of its limit kept for the work after its --budget (summary, plot)


def log(*parts) -> None:
    print(*parts, file=sys.stderr, flush=True)


def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")


def _usable_cores() -> int:
    """so3jax.parallel.xla_flags.usable_cores, without importing so3jax (and JAX) in this parent process."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def device_tag() -> str:
    """cpu-<cores>core-<model> on a CPU-only machine, gpu-<device kind> when JAX sees a GPU."""
    code = "import jax; d = jax.devices()[0]; print(d.platform, '|', d.device_kind)"
    env = dict(os.environ, XLA_PYTHON_CLIENT_PREALLOCATE="false", XLA_FLAGS="")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=False)
    platform_, _, kind = proc.stdout.strip().rpartition("\n")[-1].partition(" | ")
    if proc.returncode == 0 and platform_ in ("gpu", "cuda", "rocm"):
        return "gpu-" + _slug(kind)
    return f"cpu-{_usable_cores()}core-" + _slug(cpu_model())


def run_benchmark(name: str, script: str, args: list[str], limit: float) -> dict:
    """Run benchmarks/<script>.py with args; its JSON (last stdout line or the whole of stdout)."""
    cmd = [sys.executable, str(HERE / f"{script}.py"), *args]
    log(f"== {name} (limit {limit:.0f} s): {' '.join(cmd[1:])}")
    start, cpu_start = time.perf_counter(), _children_cpu()
    with tempfile.TemporaryDirectory() as tmp:
        partial = Path(tmp) / "runs.jsonl"
        if script == "gradients":
            cmd += ["--log", str(partial)]
        # its own session, so that on timeout its subprocesses (gradients' and sweep's children) go too
        proc = subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT, start_new_session=True
        )
        try:
            stdout, stderr = proc.communicate(timeout=limit)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            stdout, stderr = proc.communicate()
            out = {"error": f"time limit of {limit:.0f} s reached", "stderr_tail": _tail(stderr)}
            if partial.exists():  # the runs that finished
                out["runs"] = [json.loads(line) for line in partial.read_text().splitlines() if line.strip()]
            log(f"   {name}: time limit of {limit:.0f} s reached")
            return {**out, "command": " ".join(cmd[1:]), "wall_s": time.perf_counter() - start}
    wall = time.perf_counter() - start
    cpu = _children_cpu() - cpu_start
    result = _parse(stdout)
    if proc.returncode != 0 or result is None:
        result = {"error": f"exit status {proc.returncode}", "stderr_tail": _tail(stderr), "report": result}
    log(f"   {name}: {wall:.0f} s ({cpu:.0f} s of CPU)" + (f", {result['error']}" if "error" in result else ""))
    return {**result, "command": " ".join(cmd[1:]), "wall_s": wall, "cpu_s": cpu}


def _children_cpu() -> float:
    """User + system CPU seconds of this process's finished descendants."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _tail(text, n: int = 3000) -> str:
    if isinstance(text, bytes):
        text = text.decode(errors="replace")
    return (text or "")[-n:]


def _parse(stdout: str):
    """The JSON object a benchmark printed: its last line, or all of stdout (indented JSON)."""
    stdout = stdout.strip()
    for candidate in (stdout.splitlines()[-1] if stdout else "", stdout[stdout.find("{") :] if "{" in stdout else ""):
        try:
            value = json.loads(candidate)
        except json.JSONDecodeError:
            continue
        if isinstance(value, dict):
            return value
    return None


def write_atomic(path: Path, obj: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(json.dumps(obj, indent=1) + "\n")
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller sizes (about 5 minutes)")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"), help="results folder")
    parser.add_argument("--tag", help="machine tag for the file name (default: detected)")
    parser.add_argument("--only", nargs="+", choices=list(PLAN), help="run only these benchmarks")
    parser.add_argument(
        "--limit-scale",
        type=float,
        default=1.0,
        help="multiply every time limit (a loaded machine; the 19-minute total scales with it)",
    )
    args = parser.parse_args(argv)
    plan = {
        name: (script, bench_args, limit * args.limit_scale)
        for name, (script, bench_args, limit) in (QUICK_PLAN if args.quick else PLAN).items()
        if not args.only or name in args.only
    }
    started = time.perf_counter()
    load_start = list(os.getloadavg())
    tag = args.tag or device_tag()
    stem = f"{tag}-quick" if args.quick else tag
    plot = args.out / f"{stem}-throughput.png"
    report = {
        "benchmark": "all",
        "tag": tag,
        "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
        "quick": args.quick,
        "machine": {
            "cpu_model": cpu_model(),
            "cpus": os.cpu_count(),
            "affinity": _usable_cores(),
            "platform": platform.platform(),
            "python": platform.python_version(),
            "load_avg_start": load_start,
        },
        "commit": _git("rev-parse", "HEAD"),
        "uncommitted_in_so3jax": [
            line.strip()
            for line in (_git("status", "--porcelain", "--untracked-files=no", "so3jax") or "").splitlines()
        ],
        "limits_s": {name: limit for name, (_, _, limit) in plan.items()},
    }
    for name, (script, bench_args, limit) in plan.items():
        extra = []
        if script == "throughput":
            extra = ["--plot", str(plot.resolve()), "--budget", str(max(limit - THROUGHPUT_RESERVE, 0.5 * limit))]
        report[name] = run_benchmark(name, script, bench_args + extra, limit)
    report["machine"]["load_avg_end"] = list(os.getloadavg())
    report["wall_s"] = time.perf_counter() - started
    report["cpu_s"] = _children_cpu()  # of all subprocesses: about what an idle machine needs, at most
    path = args.out / f"{stem}.json"
    write_atomic(path, report)
    log(f"== all: {report['wall_s']:.0f} s; {path}")
    print(json.dumps(report))
    failed = [name for name in plan if isinstance(report.get(name), dict) and "error" in report[name]]
    return 1 if failed else 0


def _git(*args) -> str | None:
    try:
        proc = subprocess.run(["git", *args], capture_output=True, text=True, cwd=ROOT, check=False, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return proc.stdout.strip() if proc.returncode == 0 else None


if __name__ == "__main__":
    sys.exit(main())
