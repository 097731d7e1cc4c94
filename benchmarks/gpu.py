"""The GPU session's first run: what bounds so3jax on one accelerator, in one script.

    python benchmarks/gpu.py                    # one H100/H200: about 8.5 minutes (--budget 510)
    python benchmarks/gpu.py --quick            # a CPU smoke run of every part: under 2 minutes
    python benchmarks/gpu.py --parts kernels,steps --budget 200
    python benchmarks/gpu.py --report benchmarks/results/gpu-nvidia-h200.json   # its tables

Parts, in order of priority (each in its own child process with its own time limit, cut
to what is left of ``--budget``; a part that would start with less than its minimum left
is skipped and listed as such):

* ``kernels`` (a): the paper loop's and the flight loop's batched rollout (PD, float64,
  ``record_every = N``: one history block, as the sweep flies) compiled for a short
  horizon at several ``unroll`` factors; from the compiled HLO
  (``jax.jit(...).lower(...).compile().as_text()``) the launches per trajectory step.
  Method: the HLO's computations are read; from the entry computation, the computations
  that run as their own sequence of kernels are followed (while bodies and conditions,
  ``call``, the largest branch of a ``conditional``; never a fusion's own computation).
  Every instruction of those but the bookkeeping ones (parameter, constant, tuple,
  get-tuple-element, bitcast, while, call, conditional, ...) is a launch: a ``fusion``, a
  ``custom-call`` (a library call: cuBLAS, cuSOLVER, ...) or another unfused operation
  (``copy``, ``dynamic-update-slice``, ...), counted apart. Each is weighted by how many
  times its computation runs (the while loops' ``known_trip_count``s); the sum over one
  run divided by N is launches per step, and the while iterations per step (each one a
  condition evaluated, on a GPU a predicate read back by the host) likewise.
* ``steps`` (b): time per step (the median of 3 runs after a warm-up, compilation apart)
  for PD on the paper loop at batch 1 (``rollout`` with one seed: ``simulate``'s path),
  1 024 and 65 536, and the flight loop at 1 024, float64, for unroll 1, 4, 16 (the flight
  loop's step scan runs within a control period of 10 steps: 16 acts as 10), each run's
  values (metrics, final state, flight metrics) checked against unroll 1's: the largest
  difference per output relative to that output's largest value (to 1 for the
  orthogonality error, itself round-off of a unit-scale quantity), at most 1e-13.
* ``profile``: where a step's device time goes: the paper loop (PD, unroll 1, 200 steps) at
  batch 1 and 65 536 run once under ``jax.profiler.trace``; from the trace
  (:func:`trace_summary`) the kernels per step the device ran, their busy time against the
  step's wall time, the copies, and the 12 kernels that take the most time.
* ``graphs``: ``kernels``, ``steps`` (unroll 1) and ``profile`` again in a process whose
  ``XLA_FLAGS`` put the while loops' bodies and the conditionals' branches in command buffers
  too (:data:`COMMAND_BUFFERS`: CUDA graphs, one launch per loop), each run's values checked
  against the default flags' (``max_rel_diff_vs_default``).
* ``sweep`` (c): ``sweeps/default.toml`` through the sweep's Python API
  (``so3jax.jobs.api.sweep``, set up as the ``so3jax`` command sets up JAX), with the
  chunk of :mod:`so3jax.parallel.chunks` (on an accelerator the largest chunk that fits,
  the default sweep one program per controller; on CPU the sweep's own rule), cold (an
  empty compilation cache) then warm (the cache the cold run filled), each a fresh
  process: the process's wall time and the sweep's own loop time.
* ``flight`` (d), first part: a timed slice of the run of 10⁵ flight missions × 4000 s ×
  PD: the sweep's chunk program (``run_chunk``) on the chunk the policy gives for 10⁵
  samples (8192 drawn, repeated up to the chunk) over a 20 s horizon, its first call
  (compilation included) and a second one timed, extrapolated linearly to 400 000 steps
  (an extrapolation, recorded as such); then XLA's memory analysis of that program at 64
  samples (bytes per sample, against the policy's assumed figure).
* ``precision`` (e): the default sweep in float32 (a fresh process, its own cache) against
  the warm float64 run's samples: per-sample relative differences of each controller's
  metrics (median, 99th percentile, largest) and the share of samples whose diverged flag
  changes.
* ``flight`` (d), second part: ``sweeps/flight.toml`` at its 1 024 samples, cold, as
  the default sweep's runs.

Every measurement is a JSON line on stdout with its part, the command that reproduces
it, the device and the JAX version; the record (``--out``, default
``benchmarks/results/gpu-<device>.json``) is rewritten after each line, so a part that
crashes or runs out of time keeps what the others measured. Progress goes to stderr.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if __package__ in (None, ""):  # run as a script: the repository root on the path
    sys.path.insert(0, str(ROOT))

DRAWN = 8192  # samples the 10^5 slice draws (repeated up to its chunk)
TOLERANCE = 1e-13  # unrolled against unroll 1, relative to each output's largest value
PARTS = ("kernels", "steps", "profile", "graphs", "sweep", "precision", "flight")
# XLA's default command buffers plus the while loops and the conditionals ("+": added to the
# default): a loop in one CUDA graph, not a launch per kernel and a predicate read per iteration.
COMMAND_BUFFERS = "--xla_gpu_enable_command_buffer=+WHILE,+CONDITIONAL"
# (seconds at most, seconds at least to start) per child on one H100/H200; --quick: on 2 CPU cores
LIMITS = {"loops": (230, 60), "graphs": (100, 40), "sweep-cold": (130, 40), "sweep-warm": (100, 30),
          "precision": (100, 40), "flight": (120, 40), "slice": (90, 40)}
QUICK_LIMITS = {"loops": (45, 20), "graphs": (30, 10), "sweep-cold": (30, 10), "sweep-warm": (20, 8),
                "precision": (25, 10), "flight": (40, 10), "slice": (20, 8)}
BOOKKEEPING = {"parameter", "constant", "get-tuple-element", "tuple", "bitcast", "while", "call", "conditional",
               "after-all", "add-dependency", "opt-barrier", "partition-id", "replica-id", "domain"}
_T0 = time.perf_counter()


def log(*parts) -> None:
    print(f"[{time.perf_counter() - _T0:6.1f} s]", *parts, file=sys.stderr, flush=True)


def emit(**fields) -> None:
    """One measurement: a JSON line on stdout (the parent collects it)."""
    print(json.dumps(fields, default=float), flush=True)


# --- the HLO's launches ----------------------------------------------------------------------


def _computations(text: str) -> tuple[dict, str]:
    """({name: [(opcode, attributes text)]}, the entry computation's name) of HLO text."""
    comps, entry, current = {}, None, None
    header = re.compile(r"^(ENTRY\s+)?%?([\w.\-]+)\s.*\{\s*$")
    for line in text.splitlines():
        if current is None:
            m = header.match(line)
            if m and not line.startswith((" ", "HloModule")):
                current = m.group(2)
                comps[current] = []
                entry = current if m.group(1) else entry
            continue
        if line.startswith("}"):
            current = None
            continue
        m = re.match(r"^\s*(?:ROOT\s+)?%?[\w.\-]+\s*=\s*(.*)$", line)
        if not m:
            continue
        rest = m.group(1)
        if rest.startswith("("):  # a tuple type: skip to its closing parenthesis
            depth = 0
            for i, ch in enumerate(rest):
                depth += {"(": 1, ")": -1}.get(ch, 0)
                if depth == 0:
                    rest = rest[i + 1:]
                    break
        else:
            rest = rest.split(" ", 1)[1] if " " in rest else ""
        op = re.match(r"\s*([\w\-]+)\(", rest)
        if op:
            comps[current].append((op.group(1), rest))
    return comps, entry


def launches(text: str, n_steps: int) -> dict:
    """Kernel launches per trajectory step of compiled HLO text (the module docstring's method)."""
    comps, entry = _computations(text)
    counts = {"fusion": 0.0, "custom-call": 0.0, "other": 0.0}
    buffered = [0.0]  # launches inside XLA:GPU command buffers (CUDA graphs: one launch for the whole call)
    other_ops: dict[str, float] = {}
    state = {"iterations": 0.0, "unknown_trip_counts": 0}
    loops = []  # (body launches per iteration, trip count) of each while loop

    def own_launches(name):
        return sum(1 for op, _ in comps.get(name, ()) if op not in BOOKKEEPING)

    def walk(name, times, depth=0, buffer=False):
        if depth > 50 or name not in comps:
            return
        for op, rest in comps[name]:
            if op not in BOOKKEEPING:
                key = op if op in ("fusion", "custom-call") else "other"
                counts[key] += times
                buffered[0] += times if buffer else 0.0
                if key == "other":
                    other_ops[op] = other_ops.get(op, 0.0) + times
            elif op == "while":
                body = re.search(r"body=%?([\w.\-]+)", rest).group(1)
                cond = re.search(r"condition=%?([\w.\-]+)", rest).group(1)
                trip = re.search(r'known_trip_count"?\s*:\s*\{\s*"?n"?\s*:\s*"?(\d+)', rest)
                if trip is None:
                    state["unknown_trip_counts"] += 1
                n = int(trip.group(1)) if trip else 1
                loops.append({"body": body, "launches_per_iteration": own_launches(body), "trip_count": n if trip
                              else None, "runs": times})
                state["iterations"] += times * n
                walk(body, times * n, depth + 1, buffer)
                walk(cond, times * (n + 1), depth + 1, buffer)
            elif op == "call":
                m = re.search(r"to_apply=%?([\w.\-]+)", rest)
                if m:
                    walk(m.group(1), times, depth + 1, buffer or "command_buffer" in m.group(1))
            elif op == "conditional":
                found = re.search(r"branch_computations=\{([^}]*)\}", rest)
                names = re.findall(r"[\w.\-]+", found.group(1)) if found else \
                    re.findall(r"(?:true|false)_computation=%?([\w.\-]+)", rest)
                names = [n for n in names if n in comps]
                if names:  # the largest branch
                    walk(max(names, key=own_launches), times, depth + 1, buffer)

    walk(entry, 1.0)
    total = sum(counts.values())
    return {
        "launches_per_step": total / n_steps,
        "fusions_per_step": counts["fusion"] / n_steps,
        "custom_calls_per_step": counts["custom-call"] / n_steps,
        "other_per_step": counts["other"] / n_steps,
        "in_command_buffers_per_step": buffered[0] / n_steps,
        "other_ops_per_step": {k: v / n_steps for k, v in sorted(other_ops.items())},
        "while_iterations_per_step": state["iterations"] / n_steps,
        "while_loops_without_trip_count": state["unknown_trip_counts"],
        "innermost_loop": max(loops, key=lambda lp: lp["runs"] * (lp["trip_count"] or 1), default=None),
    }


# --- kernels (a) and steps (b): one child ------------------------------------------------------


def _flight_mission(n_steps: int, dt: float = 0.01):
    from so3jax.missions import mission

    return mission.load(None, [f"T={n_steps * dt!r}"])


def _program(wiring: str, batch: int, n_steps: int, unroll: int):
    """(jitted fn, its argument): PD, float64, one history block; batch 1: ``rollout`` with one seed."""
    import jax
    import jax.numpy as jnp

    import so3jax as sj
    from so3jax.sim.rollout import rollout, rollout_batch

    dt = 0.01
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sj.InertiaWarning)
        if wiring == "flight":
            m = _flight_mission(n_steps, dt)
            scenario, kwargs = m.scenario(), {"loop": m.loop()}
        else:
            scenario, kwargs = sj.paper_scenario(T=n_steps * dt, dt=dt), {}
    gains = jax.tree.map(lambda g: jnp.asarray(g, scenario.R0.dtype), sj.PAPER_PD_GAINS)
    law = sj.geometric_pd()
    outputs = lambda r: {"metrics": r.metrics, "final": r.final, "flight": r.flight}
    if batch == 1:
        fn = jax.jit(lambda s: outputs(rollout(scenario, law, gains, s, record_every=n_steps, unroll=unroll,
                                               **kwargs)))
        return fn, jnp.int32(0)
    fn = jax.jit(lambda s: outputs(rollout_batch(scenario, law, gains, s, scenario_axes=None, record_every=n_steps,
                                                 unroll=unroll, **kwargs)))
    return fn, jnp.arange(batch, dtype=jnp.int32)


