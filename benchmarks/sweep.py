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

Prints one JSON object: ``runs`` (one per device count and controller) and ``full_sweep``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time

FULL = {"samples": 1024, "steps": 400_000}


def _child(spec: dict) -> list:
    """Measurements for one device count, in this process (a subprocess of the parent)."""
    import warnings

    import jax

    jax.config.update("jax_enable_x64", True)
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
    return runs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--devices", default="1,2,4", help="forced host device counts (default 1,2,4)")
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
    for devices in map(int, args.devices.split(",")):
        spec = {"T": args.T, "samples": args.samples, "chunk": args.chunk, "controllers": args.controllers.split(",")}
        env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}")
        proc = subprocess.run(
            [sys.executable, __file__, "--child", json.dumps(spec)], env=env, capture_output=True, text=True, check=False
        )
        if proc.returncode:
            sys.exit(f"child with {devices} device(s) failed:\n{proc.stderr}")
        runs += json.loads(proc.stdout.strip().splitlines()[-1])
    full = {}
    for devices in sorted({r["devices"] for r in runs}):
        rates = {r["controller"]: r["trajectory_steps_per_s"] for r in runs if r["devices"] == devices}
        seconds = sum(FULL["samples"] * FULL["steps"] / rate for rate in rates.values())
        full[str(devices)] = {"controllers": sorted(rates), "extrapolated_s": seconds, "extrapolated_min": seconds / 60}
    report = {
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "load_avg_1min": os.getloadavg()[0]},
        "runs": runs,
        "full_sweep": {"what": "extrapolated from the compiled rates above (compile excluded)", **FULL, "by_devices": full},
    }
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
