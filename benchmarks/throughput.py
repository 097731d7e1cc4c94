"""Throughput of so3jax rollouts beside the NumPy and Numba baselines, FLOPs and the machine's peak.

What it measures, in one process (one XLA device, with ``so3jax.configure_xla()``'s XLA:CPU settings):

* a correctness gate first: so3jax (float64) against the NumPy baseline on a short
  horizon, and against the Numba baseline across both phase switches (dt = 1 s) and
  across t = 500 s at the paper's dt; rmse, effort and final R to 1e-9 relative. If
  any deviation exceeds that, it prints the JSON and exits with status 1, timing nothing;
* so3jax trajectory-steps/s for each controller, dtype (float64, float32) and batch
  size: ``jax.jit(rollout_batch)`` over seeds (scenario shared, ``scenario_axes=None``),
  one history block (``record_every = n_steps``); compile (lower + compile) timed
  apart; the median of ``--repeats`` runs after one warm-up run;
* one trajectory (``rollout`` with a scalar seed, the path ``simulate`` takes): µs/step;
* so3jax on every core (a subprocess with one XLA host device per core, as the CLI
  sets up): batch 4096 split evenly over the devices, each running its own compiled
  rollout_batch, dispatched together -- the equal-work comparison with Numba's prange,
  which also uses every core; the same process times Numba too, in rounds alternating
  with so3jax, and the median ratio is ``so3jax_all_cores_over_numba[_draw]_interleaved``
  in the summary (``..._best``: against the separate Numba rows, minutes apart);
* the baselines in the same run, same protocol: NumPy (batch 1 and 256, short
  horizons, ~1 ms/step) and Numba (batch 1, 256, 4096, prange over every core, timed
  over as many trajectory-steps as so3jax on every core; float64 only; skipped when
  numba is not installed), with ratios so3jax / baseline. so3jax draws the noise inside
  the step (its timings include the PRNG); NumPy and "numba" get it precomputed, outside
  their timing; "numba-draw" draws the same bits inside its kernel (equal work);
* FLOPs and transcendentals of one closed-loop RK4 step from XLA's cost analysis
  (one trajectory, and per trajectory in a batched step), achieved FLOP/s, and the
  fraction of the machine's peak, measured here by a float64 numpy matmul (best of 3),
  with all BLAS threads and with one (a subprocess) -- on a GPU by a jitted JAX matmul
  on the device, float64 and float32, each dtype's rows set against its own peak;
* the wall time of ``so3jax paper --no-figures --json`` (both controllers, 400 000
  steps, compile included; a subprocess, as a user runs it): its own
  ``config.wall_time_s`` and the process's total.

    python benchmarks/throughput.py [--plot throughput.png] [--budget SECONDS]
    python benchmarks/throughput.py --quick                     # smaller sizes, no paper run

The default needs about 6 minutes of CPU (some 35 XLA compilations of 5-10 s each are
most of it). With --budget, the work is done in order of priority (float64 so3jax,
one trajectory, baselines, FLOPs, peak, paper, then float32) and what would start past
the budget is skipped and listed under ``skipped``.

Progress goes to stderr; the last line of stdout is one JSON object.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

if __package__ in (None, ""):  # run as a script: the repository root on the path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

TOLERANCE = 1e-9
# Runs on every core (Numba's prange, so3jax's host devices) are timed over 20x the
# trajectory-steps of the one-core runs (4 M: ~0.5 s per run): short runs on two cores
# are dominated by whichever thread the machine delays, and by fixed per-call costs.
ALL_CORES_TARGET_FACTOR = 20
CONTROLLERS = ("pd", "adaptive")
DTYPES = ("float64", "float32")


_T0 = time.perf_counter()


def log(*parts) -> None:
    print(f"[{time.perf_counter() - _T0:6.0f} s]", *parts, file=sys.stderr, flush=True)


def _median_time(fn, repeats: int) -> tuple[float, list[float]]:
    """One warm-up call, then the median of ``repeats`` timed calls of fn() (blocking)."""
    import jax

    jax.block_until_ready(fn())
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - start)
    return statistics.median(times), times


def _steps_for(batch: int, target: int, lo: int, hi: int) -> int:
    """Steps per timed run: about ``target`` trajectory-steps, clamped to [lo, hi]."""
    return int(min(hi, max(lo, math.ceil(target / batch))))


# --- so3jax ----------------------------------------------------------------------------


def _setup(controller: str, dtype: str, n_steps: int, dt: float = 0.01):
    import jax
    import jax.numpy as jnp

    import so3jax as sj

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sj.InertiaWarning)
        scenario = sj.paper_scenario(T=n_steps * dt, dt=dt, dtype=dtype)
    assert scenario.n_steps == n_steps, (scenario.n_steps, n_steps)
    ctrl, gains = {
        "pd": (sj.geometric_pd(), sj.PAPER_PD_GAINS),
        "adaptive": (sj.adaptive_backstepping(), sj.PAPER_ADAPTIVE_GAINS),
    }[controller]
    gains = jax.tree.map(lambda g: jnp.asarray(g, dtype), gains)
    return scenario, ctrl, gains


def _batched_fn(controller: str, dtype: str, n_steps: int, dt: float = 0.01, full: bool = False):
    """jit(seeds -> metrics (and the final state if full)) of rollout_batch; AOT-compiled."""
    import jax

    from so3jax.sim.rollout import rollout_batch

    scenario, ctrl, gains = _setup(controller, dtype, n_steps, dt)

    def run(seeds):
        r = rollout_batch(scenario, ctrl, gains, seeds, scenario_axes=None, record_every=n_steps)
        return (r.metrics, r.final) if full else r.metrics

    return jax.jit(run)


def _timed_call(fn, *args):
    """(fn(*args), its wall time in s)."""
    start = time.perf_counter()
    out = fn(*args)
    return out, time.perf_counter() - start


def _compile(fn, *args):
    return _timed_call(lambda: fn.lower(*args).compile())


def so3jax_batched(controller, dtype, sizes, repeats) -> list[dict]:
    """One row per (batch, n_steps) of sizes. The programs are compiled first, one per core
    at a time (compile_s: that program's lowering plus its compilation, wall time), then
    timed one by one."""
    import jax.numpy as jnp

    from so3jax.parallel.xla_flags import usable_cores

    seeds = [jnp.arange(batch, dtype=jnp.int32) for batch, _ in sizes]
    lowered = [_timed_call(_batched_fn(controller, dtype, n_steps).lower, s) for (_, n_steps), s in zip(sizes, seeds)]
    with ThreadPoolExecutor(min(len(lowered), usable_cores())) as pool:
        programs = list(pool.map(lambda low: _timed_call(low[0].compile), lowered))
    rows = []
    for (batch, n_steps), s, (_, lower_s), (compiled, compile_s) in zip(sizes, seeds, lowered, programs):
        compile_s += lower_s
        out = compiled(s)
        assert out.rmse.dtype == jnp.dtype(dtype), out.rmse.dtype
        median, times = _median_time(functools.partial(compiled, s), repeats)
        rows.append(_row("so3jax", controller, dtype, batch, n_steps, median, times, compile_s=compile_s))
    return rows


def so3jax_single(controller, dtype, n_steps, repeats) -> dict:
    """One trajectory through ``rollout`` with a scalar seed (what ``simulate`` runs)."""
    import jax
    import jax.numpy as jnp

    from so3jax.sim.rollout import rollout

    scenario, ctrl, gains = _setup(controller, dtype, n_steps)
    fn = jax.jit(lambda seed: rollout(scenario, ctrl, gains, seed, record_every=n_steps).metrics)
    seed = jnp.int32(0)
    compiled, compile_s = _compile(fn, seed)
    median, times = _median_time(lambda: compiled(seed), repeats)
    return _row("so3jax-single", controller, dtype, 1, n_steps, median, times, compile_s=compile_s)


def so3jax_all_cores(controller, dtype, batch, n_steps, repeats, head_to_head=False) -> dict:
    """The batch split evenly over one XLA host device per core (what the CLI sets up),
    each device running its own compiled rollout_batch on its part, dispatched together
    (as ``so3jax sweep`` does): equal work to Numba's prange over all cores. In a
    subprocess, since the device count must be set before JAX starts.

    head_to_head: the same process also times the Numba baseline at the same batch and
    horizon (noise precomputed, and drawn in its kernel), in rounds that alternate the
    three, so each ratio compares runs seconds apart: this machine's rate drifts by
    +-15-30 % over minutes, more than the ratios being measured."""
    spec = {"controller": controller, "dtype": dtype, "batch": batch, "n_steps": n_steps, "repeats": repeats}
    spec["head_to_head"] = head_to_head
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env["JAX_PLATFORMS"] = "cpu"  # host devices, also on a machine with a GPU
    code = (
        f"import sys; sys.path.insert(0, {str(Path(__file__).resolve().parents[1])!r}); "
        f"from benchmarks import throughput; throughput._all_cores_child({json.dumps(spec)!r})"
    )
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=False)
    if proc.returncode:
        raise RuntimeError(f"all-cores child failed:\n{proc.stderr[-3000:]}")
    r = json.loads(proc.stdout.strip().splitlines()[-1])
    extra = {"devices": r["devices"]}
    if "head_to_head" in r:
        extra["head_to_head"] = r["head_to_head"]
        log(
            "  interleaved with Numba: so3jax / Numba "
            + ", ".join(f"{k} {v['ratio_median']:.2f}x" for k, v in r["head_to_head"].items())
        )
    return _row("so3jax-all-cores", controller, dtype, batch, n_steps, r["median"], r["times"], **extra)


def _all_cores_child(spec: str) -> None:
    from so3jax import configure_xla

    configure_xla(every_core=True)
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    spec = json.loads(spec)
    import numpy as np

    devices = jax.devices()[: spec["batch"]]
    fn = _batched_fn(spec["controller"], spec["dtype"], spec["n_steps"])
    parts = np.array_split(np.arange(spec["batch"], dtype=np.int32), len(devices))  # sizes differ by 1 at most
    shards = [jax.device_put(jnp.asarray(part), d) for part, d in zip(parts, devices)]
    lowered = [fn.lower(shard) for shard in shards]
    with ThreadPoolExecutor(len(lowered)) as pool:  # compiled in parallel, as so3jax sweep does
        compiled = list(pool.map(lambda low: low.compile(), lowered))
    run = lambda: [f(shard) for f, shard in zip(compiled, shards)]
    median, times = _median_time(run, spec["repeats"])
    out = {"median": median, "times": times, "devices": len(devices)}
    numba_loop = _numba() if spec.get("head_to_head") else None
    if numba_loop is not None:
        out["head_to_head"] = _head_to_head(run, numba_loop, spec)
    print(json.dumps(out))


def _head_to_head(run, numba_loop, spec) -> dict:
    """Rounds of (so3jax, Numba with precomputed noise, Numba drawing it), the order rotated
    each round; per baseline the median over rounds of baseline time / so3jax time."""
    import jax

    seeds = list(range(spec["batch"]))
    noise = {impl: _noise_argument(impl, seeds, spec["n_steps"], "float64") for impl in ("numba", "numba-draw")}
    contenders = {
        "so3jax": lambda: jax.block_until_ready(run()),
        **{
            impl: functools.partial(numba_loop.simulate, spec["controller"], spec["n_steps"], seeds, noise=arg)
            for impl, arg in noise.items()
        },
    }
    for fn in contenders.values():
        fn()  # warm-up (Numba: compile or cache load)
    times = {name: [] for name in contenders}
    names = list(contenders)
    for r in range(max(5, spec["repeats"])):
        first = r % len(names)  # who goes first rotates
        for name in names[first:] + names[:first]:
            times[name].append(_timed(contenders[name]))
    return {
        name: {
            "so3jax_s": times["so3jax"],
            "baseline_s": times[name],
            "ratio_median": statistics.median(b / a for a, b in zip(times["so3jax"], times[name])),
        }
        for name in names[1:]
    }


def _row(impl, controller, dtype, batch, n_steps, median, times, **extra) -> dict:
    row = {
        "impl": impl,
        "controller": controller,
        "dtype": dtype,
        "batch": batch,
        "n_steps": n_steps,
        "run_s": median,
        "runs_s": times,
        "trajectory_steps_per_s": batch * n_steps / median,
        "us_per_step": 1e6 * median / n_steps,  # one step of the whole batch
        **extra,
    }
    log(
        f"  {impl:14s} {controller:8s} {dtype:7s} B={batch:<5d} N={n_steps:<6d} "
        f"{row['trajectory_steps_per_s'] / 1e6:8.3f} M steps/s  {row['us_per_step']:9.2f} us/step"
        + (f"  compile {extra['compile_s']:.2f} s" if "compile_s" in extra else "")
    )
    return row


# --- baselines -------------------------------------------------------------------------


def _numba():
    try:
        from benchmarks.baselines import numba_loop
    except ImportError:
        return None
    return numba_loop


def _noise_argument(impl, seeds, n_steps, dtype):
    """The baselines' ``noise``: "draw" for impl "numba-draw" (the Numba kernel draws it, as
    so3jax's timings include its PRNG), else eta precomputed outside the timing."""
    import numpy as np

    from benchmarks.baselines.noise import paper_noise_batch

    return "draw" if impl == "numba-draw" else paper_noise_batch(seeds, n_steps, np.dtype(dtype))


def baseline(module, impl, controller, dtype, batch, n_steps, repeats) -> dict:
    seeds = list(range(batch))
    noise = _noise_argument(impl, seeds, n_steps, dtype)
    start = time.perf_counter()
    module.simulate(controller, n_steps, seeds, dtype=dtype, noise=noise)  # numba: compile (or cache load)
    first_s = time.perf_counter() - start
    median, times = _median_time(lambda: module.simulate(controller, n_steps, seeds, dtype=dtype, noise=noise), repeats)
    extra = {"first_call_s": first_s}
    if impl.startswith("numba"):
        import numba

        extra["threads"] = numba.get_num_threads()
    return _row(impl, controller, dtype, batch, n_steps, median, times, **extra)


# --- correctness gate ------------------------------------------------------------------


def _deviation(ours: dict, theirs: dict) -> dict:
    """Relative deviation per quantity: max |a - b| / max |b| (per array)."""
    import numpy as np

    out = {}
    for key in ("rmse", "effort", "R"):
        a, b = np.asarray(ours[key], np.float64), np.asarray(theirs[key], np.float64)
        out[key] = float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))
    return out


