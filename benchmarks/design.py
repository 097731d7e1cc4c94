"""A design campaign's wall time and where it goes, beside the same batch's value alone.

The campaign is ``so3jax tune`` on a design file (default ``tuning/design_pd.toml``, with
``--set`` overrides), run in this process from an empty compilation cache, or (``--run``)
a finished run folder of that file, whose history is read instead. From
its history: the first iteration (compilation of the goals' forward-mode derivatives and
one evaluation), the steady iterations (their mean and the whole), the held-out check.
Beside it, in the same process and on the same training batch, the goals' values alone
(no derivative: what a gradient-free method pays per evaluation), timed warm over
``--calls`` calls after the campaign: the ratio is what one iteration's derivatives cost
over one evaluation.

    python -m benchmarks.design [--config tuning/design_pd.toml] [--set KEY=VALUE ...] [--run FOLDER] [--calls 3]

Progress goes to stderr; the last line of stdout is one JSON object.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def log(*parts) -> None:
    print(*parts, file=sys.stderr, flush=True)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--config", default="tuning/design_pd.toml")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--run", help="a finished run folder of the campaign: its history, not a new run")
    parser.add_argument("--calls", type=int, default=3)
    args = parser.parse_args(argv)

    from so3jax.parallel import xla_flags

    xla_flags.configure_xla(every_core=True)
    import jax
    import jax.numpy as jnp
    import numpy as np

    jax.config.update("jax_enable_x64", True)
    from so3jax.jobs.tune import design
    from so3jax.jobs.tune.campaign import tune
    from so3jax.jobs.tune.config import load_config
    from so3jax.jobs.tune.gains import resolve_gains
    from so3jax.jobs.tune.goal_values import GoalValues
    from so3jax.jobs.tune.goals import parse_goals
    from so3jax.jobs.tune.problem import Sampler
    from so3jax.missions import config as cfg
    from so3jax.missions import draw

    config = load_config(args.config, [cfg.parse_override(text) for text in args.set])
    if args.run:
        out = Path(args.run)
        report = json.loads((out / "design.json").read_text())
        total = report["wall_s"]["design"] + report["wall_s"]["held_out"]
    else:
        out = Path(tempfile.mkdtemp(prefix="so3jax-design-bench-")) / "run"
        log(f"design campaign {args.config} {' '.join(args.set)} -> {out}")
        start = time.perf_counter()
        report = tune(config, out, progress=True)
        total = time.perf_counter() - start
    with open(out / "history.csv") as f:
        rows = list(csv.DictReader(f))
    walls = sorted({float(r["wall_s"]) for r in rows})
    first, steady = walls[0], np.diff(walls)

    goals = parse_goals(list(config.goals), config.mission)
    dtype = jnp.result_type(float)
    initial = resolve_gains(config.controller, config.initial_gains, dtype, config.diagonal_gamma, config.mission)
    parameters = design.Parameters(config, initial)
    parsed, leaves = draw.parse(config.dispersions, config.mission)
    train, _ = design.draw_inputs(Sampler(parsed, leaves, config.mission), config.train.seeds[0],
                                  config.train.samples, dtype)
    values = GoalValues(goals, config.mission, config.mission.controller(config.controller)[0], parameters.unravel)
    P = parameters.starts(config.starts, config.es.seed)
    values(P, train, jacobian=False)  # compile
    value_s = []
    for _ in range(args.calls):
        t = time.perf_counter()
        values(P, train, jacobian=False)
        value_s.append(time.perf_counter() - t)
    result = {
        "benchmark": "design",
        "command": "python -m benchmarks.design --config " + args.config + "".join(f" --set '{s}'" for s in args.set)
        + (f" --run {args.run}" if args.run else ""),
        "campaign_run": "read from its history" if args.run else "run here, compilation cache empty",
        "machine": {"platform": platform.platform(), "cpus": len(os.sched_getaffinity(0)),
                    "python": platform.python_version(), "jax": jax.__version__,
                    "device": str(jax.devices()[0].platform), "load_average_at_end": list(os.getloadavg())},
        "campaign": {"controller": config.controller, "goals": [g.name for g in goals],
                     "hard": int(sum(g.hard for g in goals)), "samples": config.train.samples,
                     "starts": config.starts, "iterations": config.iterations, "T": config.mission.T,
                     "parameters": int(len(parameters.p0))},
        "wall_s": {"total": total, "first_iteration": first, "steady_iterations": float(np.sum(steady)),
                   "steady_iteration_mean": float(np.mean(steady)) if len(steady) else None,
                   "held_out": report["wall_s"]["held_out"],
                   "other": total - walls[-1] - report["wall_s"]["held_out"]},
        "value_alone_s": {"min": min(value_s), "calls": value_s},
        "iteration_over_value": float(np.mean(steady)) / min(value_s) if len(steady) else None,
        "verdict": report["verdict"],
    }
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
