"""Statistical consistency of the MEKF in the flight loop (docs/model.md §8.3), measured
through the public API only: Monte Carlo over seeds, the NEES of the attitude and bias
blocks against the chi^2 band.

For each case, B seeds are flown over T seconds with a record at every control tick
(record_every = the control period in steps). At tick j of run i, per 3-dof block,

    attitude: e = log(R_hat^T R)^v  (R = R_hat exp(hat(e)), the filter's error convention)
    bias:     e = b - b_hat
    NEES      eps_ij = e^T P_block^-1 e   (P: the filter's covariance after the update)

and eps_j = mean_i eps_ij. For a consistent filter B eps_j ~ chi^2(3 B), so eps_j lies in
[chi^2_0.025(3B) / B, chi^2_0.975(3B) / B] ([2.21, 3.91] for B = 32) at 95 % of the ticks
and its time mean is 3. The first ``--skip`` seconds (the filter's convergence from its
initial sigma) are left out. The errors are correlated over many ticks (the bias error over
~100 s), so for a consistent filter the fraction inside the band and the bias block's time
mean vary from one seed set to another far more than for independent ticks (100 % or 65 %
inside, time means 10 % or more off 3: tests/test_filter_consistency.py sizes its
thresholds by that); an inconsistency from the model shows as a NEES in the tens to thousands.

Cases (mission overrides on the flight mission, docs/model.md §8.5):
  still          zero rate, zero torque (open_loop, ideal actuator), no disturbance
  constant_rate  symmetric inertia diag(500, 500, 500), torque-free: Omega constant
  tumbling       torque-free non-symmetric inertia (the paper's J0) with a rate off its
                 principal axes: the rate changes within every control period
  flight_pd      the flight mission's closed loop with the PD as shipped (paper inertia
                 profile, disturbance, wheels)

The gyro's output (``sensors.gyro.output``: "rate", the rate sampled at the tick; or
"increment", the angle increment over the period) is a parameter; where the mission parser
refuses that key (a tree before the rate-integrating gyro), "rate" runs without it (the
only gyro there is) and "increment" is reported as unavailable.

    python -m benchmarks.filter_consistency --gyro-output rate [--seeds 32] [--T 600]

Writes benchmarks/results/filter-consistency-<gyro output>-<machine>.json (``--out``) with
the command, machine and versions; prints a table on stderr and the records (a JSON list)
as the last line of stdout. About 1 minute on 2 cores at the defaults.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

import so3jax as sj  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
MISSION = ROOT / "missions" / "flight.toml"
ARCSEC = 180.0 / np.pi * 3600.0  # arcsec per rad
RATE = [0.01, 0.02, -0.015]  # rad/s, off every principal axis of J_TUMBLE
J_SYMMETRIC = [[500.0, 0.0, 0.0], [0.0, 500.0, 0.0], [0.0, 0.0, 500.0]]  # kg m^2
J_TUMBLE = [[625.0, 5.5, 3.0], [5.5, 350.0, 4.0], [3.0, 4.0, 1000.0]]  # the paper's J0 [kg m^2]
TORQUE_FREE = ['controllers=["open_loop"]', 'actuator.kind="ideal"', "disturbance.amplitude=0.0",
               "disturbance.noise_std=0.0"]
# case: (mission file, overrides); None: the flight mission's defaults (equal to missions/flight.toml),
# whose [inertia] tables a constant inertia.J cannot be merged with
CASES = {
    "still": (None, TORQUE_FREE + [f"inertia.J={J_TUMBLE}", "initial.rate=[0.0, 0.0, 0.0]"]),
    "constant_rate": (None, TORQUE_FREE + [f"inertia.J={J_SYMMETRIC}", f"initial.rate={RATE}"]),
    "tumbling": (None, TORQUE_FREE + [f"inertia.J={J_TUMBLE}", f"initial.rate={RATE}"]),
    "flight_pd": (MISSION, ['controllers=["pd"]']),
}


class GyroOutputRefused(ValueError):
    """The mission parser does not know sensors.gyro.output (no rate-integrating gyro)."""


def log(*parts) -> None:
    print(*parts, file=sys.stderr, flush=True)


def band(seeds: int, level: float = 0.95) -> tuple[float, float]:
    """The two-sided chi^2 band of the NEES of a 3-dof block averaged over ``seeds`` runs."""
    dof = 3 * seeds
    return (float(stats.chi2.ppf((1 - level) / 2, dof) / seeds), float(stats.chi2.ppf((1 + level) / 2, dof) / seeds))


def load(mission, overrides, gyro_output: str):
    """(Mission, note): the mission with ``sensors.gyro.output`` set; where the parser
    refuses that key, the mission without it for "rate" (note says so), else GyroOutputRefused."""
    try:
        return sj.load_mission(mission, [*overrides, f'sensors.gyro.output="{gyro_output}"']), None
    except ValueError as err:
        if "output" not in str(err):
            raise
        if gyro_output != "rate":
            raise GyroOutputRefused(f"sensors.gyro.output refused by the mission parser: {err}") from None
        return sj.load_mission(mission, overrides), f"sensors.gyro.output refused ({err}): the gyro samples the rate"


def fly(mission, seeds: int):
    """The history of ``seeds`` runs (seeds 0 .. seeds - 1) recorded at every control tick, as NumPy arrays."""
    name = mission.controllers[0]
    law, gains = mission.controller(name)
    result = sj.simulate(mission.scenario(), law, gains, np.arange(seeds), loop=mission.loop(),
                         record_every=mission.period_steps)
    return jax.tree.map(np.asarray, result.history)


def errors(h):
    """(attitude error (B, M, 3) [rad], bias error (B, M, 3) [rad/s]) in the filter's
    convention R = R_hat exp(hat(e))."""
    R_e = np.einsum("...ji,...jk->...ik", h.R_hat, h.R)  # R_hat^T R
    e_att = Rotation.from_matrix(R_e.reshape(-1, 3, 3)).as_rotvec().reshape(R_e.shape[:-1])
    return e_att, h.bias - h.bias_hat


def nees(e, P):
    """e^T P^-1 e over the leading axes: e (..., 3), P (..., 3, 3)."""
    return np.einsum("...i,...i->...", e, np.linalg.solve(P, e[..., None])[..., 0])


def consistency(h, skip: float, unit: float = 1.0) -> dict:
    """Per block: the run-averaged NEES's time mean, median and fraction of ticks inside
    (below, above) the chi^2 band, and the error RMS per axis against the filter's (mean
    reported 3 sigma per axis, and the RMS it reports: sqrt(mean tr P / 3))."""
    keep = h.t[0] >= skip
    lo, hi = band(h.t.shape[0])
    out = {}
    for block, e, s in (("attitude", errors(h)[0], slice(0, 3)), ("bias", errors(h)[1], slice(3, 6))):
        e, P = e[:, keep], h.covariance[:, keep, s, s]
        avg = nees(e, P).mean(axis=0)
        trace = np.trace(P, axis1=-2, axis2=-1)
        scale = ARCSEC if block == "attitude" else 1.0
        out[block] = {
            "mean_nees": float(avg.mean()),
            "median_nees": float(np.median(avg)),
            "fraction_inside": float(np.mean((avg >= lo) & (avg <= hi))),
            "fraction_below": float(np.mean(avg < lo)),
            "fraction_above": float(np.mean(avg > hi)),
            "rms_error_per_axis": float(np.sqrt(np.mean(e**2)) * scale),
            "reported_rms_per_axis": float(np.sqrt(np.mean(trace) / 3) * scale),
            "mean_reported_3sigma_per_axis": float(3 * np.mean(np.sqrt(trace / 3)) * scale),
            "unit": "arcsec" if block == "attitude" else "rad/s",
        }
    return out


def machine() -> str:
    try:
        lines = subprocess.run(["lscpu"], capture_output=True, text=True, check=False).stdout.splitlines()
        name = next((line.split(":", 1)[1].strip() for line in lines if line.startswith("Model name")), None)
    except OSError:
        name = None
    return name or platform.processor() or platform.machine()


def revision() -> str | None:
    """The checkout's commit, with "+dirty" where the working tree differs from it."""
    git = lambda *a: subprocess.run(["git", *a], capture_output=True, text=True, cwd=ROOT, check=False).stdout.strip()
    try:
        head = git("rev-parse", "HEAD")
        return head + ("+dirty" if git("status", "--porcelain", "--untracked-files=no") else "") if head else None
    except OSError:
        return None