@functools.cache
def _so3jax_metrics(controller, n_steps, seeds: tuple, dt, dtype="float64") -> dict:
    import jax.numpy as jnp
    import numpy as np

    seeds = jnp.asarray(seeds, jnp.int32)
    metrics, final = _batched_fn(controller, dtype, n_steps, dt, full=True)(seeds)
    return {"rmse": np.asarray(metrics.rmse), "effort": np.asarray(metrics.effort), "R": np.asarray(final.R)}


def correctness(quick: bool, controllers=CONTROLLERS) -> dict:
    """so3jax against the baselines, float64; every case's deviations and the maximum."""
    from benchmarks.baselines import numpy_loop

    numba_loop = _numba()
    cases = [("numpy", numpy_loop, 300, [0, 1], 0.01, "300 steps at dt = 0.01 s")]
    if numba_loop is not None:
        cases.append(
            ("numba", numba_loop, 2700, [0, 1], 1.0, "2700 steps at dt = 1 s: both switches (t = 500, 2600 s)")
        )
        cases.append(("numba-draw", numba_loop, 2700, [0, 1], 1.0, "as above, the noise drawn in the kernel"))
        if not quick:
            cases.append(("numba", numba_loop, 50_300, [0, 1], 0.01, "50 300 steps at dt = 0.01 s: across t = 500 s"))
    checks = []
    for impl, module, n_steps, seeds, dt, what in cases:
        for controller in controllers:
            start = time.perf_counter()
            noise = _noise_argument(impl, seeds, n_steps, "float64")
            theirs = module.simulate(controller, n_steps, seeds, dt=dt, noise=noise)
            ours = _so3jax_metrics(controller, n_steps, tuple(seeds), dt, "float64")
            dev = _deviation(ours, theirs)
            checks.append(
                {
                    "against": impl,
                    "controller": controller,
                    "n_steps": n_steps,
                    "dt": dt,
                    "seeds": seeds,
                    "what": what,
                    "relative_deviation": dev,
                    "max": max(dev.values()),
                    "s": time.perf_counter() - start,
                }
            )
            log(
                f"  check vs {impl:10s} {controller:8s} N={n_steps:<6d} dt={dt}: "
                f"max relative deviation {max(dev.values()):.2e}"
            )
    worst = max(c["max"] for c in checks)
    return {
        "tolerance": TOLERANCE,
        "max_relative_deviation": worst,
        "passed": bool(worst <= TOLERANCE),
        "numba_checked": numba_loop is not None,
        "checks": checks,
    }