# Outputs that measure round-off of a unit-scale quantity (|R^T R - I|): relative to 1.
UNIT_SCALE = ("orthogonality_error",)


def _max_rel(a, b) -> tuple[float, str]:
    """(the largest |a - b| over the output leaves, each relative to that leaf's largest |b|
    (to 1 for UNIT_SCALE's), NaNs equal; the leaf where it is)."""
    import jax
    import numpy as np

    worst, where = 0.0, ""
    for (path, x), y in zip(jax.tree_util.tree_flatten_with_path(a)[0], jax.tree.leaves(b)):
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        name = jax.tree_util.keystr(path)
        diff = np.where(np.isnan(x) & np.isnan(y), 0.0, np.abs(x - y))
        scale = np.nanmax(np.abs(y), initial=0.0) if np.any(np.isfinite(y)) else 0.0
        scale = max(scale, 1.0) if any(u in name for u in UNIT_SCALE) else scale
        d = float(np.max(diff, initial=0.0)) if not np.any(np.isnan(diff)) else float("inf")
        rel = d / scale if scale > 0 else (0.0 if d == 0 else float("inf"))
        if rel > worst:
            worst, where = rel, name
    return worst, where


def trace_summary(log_dir: str, n_steps: int, top: int = 12, device_expected: bool = False) -> dict:
    """Where a traced run's device time goes (``jax.profiler.ProfileData`` of its xplane): on a
    GPU the kernels of the device planes' stream lines (``/device:GPU:k``, ``Stream #..``), per
    trajectory step: their count, their busy time, copies (``memcpy``), and the ``top`` kernels
    by time; without a device plane (CPU) the events of XLA's host threads, likewise (nested:
    their busy time overlaps), unless ``device_expected`` (an accelerator the profiler did
    not trace)."""
    import glob

    import jax

    files = sorted(glob.glob(os.path.join(log_dir, "**", "*.xplane.pb"), recursive=True))
    if not files:
        return {"trace": "no xplane written"}
    data = jax.profiler.ProfileData.from_file(files[-1])
    device = [p for p in data.planes if p.name.startswith("/device:")]
    if device_expected and not device:
        return {"trace": "no device plane: the profiler did not trace the device",
                "planes": [p.name for p in data.planes]}
    planes = device or [p for p in data.planes if p.name.startswith("/host:CPU")]
    count, busy, lines = {}, {}, {}
    first, last = float("inf"), 0.0
    for plane in planes:
        plane_lines = [(line.name, list(line.events)) for line in plane.lines]
        for name, events in plane_lines:
            lines[f"{plane.name} {name}"] = {"events": len(events), "busy_us": sum(e.duration_ns for e in events) / 1e3}
        prefix = "Stream" if device else "tf_XLA"  # the kernels' lines (every line where none is named so)
        for _, events in [(n, ev) for n, ev in plane_lines if n.startswith(prefix)] or plane_lines:
            for e in events:
                count[e.name] = count.get(e.name, 0) + 1
                busy[e.name] = busy.get(e.name, 0.0) + e.duration_ns
                first, last = min(first, e.start_ns), max(last, e.start_ns + e.duration_ns)
    copies = sum(c for name, c in count.items() if "memcpy" in name.lower())
    ranked = sorted(busy, key=busy.get, reverse=True)[:top]
    return {"planes": [p.name for p in planes], "events_per_step": sum(count.values()) / n_steps,
            "busy_us_per_step": sum(busy.values()) / 1e3 / n_steps,
            "span_us_per_step": max(last - first, 0.0) / 1e3 / n_steps, "memcpy_per_step": copies / n_steps,
            "distinct_names": len(count),
            "top": [{"name": k, "per_step": count[k] / n_steps, "us_per_step": busy[k] / 1e3 / n_steps}
                    for k in ranked],
            "lines": dict(sorted(lines.items(), key=lambda kv: -kv[1]["events"])[:16])}


