"""After a docking: adapt, or identify the inertia and then control with it?

Flies the post-docking phase (``missions/post_docking.toml``: the docked spacecraft from
its docking rate to rest, through the flight mission's gyro, star tracker, MEKF and
wheels, 1 400 s) over samples of the docked inertia (``sweeps/default.toml``'s
dispersions of J2, its sampling seed), each sample with its own disturbance and sensor
noise seed, for:

* ``adaptive``: the adaptive law as the paper flies it (no knowledge, Theta_hat(0) = Theta(I));
* ``pd``: the PD without knowledge (J_hat = I, the paper's);
* ``pd_true``: the PD with the sample's true inertia in its feedforward (the ideal bound);
* ``identify_T``: for each manoeuvre length T_id, the open-loop excitation of
  ``missions/identify.toml`` for T_id seconds from the docking, ``so3jax identify``'s
  regression on its telemetry, then the PD with that J_hat from the state the manoeuvre
  left (wheel speeds included) to the end (with J_hat = I, as without knowledge, where the
  identification refuses the telemetry as not determining J). Its second leg restarts the disturbance's clock
  and the filter (at the true attitude), with its own noise seed.

Reports per case the RMSE of the rate error over the whole phase (exact, every step) and
over the time after T_id (from the rate error sampled every second), the delivered
effort, the divergences, and the identification's errors; writes ``results.json``,
``samples.npz`` and ``identify_then_control.png`` into --out.

    python comparisons/identify_then_control.py               # 256 samples, T_id = 60 150 300 600 s
    python comparisons/identify_then_control.py --samples 16 --lengths 150 --out /tmp/itc
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=256)
    parser.add_argument("--lengths", type=float, nargs="+", default=[60.0, 150.0, 300.0, 600.0])
    parser.add_argument("--chunk", type=int, default=64)
    parser.add_argument("--out", type=Path, default=ROOT / "comparisons" / "identify_then_control")
    args = parser.parse_args(argv)

    import jax

    jax.config.update("jax_enable_x64", True)
    sys.path.insert(0, str(ROOT))
    from benchmarks.throughput import cpu_model
    from so3jax.jobs.identify import inertia, regression, telemetry
    from so3jax.jobs.sweep.config import load_config
    from so3jax.missions import mission as missions
    from so3jax.missions.draw import draw_samples

    started = time.perf_counter()
    post = missions.load(ROOT / "missions" / "post_docking.toml")
    sweep = load_config(ROOT / "sweeps" / "default.toml")
    J = draw_samples(sweep.dispersions, sweep.seed, args.samples, sweep.max_draws).params.J2
    seeds = np.arange(args.samples)
    n = len(seeds)
    w0 = np.zeros((n, post.loop().actuator.count))  # wheel speeds at the docking [rad/s]
    Omega0 = np.broadcast_to(np.asarray(post.scenario().Omega0), (n, 3))
    R0 = np.broadcast_to(np.asarray(post.scenario().R0), (n, 3, 3))

    def progress(text):
        print(f"[{time.perf_counter() - started:7.1f} s] {text}", file=sys.stderr, flush=True)

    cases, after = {}, {}
    for name, J_hat in (("adaptive", None), ("pd", None), ("pd_true", J)):
        progress(f"flying {name}")
        r = fly(post, name.split("_")[0], J, J_hat, R0, Omega0, w0, seeds, args.chunk)
        cases[name] = r
        after[name] = {T_id: _rmse_after(r["t"], r["Omega_e"], T_id) for T_id in args.lengths}
    identification = {}
    for T_id in args.lengths:
        key = f"identify_{T_id:g}"
        progress(f"{key}: excitation")
        manoeuvre = missions.load(ROOT / "missions" / "identify.toml", [f"T={T_id!r}"])
        first = fly(manoeuvre, "open_loop", J, None, R0, Omega0, w0, seeds, args.chunk, history=True)
        progress(f"{key}: identifying {n} inertias")
        J_hat, err_moment, err_axis = np.zeros((n, 3, 3)), np.zeros((n, 3)), np.zeros((n, 3))
        refused = np.zeros(n, bool)
        for i in range(n):
            tm = telemetry.check(telemetry.from_run(manoeuvre, first["histories"][i], int(seeds[i])))
            try:
                J_hat[i] = regression.identify(tm)["J"]
            except ValueError:  # the telemetry does not determine J: no knowledge
                refused[i], J_hat[i] = True, np.eye(3)
                continue
            lam_t, V_t, _, _ = inertia.principal(J[i], np.zeros((6, 6)))
            lam, V, _, _ = inertia.principal(J_hat[i], np.zeros((6, 6)))
            err_moment[i], err_axis[i] = np.abs(lam - lam_t) / lam_t, inertia.axis_angles(V_t, V)
        kept = ~refused
        identification[key] = {"refused": int(refused.sum()),
                               "moment_error_pct_median": float(100 * np.median(err_moment[kept])),
                               "moment_error_pct_max": float(100 * err_moment[kept].max()),
                               "axis_error_deg_median": float(np.degrees(np.median(err_axis[kept]))),
                               "axis_error_deg_max": float(np.degrees(err_axis[kept].max()))}
        progress(f"{key}: pd with the identified inertia")
        rest = missions.load(ROOT / "missions" / "post_docking.toml", [f"T={post.T - T_id!r}"])
        second = fly(rest, "pd", J, J_hat, first["R"], first["Omega"], first["wheels"], seeds + 10**6, args.chunk)
        n1, n2 = round(T_id / post.dt), round((post.T - T_id) / post.dt)
        rmse = np.sqrt((n1 * first["rmse"] ** 2 + n2 * second["rmse"] ** 2) / (n1 + n2))
        cases[key] = {"rmse": rmse, "effort": first["effort"] + second["effort"],
                      "diverged": first["diverged"] | second["diverged"]}
        after[key] = {T_id: _rmse_after(second["t"] + T_id, second["Omega_e"], T_id)}

    summary = {}
    for name, c in cases.items():
        ok = ~c["diverged"]
        summary[name] = {"rmse_median": float(np.median(c["rmse"][ok])),
                         "rmse_p95": float(np.percentile(c["rmse"][ok], 95)),
                         "rmse_mean": float(np.mean(c["rmse"][ok])), "effort_mean": float(np.mean(c["effort"][ok])),
                         "diverged": int(c["diverged"].sum()),
                         "rmse_after_T_id_median": {f"{k:g}": float(np.median(v[ok])) for k, v in after[name].items()}}
        summary[name].update(identification.get(name, {}))
    report = {"command": "python comparisons/identify_then_control.py " + " ".join(argv or sys.argv[1:]),
              "machine": f"{cpu_model()}, {len(os.sched_getaffinity(0))} cores", "samples": n,
              "lengths_s": args.lengths,
              "wall_time_s": time.perf_counter() - started, "cases": summary}
    from so3jax.results.io import save_npz, write_json

    args.out.mkdir(parents=True, exist_ok=True)
    write_json(args.out / "results.json", report)
    save_npz(args.out / "samples.npz", J2=J, **{f"{k}/{f}": np.asarray(v[f]) for k, v in cases.items()
                                                for f in ("rmse", "effort", "diverged")})
    figure(args.out / "identify_then_control.png", summary, cases, after, args.lengths)
    print(json.dumps(report))
    return 0


def identified_pd():
    """(controller, gains type): the geometric PD (docs/model.md §3.1) with its nominal
    inertia J_hat among the gains, so that one compiled program flies every sample's J_hat
    (the registered PD holds J_hat as a static option)."""
    from typing import NamedTuple

    import jax

    from so3jax.controllers.base import Controller, inertial_terms, nominal_inertia, tracking_error
    from so3jax.core import so3

    class Gains(NamedTuple):
        k_R: jax.Array  # N m / rad
        k_Omega: jax.Array  # N m s / rad
        J_hat: jax.Array  # (3, 3) kg m^2

    @dataclasses.dataclass(frozen=True)
    class IdentifiedPD(Controller):
        gains_type = Gains

        def init(self, gains):
            return ()

        def torque(self, gains, state, feedback, desired, t):
            err = tracking_error(feedback, desired)
            inertial, feedforward = inertial_terms(nominal_inertia(gains.J_hat), feedback.Omega, err)
            return -gains.k_R * so3.skew_vee(err.R_e) - gains.k_Omega * err.Omega_e + inertial - feedforward, ()

    return IdentifiedPD(), Gains


def fly(mission, law, J, J_hat, R0, Omega0, wheels0, seeds, chunk, history=False) -> dict:
    """The mission flown by ``law`` over samples (true inertia J (n, 3, 3), J_hat (n, 3, 3)
    or None for the law's own, initial attitude, rate and wheel speeds, seed), in batches
    of ``chunk``: metrics, the final state, the rate error each second, and with
    ``history`` each sample's history recorded at every tick (its telemetry)."""
    import jax

    from so3jax.controllers import registry
    from so3jax.dynamics.plant import ConstantInertia
    from so3jax.sim.rollout import rollout

    scenario, loop = mission.scenario(), mission.loop()
    spec, options, gains = registry.get(law), dict(mission.options.get(law, {})), mission.gains[law]
    record_every = mission.period_steps if history else 100

    def one(J, J_hat, R0, Omega0, w0, seed):
        sc = dataclasses.replace(scenario, inertia=ConstantInertia(J), R0=R0, Omega0=Omega0)
        lp = dataclasses.replace(loop, actuator=dataclasses.replace(loop.actuator, initial_speed=w0))
        if J_hat is None:
            controller, g = spec.factory(**options), gains
        else:  # the PD with this sample's J_hat
            controller, gains_type = identified_pd()
            g = gains_type(*gains, J_hat)
        r = rollout(sc, controller, g, seed, loop=lp, record_every=record_every)
        return r if history else r._replace(history=r.history._replace(covariance=(), std=()))

    run = jax.jit(jax.vmap(one, in_axes=(0, None if J_hat is None else 0, 0, 0, 0, 0)))
    parts = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for s in range(0, len(seeds), chunk):
            sl = slice(s, s + chunk)
            r = run(J[sl], None if J_hat is None else J_hat[sl], R0[sl], Omega0[sl], wheels0[sl], seeds[sl])
            r = jax.tree.map(np.asarray, r)
            part = {"rmse": r.metrics.rmse, "effort": r.metrics.effort, "diverged": r.metrics.diverged,
                    "R": r.final.R, "Omega": r.final.Omega, "wheels": r.final.actuator,
                    "t": r.history.t, "Omega_e": r.history.Omega_e}
            if history:
                part["histories"] = [jax.tree.map(lambda x: x[i], r.history) for i in range(len(r.metrics.rmse))]
            parts.append(part)
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0] if k != "histories"}
    if history:
        out["histories"] = [h for p in parts for h in p["histories"]]
    return out