def float32_deviation(controllers=CONTROLLERS, n_steps: int = 300) -> dict:
    """For information: so3jax float32 against so3jax float64 (no tolerance)."""
    out = {}
    for controller in controllers:
        ours = _so3jax_metrics(controller, n_steps, (0, 1), 0.01, "float32")
        ref = _so3jax_metrics(controller, n_steps, (0, 1), 0.01, "float64")  # the gate's, cached
        out[controller] = _deviation(ours, ref)
    return {"n_steps": n_steps, "relative_deviation": out}


# --- FLOPs and peak --------------------------------------------------------------------


def step_cost(controller: str, dtype: str, batch: int | None) -> dict:
    """XLA's cost analysis of one closed-loop step (``so3jax.sim.rollout.step``).

    batch None: one trajectory; else a natively batched step over ``batch`` seeds
    (scenario and gains shared: a trailing unit axis), reported per trajectory.
    """
    import jax
    import jax.numpy as jnp

    from so3jax.sim.rollout import disturbance_at, initial_state, step

    scenario, ctrl, gains = _setup(controller, dtype, 10)
    if batch is None:
        key = jax.random.key(0)
        state = initial_state(scenario, ctrl, gains)
    else:
        scenario = jax.tree.map(lambda x: jnp.asarray(x)[..., None], scenario)
        gains = jax.tree.map(lambda x: jnp.asarray(x)[..., None], gains)
        key = jax.vmap(jax.random.key)(jnp.arange(batch, dtype=jnp.int32))
        state = initial_state(scenario, ctrl, gains, (batch,))

    def one(key, state):
        k = jnp.int32(0)
        return step(scenario, ctrl, gains, disturbance_at(scenario, key, k), state, k)

    cost = jax.jit(one).lower(key, state).compile().cost_analysis()
    if isinstance(cost, (list, tuple)):  # older JAX: one dict per computation
        cost = cost[0]
    per = batch or 1
    return {
        "flops": float(cost.get("flops", float("nan"))) / per,
        "transcendentals": float(cost.get("transcendentals", float("nan"))) / per,
        "bytes_accessed": float(cost.get("bytes accessed", float("nan"))) / per,
    }


