"""Throughput of ``so3jax sweep`` rollouts: samples/s and trajectory-steps/s, float64.

For each number of forced XLA host devices (each in its own subprocess, since the flag
must precede JAX) and each controller, this draws the default sweep's samples (the
paper's mission, dispersed as in sweeps/default.toml) over a horizon of T seconds at
dt = 0.01 s, and times ``so3jax.sweep.run_chunk`` -- the sweep's own chunk runner --
on --samples samples in chunks of --chunk: the first chunk (compile included) and then
the whole set again (compiled). Steps/s counts steps of single trajectories summed over
the batch; steps per CPU second (process time) is the rate that other load on a shared
machine disturbs least. From the compiled rates it extrapolates the full default sweep
(1024 samples x 400 000 steps x both controllers), stated as an extrapolation.

    python benchmarks/sweep.py                             # 1, 2, 4 devices; T = 50 s
    python benchmarks/sweep.py --devices 2 --T 200 --samples 256 --chunk 256
    python benchmarks/sweep.py --devices 1,2,2x1 --rounds 3    # one process against two on JAX's runtime

Prints one JSON object: ``runs`` (one per round, layout and controller) and ``full_sweep``
(per layout: the median rate over rounds and the extrapolation).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time

FULL = {"samples": 1024, "steps": 400_000}


def _child(spec: dict) -> list:
    """Measurements for one device count, in this process (a subprocess of the parent)."""
    import warnings

    import jax

    jax.config.update("jax_enable_x64", True)
    if spec.get("processes", 1) > 1:  # one of several processes on JAX's runtime (global mesh)
        from so3jax import distributed

        distributed.initialize(argparse.Namespace(
            distributed=True, coordinator=spec["coordinator"], num_processes=spec["processes"],
            process_id=spec["process_id"], timeout=300))
    import numpy as np

    from so3jax import dispersions, sweep
    from so3jax.scenario import InertiaWarning, steps_for_horizon

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InertiaWarning)
        config = sweep.load_config(None, (f"T={spec['T']}",))
    n_steps = steps_for_horizon(config.T, config.dt)
    mesh = sweep.batch_mesh()
    chunk = sweep.padded_chunk(spec["chunk"], mesh.size)
    n = -(-spec["samples"] // chunk) * chunk
    params = dispersions.draw_samples(config.dispersions, config.seed, n, config.max_draws).params
    runs = []
    for controller in spec["controllers"]:
        gains = jax.tree.map(np.asarray, config.gains[controller])

        def run(first, last, controller=controller, gains=gains):
            for start in range(first, last, chunk):
                part = jax.tree.map(lambda x, start=start: x[start : start + chunk], params)
                sweep.run_chunk(part, gains, controller, config.T, config.dt, mesh)

        start = time.perf_counter()
        run(0, chunk)
        first = time.perf_counter() - start
        start, cpu = time.perf_counter(), time.process_time()
        run(0, n)
        wall, cpu = time.perf_counter() - start, time.process_time() - cpu
        runs.append(
            {
                "devices": mesh.size,
                "processes": jax.process_count(),
                "controller": controller,
                "T": config.T,
                "n_steps": n_steps,
                "samples": n,
                "chunk": chunk,
                "first_chunk_s": first,
                "wall_s": wall,
                "cpu_s": cpu,
                "samples_per_s": n / wall,
                "trajectory_steps_per_s": n * n_steps / wall,
                "trajectory_steps_per_cpu_s": n * n_steps / cpu,
            }
        )
    if jax.process_count() > 1:
        from so3jax import distributed

        distributed.finish()  # every process meets; process 0 leaves last
    return runs


def _layout(text: str) -> tuple[int, int]:
    """'2' -> one process with 2 devices; '2x1' -> 2 processes with 1 device each."""
    processes, _, devices = text.partition("x")
    return (int(processes), int(devices)) if devices else (1, int(processes))


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run_children(spec: dict, processes: int, devices: int) -> list:
    """The measurements of process 0 of ``processes`` children with ``devices`` each."""
    env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}")
    coordinator = f"127.0.0.1:{_free_port()}"
    children = []
    for i in range(processes):
        child = {**spec, "processes": processes, "process_id": i, "coordinator": coordinator}
        children.append(subprocess.Popen([sys.executable, __file__, "--child", json.dumps(child)], env=env,
                                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    outputs = [child.communicate() for child in children]
    for child, (_, stderr) in zip(children, outputs):
        if child.returncode:
            sys.exit(f"child of {processes} x {devices} device(s) failed:\n{stderr}")
    lines = [line for line in outputs[0][0].splitlines() if line.startswith("[{")]
    return json.loads(lines[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--devices", default="1,2,4",
                        help="layouts: N (one process, N host devices) or PxD (P processes of D devices, joined "
                             "on JAX's runtime over 127.0.0.1); default 1,2,4")
    parser.add_argument("--rounds", type=int, default=1, help="rounds alternating the layouts (default 1)")
    parser.add_argument("--controllers", default="pd,adaptive")
    parser.add_argument("--T", type=float, default=50.0, help="horizon [s] (default 50)")
    parser.add_argument("--samples", type=int, default=128, help="samples timed (default 128)")
    parser.add_argument("--chunk", type=int, default=64, help="samples per chunk (default 64)")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(_child(json.loads(args.child))))
        return
    runs = []
    layouts = [_layout(text) for text in args.devices.split(",")]
    for _ in range(args.rounds):  # rounds alternate the layouts: a shared machine's load hits each alike
        for processes, devices in layouts:
            spec = {"T": args.T, "samples": args.samples, "chunk": args.chunk, "controllers": args.controllers.split(",")}
            runs += _run_children(spec, processes, devices)
    full = {}
    for layout in dict.fromkeys((r["processes"], r["devices"]) for r in runs):
        rates = {}
        for r in runs:
            if (r["processes"], r["devices"]) == layout:
                rates.setdefault(r["controller"], []).append(r["trajectory_steps_per_s"])
        rates = {c: statistics.median(v) for c, v in rates.items()}
        seconds = sum(FULL["samples"] * FULL["steps"] / rate for rate in rates.values())
        name = f"{layout[0]}x{layout[1] // layout[0]}" if layout[0] > 1 else str(layout[1])
        full[name] = {"controllers": sorted(rates), "median_trajectory_steps_per_s": rates,
                      "extrapolated_s": seconds, "extrapolated_min": seconds / 60}
    report = {
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "load_avg_1min": os.getloadavg()[0]},
        "runs": runs,
        "full_sweep": {"what": "extrapolated from the compiled rates above (compile excluded)", **FULL, "by_devices": full},
    }
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
