"""Accuracy and consistency of ``so3jax identify`` on simulated telemetry.

Flies ``missions/identify.toml`` (the docked spacecraft J2, the flight mission's gyro, star
tracker and wheels, an open-loop square-wave excitation) for R seeds in one batched
rollout, writes each seed's telemetry as ``so3jax fly`` does, identifies J by each method,
and reports against the truth:

* the error of each principal moment [%] and each principal axis [deg] (max and 95th
  percentile over the runs);
* coverage: the share of the inertia's 6 entries, of the principal moments and of the
  principal axes whose reported 3-sigma bounds hold the truth, and the RMS of the
  standardized errors (1 for a calibrated covariance);

for each manoeuvre length and each excitation (a scale on the mission's amplitudes).

    python benchmarks/identify.py                                  # 100 runs of 600 s, both methods
    python benchmarks/identify.py --runs 20 --lengths 150 300 600 --scales 0.5 1 --methods regression

Prints one JSON line per (method, length, scale) and a final JSON object with them all.
"""

from __future__ import annotations

import argparse
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
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--lengths", type=float, nargs="+", default=[600.0], help="manoeuvre lengths T [s]")
    parser.add_argument("--scales", type=float, nargs="+", default=[1.0], help="excitation amplitude scales")
    parser.add_argument("--methods", nargs="+", default=["regression", "simulation"])
    parser.add_argument("--mission", default="missions/identify.toml")
    args = parser.parse_args(argv)

    import jax

    jax.config.update("jax_enable_x64", True)
    sys.path.insert(0, str(ROOT))
    import so3jax as sj
    from benchmarks.throughput import cpu_model
    from so3jax.jobs.identify import METHODS, inertia, telemetry
    from so3jax.missions import mission as missions

    rows = []
    for length in args.lengths:
        for scale in args.scales:
            base = missions.load(args.mission)
            amplitude = (np.asarray(base.options["open_loop"]["amplitude"]) * scale).tolist()
            m = missions.load(args.mission,
                              [f"T={length!r}", f"controller.open_loop.amplitude={json.dumps(amplitude)}"])
            J_true = np.asarray(m.scenario().inertia.J) if hasattr(m.scenario().inertia, "J") else None
            controller, gains = m.controller("open_loop")
            seeds = np.arange(args.runs)
            start = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                history = jax.tree.map(np.asarray, sj.simulate(m.scenario(), controller, gains,
                                                               jax.numpy.asarray(seeds), loop=m.loop(),
                                                               record_every=m.record_every).history)
            flown = time.perf_counter() - start
            tms = [telemetry.check(telemetry.from_run(m, _one(history, i, len(seeds)), int(s)))
                   for i, s in enumerate(seeds)]
            lam_t, V_t, _, _ = inertia.principal(J_true, np.zeros((6, 6)))
            for method in args.methods:
                start = time.perf_counter()
                z, moment_err, axis_err, moment_z, axis_z, converged = [], [], [], [], [], 0
                for tm in tms:
                    fit = METHODS[method](tm)
                    converged += bool(fit["converged"])
                    std = np.sqrt(np.diag(fit["theta_cov"]))
                    z.append((inertia.entries(fit["J"]) - inertia.entries(J_true)) / std)
                    lam, V, lam_std, axis_std = inertia.principal(fit["J"], fit["theta_cov"])
                    moment_err.append(np.abs(lam - lam_t) / lam_t)
                    axis_err.append(inertia.axis_angles(V_t, V))
                    moment_z.append((lam - lam_t) / lam_std)
                    axis_z.append(axis_err[-1] / axis_std)
                z, moment_err, axis_err = np.array(z), np.array(moment_err), np.array(axis_err)
                moment_z, axis_z = np.array(moment_z), np.array(axis_z)
                row = {
                    "method": method, "length_s": length, "excitation_scale": scale, "amplitude_N_m": amplitude,
                    "runs": len(tms), "converged": converged,
                    "moment_error_pct_max": (100 * moment_err.max(0)).tolist(),
                    "moment_error_pct_p95": (100 * np.percentile(moment_err, 95, axis=0)).tolist(),
                    "axis_error_deg_max": np.degrees(axis_err.max(0)).tolist(),
                    "axis_error_deg_p95": np.degrees(np.percentile(axis_err, 95, axis=0)).tolist(),
                    "entries_3sigma_coverage": float(np.mean(np.abs(z) <= 3)),
                    "entries_all_six_3sigma_coverage": float(np.mean(np.all(np.abs(z) <= 3, axis=1))),
                    "moments_3sigma_coverage": float(np.mean(np.abs(moment_z) <= 3)),
                    "axes_3sigma_coverage": float(np.mean(axis_z <= 3)),
                    "entries_z_rms": np.sqrt(np.mean(z ** 2, axis=0)).tolist(),
                    "fly_s": flown, "identify_s_per_run": (time.perf_counter() - start) / len(tms),
                }
                print(json.dumps(row), flush=True)
                rows.append(row)
    print(json.dumps({"command": "python benchmarks/identify.py " + " ".join(argv or sys.argv[1:]),
                      "machine": f"{cpu_model()}, {len(os.sched_getaffinity(0))} cores", "results": rows}))
    return 0


def _one(history, i, n):
    """Run i of a batched history (batch axis first on every leaf, n runs)."""
    import jax

    return jax.tree.map(lambda x: x[i], history)


if __name__ == "__main__":
    sys.exit(main())