def _rmse_after(t, Omega_e, T_id):
    """RMSE of the rate error over t >= T_id, from samples (n, M) every second [rad/s]."""
    mask = t >= T_id - 1e-9
    return np.sqrt(np.sum(np.sum(Omega_e ** 2, -1) * mask, -1) / np.sum(mask, -1))


def figure(path, summary, cases, after, lengths):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from so3jax.results.io import save_figure

    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    L = np.asarray(lengths)
    ident = [f"identify_{x:g}" for x in lengths]
    styles = {"adaptive": dict(color="tab:red"), "pd": dict(color="tab:blue"), "pd_true": dict(color="tab:green")}
    labels = {"adaptive": "adaptive (no knowledge)", "pd": "PD, J_hat = I", "pd_true": "PD, true J (bound)"}
    for ax, field, title in ((axes[0], "rmse", "RMSE over the post-docking phase"),
                             (axes[2], "effort", "delivered effort [N^2 m^2 s]")):
        med = [np.median(cases[k][field]) for k in ident]
        lo = [np.percentile(cases[k][field], 5) for k in ident]
        hi = [np.percentile(cases[k][field], 95) for k in ident]
        ax.errorbar(L, med, yerr=[np.subtract(med, lo), np.subtract(hi, med)], fmt="o-", color="tab:purple",
                    capsize=3, label="identify for T_id, then PD with J_hat")
        for k, st in styles.items():
            ax.axhline(np.median(cases[k][field]), ls="--", label=labels[k], **st)
        ax.set_xlabel("identification manoeuvre T_id [s]")
        ax.set_title(title + " (median, 5-95 %)" if field == "rmse" else title)
    axes[0].set_ylabel("RMSE [rad/s]")
    for k, st in styles.items():
        axes[1].plot(L, [np.median(after[k][x]) for x in lengths], "--", label=labels[k], **st)
    axes[1].plot(L, [np.median(after[f"identify_{x:g}"][x]) for x in lengths], "o-", color="tab:purple",
                 label="identify, then PD")
    axes[1].set_yscale("log")
    axes[1].set_xlabel("T_id [s]")
    axes[1].set_ylabel("RMSE after T_id [rad/s] (median)")
    axes[1].set_title("after the manoeuvre (rate error each second)")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)


if __name__ == "__main__":
    sys.exit(main())