def _flat(tree) -> dict:
    import jax
    import numpy as np

    return {jax.tree_util.keystr(path): np.asarray(x) for path, x in jax.tree_util.tree_flatten_with_path(tree)[0]}


def child_loops(spec: dict) -> None:
    """Parts a, b and the profile: the loops' programs compiled side by side, then counted,
    timed and traced in priority order. ``spec["variant"]`` names the process's XLA flags
    (``default``; ``command-buffers``: the while loops too in CUDA graphs); ``save``: unroll
    1's outputs to an npz, ``compare``: against such a file (another variant's)."""
    from so3jax import configure_xla

    configure_xla()  # XLA:CPU's settings of the command (nothing on a GPU)
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    n_steps, mid, variant = spec["n_steps"], spec["batch"], spec.get("variant", "default")
    jobs = []  # (part, wiring, batch, unroll, steps), in priority order
    if "kernels" in spec["parts"]:
        jobs += [("kernels", "paper", mid, u, n_steps) for u in spec["kernel_unrolls"]]
        jobs += [("kernels", "flight", mid, u, n_steps) for u in spec["flight_unrolls"]]
    if "steps" in spec["parts"]:
        jobs += [("steps", "paper", b, u, n_steps) for b in spec["step_batches"] for u in spec["step_unrolls"]]
        jobs += [("steps", "flight", mid, u, n_steps) for u in spec["flight_step_unrolls"]]
    if "profile" in spec["parts"]:
        jobs += [("profile", "paper", b, 1, spec["profile_steps"]) for b in spec["profile_batches"]]
    effective = lambda wiring, unroll, n: min(unroll, 10) if wiring == "flight" else min(unroll, n)
    programs = {}  # one per (wiring, batch, effective unroll, steps): the flight loop's 16 is its 10
    for _, wiring, batch, unroll, n in jobs:
        programs.setdefault((wiring, batch, effective(wiring, unroll, n), n), None)

    def build(key, low, arg, lower_s):
        start = time.perf_counter()
        return low.compile(), arg, lower_s, time.perf_counter() - start

    pool = ThreadPoolExecutor(max(1, min(len(programs), os.cpu_count() or 1)))
    futures = {}
    for key in programs:  # each compiles (in the pool) while the next one is traced
        start = time.perf_counter()
        fn, arg = _program(key[0], key[1], key[3], key[2])
        low = fn.lower(arg)
        futures[key] = pool.submit(build, key, low, arg, time.perf_counter() - start)
    log(f"{variant}: lowered {len(futures)} programs")
    compiled = {}
    base = {}  # (wiring, batch) -> unroll 1's outputs
    saved = {}  # unroll 1's outputs, flattened, for another variant's comparison
    other = dict(np.load(spec["compare"])) if spec.get("compare") and os.path.exists(spec["compare"]) else None
    command = spec["command"]
    for part, wiring, batch, unroll, n in jobs:
        key = (wiring, batch, effective(wiring, unroll, n), n)
        if key not in compiled:
            compiled[key] = futures[key].result()
        program, arg, lower_s, compile_s = compiled[key]
        common = dict(loop=wiring, controller="pd", dtype="float64", batch=batch, n_steps=n, unroll=unroll,
                      effective_unroll=key[2], variant=variant, lower_s=lower_s, compile_s=compile_s,
                      command=command)
        if part == "kernels":
            counts = launches(program.as_text(), n)
            emit(part="kernels", **common, **counts)
            log(f"{variant} kernels {wiring} B={batch} unroll {unroll}: {counts['launches_per_step']:.1f} "
                f"launches/step ({counts['fusions_per_step']:.1f} fusions, "
                f"{counts['in_command_buffers_per_step']:.1f} in command buffers), "
                f"{counts['while_iterations_per_step']:.3f} while iterations/step")
            continue
        out = jax.block_until_ready(program(arg))
        times = []
        for _ in range(spec["repeats"]):
            start = time.perf_counter()
            jax.block_until_ready(program(arg))
            times.append(time.perf_counter() - start)
        run_s = statistics.median(times)
        row = dict(part=part, **common, run_s=run_s, runs_s=times, us_per_step=1e6 * run_s / n,
                   trajectory_steps_per_s=batch * n / run_s)
        if part == "profile":
            with tempfile.TemporaryDirectory(prefix="so3jax-trace-") as trace_dir:
                try:
                    start = time.perf_counter()
                    with jax.profiler.trace(trace_dir):
                        jax.block_until_ready(program(arg))
                    row.update(traced_run_s=time.perf_counter() - start, **trace_summary(
                        trace_dir, n, device_expected=jax.default_backend() != "cpu"))
                except Exception as err:  # a profiler that cannot start here: the row says so
                    row.update(trace=f"failed: {type(err).__name__}: {err}")
            emit(**row)
            log(f"{variant} profile paper B={batch}: {row.get('events_per_step', 0):.1f} events/step, "
                f"busy {row.get('busy_us_per_step', 0):.2f} of {row['us_per_step']:.2f} us/step")
            continue
        if unroll == 1:
            base[(wiring, batch)] = jax.tree.map(np.asarray, out)
            flat = {f"{wiring}-{batch}{k}": v for k, v in _flat(out).items()}
            if spec.get("save"):
                saved.update(flat)
                np.savez(spec["save"], **saved)
            if other is not None and all(k in other for k in flat):
                rel, where = _max_rel(out, [other[k] for k in flat])
                row.update(max_rel_diff_vs_default=rel, max_rel_diff_vs_default_output=where)
        if (wiring, batch) in base and unroll != 1:
            rel, where = _max_rel(out, base[(wiring, batch)])
            row.update(max_rel_diff_vs_unroll_1=rel, max_rel_diff_output=where, equal_to_unroll_1=rel <= TOLERANCE)
        emit(**row)
        log(f"{variant} steps {wiring} B={batch} unroll {unroll}: {row['us_per_step']:.2f} us/step, "
            f"{row['trajectory_steps_per_s'] / 1e6:.4g} M steps/s"
            + (f", vs unroll 1: {row['max_rel_diff_vs_unroll_1']:.1e}" if "max_rel_diff_vs_unroll_1" in row else "")
            + (f", vs default: {row['max_rel_diff_vs_default']:.1e}" if "max_rel_diff_vs_default" in row else ""))
    pool.shutdown(wait=False, cancel_futures=True)


