"""One tuning step on every host device beside one device.

A tuning step is ``so3jax.jobs.tune.cost_and_grad`` (what ``so3jax tune`` runs every
iteration of a gradient campaign): the cost and its gradient over the tuning batch, the
batch split over a Mesh of the host devices as ``tune.build_problem`` chooses (at least
``tune.MIN_SHARD`` rollouts per device: a campaign's batch of 2 stays on one device; the
report says how many devices each batch was split over). The cost's normalizers are
set to 1 (a step's work does not depend on them). Each device count
runs in its own child process (``--xla_force_host_platform_device_count`` is fixed when
JAX starts), with the XLA:CPU settings of the ``so3jax`` command and no persistent
compilation cache. The children compile one after the other (lowering + XLA compilation,
timed apart), then take turns round by round, one working while the other waits, so each
round compares runs seconds apart on a machine whose speed drifts; the speed-up of a
round is (time on one device) / (time on all of them); CPU seconds per step (all threads
of the child) are recorded beside the wall time, and before each round the cores the
machine gives at that moment (a CPU-bound loop alone and in N processes at once): on a
loaded machine the devices' threads wait for a core, and no round's speed-up can exceed
what that round was given. Batches: the campaign's own
training batch and a larger one (its inertia scales x enough seeds), at a short horizon.
The children's costs and gradients are compared too (floating-point reduction order and
vectorization width only: ~1e-15 relative).

    python -m benchmarks.tune [--campaign tuning/pd_equal_effort.toml] [--T 20] [--batches 0,64]
                              [--devices 1,2] [--rounds 5] [--calls 3]

--batches: 0 is the campaign's batch. --devices: default 1 and one per usable core.
Progress goes to stderr; the last line of stdout is one JSON object.
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
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run as a script: benchmarks.throughput and so3jax from this tree
    sys.path.insert(0, str(ROOT))


def log(*parts) -> None:
    print(*parts, file=sys.stderr, flush=True)


def _usable_cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


# --- child: one device count ---------------------------------------------------------


class _Step:
    """cost_and_grad of one batch, compiled, with its arguments (in a child process)."""

    def __init__(self, spec: dict, batch: int):
        import dataclasses
        import warnings

        import jax
        import jax.numpy as jnp

        from so3jax.jobs import tune
        from so3jax.parallel import devices

        config = tune.load_config(spec["campaign"], [("T", spec["T"])])
        if batch:
            scales = config.train.inertia_scales
            if batch % len(scales):
                scales = (1.0,)
            seeds = tuple(range(1000, 1000 + batch // len(scales)))  # held out of no campaign's validation
            config = dataclasses.replace(config, train=tune.ScenarioSet(seeds, scales))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the campaigns' inertia scales warn (InertiaWarning)
            problem = tune.build_problem(config)
        dtype = problem.scenario.R0.dtype
        initial = tune.resolve_gains(config.controller, config.initial_gains, dtype, config.diagonal_gamma,
                                     config.mission)
        self.size = int(problem.train.seed.shape[0])
        self.n_steps = int(problem.scenario.n_steps)
        self.devices_used = 1 if problem.mesh is None else problem.mesh.size
        # Normalizers of unit value, shaped as tune() makes them (one budget per scenario
        # where a controller sets it): a step's work does not depend on their values, and
        # taking them from an evaluation would add a compilation per child and batch.
        one = jnp.ones((), dtype)
        per_scenario = config.cost.mode == "equal_effort" and config.cost.budget_controller is not None
        effort = jnp.ones((self.size,), dtype) if per_scenario else one
        refs = devices.place(tune.CostRefs(one, effort, jnp.asarray(config.cost.weight, dtype)), problem.mesh)
        params = devices.place(tune.to_params(initial), problem.mesh)
        self.args = (params, problem.scenario, problem.train, refs, problem.loop)
        self.static = {"controller": config.mission.controller(config.controller)[0], "mode": config.cost.mode,
                       "gradient": config.gradient, "record_every": problem.record_every, "mesh": problem.mesh}
        self.compiled = None
        self.jax = jax

    def compile(self) -> float:
        from so3jax.jobs import tune

        params, scenario, batch, refs, loop = self.args
        start = time.perf_counter()
        self.compiled = tune.cost_and_grad.lower(params, scenario, batch=batch, refs=refs, loop=loop,
                                                 **self.static).compile()
        return time.perf_counter() - start

    def call(self):
        params, scenario, batch, refs, loop = self.args
        return self.jax.block_until_ready(self.compiled(params, scenario, batch=batch, refs=refs, loop=loop))

    def run(self, calls: int) -> tuple[float, float]:
        """Median wall seconds of one step over calls (after one untimed call), and the
        process's CPU seconds per step (all its threads)."""
        self.call()
        times = []
        cpu = time.process_time()
        for _ in range(calls):
            start = time.perf_counter()
            self.call()
            times.append(time.perf_counter() - start)
        return statistics.median(times), (time.process_time() - cpu) / calls

    def values(self) -> dict:
        from jax.flatten_util import ravel_pytree

        evaluation, grad = self.call()
        return {"cost": float(evaluation.cost), "grad": [float(g) for g in ravel_pytree(grad)[0]]}


