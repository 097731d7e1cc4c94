"""Where the sweep path's time goes: the per-sample scenario, one part at a time.

Draws B samples of the default sweep (sweeps/default.toml, horizon T) and times their
natively batched rollout (``so3jax.sim.rollout.rollout_batch``, no history, one host device)
with every part of the scenario per sample (the sweep path), with each part in turn
shared by the whole batch (the first sample's: the reference, the inertia, the
disturbance, the initial state), with the same scenario repeated per sample, and with one
scenario for the batch (the paper's batches), and with XLA's scalar float64 sin and atan2
in place of so3jax.core._trig's vectorized ones ("library trigonometry"). The gap between a
row and "dispersed" is what evaluating that part per sample costs. Rounds interleave the variants; the best
round counts. Prints one JSON object.

    python benchmarks/sweep_profile.py                        # B = 64, T = 4000 s
    python benchmarks/sweep_profile.py --batch 64 --T 500 --rounds 3
    python benchmarks/sweep_profile.py --T 500 --rounds 4 --variants dispersed,"library trigonometry"
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import sys
import time
import warnings
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=64,
                        help="samples per batch (default 64: a chunk of 128 on 2 devices)")
    parser.add_argument("--T", type=float, default=4000.0, help="horizon [s] (default 4000: every phase)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--controllers", default="pd,adaptive")
    parser.add_argument("--variants", default=None, help="comma-separated subset of the variants (default: all)")
    args = parser.parse_args()
    os.environ["XLA_FLAGS"] = os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=1"
    from so3jax import configure_xla

    configure_xla()
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks.*, run as a script too
    from benchmarks.throughput import cpu_model
    from so3jax.core import _trig
    from so3jax.dynamics.inertia import InertiaWarning
    from so3jax.jobs import sweep
    from so3jax.missions import batched, build, draw
    from so3jax.sim.rollout import rollout_batch

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InertiaWarning)
        config = sweep.load_config(None, (f"T={args.T}",))
        samples = draw.draw(config.dispersions, config.leaves, config.seed, args.batch, config.max_draws,
                            mission=config.mission)
    params, _ = batched.inputs(samples, jnp.float64)
    mission = config.mission
    per_sample = jax.vmap(lambda p: build.scenario(mission, p))(params)
    first = jax.tree.map(lambda x: x[0], per_sample)
    axes = jax.tree.map(lambda _: 0, per_sample)

    def sharing(**parts):  # those parts of the scenario the first sample's, shared by the batch
        scenario = dataclasses.replace(per_sample, **{name: getattr(first, name) for name in parts})
        return scenario, dataclasses.replace(axes, **dict.fromkeys(parts))

    variants = {
        "dispersed": (per_sample, 0),
        "reference shared": sharing(reference=True),
        "inertia shared": sharing(inertia=True),
        "disturbance shared": sharing(disturbance=True),
        "initial state shared": sharing(R0=True, Omega0=True),
        "one scenario repeated per sample": (
            jax.tree.map(lambda x: jax.numpy.broadcast_to(x[0], x.shape), per_sample), 0),
        "one scenario for the batch": (first, None),
        "library trigonometry": (per_sample, 0),
    }
    if args.variants:
        variants = {name: variants[name] for name in args.variants.split(",")}
    vectorized = {"sin": _trig.sin, "atan2": _trig.atan2}
    library = {"sin": jnp.sin, "atan2": jnp.arctan2}
    n_steps = round(args.T / config.dt)
    rows = []
    for controller in args.controllers.split(","):
        law = mission.controller(controller)[0]
        gains = jax.tree.map(jnp.asarray, config.gains[controller])
        runs = {}
        for name, (scenario, scenario_axes) in variants.items():
            run = jax.jit(lambda s, g, seeds, a=scenario_axes: rollout_batch(
                s, law, g, seeds, scenario_axes=a, record_every=n_steps).metrics.rmse)
            for fn, impl in (library if name == "library trigonometry" else vectorized).items():
                setattr(_trig, fn, impl)  # read when the rollout is traced, at its first call
            start = time.perf_counter()
            jax.block_until_ready(run(scenario, gains, params.seed))
            for fn, impl in vectorized.items():
                setattr(_trig, fn, impl)
            runs[name] = (run, scenario, time.perf_counter() - start, [])
        for _ in range(args.rounds):
            for run, scenario, _, times in runs.values():
                start = time.perf_counter()
                jax.block_until_ready(run(scenario, gains, params.seed))
                times.append(time.perf_counter() - start)
        for name, (_, _, first_s, times) in runs.items():
            rows.append({"controller": controller, "variant": name, "first_call_s": first_s,
                         "trajectory_steps_per_s": args.batch * n_steps / min(times), "seconds": times})
    print(json.dumps({
        "machine": {"cpu": cpu_model(), "cpus": os.cpu_count(), "platform": platform.platform(),
                    "load_avg_1min": os.getloadavg()[0]},
        "batch": args.batch, "T": args.T, "n_steps": n_steps, "devices": 1, "rounds": args.rounds,
        "rows": rows,
    }, indent=2))


if __name__ == "__main__":
    main()
