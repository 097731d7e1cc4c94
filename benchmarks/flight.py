"""The flight loop's speed beside the paper's mode, and the paper's mode beside another
source tree (e.g. the previous commit), all on every core of this machine.

* ``rates``: trajectory-steps/s of ``rollout_batch`` for the paper's mode (continuous
  wiring) and the flight mission of docs/model.md §8.5 (sampled wiring: gyro, star tracker, MEKF,
  four wheels, Delta_c = 10 dt), each controller, batch split evenly over one XLA host
  device per core and dispatched together (as ``so3jax sweep`` does), timed in rounds
  that alternate the two wirings; the median of the per-round ratios flight / paper.
  Also one trajectory (``rollout`` with a scalar seed, what ``simulate`` runs), in µs/step.
* ``--against TREE``: the paper's mode of this tree and of TREE (a checkout of another
  revision), batched and one trajectory, in child processes that alternate, round by
  round; the median ratios (above 1: this tree is faster).

    python -m benchmarks.flight [--batch 4096] [--steps 2000] [--rounds 5] [--against /tmp/base]

Progress goes to stderr; the last line of stdout is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONTROLLERS = ("pd", "adaptive")


def log(*parts) -> None:
    print(*parts, file=sys.stderr, flush=True)


def _law(controller: str):
    """(Controller, gains) at the paper's values, by names every revision of so3jax has."""
    import so3jax as sj

    if controller == "pd":
        return sj.geometric_pd(), sj.PAPER_PD_GAINS
    return sj.adaptive_backstepping(), sj.PAPER_ADAPTIVE_GAINS


def _programs(wiring: str, controller: str, batch: int, n_steps: int):
    """Compiled (one per device) rollout_batch programs of a wiring and their inputs."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import so3jax as sj
    from so3jax.sim.rollout import rollout_batch

    dt = 0.01
    kwargs = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sj.InertiaWarning)
        scenario = sj.paper_scenario(T=n_steps * dt, dt=dt)
        if wiring == "flight":
            from so3jax.missions import mission

            m = mission.load(None, [f"T={n_steps * dt!r}"])
            scenario, kwargs = m.scenario(), {"loop": m.loop()}
    law, gains = _law(controller)
    gains = jax.tree.map(lambda g: jnp.asarray(g, scenario.R0.dtype), gains)
    fn = jax.jit(lambda s: rollout_batch(scenario, law, gains, s, scenario_axes=None, record_every=n_steps,
                                            **kwargs).metrics)
    devices = jax.devices()[:batch]
    parts = np.array_split(np.arange(batch, dtype=np.int32), len(devices))
    shards = [jax.device_put(jnp.asarray(p), d) for p, d in zip(parts, devices)]
    with ThreadPoolExecutor(len(shards)) as pool:
        compiled = list(pool.map(lambda s: fn.lower(s).compile(), shards))
    return lambda: jax.block_until_ready([f(s) for f, s in zip(compiled, shards)])


def _single(wiring: str, controller: str, n_steps: int) -> float:
    """One trajectory's µs/step (median of 5, after a warm-up)."""
    import jax
    import jax.numpy as jnp

    import so3jax as sj

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sj.InertiaWarning)
        scenario, kwargs = sj.paper_scenario(T=n_steps * 0.01, dt=0.01), {}
        if wiring == "flight":
            from so3jax.missions import mission

            m = mission.load(None, [f"T={n_steps * 0.01!r}"])
            scenario, kwargs = m.scenario(), {"loop": m.loop()}
    law, gains = _law(controller)
    gains = jax.tree.map(lambda g: jnp.asarray(g, scenario.R0.dtype), gains)
    fn = jax.jit(lambda s: sj.rollout(scenario, law, gains, s, record_every=n_steps, **kwargs).metrics)
    seed = jnp.int32(0)
    jax.block_until_ready(fn(seed))
    times = []
    for _ in range(5):
        start = time.perf_counter()
        jax.block_until_ready(fn(seed))
        times.append(time.perf_counter() - start)
    return statistics.median(times) / n_steps * 1e6


def _time(run) -> float:
    start = time.perf_counter()
    run()
    return time.perf_counter() - start