def prng_cost(dtype: str) -> dict:
    """XLA's count for the disturbance draw alone (the fold_in + normal of docs/model.md §4, as so3jax draws
    it), part of every step."""
    import jax

    from so3jax.dynamics.disturbance import noise

    def draw(key, k):
        return noise(key, k, dtype)

    cost = jax.jit(draw).lower(jax.random.key(0), jax.numpy.int32(0)).compile().cost_analysis()
    if isinstance(cost, (list, tuple)):
        cost = cost[0]
    return {
        "flops": float(cost.get("flops", float("nan"))),
        "transcendentals": float(cost.get("transcendentals", float("nan"))),
    }


def _matmul_peak(n: int, repeats: int = 3) -> float:
    import numpy as np

    rng = np.random.default_rng(0)
    a, b = rng.standard_normal((n, n)), rng.standard_normal((n, n))
    a @ b  # warm-up
    best = min(_timed(lambda: a @ b) for _ in range(repeats))
    return 2.0 * n**3 / best


def _timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def _device_matmul_peak(dtype: str, n: int, repeats: int = 5) -> float:
    """FLOP/s of a jitted n x n matmul on JAX's default device (best of ``repeats``)."""
    import jax
    import jax.numpy as jnp

    keys = jax.random.split(jax.random.key(0))
    a, b = (jax.random.normal(k, (n, n), dtype) for k in keys)
    matmul = jax.jit(lambda a, b: jnp.matmul(a, b, precision="highest"))
    matmul(a, b).block_until_ready()  # compile and warm up
    best = min(_timed(lambda: matmul(a, b).block_until_ready()) for _ in range(repeats))
    return 2.0 * n**3 / best


