"""``so3jax identify``: the inertia (with the gyro bias and a disturbance torque) from a
telemetry file, by equation error (``regression``) or output error (``simulation``)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

DISTURBANCE = {"none": -1, "constant": 0, "linear": 1, "quadratic": 2, "cubic": 3}
DEFAULT_DISTURBANCE = {"regression": "linear", "simulation": "cubic"}


def register(subparsers) -> None:
    from so3jax.commands import add_precision_argument

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
    p.add_argument("--out", type=Path, default=Path("results/identify"), help="output folder (default results/identify)")
    p.add_argument("--json", action="store_true", help="print one JSON object (last line of stdout)")
    p.add_argument("--no-figures", action="store_true", help="skip the residual figure")
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
    from so3jax.jobs.identify import inertia

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
    from so3jax.missions import mission as missions
    from so3jax.results import runfolder
    from so3jax.jobs.identify import telemetry

    _check(args)
    initial = _initial(args.initial_inertia)
    mission = missions.load(args.mission)
    wheels = mission.actuator.get("wheels")
    geometry = None if wheels is None else (np.asarray(wheels["axes"], float).T, wheels["spin_inertia"])
    tm = telemetry.load(args.telemetry, geometry)
    with runfolder.claim(args.out, "identify", vars(args)):
        return _identify_into(args, tm, initial)


def _identify_into(args, tm, initial) -> int:
    import time

    from so3jax.jobs.identify import METHODS
    from so3jax.results.io import dumps, write_json, write_text

    disturbance = args.disturbance or DEFAULT_DISTURBANCE[args.method]
    options = dict(bias=not args.no_bias, degree=DISTURBANCE[disturbance])
    if args.method == "regression":
        options["interval"] = args.interval
    else:
        options.update(window=args.window, initial=initial)
    print(f"identifying from {len(tm.t)} samples over {tm.t[-1] - tm.t[0]:g} s ({args.method}) ...",
          file=sys.stderr, flush=True)
    start = time.perf_counter()
    fit = METHODS[args.method](tm, **options)
    wall = time.perf_counter() - start
    report = summary(fit)
    report["config"] = {"telemetry": str(args.telemetry), "mission": None if args.mission is None else str(args.mission),
                        "method": args.method, "bias": options["bias"], "disturbance": disturbance,
                        **({"interval_s": args.interval} if args.method == "regression" else
                           {"window_s": args.window, "initial_inertia": None if initial is None else initial.tolist()}),
                        "samples": len(tm.t), "duration_s": float(tm.t[-1] - tm.t[0]), "wall_time_s": wall}
    write_json(args.out / "identification.json", report)
    write_text(args.out / "J_hat.toml", j_hat_toml(fit["J"], report))
    figures = [] if args.no_figures else _figures(args.out, fit)
    if args.json:
        print(dumps(report))
    else:
        print(format_report(report))
        print(f"\n{wall:.1f} s; results in {args.out}/ (identification.json, J_hat.toml, {len(figures)} figure(s))")
    if "warning" in fit:
        print(f"warning: {fit['warning']}", file=sys.stderr)
    if not fit["converged"]:
        print("warning: the fit did not converge; the estimate is the last iterate", file=sys.stderr)
        return 1
    return 0


def summary(fit) -> dict:
    """The estimate as JSON-ready data: J and its entries' covariance, principal moments and
    axes with 1 sigma, the bias and disturbance with theirs, the residuals' RMS."""
    from so3jax.jobs.identify import inertia
    from so3jax.results.io import to_builtin

    lam, V, lam_std, axis_std = inertia.principal(fit["J"], fit["theta_cov"])
    out = {"J": fit["J"], "J_entries": list(inertia.ENTRIES), "J_entries_std": np.sqrt(np.diag(fit["theta_cov"])),
           "J_entries_covariance": fit["theta_cov"],
           "principal_moments": lam, "principal_moments_std": lam_std,
           "principal_axes": V, "principal_axes_std_deg": np.degrees(axis_std),
           "bias": fit["bias"], "bias_std": None if fit["bias"] is None else np.sqrt(np.diag(fit["bias_cov"])),
           "disturbance": fit["disturbance"],
           "disturbance_std": None if fit["disturbance"] is None else np.sqrt(np.diag(fit["disturbance_cov"])).reshape(-1, 3),
           "residual_rms": fit["residual_rms"], "iterations": fit["iterations"], "converged": fit["converged"]}
    for key in ("intervals", "windows", "sigma_gyro", "sigma_star", "sigma_momentum_jump", "warning"):
        if key in fit:
            out[key] = fit[key]
    return to_builtin(out)


