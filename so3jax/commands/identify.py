"""``so3jax identify``: the inertia (with the gyro bias and a disturbance torque) from a
telemetry file, by equation error (``regression``) or output error (``simulation``); the
job: :mod:`so3jax.jobs.identify`, its report :mod:`so3jax.jobs.identify.report`."""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from so3jax.commands.common import add_output_arguments, add_precision_argument
from so3jax.jobs.api import DEFAULT_DISTURBANCE, DISTURBANCE, identification_options
from so3jax.jobs.identify import CHECKS, METHODS, inertia, telemetry
from so3jax.jobs.identify import report as reports
from so3jax.missions import mission as missions
from so3jax.results import runfolder
from so3jax.results.io import dumps, write_json, write_text


def register(subparsers) -> None:
    p = subparsers.add_parser("identify", help="identify the inertia from telemetry (gyro, star tracker, wheel speeds)",
                              description="The inertia, a constant gyro bias and a body-fixed disturbance torque "
                              "estimated from a telemetry file: identification.json, J_hat.toml and residuals.png.")
    p.add_argument("telemetry", type=Path, help="telemetry file (.npz; `so3jax fly` writes OUT/telemetry/NAME.npz)")
    p.add_argument("--mission", type=Path,
                   help="mission file whose [actuator.wheels] gives the wheels' geometry where the telemetry has none "
                        "(default: the flight mission)")
    p.add_argument("--method", choices=("regression", "simulation"), default="regression",
                   help="regression: equation error, momentum-integral form, instrumental variables (default); "
                        "simulation: output error through the simulated plant over short windows")
    p.add_argument("--no-bias", action="store_true", help="take the gyro as unbiased (default: fit a constant bias)")
    p.add_argument("--disturbance", choices=tuple(DISTURBANCE),
                   help="the body-fixed disturbance torque fitted, a polynomial in time "
                        "(default: linear for regression, cubic for simulation)")
    p.add_argument("--interval", type=float, default=5.0, help="regression: averaging block length [s] (default 5)")
    p.add_argument("--window", type=float, default=10.0, help="simulation: window length [s] (default 10)")
    p.add_argument("--initial-inertia", metavar="J",
                   help="simulation: first guess, a number (isotropic) or a 3x3 JSON list [kg m^2] "
                        "(default: the regression's estimate)")
    add_output_arguments(p, "results/identify", "the residual figure")
    add_precision_argument(p)
    p.set_defaults(func=run)


def _initial(text):
    if text is None:
        return None
    try:
        value = np.asarray(json.loads(text), float)
    except (ValueError, TypeError):
        raise ValueError(f"--initial-inertia must be a number or a 3x3 JSON list, got {text!r}") from None
    if value.shape == ():
        value = value * np.eye(3)
    if value.shape != (3, 3) or not np.all(np.isfinite(value)):
        raise ValueError(f"--initial-inertia must be a number or a 3x3 list of finite numbers, got shape {value.shape}")

    if not inertia.is_physical(value):
        raise ValueError("--initial-inertia is not a physical inertia (symmetric, triangle inequality)")
    return value


def _check(args) -> None:
    for name in ("interval", "window"):
        value = getattr(args, name)
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"--{name} must be a positive number of seconds, got {value!r}")
    if args.method == "regression" and args.initial_inertia is not None:
        raise ValueError("--initial-inertia is the simulation method's first guess; the regression needs none")


def run(args) -> int:
    _check(args)
    initial = _initial(args.initial_inertia)
    mission = missions.load(args.mission)
    wheels = mission.actuator.get("wheels")
    geometry = None if wheels is None else (np.asarray(wheels["axes"], float).T, wheels["spin_inertia"])
    tm = telemetry.load(args.telemetry, geometry)
    options = _options(args, initial)
    CHECKS[args.method](tm, **options)  # the telemetry must determine J: refused before anything is written
    with runfolder.claim(args.out, "identify", vars(args)):
        return _identify_into(args, tm, initial, options)


def _options(args, initial) -> dict:
    """The method's keyword arguments."""
    return identification_options(args.method, bias=not args.no_bias, disturbance=args.disturbance,
                                  interval=args.interval, window=args.window, initial=initial)


def _identify_into(args, tm, initial, options) -> int:
    disturbance = args.disturbance or DEFAULT_DISTURBANCE[args.method]
    print(f"identifying from {len(tm.t)} samples over {tm.t[-1] - tm.t[0]:g} s ({args.method}) ...",
          file=sys.stderr, flush=True)
    start = time.perf_counter()
    fit = METHODS[args.method](tm, **options)
    wall = time.perf_counter() - start
    report = reports.summary(fit)
    report["config"] = {"telemetry": str(args.telemetry),
                        "mission": None if args.mission is None else str(args.mission),
                        "method": args.method, "bias": options["bias"], "disturbance": disturbance,
                        **({"interval_s": args.interval} if args.method == "regression" else
                           {"window_s": args.window, "initial_inertia": None if initial is None else initial.tolist()}),
                        "samples": len(tm.t), "duration_s": float(tm.t[-1] - tm.t[0]), "wall_time_s": wall}
    write_json(args.out / "identification.json", report)
    write_text(args.out / "J_hat.toml", reports.j_hat_toml(fit["J"], report))
    figures = [] if args.no_figures else reports.write_figures(args.out, fit)
    if args.json:
        print(dumps(report))
    else:
        print(reports.format_report(report))
        print(f"\n{wall:.1f} s; results in {args.out}/ (identification.json, J_hat.toml, {len(figures)} figure(s))")
    if "warning" in fit:
        print(f"warning: {fit['warning']}", file=sys.stderr)
    if not fit["converged"]:
        print("warning: the fit did not converge; the estimate is the last iterate", file=sys.stderr)
        return 1
    return 0