def peak_flops(n: int) -> dict:
    """The machine's peak, by matmul FLOP/s. On CPU: float64 numpy, all BLAS threads
    (here) and one thread (a subprocess). On an accelerator: a jitted JAX matmul on the
    device, float64 and float32 (each dtype's rows are set against its own peak)."""
    import jax

    if jax.default_backend() != "cpu":
        n = max(n, 8192)  # a GPU needs a large matmul to reach its peak
        by_dtype = {d: _device_matmul_peak(d, n) for d in DTYPES}
        log("  peak matmul on the device, " + ", ".join(f"{d} {v / 1e12:.1f} TFLOP/s" for d, v in by_dtype.items()))
        return {
            "matmul_n": n,
            "flops_per_s": by_dtype["float64"],
            "flops_per_s_by_dtype": by_dtype,
            "flops_per_s_one_thread": None,
            "what": f"best of 5, jax.jit matmul (precision highest) on {jax.devices()[0].device_kind}",
        }
    all_threads = _matmul_peak(n)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    n1 = min(n, 2048)  # one thread reaches its peak by then, in a quarter of the time
    code = (f"import sys; sys.path.insert(0, {str(Path(__file__).resolve().parent)!r}); "
            f"import throughput; print(throughput._matmul_peak({n1}))")
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=False)
    one_thread = float(proc.stdout.strip().splitlines()[-1]) if proc.returncode == 0 else None
    log(
        f"  peak float64 matmul {n}x{n}: {all_threads / 1e9:.1f} GFLOP/s (all threads), "
        f"{(one_thread or float('nan')) / 1e9:.1f} GFLOP/s (one thread)"
    )
    return {
        "matmul_n": n,
        "flops_per_s_all_threads": all_threads,
        # on a busy machine one thread can beat all of them: the peak is the best this run saw
        "flops_per_s": max(all_threads, one_thread or 0.0),
        "matmul_n_one_thread": n1,
        "flops_per_s_one_thread": one_thread,
        "what": "best of 3, numpy float64 (OpenBLAS threads: all, then 1)",
    }


# --- so3jax paper ----------------------------------------------------------------------


def paper_wall_time(timeout: float) -> dict:
    """``so3jax paper --no-figures --json`` in a subprocess (its default: one host device per
    core), cold: the CLI's persistent compilation cache is turned off, so compile is included."""
    with tempfile.TemporaryDirectory() as out:
        cmd = [sys.executable, "-m", "so3jax.commands", "paper", "--no-figures", "--json", "--out", out]
        env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
        env["SO3JAX_CACHE_DIR"] = ""  # no cached compilations
        start = time.perf_counter()
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env, check=False)
        except subprocess.TimeoutExpired:
            return {"error": f"timed out after {timeout} s"}
        total = time.perf_counter() - start
    if proc.returncode != 0:
        return {"error": proc.stderr[-2000:], "returncode": proc.returncode}
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    config = report["config"]
    result = {
        "command": "SO3JAX_CACHE_DIR= so3jax paper --no-figures --json",
        "n_steps": config["n_steps"],
        "wall_time_s": config["wall_time_s"],  # both rollouts, compile included (its own clock)
        "process_wall_s": total,  # the whole command: Python + JAX import, validation, output
        "devices": config["devices"],
        "rmse": {c: report[c]["rmse"] for c in CONTROLLERS},
        "diverged": {c: report[c]["diverged"] for c in CONTROLLERS},
    }
    log(f"  so3jax paper: {result['wall_time_s']:.2f} s (rollouts + compile), {total:.2f} s (process)")
    return result


# --- report ----------------------------------------------------------------------------


def ratios(rows: list[dict]) -> list[dict]:
    """so3jax / baseline trajectory-steps/s at equal controller and batch (baseline dtype float64
    unless it was run in the same dtype)."""
    out = []
    ours = [r for r in rows if r["impl"] in ("so3jax", "so3jax-all-cores")]
    for base in (r for r in rows if r["impl"] in ("numpy", "numba", "numba-draw")):
        for r in ours:
            if r["controller"] != base["controller"] or r["batch"] != base["batch"]:
                continue
            if base["dtype"] != r["dtype"] and any(
                b["impl"] == base["impl"]
                and b["controller"] == base["controller"]
                and b["batch"] == base["batch"]
                and b["dtype"] == r["dtype"]
                for b in rows
            ):
                continue  # the same-dtype baseline exists: compare with that one
            if r["impl"] == "so3jax-all-cores" and not base["impl"].startswith("numba"):
                continue
            out.append(
                {
                    "controller": r["controller"],
                    "batch": r["batch"],
                    "so3jax": r["impl"],
                    "so3jax_dtype": r["dtype"],
                    "baseline": base["impl"],
                    "baseline_dtype": base["dtype"],
                    "so3jax_over_baseline": r["trajectory_steps_per_s"] / base["trajectory_steps_per_s"],
                }
            )
    return out