# --- sweeps (c, d, e): one child per run ----------------------------------------------------------


def policy_chunk(config, mesh) -> tuple[int, float]:
    """(the chunk the sweep runs on this mesh, the bytes per sample it assumed: None on the
    host): :func:`so3jax.jobs.sweep.engine.device_chunk`."""
    from so3jax.jobs.sweep import engine

    return engine.device_chunk(config, mesh)


def _setup_command_jax(precision: str):
    """JAX as the ``so3jax`` command sets it up (XLA flags, precision, the compilation cache
    of $SO3JAX_CACHE_DIR)."""
    from so3jax.commands import configure_jax
    from so3jax.parallel.xla_flags import configure_xla

    configure_xla(every_core=True)
    configure_jax(precision)


def child_sweep(spec: dict) -> None:
    _setup_command_jax(spec["precision"])
    import jax

    from so3jax.jobs import api
    from so3jax.jobs.sweep import engine, load_config

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        config = load_config(ROOT / spec["config"], tuple(spec["overrides"]))
    mesh = engine.batch_mesh()
    chunk, per_sample = policy_chunk(config, mesh)
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        summary = api.sweep(ROOT / spec["config"], spec["out"], overrides=spec["overrides"], chunk=chunk,
                            progress=False)
    emit(part=spec["part"], name=spec["name"], config=spec["config"], overrides=spec["overrides"],
         precision=spec["precision"], cache=spec["cache"], samples=config.samples,
         controllers=list(config.controllers), chunk=chunk, configured_chunk=config.chunk,
         bytes_per_sample_assumed=per_sample, devices=jax.device_count(), api_s=time.perf_counter() - start,
         sweep_loop_s=summary["run"]["wall_s"], trajectory_steps_per_s=summary["run"]["trajectory_steps_per_s"],
         memory=summary["run"]["memory"], command=spec["command"])


