"""A mission with navigation errors (:mod:`so3jax.components.navigation`, Basilisk's
simpleNav) compared as distributions: the two simulators draw from their own generators, so
no two runs share a trajectory. Each side flies ``runs`` runs (so3jax the seeds seed, ...,
seed + runs - 1; Basilisk simpleNav's RNGSeed the same numbers); per run, the
RMS over the ticks of

* ``attitude_knowledge``: |log(R_hat^T R)| [rad], the navigation's attitude error;
* ``rate_knowledge``: |Omega_hat - Omega| [rad/s], its rate error;
* ``pointing``: |log(R_d^T R)| [rad], the true attitude's error from the reference.

Per quantity, each side's mean and standard error over its runs and Welch's t test of equal
means: the two agree where every p-value is above :data:`ALPHA`."""

from __future__ import annotations

import dataclasses
import time
import warnings

import numpy as np

from so3jax.dynamics.inertia import InertiaWarning
from so3jax.jobs.crosscheck import basilisk
from so3jax.sim.rollout import simulate

QUANTITIES = (("attitude_knowledge", "rad"), ("rate_knowledge", "rad/s"), ("pointing", "rad"))
ALPHA = 1e-3  # a p-value below it: the means differ
UNITS = {q: unit for q, unit in QUANTITIES} | {"wall_time_s": "s"}


def angle(A, B) -> np.ndarray:
    """|log(A^T B)| (M,) [rad] of rotations A, B (M, 3, 3)."""
    from scipy.spatial.transform import Rotation  # SciPy where it is used: the command line starts without it

    return np.linalg.norm(Rotation.from_matrix(np.einsum("mji,mjk->mik", A, B)).as_rotvec(), axis=1)


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def per_run(R, Omega, R_hat, Omega_hat, R_d) -> dict:
    """{quantity: RMS over the ticks} of one run's records (M, ...)."""
    return {"attitude_knowledge": _rms(angle(R_hat, R)),
            "rate_knowledge": _rms(np.linalg.norm(Omega_hat - Omega, axis=1)),
            "pointing": _rms(angle(R_d, R))}


def _so3jax_runs(mission, name: str, runs: int, dtype: str) -> list[dict]:
    """The runs one seed after another: one compiled trajectory (a batch compiles for longer
    than the few runs take)."""
    controller, gains = mission.controller(name)
    scenario, loop = mission.scenario(dtype), mission.loop(dtype)
    out = []
    for seed in range(mission.seed, mission.seed + runs):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", InertiaWarning)  # reported once, when the mission was read
            history = simulate(scenario, controller, gains, seed, loop=loop, record_every=mission.record_every).history
        out.append(per_run(*(np.asarray(getattr(history, f)) for f in ("R", "Omega", "R_hat", "Omega_hat", "R_d"))))
    return out


def _basilisk_runs(mission, name: str, runs: int) -> list[dict]:
    out = []
    for seed in range(mission.seed, mission.seed + runs):
        flown = basilisk.fly(mission, name, seed)
        out.append(per_run(flown.R, flown.Omega, flown.R_hat, flown.Omega_hat, flown.R_d))  # the reference it tracked
    return out


def compare(so3jax_runs: list[dict], basilisk_runs: list[dict]) -> dict:
    """Per quantity: each side's mean and standard error, Welch's t and its two-sided p."""
    from scipy import stats

    out = {}
    for q, _ in QUANTITIES:
        a = np.array([r[q] for r in so3jax_runs])
        b = np.array([r[q] for r in basilisk_runs])
        test = stats.ttest_ind(a, b, equal_var=False)
        t, p = float(test.statistic), float(test.pvalue)
        if np.ptp(a) == 0 and np.ptp(b) == 0 and a[0] == b[0]:  # one constant on both sides (a walk neither flies)
            t, p = 0.0, 1.0
        out[q] = {"so3jax_mean": float(a.mean()), "so3jax_std_error": float(a.std(ddof=1) / np.sqrt(len(a))),
                  "basilisk_mean": float(b.mean()), "basilisk_std_error": float(b.std(ddof=1) / np.sqrt(len(b))),
                  "t": t, "p": p}
    return out


@dataclasses.dataclass
class Runs:
    """One controller's runs on both sides: {side: [{quantity: RMS}]} and wall times [s]."""

    so3jax: list
    basilisk: list
    wall: dict


def crosscheck(mission, runs: int, dtype: str = "float64") -> tuple[dict, dict]:
    """Every controller of ``mission`` flown ``runs`` times by each side: ({name: report},
    {name: Runs})."""
    reports, flown = {}, {}
    for name in mission.controllers:
        start = time.perf_counter()
        ours = _so3jax_runs(mission, name, runs, dtype)
        middle = time.perf_counter()
        theirs = _basilisk_runs(mission, name, runs)
        wall = {"so3jax": middle - start, "basilisk": time.perf_counter() - middle}
        compared = compare(ours, theirs)
        reports[name] = {"runs": runs, "quantities": compared, "agree": all(c["p"] > ALPHA for c in compared.values()),
                         "wall_time_s": wall}
        flown[name] = Runs(ours, theirs, wall)
    return reports, flown


def format_table(reports: dict) -> str:
    """A row per controller and quantity: each side's mean +- standard error, t, p."""
    lines = [f"{'controller / quantity':34s}{'so3jax':>24s}{'Basilisk':>24s}{'t':>8s}{'p':>10s}"]
    for name, report in reports.items():
        for q, unit in QUANTITIES:
            c = report["quantities"][q]
            sides = [f"{c[f'{s}_mean']:.3e} +- {c[f'{s}_std_error']:.1e}" for s in ("so3jax", "basilisk")]
            lines.append(f"{f'{name} {q} [{unit}]':34s}{sides[0]:>24s}{sides[1]:>24s}{c['t']:>8.2f}{c['p']:>10.3g}")
        label, wall = f"{name}: {report['runs']} runs each, wall", report["wall_time_s"]
        verdict = "agree" if report["agree"] else "DIFFER"
        lines.append(f"{label:34s}{wall['so3jax']:>22.1f} s{wall['basilisk']:>22.1f} s  {verdict}")
    return "\n".join(lines)


def write_figures(out, mission, runs: dict) -> list:
    """crosscheck.png: each quantity's per-run values, side by side (:mod:`so3jax.viz.crosscheck`)."""
    from so3jax.results import io
    from so3jax.viz import crosscheck as plots  # here: matplotlib only when drawing

    return io.save_figures(out, {"crosscheck.png": plots.runs_figure(mission, runs, QUANTITIES)})
