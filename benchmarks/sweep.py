"""Throughput of ``so3jax sweep`` rollouts: samples/s and trajectory-steps/s, float64.

For each number of forced XLA host devices (each in its own subprocess, since the flag
must precede JAX) and each controller, this draws the default sweep's samples (the
paper's mission, dispersed as in sweeps/default.toml) over a horizon of T seconds at
dt = 0.01 s, and times ``so3jax.jobs.sweep.run_chunk`` -- the sweep's own chunk runner --
on --samples samples in chunks of --chunk: the first chunk (compile included) and then
the whole set again (compiled). Steps/s counts steps of single trajectories summed over
the batch; steps per CPU second (process time) is the rate that other load on a shared
machine disturbs least. From the compiled rates it extrapolates the full default sweep
(1024 samples x 400 000 steps x both controllers), stated as an extrapolation.

    python benchmarks/sweep.py                             # 1, 2, 4 devices; T = 50 s
    python benchmarks/sweep.py --devices 2 --T 200 --samples 256 --chunk 256
    python benchmarks/sweep.py --devices 1,2,2x1 --rounds 3    # one process against two on JAX's runtime
    python benchmarks/sweep.py --devices 2x1,2x1:mesh --hog    # the two layouts, one core shared with a busy loop

Several processes (PxD) share the chunks as ``so3jax sweep`` does: whole chunks, each
taken by the first free process through a claim file (layout "chunks", the default), or
every chunk over all processes' devices (PxD:mesh). --hog pins process i to core i and
runs a busy loop on the last core for the whole benchmark: a host slower than the others.

With --numba, each one-process layout's child also times the Numba baseline of the
dispersed sweep (benchmarks/baselines/numba_dispersed.py: the same closed loop, each
trajectory with its own scenario, its noise drawn in the kernel) on the same samples,
right after so3jax's run of them, on as many Numba threads as the layout has devices
(its compile excluded: a run on a tiny batch first). Each round is one such child, so
the ratio so3jax / Numba of a round compares runs seconds apart:

    python benchmarks/sweep.py --devices 2 --T 20 --samples 256 --chunk 128 --rounds 2 --numba

--flops adds XLA's count of FLOPs per trajectory-step of the sweep path (one natively
batched step of 64 samples, and in the sampled wiring a control tick per period) and the share of the machine's float64
peak (a numpy matmul on every BLAS thread) that each run's rate reaches.

--config times another sweep file's samples the same way, e.g. the flight mission's
(sensors, MEKF, wheels, dispersed hardware; no Numba baseline flies that loop):

    python benchmarks/sweep.py --config sweeps/flight.toml --devices 2 --T 400 --samples 128 --chunk 128

--set KEY=VALUE overrides an entry of the sweep file, as ``so3jax sweep --set`` does.

--undispersed also times, right after each run and on the same samples, the same sweep with
its dispersed component parameters left at the mission's values (every sample flying the
mission's loop: the batched loop without dispersion, the scenario still dispersed), and
gives the ratio of the rates per round (``dispersed_over_undispersed``):

    python benchmarks/sweep.py --config sweeps/flight.toml --devices 2 --T 100 --samples 256 --chunk 128 \
        --rounds 3 --undispersed

--rigid likewise times the same sweep without its appendages and slosh (``[[appendages]]``, ``[[slosh]]``,
``[hub]`` and their dispersions left out: the rigid body), and gives ``flexible_over_rigid``:

    python benchmarks/sweep.py --config sweeps/flexible.toml --devices 2 --T 100 --samples 256 --chunk 128 \
        --rounds 3 --rigid

--faultless also times, right after each run and on the same samples, the same sweep without
its faults (``[[faults]]`` and their dispersions left out: every sample flying the mission's
loop without the faults' program), and gives the ratio of the rates per round
(``faulted_over_faultless``):

    python benchmarks/sweep.py --config sweeps/faults.toml --devices 2 --T 1000 --samples 128 --chunk 64 \
        --rounds 3 --faultless

Prints one JSON object: ``runs`` (one per round, layout and controller; with --numba, also
the Numba rate and the ratio), ``full_sweep`` (per layout: the median rate over rounds and
the extrapolation) and, with --numba, ``numba_head_to_head`` (per layout and controller:
both rates and the ratio per round, and the ratio's median).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if __package__ in (None, ""):  # run as a script: the repository root on the path (benchmarks.baselines)
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

FULL = {"samples": 1024, "steps": 400_000}


def _child(spec: dict) -> list:
    """Measurements for one device count, in this process (a subprocess of the parent)."""
    import warnings

    from so3jax import configure_xla

    configure_xla()  # before JAX starts its backend (the parent sets the device count)
    import jax

    if spec.get("pin") is not None:
        os.sched_setaffinity(0, {spec["pin"]})
    jax.config.update("jax_enable_x64", True)
    if spec.get("processes", 1) > 1:  # one of several processes on JAX's runtime
        from so3jax.parallel import distributed

        distributed.initialize(argparse.Namespace(
            distributed=True, coordinator=spec["coordinator"], num_processes=spec["processes"],
            process_id=spec["process_id"], timeout=300))
    import numpy as np

    from so3jax.dynamics.inertia import InertiaWarning
    from so3jax.dynamics.scenario import steps_for_horizon
    from so3jax.jobs import sweep
    from so3jax.missions import batched, draw
    from so3jax.parallel import distributed

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InertiaWarning)
        config = sweep.load_config(spec.get("config"), (f"T={spec['T']}", *spec.get("overrides", ())))
    n_steps = steps_for_horizon(config.T, config.dt)
    layout = spec.get("layout", "chunks")
    mesh = sweep.batch_mesh(layout)
    chunk = sweep.padded_chunk(spec["chunk"], mesh.size)
    n = -(-spec["samples"] // chunk) * chunk
    drawn = draw.draw(config.dispersions, config.leaves, config.seed, n, config.max_draws, mission=config.mission)
    params, leaves = batched.inputs(drawn, np.float64)  # leaves: the dispersed component parameters
    key = config.mission
    # the same samples flown without a part of the mission: (option, what is left out, the leaves' prefixes)
    without = {"faultless": (dict(faults=()), ("faults.",)),
               "rigid": (dict(appendages=(), slosh=(), hub_mass=None), ("appendages.", "slosh."))}
    use_numba = spec.get("numba", False) and jax.process_count() == 1 and not leaves  # Numba flies the paper's loop
    if use_numba:  # the parent raised NUMBA_NUM_THREADS to at least the device count
        import numba

        from benchmarks.baselines.numba_dispersed import simulate_dispersed

        numba.set_num_threads(jax.local_device_count())
    peak = None
    if spec.get("flops"):  # the machine's float64 peak: a numpy matmul on every BLAS thread (best of 3)
        from benchmarks.throughput import _matmul_peak

        peak = _matmul_peak(2048)
    runs = []
    for controller in spec["controllers"]:
        gains = jax.tree.map(np.asarray, config.gains[controller])
        rmse = {}  # first sample of a chunk -> so3jax's rmse of the chunk

        def run(first, last, controller=controller, gains=gains, claims=None, rmse=rmse, leaves=leaves, key=key):
            for start in range(first, last, chunk):
                if claims is not None and not sweep.claim_chunk(claims, controller, start):
                    continue
                part = jax.tree.map(lambda x, start=start: x[start : start + chunk], (params, leaves))
                rmse[start] = sweep.run_chunk(part, gains, controller, key, mesh)["rmse"]
            distributed.barrier(f"benchmark: {controller} {first}-{last}")

        start = time.perf_counter()
        run(0, chunk)  # every process compiles (layout "chunks": on its own devices)
        first = time.perf_counter() - start
        shared = layout == "chunks" and jax.process_count() > 1
        claims = Path(spec["claims"]) if shared else None  # claim files are named by controller
        start, cpu = time.perf_counter(), time.process_time()
        run(0, n, claims=claims)
        wall, cpu = time.perf_counter() - start, time.process_time() - cpu
        head_to_head = {}
        if use_numba:
            numba_run = lambda p, steps, controller=controller: simulate_dispersed(
                controller, p, steps, dt=config.dt, gains=config.gains[controller])
            numba_run(jax.tree.map(lambda x: x[:2], params), 2)  # compile (or cache load), not timed
            start_n, cpu_n = time.perf_counter(), time.process_time()
            numba_out = numba_run(params, n_steps)
            wall_n, cpu_n = time.perf_counter() - start_n, time.process_time() - cpu_n
            ours = np.concatenate([rmse[s] for s in sorted(rmse)])
            head_to_head = {
                "numba_threads": numba.get_num_threads(),
                "numba_wall_s": wall_n,
                "numba_cpu_s": cpu_n,
                "numba_trajectory_steps_per_s": n * n_steps / wall_n,
                "so3jax_over_numba": wall_n / wall,  # the ratio of the rates
                "numba_rmse_max_rel_diff": float(np.max(np.abs(numba_out["rmse"] - ours) / np.abs(ours))),
            }
        if spec.get("undispersed") and leaves and jax.process_count() == 1:  # every component at the mission's values
            run(0, chunk, leaves={}, rmse={})  # compile, not timed
            start_u = time.perf_counter()
            run(0, n, leaves={}, rmse={})
            wall_u = time.perf_counter() - start_u
            head_to_head |= {"undispersed_wall_s": wall_u, "undispersed_trajectory_steps_per_s": n * n_steps / wall_u,
                             "dispersed_over_undispersed": wall_u / wall}  # the ratio of the rates
        for option, (left_out, prefixes) in without.items():
            lighter = dataclasses.replace(key, **left_out)
            if not spec.get(option) or lighter == key or jax.process_count() > 1:
                continue
            kept = {k: v for k, v in leaves.items() if not k.startswith(prefixes)}
            run(0, chunk, leaves=kept, rmse={}, key=lighter)  # compile, not timed
            start_w = time.perf_counter()
            run(0, n, leaves=kept, rmse={}, key=lighter)
            wall_w = time.perf_counter() - start_w
            ratio = {"faultless": "faulted_over_faultless", "rigid": "flexible_over_rigid"}[option]
            head_to_head |= {f"{option}_wall_s": wall_w, f"{option}_trajectory_steps_per_s": n * n_steps / wall_w,
                             ratio: wall_w / wall}  # the ratio of the rates
        if spec.get("flops"):
            flops = _step_flops(config, controller, params)
            head_to_head |= {"flops_per_trajectory_step": flops, "flops_per_s": flops * n * n_steps / wall,
                             "share_of_peak": flops * n * n_steps / wall / peak}
        runs.append(
            {
                "devices": jax.device_count(),
                "processes": jax.process_count(),
                "layout": layout if jax.process_count() > 1 else None,
                "hog": spec.get("pin") is not None,
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
                **head_to_head,
            }
        )
    distributed.finish()  # every process meets; process 0 leaves last
    return runs


def _step_flops(config, controller: str, params, batch: int = 64) -> float:
    """XLA's count of FLOPs per trajectory-step of the sweep path: one natively batched
    step (``so3jax.sim.loop.step`` with the per-sample constants of ``so3jax.dynamics.stepped``, and the
    disturbance draw) of ``batch`` samples, per trajectory; in the sampled wiring, plus a
    control tick (``so3jax.sim.loop.tick``) per control period's steps. The mission's nominal loop."""
    import jax
    import jax.numpy as jnp

    from so3jax.dynamics import stepped
    from so3jax.missions import build
    from so3jax.sim.loop import initial_state, step, tick
    from so3jax.sim.rollout import _batch_last, _keys, disturbance_at

    mission = config.mission
    law = mission.controller(controller)[0]
    gains = jax.tree.map(lambda g: jnp.asarray(g)[..., None], config.gains[controller])  # shared: a unit axis
    batch = min(batch, len(params.seed))
    part = jax.tree.map(lambda x: x[:batch], params)
    scenario = _batch_last(jax.vmap(lambda p: build.scenario(mission, p))(part), 0)
    loop = mission.loop(jnp.float64)
    key = _keys(part.seed)
    state = initial_state(scenario, law, gains, (batch,), loop)

    def flops(f, *args):
        cost = jax.jit(f).lower(*args).compile().cost_analysis()
        return float((cost[0] if isinstance(cost, (list, tuple)) else cost)["flops"])

    def one(scenario, constants, key, state):
        k = jnp.int32(0)
        return step(scenario, law, gains, disturbance_at(scenario, key, k), state, k, loop, constants)

    total = flops(one, scenario, stepped.constants(scenario), key, state)
    if not loop.continuous:
        total += flops(lambda scenario, key, state: tick(scenario, loop, law, gains, key, state, jnp.int32(1)),
                       scenario, key, state) / loop.period_steps
    return total / batch


def _layout(text: str) -> tuple[int, int, str]:
    """'2' -> one process with 2 devices; '2x1' -> 2 processes with 1 device each, whole
    chunks per process; '2x1:mesh' -> the same, every chunk over both."""
    text, _, layout = text.partition(":")
    processes, _, devices = text.partition("x")
    return (int(processes), int(devices), layout or "chunks") if devices else (1, int(processes), "chunks")


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run_children(spec: dict, processes: int, devices: int, layout: str, pin: bool) -> list:
    """The measurements of process 0 of ``processes`` children with ``devices`` each (pinned
    to core i if ``pin`` and several)."""
    env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}")
    if spec.get("numba") and processes == 1:  # a Numba thread per device, even beyond the cores
        env["NUMBA_NUM_THREADS"] = str(max(devices, int(env.get("NUMBA_NUM_THREADS", 0)), os.cpu_count() or 1))
    coordinator = f"127.0.0.1:{_free_port()}"
    claims = tempfile.mkdtemp(prefix="so3jax-claims-")
    children = []
    for i in range(processes):
        child = {**spec, "processes": processes, "process_id": i, "coordinator": coordinator, "layout": layout,
                 "claims": claims, "pin": i % os.cpu_count() if pin and processes > 1 else None}
        children.append(subprocess.Popen([sys.executable, __file__, "--child", json.dumps(child)], env=env,
                                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    outputs = [child.communicate() for child in children]
    shutil.rmtree(claims, ignore_errors=True)
    for child, (_, stderr) in zip(children, outputs):
        if child.returncode:
            sys.exit(f"child of {processes} x {devices} device(s) failed:\n{stderr}")
    lines = [line for line in outputs[0][0].splitlines() if line.startswith("[{")]
    return json.loads(lines[-1])


def _head_to_head(runs: list) -> dict:
    """{layout: {controller: both rates and so3jax / Numba per round, the ratio's median}}."""
    out = {}
    for r in runs:
        if "so3jax_over_numba" not in r:
            continue  # a layout of several processes
        row = out.setdefault(r["name"], {}).setdefault(r["controller"], {
            "numba_threads": r["numba_threads"], "so3jax_trajectory_steps_per_s": [],
            "numba_trajectory_steps_per_s": [], "so3jax_over_numba": []})
        row["so3jax_trajectory_steps_per_s"].append(r["trajectory_steps_per_s"])
        row["numba_trajectory_steps_per_s"].append(r["numba_trajectory_steps_per_s"])
        row["so3jax_over_numba"].append(r["so3jax_over_numba"])
    for rows in out.values():
        for row in rows.values():
            row["median_so3jax_over_numba"] = statistics.median(row["so3jax_over_numba"])
    return out


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
    parser.add_argument("--hog", action="store_true",
                        help="pin process i of several to core i and keep the last core half busy with a busy loop")
    parser.add_argument("--config", help="sweep file (default: the built-in default sweep, sweeps/default.toml)")
    parser.add_argument("--set", action="append", default=[], dest="overrides", metavar="KEY=VALUE",
                        help="override an entry of the sweep file, as so3jax sweep --set (repeatable)")
    parser.add_argument("--numba", action="store_true",
                        help="one-process layouts: also time the Numba dispersed baseline on the same samples, "
                             "after so3jax in each round, on as many threads as devices")
    parser.add_argument("--flops", action="store_true",
                        help="also XLA's FLOPs per trajectory-step of the sweep path (a step, plus a tick per "
                             "control period) and the share of the machine's float64 matmul peak reached")
    parser.add_argument("--undispersed", action="store_true",
                        help="also time each run's samples with the dispersed component parameters at the mission's "
                             "values (the batched loop without dispersion), right after it")
    parser.add_argument("--faultless", action="store_true",
                        help="also time each run's samples without the sweep's faults (the mission's loop without "
                             "them), right after it")
    parser.add_argument("--rigid", action="store_true",
                        help="also time each run's samples without the mission's appendages and slosh (the rigid "
                             "body), right after it")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(_child(json.loads(args.child))))
        return
    runs = []
    layouts = dict(zip(args.devices.split(","), (_layout(text) for text in args.devices.split(","))))
    hog = None
    if args.hog:
        last = os.cpu_count() - 1
        hog = subprocess.Popen([sys.executable, "-c",
                                f"import os; os.sched_setaffinity(0, {{{last}}})\nwhile True: pass"])
    try:
        for _ in range(args.rounds):  # rounds alternate the layouts: a shared machine's load hits each alike
            for name, (processes, devices, layout) in layouts.items():
                spec = {"T": args.T, "samples": args.samples, "chunk": args.chunk, "config": args.config,
                        "overrides": args.overrides,
                        "controllers": args.controllers.split(","), "numba": args.numba,
                        "flops": args.flops, "undispersed": args.undispersed, "faultless": args.faultless,
                        "rigid": args.rigid}
                runs += [{**run, "name": name} for run in _run_children(spec, processes, devices, layout, args.hog)]
    finally:
        if hog is not None:
            hog.kill()
    full = {}
    for name in layouts:
        rates = {}
        for r in runs:
            if r["name"] == name:
                rates.setdefault(r["controller"], []).append(r["trajectory_steps_per_s"])
        rates = {c: statistics.median(v) for c, v in rates.items()}
        seconds = sum(FULL["samples"] * FULL["steps"] / rate for rate in rates.values())
        full[name] = {"controllers": sorted(rates), "median_trajectory_steps_per_s": rates,
                      "extrapolated_s": seconds, "extrapolated_min": seconds / 60}
    report = {
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "load_avg_1min": os.getloadavg()[0]},
        "runs": runs,
        "full_sweep": {"what": "extrapolated from the compiled rates above (compile excluded)", **FULL,
                       "by_devices": full},
    }
    if args.numba:
        report["numba_head_to_head"] = _head_to_head(runs)
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