def child_slice(spec: dict) -> None:
    """A timed slice of the 10^5 flight missions run: the chunk program over a short horizon."""
    _setup_command_jax("float64")
    import jax
    import numpy as np

    from so3jax.dynamics.scenario import steps_for_horizon
    from so3jax.jobs.sweep import engine, load_config
    from so3jax.missions import batched, draw
    from so3jax.parallel import chunks

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        config = load_config(ROOT / "sweeps/flight.toml", (f"T={spec['T']!r}", f"sweep.samples={spec['samples']}",
                                                           'controllers=["pd"]', *spec["overrides"]))
    mesh = engine.batch_mesh()
    chunk, per_sample = policy_chunk(config, mesh)
    start = time.perf_counter()
    drawn = min(chunk, DRAWN)  # drawn, then repeated up to the chunk: the time per step does not depend on values
    samples = draw.draw(config.dispersions, config.leaves, config.seed, drawn, config.max_draws,
                        mission=config.mission)
    inputs = jax.tree.map(lambda x: x[np.arange(chunk) % drawn], batched.inputs(samples, np.float64))
    draw_s = time.perf_counter() - start
    gains = jax.tree.map(np.asarray, config.gains["pd"])
    start = time.perf_counter()
    engine.run_chunk(inputs, gains, "pd", config.mission, mesh)
    first_s = time.perf_counter() - start
    start = time.perf_counter()
    engine.run_chunk(inputs, gains, "pd", config.mission, mesh)
    run_s = time.perf_counter() - start
    n_steps = steps_for_horizon(config.T, config.dt)
    full_steps, full_samples = 400_000, 100_000
    per_chunk = run_s * full_steps / n_steps
    emit(part="flight", name="slice-1e5", extrapolated=True, chunk=chunk, samples_drawn=drawn, T=config.T,
         n_steps=n_steps, draw_s=draw_s, first_call_s_compile_included=first_s, run_s=run_s,
         trajectory_steps_per_s=chunk * n_steps / run_s, bytes_per_sample_assumed=per_sample,
         extrapolation=f"{full_samples} missions x {full_steps} steps x PD: {-(-full_samples // chunk)} chunk(s) "
                       f"of {chunk} at {per_chunk:.1f} s each (run_s x {full_steps}/{n_steps}), linear in steps; "
                       f"{drawn} samples drawn, repeated to the chunk",
         full_run_s_extrapolated=-(-full_samples // chunk) * per_chunk, command=spec["command"])
    if spec.get("measure_bytes"):  # XLA's own figure for the chunk program, at a probe size (one more compile)
        probe = chunks.host_chunk(64, mesh.size)
        args = jax.tree.map(lambda x: x[:probe], inputs)
        run = functools.partial(engine.simulate_batch, controller="pd", mission=config.mission, mesh=None)
        try:
            measured = chunks.compiled_bytes_per_sample(run, *args, gains, samples=probe)
        except Exception as err:  # a backend without memory analysis
            measured = f"unavailable: {err}"
        emit(part="flight", name="bytes-per-sample", probe_samples=probe, bytes_per_sample_compiled=measured,
             working_bytes_assumed=chunks.WORKING_BYTES, command=spec["command"])


# --- the parent ----------------------------------------------------------------------------


def child_info(spec: dict) -> None:
    import jax

    d = jax.devices()[0]
    from so3jax.parallel import chunks

    emit(part="info", jax=jax.__version__, backend=jax.default_backend(), device=d.device_kind,
         platform=d.platform, devices=jax.device_count(), free_bytes=chunks.device_memory(d),
         python=sys.version.split()[0], command=spec["command"])


def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-") or "device"


class Record:
    def __init__(self, path: Path | None, command: str):
        self.path, self.lines, self.skipped, self.failures = path, [], [], []
        self.stamp = {}
        self.command = command
        self.lock = threading.Lock()

    def add(self, line: dict) -> None:
        with self.lock:
            line = {**line, **self.stamp}
            self.lines.append(line)
            print(json.dumps(line), flush=True)
            self.write()

    def write(self) -> None:
        if self.path is None:
            return
        record = {"command": self.command, **self.stamp, "measurements": self.lines, "skipped": self.skipped,
                  "failures": self.failures}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_suffix(".tmp")
        tmp.write_text(json.dumps(record, indent=1, default=float) + "\n")
        tmp.replace(self.path)


def run_child(kind: str, spec: dict, limit: float, record: Record, env: dict | None = None) -> int:
    """Run one child (this script, --child KIND), its JSON lines into the record as they come;
    killed at ``limit`` seconds. The number of its lines (0 where it failed before any)."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", kind, "--spec", json.dumps(spec)]
    start = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=None, text=True, env=env or os.environ.copy(),
                            cwd=ROOT)
    timer = threading.Timer(limit, proc.kill)
    timer.start()
    lines = 0
    try:
        for line in proc.stdout:
            line = line.strip()
            if line.startswith("{"):
                try:
                    record.add({**json.loads(line), "child_wall_s": time.perf_counter() - start})
                    lines += 1
                except ValueError:
                    pass
        code = proc.wait()
    finally:
        timer.cancel()
    wall = time.perf_counter() - start
    if code != 0:
        why = f"killed at its limit of {limit:.0f} s" if wall >= limit - 1 else f"exit status {code}"
        why += f", after {lines} measurement(s)" if lines else ""
        record.failures.append({"child": kind, "name": spec.get("name"), "why": why, "wall_s": wall})
        record.write()
        log(f"{kind} {spec.get('name', '')}: {why}")
    return lines


def compare_precision(f64: Path, f32: Path, controllers) -> dict:
    """Per-sample relative differences of each controller's metrics, float32 against float64
    (UNIT_SCALE's relative to 1), and the share of samples whose diverged flag changes."""
    import numpy as np

    a, b = np.load(f64 / "samples.npz", allow_pickle=False), np.load(f32 / "samples.npz", allow_pickle=False)
    n = min(len(a["index"]), len(b["index"]))
    metrics, flips = {}, {}
    for c in controllers:
        for key in a.files:
            if not key.startswith(f"{c}_") or key not in b.files or a[key].dtype.kind != "f":
                continue
            x, y = a[key][:n].astype(np.float64), b[key][:n].astype(np.float64)
            if key.endswith(("_diverged", "_nonfinite", "_at_limit")):
                if key.endswith("_diverged"):
                    ok = np.isfinite(x) & np.isfinite(y)
                    flips[c] = {"changed": int(np.sum(x[ok] != y[ok])), "samples": int(np.sum(ok)),
                                "share": float(np.mean(x[ok] != y[ok])) if ok.any() else None}
                continue
            ok = np.isfinite(x) & np.isfinite(y) & (x != 0)
            if not ok.any():
                continue
            scale = 1.0 if any(u in key for u in UNIT_SCALE) else np.abs(x[ok])  # as _max_rel
            rel = np.abs(y[ok] - x[ok]) / scale
            metrics[key] = {"median": float(np.median(rel)), "p99": float(np.quantile(rel, 0.99)),
                            "max": float(rel.max()), "samples": int(ok.sum()),
                            "finite_in_one_only": int(np.sum(np.isfinite(x) != np.isfinite(y)))}
    return {"samples": int(n), "relative_difference": metrics, "diverged_flag_changes": flips}


GOALS = {"default sweep, warm loop [s]": 5.0, "PD, paper loop, batch 65 536 [M steps/s]": 2000.0,
         "1e5 flight missions x 4000 s x PD [s]": 600.0}


def report(record: dict) -> str:
    """A record's tables (markdown): the goals, the step times by batch, unroll and XLA flags,
    the launches per step, the profiles, the sweeps and float32 against float64."""
    rows = record["measurements"]
    of = lambda part: [r for r in rows if r.get("part") == part]
    g = lambda x, f=".3g": "–" if x is None else format(x, f)
    out = [f"Device {record.get('device')}, JAX {record.get('jax')}: `{record.get('command')}`", ""]
    warm_row = next((r for r in of("sweep") if r.get("name") == "default-warm"), None)
    warm = warm_row and warm_row["sweep_loop_s"]
    big = [r for r in of("steps") if r["loop"] == "paper" and r["batch"] == 65536]
    best = max(big, key=lambda r: r["trajectory_steps_per_s"], default=None)
    flight = next((r for r in of("flight") if r.get("name") == "slice-1e5"), None)
    got = {"default sweep, warm loop [s]": (warm, warm is not None and not warm_row["overrides"] and warm <= 5.0,
                                            warm_row and (f"overrides {warm_row['overrides']}" if warm_row["overrides"]
                                                          else f"chunk {warm_row['chunk']}")),
           "PD, paper loop, batch 65 536 [M steps/s]": (
               best and best["trajectory_steps_per_s"] / 1e6,
               best is not None and best["trajectory_steps_per_s"] >= 2e9,
               best and f"unroll {best['unroll']}, {best.get('variant', 'default')}"),
           "1e5 flight missions x 4000 s x PD [s]": (
               flight and flight["full_run_s_extrapolated"],
               flight is not None and flight["full_run_s_extrapolated"] <= 600.0,
               flight and f"extrapolated from {flight['n_steps']} steps, chunk {flight['chunk']}")}
    out += ["| goal | limit | measured | met | how |", "|---|---:|---:|---|---|"]
    out += [f"| {k} | {g(GOALS[k])} | {g(v)} | {'yes' if ok else 'no' if v is not None else '–'} | {how or ''} |"
            for k, (v, ok, how) in got.items()]
    out += ["", "| loop | batch | unroll | XLA flags | µs/step | M steps/s | vs unroll 1 | vs default flags |",
            "|---|---:|---:|---|---:|---:|---:|---:|"]
    out += [f"| {r['loop']} | {r['batch']} | {r['unroll']} | {r.get('variant', 'default')} | {g(r['us_per_step'])} | "
            f"{g(r['trajectory_steps_per_s'] / 1e6)} | {g(r.get('max_rel_diff_vs_unroll_1'), '.1e')} | "
            f"{g(r.get('max_rel_diff_vs_default'), '.1e')} |" for r in of("steps")]
    out += ["", "| loop | unroll | XLA flags | launches/step | fusions | in command buffers | while iterations/step "
            "| compile [s] |", "|---|---:|---|---:|---:|---:|---:|---:|"]
    out += [f"| {r['loop']} | {r['unroll']} | {r.get('variant', 'default')} | {g(r['launches_per_step'], '.1f')} | "
            f"{g(r['fusions_per_step'], '.1f')} | {g(r['in_command_buffers_per_step'], '.1f')} | "
            f"{g(r['while_iterations_per_step'])} | {g(r['compile_s'], '.1f')} |" for r in of("kernels")]
    out += ["", "| batch | XLA flags | µs/step | events/step | busy µs/step | memcpy/step | costliest |",
            "|---:|---|---:|---:|---:|---:|---|"]
    out += [f"| {r['batch']} | {r.get('variant', 'default')} | {g(r['us_per_step'])} | "
            f"{g(r.get('events_per_step'), '.1f')} | {g(r.get('busy_us_per_step'))} | "
            f"{g(r.get('memcpy_per_step'), '.2f')} | "
            + ", ".join(f"{t['name'][:40]} {t['us_per_step']:.2g} µs" for t in r.get("top", [])[:3]) + " |"
            for r in of("profile")]
    runs = [r for r in of("sweep") + of("flight") + of("precision") if "sweep_loop_s" in r]
    out += ["", "| run | precision | cache | chunk | process [s] | loop [s] | M steps/s |",
            "|---|---|---|---:|---:|---:|---:|"]
    out += [f"| {r['name']} | {r['precision']} | {r['cache']} | {r['chunk']} | {g(r.get('child_wall_s'))} | "
            f"{g(r['sweep_loop_s'])} | {g(r['trajectory_steps_per_s'] / 1e6)} |" for r in runs]
    for r in of("precision"):
        if "relative_difference" in r:
            out += ["", f"float32 against float64, {r['samples']} samples: diverged flags changed "
                    + ", ".join(f"{c} {v['changed']} of {v['samples']}" for c, v in r["diverged_flag_changes"].items()),
                    "", "| metric | median | p99 | max |", "|---|---:|---:|---:|"]
            out += [f"| {k} | {v['median']:.1e} | {v['p99']:.1e} | {v['max']:.1e} |"
                    for k, v in r["relative_difference"].items()]
    out += ["", f"failures: {record.get('failures') or 'none'}; skipped: {record.get('skipped') or 'none'}"]
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes: a CPU smoke run of every part")
    parser.add_argument("--out", type=Path, help="the JSON record (default benchmarks/results/gpu-<device>.json)")
    parser.add_argument("--budget", type=float, help="seconds for everything (default 510; --quick 115)")
    parser.add_argument("--parts", default=",".join(PARTS), help=f"comma-separated, of {', '.join(PARTS)}")
    parser.add_argument("--report", type=Path, help="print a record's tables (markdown) and exit")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    parser.add_argument("--spec", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.report:
        print(report(json.loads(args.report.read_text())), end="")
        return 0
    if args.child:
        os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")
        {"info": child_info, "loops": child_loops, "sweep": child_sweep, "slice": child_slice}[args.child](
            json.loads(args.spec))
        return 0
    parts = [p.strip() for p in args.parts.split(",") if p.strip()]
    unknown = set(parts) - set(PARTS)
    if unknown:
        parser.error(f"unknown parts {sorted(unknown)}; choose from {', '.join(PARTS)}")
    quick = args.quick
    default_budget = 115.0 if quick else 510.0
    budget = args.budget or default_budget
    scale = max(1.0, budget / default_budget)  # a larger budget widens each part's limit alike
    limits = {k: (most * scale, least) for k, (most, least) in (QUICK_LIMITS if quick else LIMITS).items()}
    deadline = time.perf_counter() + budget
    me = "python benchmarks/gpu.py" + (" --quick" if quick else "")
    record = Record(None, "python benchmarks/gpu.py " + " ".join(sys.argv[1:] if argv is None else argv))

    def left() -> float:
        return deadline - time.perf_counter()

    def start(name: str, what: str) -> float | None:
        most, least = limits[name]
        if left() < least:
            record.skipped.append({"what": what, "why": f"{left():.0f} s of the budget left, {least} s needed"})
            record.write()
            log(f"skipped {what}: {left():.0f} s left")
            return None
        return min(most, left())

    run_child("info", {"command": me}, 120, record)
    info = next((line for line in record.lines if line.get("part") == "info"), {})
    record.stamp = {"device": info.get("device", "unknown"), "jax": info.get("jax")}
    record.path = args.out or ROOT / "benchmarks" / "results" / f"gpu-{_slug(record.stamp['device'])}.json"
    if quick:
        record.path = args.out or Path(tempfile.gettempdir()) / "gpu-quick.json"
    record.write()
    log(f"device {record.stamp['device']}, JAX {record.stamp['jax']}: record {record.path}")

    work = Path(tempfile.mkdtemp(prefix="so3jax-gpu-bench-"))

    def loops() -> None:  # parts a, b, the profile, then the same under command buffers
        loop_parts = [p for p in parts if p in ("kernels", "steps", "profile")]
        sizes = {"n_steps": 100 if quick else 2000, "batch": 64 if quick else 1024, "repeats": 3,
                 "step_batches": [64] if quick else [1, 1024, 65536], "profile_steps": 50 if quick else 200,
                 "profile_batches": [64] if quick else [1, 65536]}
        if loop_parts:
            spec = {**sizes, "parts": loop_parts, "save": str(work / "default.npz"),
                    "kernel_unrolls": [1, 2] if quick else [1, 2, 4, 8, 16],
                    "flight_unrolls": [1] if quick else [1, 2, 4, 10],
                    "step_unrolls": [1, 2] if quick else [1, 4, 16],
                    "flight_step_unrolls": [1] if quick else [1, 4, 16],
                    "command": f"{me} --parts {','.join(loop_parts)}"}
            limit = start("loops", "kernels, steps and profile")
            if limit:
                run_child("loops", spec, limit, record)
        if "graphs" in parts:  # the same programs at unroll 1, the while loops in command buffers too
            spec = {**sizes, "parts": ["kernels", "steps", "profile"], "variant": "command-buffers",
                    "compare": str(work / "default.npz"), "kernel_unrolls": [1], "flight_unrolls": [1],
                    "step_unrolls": [1], "flight_step_unrolls": [1],
                    "command": f"XLA_FLAGS='{COMMAND_BUFFERS}' {me} --parts graphs"}
            limit = start("graphs", "graphs: command buffers")
            if limit:
                flags = f"{os.environ.get('XLA_FLAGS', '')} {COMMAND_BUFFERS}".strip()
                run_child("loops", spec, limit, record, dict(os.environ, XLA_FLAGS=flags))

    small = ["sweep.samples=16", "T=1.0", "sweep.chunk=16", 'controllers=["pd"]'] if quick else []
    outs = {}

    def sweep(name: str, part: str, config: str, overrides: list, precision: str, cache: Path, label: str) -> None:
        limit = start(name if name in limits else part, f"{part}: {label}")
        if limit is None:
            return
        out = work / f"{label}-out"
        shutil.rmtree(out, ignore_errors=True)
        extra = "".join(f" --set '{o}'" for o in overrides)
        spec = {"part": part, "name": label, "config": config, "overrides": overrides, "precision": precision,
                "out": str(out), "cache": "cold" if not any(cache.iterdir()) else "warm",
                "command": f"SO3JAX_CACHE_DIR={'<empty>' if not any(cache.iterdir()) else '<filled>'} "
                           f"so3jax sweep {config} --precision {precision} --chunk <policy>{extra}"}
        env = dict(os.environ, SO3JAX_CACHE_DIR=str(cache))
        if run_child("sweep", spec, limit, record, env):  # its line: the run and its folder complete
            outs[label] = out

    try:
        loops()
        if "sweep" in parts or "precision" in parts:
            cache = work / "cache-f64"
            cache.mkdir()
            if "sweep" in parts:
                sweep("sweep-cold", "sweep", "sweeps/default.toml", small, "float64", cache, "default-cold")
            sweep("sweep-warm", "sweep", "sweeps/default.toml", small, "float64", cache, "default-warm")
        flight_cache = work / "cache-flight"
        flight_cache.mkdir()
        if "flight" in parts:  # the 10^5 slice before the 1024-sample flight sweep: a goal of its own
            limit = start("slice", "flight: the 1e5 slice")
            if limit:
                # --quick: the quick flight sweep's program (its horizon, chunk and controller)
                spec = {"samples": 16 if quick else 100_000, "T": 1.0 if quick else 20.0, "measure_bytes": not quick,
                        "overrides": ["sweep.chunk=16"] if quick else [], "command": f"{me} --parts flight"}
                run_child("slice", spec, limit, record, dict(os.environ, SO3JAX_CACHE_DIR=str(flight_cache)))
        if "precision" in parts and "default-warm" in outs:
            cache32 = work / "cache-f32"
            cache32.mkdir()
            sweep("precision", "precision", "sweeps/default.toml", small, "float32", cache32, "default-float32")
            if "default-float32" in outs:
                controllers = ["pd"] if quick else ["pd", "adaptive"]
                record.add({"part": "precision", "name": "float32-vs-float64",
                            "command": f"{me} --parts sweep,precision",
                            **compare_precision(outs["default-warm"], outs["default-float32"], controllers)})
        if "flight" in parts:  # cold (--quick: the slice's program, compiled by the slice)
            sweep_cache = flight_cache if quick else work / "cache-flight-sweep"
            sweep_cache.mkdir(exist_ok=True)
            sweep("flight", "flight", "sweeps/flight.toml", small, "float64", sweep_cache, "flight-1024")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    record.write()
    log(f"done in {time.perf_counter() - _T0:.0f} s; {len(record.lines)} measurements, {len(record.failures)} "
        f"failures, {len(record.skipped)} skipped: {record.path}")
    return 0 if not record.failures else 1


if __name__ == "__main__":
    sys.exit(main())