def _child(spec: dict) -> None:
    """Answer the parent's requests, one JSON line each: compile B, run B, values B."""
    import jax

    jax.config.update("jax_enable_x64", True)
    steps = {}
    print(json.dumps({"devices": len(jax.devices())}), flush=True)
    for line in sys.stdin:
        request = json.loads(line)
        batch = request["batch"]
        if request["op"] == "compile":
            steps[batch] = _Step(spec, batch)
            step = steps[batch]
            answer = {"compile_s": step.compile(), "size": step.size, "n_steps": step.n_steps,
                      "devices_used": step.devices_used}
        elif request["op"] == "run":
            wall, cpu = steps[batch].run(request["calls"])
            answer = {"step_s": wall, "cpu_s": cpu}
        else:
            answer = steps[batch].values()
        print(json.dumps(answer), flush=True)


# --- parent ----------------------------------------------------------------------------


class _Process:
    def __init__(self, devices: int, spec: dict):
        from so3jax.parallel import xla_flags as _xla_flags

        env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "JAX_COMPILATION_CACHE_DIR")}
        env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
        env["JAX_PLATFORMS"] = "cpu"  # host devices, also on a machine with a GPU
        saved = os.environ.get("XLA_FLAGS")
        os.environ["XLA_FLAGS"] = env["XLA_FLAGS"]
        try:
            _xla_flags.configure_cpu_codegen()  # the so3jax command's XLA:CPU settings
            env["XLA_FLAGS"] = os.environ["XLA_FLAGS"]
        finally:
            if saved is None:
                os.environ.pop("XLA_FLAGS")
            else:
                os.environ["XLA_FLAGS"] = saved
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
        self.proc = subprocess.Popen(
            [sys.executable, str(Path(__file__).resolve()), "--child", json.dumps(spec)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT, env=env,
        )
        self.devices = self._read()["devices"]
        if self.devices != devices:
            raise RuntimeError(f"asked for {devices} host devices, the child has {self.devices}")

    def _read(self) -> dict:
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"child with {self.devices if hasattr(self, 'devices') else '?'} devices died")
        return json.loads(line)

    def ask(self, **request) -> dict:
        self.proc.stdin.write(json.dumps(request) + "\n")
        self.proc.stdin.flush()
        return self._read()

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(timeout=60)


def _spin(n: int) -> int:
    total = 0
    for i in range(n):
        total += i
    return total


class _CoreProbe:
    """Cores this machine gives right now: a CPU-bound loop timed alone and in n processes
    at once (n x time alone / time together; ~0.15 s). On a shared machine the other
    jobs' load moves it from minute to minute, and no speed-up can exceed it."""

    def __init__(self, n: int):
        import multiprocessing

        self.n = n
        self.pool = multiprocessing.get_context("spawn").Pool(n)
        self.pool.map(_spin, [1] * n)

    def __call__(self, work: int = 2_000_000) -> float:
        start = time.perf_counter()
        self.pool.apply(_spin, (work,))
        alone = time.perf_counter() - start
        start = time.perf_counter()
        self.pool.map(_spin, [work] * self.n, chunksize=1)
        return self.n * alone / (time.perf_counter() - start)

    def close(self) -> None:
        self.pool.close()
        self.pool.join()


def _relative(a: list, b: list) -> float:
    scale = max(max(abs(x) for x in b), 1e-300)
    return max(abs(x - y) for x, y in zip(a, b)) / scale