def run(gyro_output: str, seeds: int, T: float, skip: float, cases) -> tuple[list, list]:
    """(records, notes): one record per case and block (or one per case that could not run)."""
    records, notes = [], []
    for case in cases:
        path, overrides = CASES[case]
        overrides = [f"T={T!r}", *overrides]
        try:
            mission, note = load(path, overrides, gyro_output)
        except GyroOutputRefused as err:
            log(f"{case}: {err}")
            notes.append(f"{case}: {err}")
            records.append({"case": case, "gyro_output": gyro_output, "error": str(err)})
            continue
        if note and note not in notes:
            notes.append(note)
        start = time.perf_counter()
        h = fly(mission, seeds)
        wall = time.perf_counter() - start
        output = mission.sensors["gyro"].get("output", "rate (no output key)")
        log(f"{case}: {seeds} runs x {T:g} s in {wall:.1f} s (gyro output: {output})")
        for block, numbers in consistency(h, skip).items():
            records.append({"case": case, "gyro_output": output, "block": block, **numbers,
                            "mission": "missions/flight.toml" if path else None, "overrides": overrides,
                            "wall_s": round(wall, 2)})
    return records, notes


def table(records, lo, hi) -> str:
    rows = [f"NEES band [{lo:.2f}, {hi:.2f}]",
            f"{'case':14s} {'gyro':9s} {'block':8s} {'mean NEES':>10s} {'median':>9s} {'inside':>7s} "
            f"{'RMS/axis':>10s} {'3sigma/axis':>11s}  unit"]
    for r in records:
        if "error" in r:
            rows.append(f"{r['case']:14s} {r['gyro_output']:9s} unavailable: {r['error']}")
            continue
        rows.append(f"{r['case']:14s} {r['gyro_output']:9s} {r['block']:8s} {r['mean_nees']:10.3g} "
                    f"{r['median_nees']:9.3g} {100 * r['fraction_inside']:6.1f}% {r['rms_error_per_axis']:10.3g} "
                    f"{r['mean_reported_3sigma_per_axis']:11.3g}  {r['unit']}")
    return "\n".join(rows)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--gyro-output", choices=("rate", "increment"), default="rate")
    p.add_argument("--seeds", type=int, default=32, help="runs per case (seeds 0 .. seeds - 1)")
    p.add_argument("--T", type=float, default=600.0, help="horizon [s]")
    p.add_argument("--skip", type=float, default=60.0, help="seconds left out at the start [s]")
    p.add_argument("--cases", nargs="+", choices=tuple(CASES), default=tuple(CASES))
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    p.add_argument("--machine-tag", default="cpu-2core-xeon", help="the result file's machine part")
    args = p.parse_args(argv)

    lo, hi = band(args.seeds)
    records, notes = run(args.gyro_output, args.seeds, args.T, args.skip, args.cases)
    log(table(records, lo, hi))
    report = {
        "command": "python -m benchmarks.filter_consistency " + " ".join(sys.argv[1:] if argv is None else argv),
        "machine": machine(),
        "cpus": os.cpu_count(),
        "jax": jax.__version__,
        "so3jax": sj.__version__,
        "revision": revision(),
        "gyro_output": args.gyro_output,
        "seeds": args.seeds,
        "T": args.T,
        "skip_s": args.skip,
        "band": [lo, hi],
        "band_level": 0.95,
        "notes": notes,
        "records": records,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"filter-consistency-{args.gyro_output}-{args.machine_tag}.json"
    path.write_text(json.dumps(report, indent=1) + "\n")
    log(f"wrote {path}")
    print(json.dumps(records))
    return 0


if __name__ == "__main__":
    sys.exit(main())