def flop_rates(rows, costs, peak) -> list[dict]:
    out = []
    for r in rows:
        if r["impl"] not in ("so3jax", "so3jax-single"):
            continue
        cost = costs[r["controller"]][r["dtype"]]
        cost_from = "batched" if r["batch"] > 1 and cost["batched"] else "single"
        cost = cost[cost_from]
        if cost is None:
            continue
        achieved = cost["flops"] * r["trajectory_steps_per_s"]
        peak_here = peak.get("flops_per_s_by_dtype", {}).get(r["dtype"], peak["flops_per_s"])
        out.append(
            {
                "impl": r["impl"],
                "controller": r["controller"],
                "dtype": r["dtype"],
                "batch": r["batch"],
                "flops_per_step": cost["flops"],
                "flops_counted_on": cost_from,
                "achieved_flops_per_s": achieved,
                "fraction_of_peak": achieved / peak_here,
                "fraction_of_one_thread_peak": achieved / peak["flops_per_s_one_thread"]
                if peak["flops_per_s_one_thread"]
                else None,
            }
        )
    return out


def plot(path: str, report: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = report["throughput"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    styles = {"so3jax": "-o", "so3jax-all-cores": "-D", "numpy": ":s", "numba": "--^", "numba-draw": "--v"}
    labels = {
        "so3jax": "so3jax, one core",
        "so3jax-all-cores": "so3jax, every core",
        "numpy": "NumPy",
        "numba": "Numba, every core, noise given",
        "numba-draw": "Numba, every core, draws noise",
    }
    for ax, controller in zip(axes, CONTROLLERS):
        for impl, style in styles.items():
            for dtype in DTYPES:
                pts = sorted(
                    (r["batch"], r["trajectory_steps_per_s"])
                    for r in rows
                    if r["impl"] == impl and r["controller"] == controller and r["dtype"] == dtype
                )
                if pts:
                    ax.plot(
                        *zip(*pts), style, label=f"{labels[impl]} {dtype}", alpha=1.0 if dtype == "float64" else 0.55
                    )
        ax.set_xscale("log", base=2)
        ax.set_yscale("log")
        ax.set_title(f"{controller}")
        ax.set_xlabel("batch (trajectories)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("trajectory-steps / s")
    axes[1].legend(fontsize=8)
    m = report["machine"]
    fig.suptitle(
        f"so3jax throughput, {m['device']} ({m['cpu_model']}, {m['affinity']} cores), "
        f"load avg {m['load_avg_start'][0]:.1f}, {report['date']}",
        fontsize=9,
    )
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--quick", action="store_true", help="small sizes, 3 repeats, no paper run, no 50 300-step check"
    )
    parser.add_argument("--controllers", nargs="+", default=list(CONTROLLERS), choices=CONTROLLERS)
    parser.add_argument("--dtypes", nargs="+", default=list(DTYPES), choices=DTYPES)
    parser.add_argument("--batches", nargs="+", type=int, help="so3jax batch sizes (default 1 16 256 4096)")
    parser.add_argument("--target", type=int, help="trajectory-steps per timed run (default 200 000)")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs after the warm-up (default 3)")
    parser.add_argument("--single-steps", type=int, help="steps of the one-trajectory timing (default 20 000)")
    parser.add_argument(
        "--single-dtypes",
        nargs="+",
        default=["float64"],
        choices=DTYPES,
        help="dtypes of the one-trajectory timing (default float64)",
    )
    parser.add_argument("--numpy-batches", nargs="+", type=int, help="NumPy baseline batches (default 1 256)")
    parser.add_argument("--numba-batches", nargs="+", type=int, help="Numba baseline batches (default 1 256 4096)")
    parser.add_argument(
        "--all-cores-batches", nargs="+", type=int, help="so3jax on every core (host devices) batches (default 4096)"
    )
    parser.add_argument("--no-baselines", action="store_true", help="skip timing the baselines (the gate still runs)")
    parser.add_argument("--no-paper", action="store_true", help="skip the so3jax paper wall time")
    parser.add_argument("--paper-timeout", type=float, default=180.0)
    parser.add_argument(
        "--matmul-n",
        type=int,
        help="size of the peak-measuring matmul (default 4096; quick 1024; one thread: at most 2048)",
    )
    parser.add_argument("--plot", help="write a PNG of throughput against batch size here")
    parser.add_argument("--budget", type=float, help="seconds: once past it, skip the remaining (lower-priority) work")
    args = parser.parse_args(argv)
    quick = args.quick
    batches = args.batches or ([1, 16] if quick else [1, 16, 256, 4096])
    target = args.target or (20_000 if quick else 200_000)
    repeats = args.repeats
    single_steps = args.single_steps or (2_000 if quick else 20_000)
    numpy_batches = args.numpy_batches or ([1] if quick else [1, 256])
    numba_batches = args.numba_batches or ([1, 16] if quick else [1, 256, 4096])
    matmul_n = args.matmul_n or (1024 if quick else 4096)
    all_cores_batches = args.all_cores_batches or ([16] if quick else [4096])

    import jax

    from so3jax import configure_xla
    from so3jax.parallel.xla_flags import usable_cores

    configure_xla()  # before JAX starts its backend

    jax.config.update("jax_enable_x64", True)  # float64 available; float32 runs build float32 scenarios
    import numpy as np

    started = time.perf_counter()
    device = jax.devices()[0]
    report = {
        "benchmark": "throughput",
        "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
        "quick": quick,
        "machine": {
            "device": f"{device.platform}:{device.device_kind}",
            "jax_devices": len(jax.devices()),
            "cpu_model": cpu_model(),
            "cpus": os.cpu_count(),
            "affinity": usable_cores(),
            "platform": platform.platform(),
            "python": platform.python_version(),
            "jax": jax.__version__,
            "numpy": np.__version__,
            "load_avg_start": list(os.getloadavg()),
        },
        "protocol": {
            "batches": batches,
            "target_trajectory_steps_per_run": target,
            "repeats": repeats,
            "statistic": "median after one warm-up run",
            "dt": 0.01,
            "scenario": "the paper's (phase 0 at these horizons)",
            "so3jax": "jax.jit(rollout_batch(..., scenario_axes=None, record_every=n_steps)), AOT-compiled",
            "baselines": "numpy, numba: noise precomputed outside the timing; numba-draw: drawn inside its "
            "kernel (the same bits), as so3jax draws it (threefry) inside",
        },
    }

    log("correctness gate (float64):")
    report["correctness"] = correctness(quick, args.controllers)
    if not report["correctness"]["passed"]:
        log(f"FAILED: deviation {report['correctness']['max_relative_deviation']:.2e} > {TOLERANCE:g}; not timing")
        print(json.dumps(report))
        return 1

    # The work in order of priority; with --budget, what would start after it is skipped (and listed).
    rows, costs = [], {c: {d: {"single": None, "batched": None} for d in args.dtypes} for c in args.controllers}
    numba_loop = None if args.no_baselines else _numba()
    report["numba_available"] = _numba() is not None
    tasks = []

    def batched(controller, dtype):
        sizes = [(batch, _steps_for(batch, target, 100, 40_000)) for batch in batches]
        rows.extend(so3jax_batched(controller, dtype, sizes, repeats))

    def all_cores(controller, dtype):
        for batch in all_cores_batches:
            n_steps = _steps_for(batch, ALL_CORES_TARGET_FACTOR * target, 100, 40_000)
            head_to_head = numba_loop is not None and dtype == "float64"
            rows.append(so3jax_all_cores(controller, dtype, batch, n_steps, repeats, head_to_head))

    def cost(controller, dtype, batch):
        costs[controller][dtype]["batched" if batch else "single"] = step_cost(controller, dtype, batch)

    def numpy_baseline(controller, dtype):
        from benchmarks.baselines import numpy_loop

        for batch in numpy_batches:
            rows.append(baseline(numpy_loop, "numpy", controller, dtype, batch, 100 if batch == 1 else 30, repeats))

    def numba_baseline(controller):
        for batch in numba_batches:
            n_steps = _steps_for(batch, ALL_CORES_TARGET_FACTOR * target, 200, 200_000)
            for impl in ("numba", "numba-draw"):
                rows.append(baseline(numba_loop, impl, controller, "float64", batch, n_steps, repeats))

    def peak():
        report["peak"] = peak_flops(matmul_n)

    def paper():
        report["paper"] = paper_wall_time(args.paper_timeout)

    def f32_deviation():
        report["float32_vs_float64"] = float32_deviation(args.controllers)

    first, *others = args.dtypes
    for c in args.controllers:
        tasks.append((f"so3jax batched {c} {first}", functools.partial(batched, c, first)))
    for c in args.controllers:
        for d in args.single_dtypes:
            tasks.append(
                (
                    f"so3jax single {c} {d}",
                    functools.partial(lambda c, d: rows.append(so3jax_single(c, d, single_steps, repeats)), c, d),
                )
            )
    if not args.no_baselines:
        for c in args.controllers:
            tasks.append((f"numpy {c} float64", functools.partial(numpy_baseline, c, "float64")))
            if numba_loop is not None:
                tasks.append((f"numba {c}", functools.partial(numba_baseline, c)))
    for c in args.controllers:
        tasks.append((f"so3jax all cores {c} {first}", functools.partial(all_cores, c, first)))
    for c in args.controllers:
        tasks.append((f"step cost {c} {first}", functools.partial(cost, c, first, None)))
    tasks.append(("PRNG cost", lambda: report.__setitem__("prng_cost", {first: prng_cost(first)})))
    tasks.append(("peak", peak))
    if not (quick or args.no_paper):
        tasks.append(("so3jax paper", paper))
    for d in others:
        for c in args.controllers:
            tasks.append((f"so3jax batched {c} {d}", functools.partial(batched, c, d)))
        for c in args.controllers:
            tasks.append((f"step cost {c} {d}", functools.partial(cost, c, d, None)))
        if not args.no_baselines:
            for c in args.controllers:
                tasks.append((f"numpy {c} {d}", functools.partial(numpy_baseline, c, d)))
        tasks.append((f"{d} deviation", f32_deviation))
    if not quick:
        for c in args.controllers:
            tasks.append((f"step cost {c} {first} batch 256", functools.partial(cost, c, first, 256)))

    skipped = []
    for name, task in tasks:
        if args.budget and time.perf_counter() - started > args.budget:
            skipped.append(name)
            continue
        log(f"{name}:")
        task()
    if skipped:
        log(f"over the budget of {args.budget:.0f} s; skipped: {', '.join(skipped)}")
    report["skipped"] = skipped
    report["throughput"] = rows
    report["ratios"] = ratios(rows)
    report["step_cost"] = {
        "what": "XLA cost_analysis of so3jax.sim.rollout.step (one RK4 step, PRNG included); "
        "batched: per trajectory in a batch of 256",
        **costs,
    }
    for c, by_dtype in costs.items():
        for d, cost_d in by_dtype.items():
            single, batch_cost = cost_d["single"], cost_d["batched"]
            if single:
                log(
                    f"  {c:8s} {d}: {single['flops']:.0f} FLOPs + {single['transcendentals']:.0f} "
                    f"transcendentals / step "
                    f"(one trajectory)"
                    + (
                        f"; {batch_cost['flops']:.0f} + {batch_cost['transcendentals']:.1f} per "
                        f"trajectory in a batch of 256"
                        if batch_cost
                        else ""
                    )
                )
    if "peak" in report:
        report["flop_rates"] = flop_rates(rows, costs, report["peak"])

    report["summary"] = summary(report)
    report["machine"]["load_avg_end"] = list(os.getloadavg())
    report["wall_s"] = time.perf_counter() - started
    if args.plot:
        plot(args.plot, report)
        report["plot"] = args.plot
    print(json.dumps(report))
    return 0


def summary(report: dict) -> dict:
    """The headline numbers, float64: per controller, best batched rate and one-trajectory cost."""
    rows = report["throughput"]
    out = {}
    for controller in {r["controller"] for r in rows}:

        def pick(impl, dtype="float64", batch=None, controller=controller):
            cands = [
                r
                for r in rows
                if r["impl"] == impl
                and r["controller"] == controller
                and r["dtype"] == dtype
                and (batch is None or r["batch"] == batch)
            ]
            return max(cands, key=lambda r: r["trajectory_steps_per_s"]) if cands else None

        entry = {}
        for dtype in DTYPES:
            best, single = pick("so3jax", dtype), pick("so3jax-single", dtype)
            if best:
                entry[f"so3jax_{dtype}_best_Msteps_per_s"] = best["trajectory_steps_per_s"] / 1e6
                entry[f"so3jax_{dtype}_best_batch"] = best["batch"]
            if single:
                entry[f"so3jax_{dtype}_single_us_per_step"] = single["us_per_step"]
        for impl in ("numpy", "numba", "numba-draw"):
            best, single = pick(impl), pick(impl, batch=1)
            name = impl.replace("-", "_")
            if best:
                entry[f"{name}_best_Msteps_per_s"] = best["trajectory_steps_per_s"] / 1e6
                entry[f"{name}_best_batch"] = best["batch"]
            if single:
                entry[f"{name}_single_us_per_step"] = single["us_per_step"]
        all_cores = pick("so3jax-all-cores")
        if all_cores:
            entry["so3jax_all_cores_float64_best_Msteps_per_s"] = all_cores["trajectory_steps_per_s"] / 1e6
            entry["so3jax_all_cores_best_batch"] = all_cores["batch"]
            entry["so3jax_all_cores_devices"] = all_cores["devices"]
        if "numba_best_Msteps_per_s" in entry and "so3jax_float64_best_Msteps_per_s" in entry:
            entry["so3jax_over_numba_best"] = (
                entry["so3jax_float64_best_Msteps_per_s"] / entry["numba_best_Msteps_per_s"]
            )
        for impl in ("numba", "numba-draw") if all_cores else ():
            # both on every core: Numba's prange threads, so3jax's host devices
            name = impl.replace("-", "_")
            if f"{name}_best_Msteps_per_s" in entry:
                entry[f"so3jax_all_cores_over_{name}_best"] = (
                    entry["so3jax_all_cores_float64_best_Msteps_per_s"] / entry[f"{name}_best_Msteps_per_s"]
                )
            interleaved = all_cores.get("head_to_head", {}).get(impl)
            if interleaved:  # same batch, runs seconds apart: the robust ratio
                entry[f"so3jax_all_cores_over_{name}_interleaved"] = interleaved["ratio_median"]
        cost = report.get("step_cost", {}).get(controller, {}).get("float64")
        if cost and cost["single"]:
            entry["flops_per_step"] = cost["single"]["flops"]
            entry["transcendentals_per_step"] = cost["single"]["transcendentals"]
        out[controller] = entry
    return out


if __name__ == "__main__":
    sys.exit(main())