def j_hat_toml(J, report) -> str:
    """A [controller.NAME] J_hat block per law that takes a nominal inertia, ready to paste
    into a mission file."""
    from so3jax.controllers import registry

    rows = ", ".join("[" + ", ".join(f"{x:.10g}" for x in row) + "]" for row in np.asarray(J))
    lines = [f"# J_hat identified by so3jax identify ({report['config']['method']}) from {report['config']['telemetry']}",
             f"# principal moments {', '.join(f'{m:.6g}' for m in report['principal_moments'])} kg m^2, "
             f"1 sigma {', '.join(f'{s:.2g}' for s in report['principal_moments_std'])}"]
    for name in registry.names():
        if any(p.name == "J_hat" for p in registry.get(name).options):
            lines += [f"[controller.{name}]", f"J_hat = [{rows}]"]
    return "\n".join(lines) + "\n"


def format_report(r) -> str:
    J, std = np.asarray(r["J"]), r["J_entries_std"]
    lines = ["J [kg m^2] (1 sigma of each entry):"]
    lines += ["  " + "  ".join(f"{x:12.4f}" for x in row) for row in J]
    lines.append("  sigma  " + ", ".join(f"{n} {s:.3g}" for n, s in zip(r["J_entries"], std)))
    lines.append("principal moments [kg m^2]: " + ", ".join(
        f"{m:.4f} +- {s:.3g}" for m, s in zip(r["principal_moments"], r["principal_moments_std"])))
    axes = np.asarray(r["principal_axes"])
    for i in range(3):
        lines.append(f"  axis {i + 1}: [{', '.join(f'{x:+.5f}' for x in axes[:, i])}] +- {r['principal_axes_std_deg'][i]:.3g} deg")
    if r["bias"] is not None:
        lines.append("gyro bias [deg/h]: " + ", ".join(
            f"{math.degrees(b) * 3600:.4f} +- {math.degrees(s) * 3600:.2g}" for b, s in zip(r["bias"], r["bias_std"])))
    if r["disturbance"] is not None:
        for p, (d, s) in enumerate(zip(r["disturbance"], r["disturbance_std"])):
            lines.append(f"disturbance s^{p} [N m]: " + ", ".join(f"{x:+.4g} +- {e:.2g}" for x, e in zip(d, s)))
    lines.append(f"converged: {r['converged']} ({r['iterations']} iterations)")
    return "\n".join(lines)


def _figures(out: Path, fit) -> list:
    """residuals.png: each residual series against time, per axis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from so3jax.results.io import save_figures

    series = {k: v for k, v in fit["residuals"].items() if k != "t"}
    fig, axes = plt.subplots(len(series), 1, figsize=(8, 2.6 * len(series)), sharex=True, squeeze=False)
    for ax, (name, values) in zip(axes[:, 0], series.items()):
        for i, label in enumerate("xyz"):
            ax.plot(fit["residuals"]["t"], values[:, i], lw=0.6, label=label)
        ax.set_ylabel(name)
        ax.legend(loc="upper right", fontsize=8, ncol=3)
    axes[-1, 0].set_xlabel("t [s]")
    axes[0, 0].set_title("identification residuals (measured - fitted)")
    return save_figures(out, {"residuals.png": fig})