def rates(batch: int, n_steps: int, rounds: int, controllers=CONTROLLERS) -> dict:
    out = {}
    for controller in controllers:
        runs = {w: _programs(w, controller, batch, n_steps) for w in ("paper", "flight")}
        for run in runs.values():
            run()  # warm-up
        times = {w: [] for w in runs}
        for _ in range(rounds):
            for w, run in runs.items():
                times[w].append(_time(run))
        steps = batch * n_steps
        row = {w: {"M_steps_per_s": steps / statistics.median(t) / 1e6, "times_s": t} for w, t in times.items()}
        per_round = [p / f for p, f in zip(times["paper"], times["flight"])]
        row["flight_over_paper_median"] = statistics.median(per_round)
        row["flight_over_paper_rounds"] = per_round
        row["single_us_per_step"] = {w: _single(w, controller, n_steps) for w in runs}
        log(f"{controller}: paper {row['paper']['M_steps_per_s']:.2f} M/s, flight {row['flight']['M_steps_per_s']:.2f}"
            f" M/s, flight/paper {row['flight_over_paper_median']:.2f}"
            f" (rounds {', '.join(f'{r:.2f}' for r in per_round)})")
        out[controller] = row
    return out


def _child(spec: str) -> None:
    """In a child process: the paper's mode rate of the so3jax found first on sys.path."""
    spec = json.loads(spec)
    from so3jax import configure_xla

    configure_xla(every_core=True)
    import jax

    jax.config.update("jax_enable_x64", True)
    run = _programs("paper", spec["controller"], spec["batch"], spec["n_steps"])
    run()
    t = statistics.median(_time(run) for _ in range(spec["repeats"]))
    single = _single("paper", spec["controller"], spec["single_steps"])
    print(json.dumps({"M_steps_per_s": spec["batch"] * spec["n_steps"] / t / 1e6, "single_us_per_step": single}))


def against(tree: Path, batch: int, n_steps: int, rounds: int) -> dict:
    """Paper's mode here and in ``tree``, child processes alternating round by round."""
    out = {}
    for controller in CONTROLLERS:
        spec = json.dumps({"controller": controller, "batch": batch, "n_steps": n_steps, "repeats": 3,
                           "single_steps": 20 * n_steps})
        got = {"here": [], "there": []}
        single = {"here": [], "there": []}
        for _ in range(rounds):
            for side, path in (("here", ROOT), ("there", tree)):
                env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
                env["PYTHONPATH"] = str(path)  # the so3jax of that tree; this file run by its path
                proc = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child", spec], env=env,
                                      capture_output=True, text=True, cwd=path, check=False)
                if proc.returncode:
                    raise RuntimeError(proc.stderr[-2000:])
                child = json.loads(proc.stdout.strip().splitlines()[-1])
                got[side].append(child["M_steps_per_s"])
                single[side].append(child["single_us_per_step"])
        per_round = [a / b for a, b in zip(got["here"], got["there"])]
        single_rounds = [b / a for a, b in zip(single["here"], single["there"])]  # speed ratio: time there / here
        out[controller] = {"here_M_steps_per_s": got["here"], "there_M_steps_per_s": got["there"],
                           "here_over_there_median": statistics.median(per_round), "rounds": per_round,
                           "single_here_us_per_step": single["here"], "single_there_us_per_step": single["there"],
                           "single_speed_here_over_there_median": statistics.median(single_rounds)}
        log(f"{controller}: this tree / {tree}: batched {statistics.median(per_round):.3f} "
            f"(rounds {', '.join(f'{r:.3f}' for r in per_round)}), one trajectory "
            f"{statistics.median(single_rounds):.3f} (rounds {', '.join(f'{r:.3f}' for r in single_rounds)})")
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--batch", type=int, default=4096)
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--controllers", default=",".join(CONTROLLERS),
                   help="comma-separated, among " + ", ".join(CONTROLLERS))
    p.add_argument("--against", type=Path, help="another source tree: compare the paper's mode with it")
    p.add_argument("--child", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        _child(args.child)
        return 0
    report = {"batch": args.batch, "n_steps": args.steps, "rounds": args.rounds, "cores": os.cpu_count()}
    if args.against is not None:
        report["paper_mode_against"] = {"tree": str(args.against), **against(args.against, args.batch, args.steps,
                                                                             args.rounds)}
    else:
        from so3jax import configure_xla

        configure_xla(every_core=True)
        import jax

        jax.config.update("jax_enable_x64", True)
        report["devices"] = len(jax.devices())
        report["rates"] = rates(args.batch, args.steps, args.rounds, tuple(args.controllers.split(",")))
    print(json.dumps(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
