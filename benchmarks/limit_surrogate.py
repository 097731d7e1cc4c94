"""Does a smooth surrogate of the wheels' torque limit help gradient tuning? (docs/model.md §8.4, §16)

While a wheel's motor torque is clipped at +-u_max its derivative with respect to the
gains is zero, so a gradient sees only the unclipped ticks. This flies the flight mission
(missions/flight.toml) over a horizon T with a motor torque limit low enough that it binds
part of the time, and tunes each law's log-gains with Adam in forward mode from the
mission's gains, twice from the same start:

* ``exact``: gradients of the exact model (u = clip(u_cmd, -u_max, u_max));
* ``surrogate``: gradients of a model whose clip is smoothed over a width w = width u_max,
  clip_w(x) = x - w softplus((x - u_max) / w) + w softplus((-x - u_max) / w), equal to the
  clip to within w log 2 and to x well inside the limits.

Both runs are judged on the exact model: every iterate's cost (docs/model.md §6, weighted:
RMSE / RMSE_0 + Effort / Effort_0, means over a batch of seeds; the references are the
starting gains') is evaluated on the exact loop, on the training seeds and on held-out
seeds. Prints one JSON object: per law, the cost after each iteration in both runs.

    python benchmarks/limit_surrogate.py                                 # T = 200 s, u_max = 0.05 N m
    python benchmarks/limit_surrogate.py --T 100 --iterations 5 --laws pd
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _smooth_wheels(wheels, width: float):
    """The mission's wheels with the motor torque clip smoothed over width * u_max."""
    import jax

    from so3jax.components.actuators import Wheels
    from so3jax.core.pytree import pytree_dataclass

    @pytree_dataclass
    class SmoothWheels(Wheels):
        def torque_limited(self, u, u_max):
            w = width * u_max
            return u - w * jax.nn.softplus((u - u_max) / w) + w * jax.nn.softplus((-u - u_max) / w)

    return SmoothWheels(**{f.name: getattr(wheels, f.name) for f in dataclasses.fields(wheels)})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--T", type=float, default=200.0, help="horizon [s]")
    parser.add_argument("--max-torque", type=float, default=0.05, help="motor torque limit u_max [N m]")
    parser.add_argument("--width", type=float, default=0.1, help="smoothing width, a share of u_max")
    parser.add_argument("--iterations", type=int, default=15)
    parser.add_argument("--learning-rate", type=float, default=0.1, help="Adam's step in log-gain")
    parser.add_argument("--seeds", type=int, default=4, help="training seeds (as many held-out seeds follow them)")
    parser.add_argument("--laws", nargs="+", default=["pd", "adaptive"])
    args = parser.parse_args()

    from so3jax import configure_xla

    configure_xla()
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np
    import optax

    from so3jax.dynamics.inertia import InertiaWarning
    from so3jax.jobs import tune
    from so3jax.missions import mission as missions
    from so3jax.sim import gradients

    warnings.simplefilter("ignore", InertiaWarning)
    flown = missions.load(str(ROOT / "missions/flight.toml"),
                          [f"T={args.T!r}", f"actuator.wheels.max_torque={args.max_torque!r}"])
    scenario, exact_loop = flown.scenario(jnp.float64), flown.loop(jnp.float64)
    loops = {"exact": exact_loop,
             "surrogate": dataclasses.replace(exact_loop, actuator=_smooth_wheels(exact_loop.actuator, args.width))}
    train = gradients.make_batch([1.0], list(range(args.seeds)), jnp.float64)
    held_out = gradients.make_batch([1.0], list(range(args.seeds, 2 * args.seeds)), jnp.float64)
    started = time.perf_counter()
    report = {"benchmark": "limit_surrogate", "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                                                          "jax": jax.__version__},
              "T": args.T, "max_torque": args.max_torque, "width": args.width, "iterations": args.iterations,
              "learning_rate": args.learning_rate, "seeds": args.seeds, "laws": {}}
    for name in args.laws:
        controller = flown.controller(name)[0]
        gains = tune.resolve_gains(name, "mission" if name in flown.controllers else "paper", jnp.float64, False, flown)
        params0 = tune.to_params(gains)

        def metrics(params, loop, batch):
            return gradients.batch_metrics(scenario, controller, tune.to_gains(params), batch, loop=loop)

        first = jax.jit(lambda p, b: metrics(p, exact_loop, b))(params0, train)
        refs = tune.CostRefs(jnp.mean(first.rmse), jnp.mean(first.effort), jnp.asarray(1.0))

        def cost(params, loop, batch):
            m = metrics(params, loop, batch)
            return jnp.mean(tune.scenario_costs(m, refs, "weighted")), m

        exact_cost = jax.jit(lambda p, b: cost(p, exact_loop, b)[0])
        steps = {kind: jax.jit(gradients.value_and_grad(lambda p, loop=loop: cost(p, loop, train), "forward"))
                 for kind, loop in loops.items()}
        law = {}
        for kind, step in steps.items():
            tx = optax.adam(args.learning_rate)
            params, state = params0, tx.init(params0)
            rows = []
            for i in range(args.iterations + 1):
                (value, m), grad = step(params)
                table = {k: np.asarray(v).tolist() for k, v in tune.to_gains(params)._asdict().items()}
                rows.append({"iteration": i, "gains": table,
                             "trained_on": float(value), "exact_train": float(exact_cost(params, train)),
                             "exact_held_out": float(exact_cost(params, held_out))})
                if i == args.iterations:
                    break
                with jax.numpy_dtype_promotion("standard"):
                    updates, state = tx.update(grad, state, params)
                params = optax.apply_updates(params, updates)
            law[kind] = rows
            print(f"{name} {kind}: exact train {rows[0]['exact_train']:.4f} -> {rows[-1]['exact_train']:.4f}, "
                  f"held out {rows[0]['exact_held_out']:.4f} -> {rows[-1]['exact_held_out']:.4f}", flush=True)
        report["laws"][name] = law
    report["wall_s"] = time.perf_counter() - started
    report["machine"]["load_average_at_end"] = os.getloadavg()
    print(json.dumps(report))


if __name__ == "__main__":
    main()