def measure(campaign: str, T: float, batches: list[int], devices: list[int], rounds: int, calls: int,
            spawn=None) -> dict:
    """The report's "batches" section; spawn(n, spec) starts the child for n devices."""
    spec = {"campaign": campaign, "T": T}
    children = {n: (spawn or _Process)(n, spec) for n in devices}
    probe = _CoreProbe(max(devices)) if spawn is None else (lambda: float(max(devices)))
    try:
        out = {}
        for batch in batches:
            compiled = {}
            for n, child in children.items():
                compiled[n] = child.ask(op="compile", batch=batch)
                log(f"batch {compiled[n]['size']} on {n} device(s): compiled in {compiled[n]['compile_s']:.1f} s")
            times, cpu, free = {n: [] for n in children}, {n: [] for n in children}, []
            for r in range(rounds):
                free.append(probe())
                order = list(children) if r % 2 == 0 else list(children)[::-1]
                for n in order:
                    answer = children[n].ask(op="run", batch=batch, calls=calls)
                    times[n].append(answer["step_s"])
                    cpu[n].append(answer["cpu_s"])
            values = {n: child.ask(op="values", batch=batch) for n, child in children.items()}
            one, many = devices[0], devices[-1]
            rounds_ratio = [a / b for a, b in zip(times[one], times[many])]
            size = compiled[one]["size"]
            key = f"campaign ({size})" if batch == 0 else str(size)
            out[key] = {
                "scenarios": size,
                "n_steps": compiled[one]["n_steps"],
                **{f"devices_{n}": {"batch_split_over": compiled[n]["devices_used"],
                                    "compile_s": compiled[n]["compile_s"],
                                    "step_s": times[n], "step_s_median": statistics.median(times[n]),
                                    "cpu_s_per_step": cpu[n]} for n in children},
                f"speedup_{many}_over_{one}_rounds": rounds_ratio,
                f"speedup_{many}_over_{one}_median": statistics.median(rounds_ratio),
                "free_cores_rounds": free,  # _CoreProbe before each round
                "max_relative_difference": {
                    "cost": _relative([values[many]["cost"]], [values[one]["cost"]]),
                    "grad": _relative(values[many]["grad"], values[one]["grad"]),
                },
            }
            log(f"batch {size}: step {statistics.median(times[one]) * 1e3:.1f} ms on {one} device(s), "
                f"{statistics.median(times[many]) * 1e3:.1f} ms on {many} (split over "
                f"{compiled[many]['devices_used']}); speed-up {statistics.median(rounds_ratio):.2f}"
                f" (rounds {', '.join(f'{x:.2f}' for x in rounds_ratio)}; free cores "
                f"{', '.join(f'{x:.1f}' for x in free)})")
        return out
    finally:
        for child in children.values():
            child.close()
        if spawn is None:
            probe.close()


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--campaign", default="tuning/pd_equal_effort.toml")
    p.add_argument("--T", type=float, default=20.0, help="horizon [s] (the campaign mission's T; its dt)")
    p.add_argument("--batches", default="0,64", help="scenarios per batch; 0: the campaign's training batch")
    p.add_argument("--devices", help="two device counts, e.g. 1,2 (default: 1 and one per usable core)")
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--calls", type=int, default=3, help="timed steps per round (the median is kept)")
    p.add_argument("--child", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        _child(json.loads(args.child))
        return 0
    from benchmarks.throughput import cpu_model

    devices = [int(n) for n in args.devices.split(",")] if args.devices else [1, _usable_cores()]
    if len(devices) != 2:
        p.error("--devices takes two device counts")
    report = {
        "benchmark": "tune",
        "command": " ".join(["python -m benchmarks.tune", *(argv if argv is not None else sys.argv[1:])]),
        "commit": subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=ROOT,
                                 check=False).stdout.strip() or None,
        "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
        "machine": {"cpu_model": cpu_model(), "cpus": os.cpu_count(), "affinity": _usable_cores(),
                    "platform": platform.platform(), "python": platform.python_version(),
                    "load_avg_start": list(os.getloadavg())},
        "campaign": args.campaign,
        "T": args.T,
        "devices": devices,
        "rounds": args.rounds,
        "calls_per_round": args.calls,
    }
    start = time.perf_counter()
    report["batches"] = measure(args.campaign, args.T, [int(b) for b in args.batches.split(",")], devices,
                                args.rounds, args.calls)
    report["machine"]["load_avg_end"] = list(os.getloadavg())
    report["wall_s"] = time.perf_counter() - start
    print(json.dumps(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
