"""Gradients of the docs/model.md §6 tuning cost through whole rollouts: time and memory.

For each controller and horizon N (steps of dt = 0.01 s) this measures, on a batch of B
scenarios (inertia scales x disturbance seeds, vmapped, one XLA CPU device), float64:

* ``value``: the cost alone (forward rollouts), compile and run time, peak RSS;
* ``forward``: value and gradient by forward mode (jax.jacfwd over the log-gains);
* ``reverse``: value and gradient by reverse mode (jax.value_and_grad through the
  rollout's sqrt(N)-block checkpointing);

each in its own subprocess, so every peak resident set size (ru_maxrss) belongs to one
computation; the peak once compiled, before running, is reported too (XLA's compilation
of the reverse-mode program is itself a large part of the peak). XLA's own estimate of the temporaries of the
compiled program is reported alongside. At ``--fd-horizon`` the gradients are checked
against central finite differences of the value (step 1e-4 in log-gain).

    python benchmarks/gradients.py                       # N = 1e4, 3e4, 1e5, 4e5; B = 8
    python benchmarks/gradients.py --horizons 10000 --batch 2 --controllers pd

With ``--mission FILE`` the rollouts fly that mission's loop (e.g. missions/flight.toml:
sensors, MEKF, wheels, sampled control) at its gains, over B seeds of its scenario:

    python benchmarks/gradients.py --mission missions/flight.toml --horizons 400000 --batch 4 \
        --controllers pd adaptive mrp_feedback sliding_mode --fd-horizon 0 --modes forward reverse

Prints one JSON object: ``runs`` (one per subprocess), ``summary`` (gradient / value
time ratios, from runs interleaved with the value's in one process, and peak RSS per
controller and N) and ``fd_check``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import queue
import resource
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

WHATS = ("value", "forward", "reverse")
FD_STEP = 1e-4


def _child(spec: dict) -> dict:
    """One measurement, in this process (run as a subprocess by the parent)."""
    from so3jax import configure_xla

    configure_xla()  # before JAX starts its backend
    import jax

    jax.config.update("jax_enable_x64", True)
    import warnings

    import jax.numpy as jnp
    import numpy as np
    from jax.flatten_util import ravel_pytree

    from so3jax.dynamics.inertia import InertiaWarning
    from so3jax.dynamics.scenario import paper_scenario
    from so3jax.jobs import tune
    from so3jax.sim import gradients

    rss_start = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    diagonal = spec.get("diagonal_gamma", False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InertiaWarning)
        if spec.get("mission"):  # the mission's scenario and loop, B seeds, its gains
            from so3jax.missions import mission as missions

            flown = missions.load(spec["mission"], [f"T={spec['N'] * 0.01!r}"])
            scenario, loop = flown.scenario(jnp.float64), flown.loop(jnp.float64)
            batch = gradients.make_batch([1.0], list(range(spec["batch"])), jnp.float64)
            controller = flown.controller(spec["controller"])[0]
            source = "mission" if spec["controller"] in flown.controllers else "paper"
            gains = tune.resolve_gains(spec["controller"], source, jnp.float64, diagonal, flown)
        else:
            scenario, loop, flown = paper_scenario(T=spec["N"] * 0.01), None, None
            scales = [0.9, 1.0, 1.1, 1.2][: max(1, spec["batch"] // 2)]
            seeds = list(range(spec["batch"] // len(scales)))
            batch = gradients.make_batch(scales, seeds, jnp.float64)
            controller = tune.CONTROLLERS[spec["controller"]]
            gains = tune.resolve_gains(spec["controller"], "paper", jnp.float64, diagonal_gamma=diagonal)
    refs = tune.CostRefs(jnp.asarray(1e-3), jnp.asarray(100.0), jnp.asarray(1.0))
    params = tune.to_params(gains)
    flat, unravel = ravel_pytree(params)
    through = {} if loop is None else {"loop": loop, "record_every": gradients.checkpoint_steps(loop, spec["what"])}

    def cost(p):
        metrics = gradients.batch_metrics(scenario, controller, tune.to_gains(p), batch, **through)
        return jnp.mean(tune.scenario_costs(metrics, refs, "weighted")), ()

    if spec["what"] == "value":

        def fn(x):
            return cost(unravel(x))[0]

    else:
        value_and_grad = gradients.value_and_grad(cost, spec["what"])

        def fn(x):
            (value, _), grad = value_and_grad(unravel(x))
            return value, ravel_pytree(grad)[0]

    t0 = time.perf_counter()
    compiled = jax.jit(fn).lower(flat).compile()
    compile_s = time.perf_counter() - t0
    rss_compiled = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    memory = compiled.memory_analysis()
    runs = []
    for _ in range(spec["repeat"]):
        t0 = time.perf_counter()
        out = jax.block_until_ready(compiled(flat))
        runs.append(time.perf_counter() - t0)
    result = {
        **spec,
        "n_params": int(flat.size),
        "compile_s": compile_s,
        "run_s": min(runs),
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "rss_after_import_mb": rss_start,
        "peak_rss_after_compile_mb": rss_compiled,
        "xla_temp_mb": memory.temp_size_in_bytes / 2**20 if memory is not None else None,
        "device": f"{jax.devices()[0].platform}:{jax.devices()[0].device_kind}",
    }
    stats = jax.devices()[0].memory_stats() if jax.default_backend() != "cpu" else None
    if stats and "peak_bytes_in_use" in stats:  # on an accelerator the peak that matters is the device's
        result["device_peak_mb"] = stats["peak_bytes_in_use"] / 2**20
    if spec["what"] == "value":
        result["value"] = float(out)
        if spec.get("fd"):
            steps = np.eye(flat.size) * FD_STEP
            result["fd_gradient"] = [
                (float(compiled(flat + e)) - float(compiled(flat - e))) / (2 * FD_STEP) for e in steps
            ]
    else:
        result["value"] = float(out[0])
        result["gradient"] = np.asarray(out[1]).tolist()
        # The time ratio, from runs interleaved in this process (after the RSS reading):
        # robust to a load that changes between subprocesses.
        value = jax.jit(lambda x: cost(unravel(x))[0]).lower(flat).compile()
        jax.block_until_ready(value(flat))
        pairs = []
        for _ in range(spec["repeat"]):
            t0 = time.perf_counter()
            jax.block_until_ready(compiled(flat))
            t1 = time.perf_counter()
            jax.block_until_ready(value(flat))
            pairs.append((t1 - t0, time.perf_counter() - t1))
        result["ratio_to_value_interleaved"] = min(g for g, _ in pairs) / min(v for _, v in pairs)
    return result


def _run_child(spec: dict, cpu: int | None) -> dict:
    env = dict(os.environ, XLA_FLAGS="")  # one XLA CPU device
    cmd = [sys.executable, __file__, "--child", json.dumps(spec)]
    if cpu is not None:
        cmd = ["taskset", "-c", str(cpu)] + cmd
    proc = subprocess.run(cmd, check=False, capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        return {**spec, "error": proc.stderr[-2000:]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _relative_error(a, b):
    num = sum((x - y) ** 2 for x, y in zip(a, b)) ** 0.5
    return num / sum(y**2 for y in b) ** 0.5


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--child", help=argparse.SUPPRESS)
    parser.add_argument("--controllers", nargs="+", default=["pd", "adaptive"],
                        choices=["pd", "adaptive", "mrp_feedback", "sliding_mode"])
    parser.add_argument("--mission", help="fly this mission file's loop and gains (default: the paper's scenario)")
    parser.add_argument("--horizons", nargs="+", type=int, default=[10_000, 30_000, 100_000, 400_000])
    parser.add_argument("--batch", type=int, default=8, help="scenarios per batch (even: 2 seeds x B/2 inertias)")
    parser.add_argument("--modes", nargs="+", default=["forward", "reverse"], choices=["forward", "reverse"])
    parser.add_argument("--diagonal-gamma", action="store_true", help="adaptive: 11 log-gains (Gamma's diagonal)")
    parser.add_argument("--fd-horizon", type=int, default=400_000, help="N of the finite-difference check (0: none)")
    parser.add_argument("--jobs", type=int, default=1, help="subprocesses at a time, each pinned to its own core")
    parser.add_argument("--log", help="also append each run's JSON to this file as it finishes")
    args = parser.parse_args()
    if args.child:
        print(json.dumps(_child(json.loads(args.child))))
        return

    specs = [
        {
            "controller": c,
            "N": n,
            "what": what,
            "batch": args.batch,
            "repeat": max(1, min(3, 100_000 // n)),
            "fd": what == "value" and n == args.fd_horizon,
            "diagonal_gamma": args.diagonal_gamma and c == "adaptive",
            "mission": str(Path(args.mission).resolve()) if args.mission else None,
        }
        for c in args.controllers
        for n in args.horizons
        for what in ("value", *args.modes)
    ]

    def guess(spec):  # rough relative duration, measured at B = 8
        work = {"value": 1 + 2 * spec["fd"] * (2 if spec["controller"] == "pd" else 3), "forward": 5, "reverse": 7}
        return spec["N"] * work[spec["what"]] * (1.6 if spec["controller"] == "adaptive" else 1.0)

    order = sorted(range(len(specs)), key=lambda i: -guess(specs[i]))  # longest first
    free_cpus = queue.Queue()  # a core per running subprocess, never two on one core
    for cpu in sorted(os.sched_getaffinity(0))[: args.jobs] if args.jobs > 1 else [None]:
        free_cpus.put(cpu)
    started = time.perf_counter()

    def run(i):
        cpu = free_cpus.get()
        try:
            result = _run_child(specs[i], cpu)
        finally:
            free_cpus.put(cpu)
        if args.log:
            with open(args.log, "a") as f:
                f.write(json.dumps(result) + "\n")
        return result

    with ThreadPoolExecutor(args.jobs) as pool:
        futures = {i: pool.submit(run, i) for i in order}
        runs = [futures[i].result() for i in range(len(specs))]

    summary, fd_check = {}, {}
    for c in args.controllers:
        for n in args.horizons:
            by_what = {r["what"]: r for r in runs if r["controller"] == c and r["N"] == n and "error" not in r}
            if "value" not in by_what:
                continue
            value = by_what["value"]
            entry = {"value_s": value["run_s"], "peak_rss_mb": {w: r["peak_rss_mb"] for w, r in by_what.items()}}
            if "device_peak_mb" in value:
                entry["device_peak_mb"] = {w: r.get("device_peak_mb") for w, r in by_what.items()}
            for mode in args.modes:
                if mode in by_what:
                    entry[f"{mode}_s"] = by_what[mode]["run_s"]
                    entry[f"{mode}_over_value"] = by_what[mode]["ratio_to_value_interleaved"]
            summary.setdefault(c, {})[str(n)] = entry
            if "fd_gradient" in value:
                fd_check[c] = {
                    "N": n,
                    "fd_gradient": value["fd_gradient"],
                    **{
                        f"{mode}_relative_error": _relative_error(by_what[mode]["gradient"], value["fd_gradient"])
                        for mode in args.modes
                        if mode in by_what
                    },
                }
    import jax

    report = {
        "benchmark": "gradients",
        "machine": {
            "device": f"{jax.devices()[0].platform}:{jax.devices()[0].device_kind}",
            "platform": platform.platform(),
            "cpus": os.cpu_count(),
            "affinity": len(os.sched_getaffinity(0)),
            "python": platform.python_version(),
            "jax": jax.__version__,
            "load_average_at_end": os.getloadavg(),
        },
        "batch": args.batch,
        "mission": args.mission,
        "dt": 0.01,
        "wall_s": time.perf_counter() - started,
        "summary": summary,
        "fd_check": fd_check,
        "runs": runs,
    }
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
