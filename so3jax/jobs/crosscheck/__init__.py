"""The job ``so3jax crosscheck basilisk`` (:mod:`so3jax.commands.crosscheck`): a mission
Basilisk can represent (:mod:`.representable`) flown by so3jax's loop and by Basilisk's own
modules (:mod:`.basilisk`), compared at every recorded control tick: the attitude
|log(R^T R_B)| [rad], the body rate [rad/s], the wheels' speeds [rad/s] and mrpFeedback's
torque command [N m], with [[appendages]] and [[slosh]] the hinge angles [rad] and the slosh
displacements [m], with each side's wall time. A mission with navigation errors is
compared as distributions over runs instead (:mod:`.statistics`)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from so3jax.jobs import fly as flights
from so3jax.jobs.crosscheck import basilisk, representable, statistics

QUANTITIES = (("attitude", "rad"), ("rate", "rad/s"), ("wheel_speed", "rad/s"), ("torque", "N m"))
# with [[appendages]] and [[slosh]] (docs/model.md §8.9): the largest difference over the panels, the particles
FLEXIBLE_QUANTITIES = (("hinge_angle", "rad"), ("slosh_displacement", "m"))
# crosscheck.json's units (so3jax.results.units)
UNITS = {**{f"max_{q}": unit for q, unit in QUANTITIES + FLEXIBLE_QUANTITIES}, "max_torque_relative": "-",
         "max_torque_command": "N m", "wall_time_s": "s"}


def quantities(mission) -> tuple:
    """The quantities compared on ``mission``: QUANTITIES, and the hinge angles with
    [[appendages]], the slosh displacements with [[slosh]]."""
    present = {"hinge_angle": bool(getattr(mission, "appendages", ())),
               "slosh_displacement": bool(getattr(mission, "slosh", ()))}
    return QUANTITIES + tuple((q, unit) for q, unit in FLEXIBLE_QUANTITIES if present[q])


class Differences(NamedTuple):
    """|so3jax - Basilisk| at the ticks t [s] (M,): attitude (M,) [rad], rate (M,) [rad/s]
    and wheel_speed (M,) [rad/s] (largest component), torque (M,) [N m] (largest component);
    hinge_angle (M,) [rad] and slosh_displacement (M,) [m] (largest over the panels, the
    particles) where the mission has them, else None."""

    t: np.ndarray
    attitude: np.ndarray
    rate: np.ndarray
    wheel_speed: np.ndarray
    torque: np.ndarray
    hinge_angle: np.ndarray | None = None
    slosh_displacement: np.ndarray | None = None


def module_torque(mission, history) -> np.ndarray:
    """mrpFeedback's command (M, 3) [N m] from so3jax's history: the law's, plus the wheels'
    momentum compensation Omega x h_w where the actuator adds it (law_type 1's term)."""
    tau = np.asarray(history.tau_cmd)
    wheels = mission.actuator.get("wheels") if mission.actuator["kind"] == "wheels" else None
    if wheels is None or not wheels["momentum_compensation"]:
        return tau
    G = np.asarray(wheels["axes"], float).T
    J_s = np.broadcast_to(np.asarray(wheels["spin_inertia"], float), (G.shape[1],))
    Omega = np.asarray(history.Omega)
    h_w = ((Omega @ G + np.asarray(history.actuator)) * J_s) @ G.T
    return tau + np.cross(Omega, h_w)


def compare(mission, history, flown: basilisk.Flown) -> Differences:
    """The differences at so3jax's recorded ticks (Basilisk records every tick)."""
    t = np.asarray(history.t)
    ticks = np.rint(t / mission.period).astype(int)
    if ticks.max() >= len(flown.t) or np.max(np.abs(flown.t[ticks] - t)) > 1e-9:
        raise RuntimeError("so3jax's records and Basilisk's ticks do not line up")
    R_b = flown.R[ticks]
    angle = statistics.angle(np.asarray(history.R), R_b)
    rate = np.max(np.abs(np.asarray(history.Omega) - flown.Omega[ticks]), axis=1)
    if flown.wheel_speed.shape[1]:
        speed = np.max(np.abs(np.asarray(history.actuator) - flown.wheel_speed[ticks]), axis=1)
    else:
        speed = np.zeros_like(t)
    torque = np.max(np.abs(module_torque(mission, history) - flown.torque[ticks]), axis=1)
    modal = {}
    for (q, _), ours, theirs in zip(FLEXIBLE_QUANTITIES, ("theta", "rho"), ("hinge_angle", "slosh_displacement")):
        if q in dict(quantities(mission)):
            gap = np.abs(np.asarray(getattr(history.flexible, ours)) - getattr(flown, theirs)[ticks])
            modal[q] = np.max(gap, axis=1)
    return Differences(t, angle, rate, speed, torque, **modal)


def report(differences: Differences, flown: basilisk.Flown, so3jax_wall: float, torque_scale: float) -> dict:
    """JSON-ready: the largest difference of each quantity compared, the torque's also
    relative to the largest torque command, and each side's wall time [s]."""
    out = {f"max_{q}": float(np.max(getattr(differences, q))) for q, _ in QUANTITIES + FLEXIBLE_QUANTITIES
           if getattr(differences, q) is not None}
    out["max_torque_relative"] = out["max_torque"] / torque_scale if torque_scale > 0 else 0.0
    out["max_torque_command"] = torque_scale
    out["ticks_compared"] = len(differences.t)
    out["wall_time_s"] = {"so3jax": so3jax_wall, "basilisk": flown.wall}
    return out


def crosscheck(mission, dtype: str = "float64") -> tuple[dict, dict, float]:
    """Every controller of ``mission`` flown by both: ({name: report}, {name:
    Differences}, so3jax's wall time [s], compile included). ValueError first where
    Basilisk cannot represent the mission or is not installed."""
    representable.check(mission)
    basilisk.require()
    results, wall = flights.fly(mission, dtype)
    reports, differences = {}, {}
    for name in mission.controllers:
        flown = basilisk.fly(mission, name)
        history = results[name].history
        differences[name] = compare(mission, history, flown)
        scale = float(np.max(np.abs(module_torque(mission, history))))
        reports[name] = report(differences[name], flown, wall, scale)
    return reports, differences, wall


def format_table(reports: dict) -> str:
    """A row per quantity, a column per controller."""
    names = list(reports)
    width = max(14, *(len(n) + 2 for n in names))
    lines = [f"{'max |so3jax - Basilisk|':34s}" + "".join(f"{n:>{width}s}" for n in names)]
    for q, unit in QUANTITIES + FLEXIBLE_QUANTITIES:
        if f"max_{q}" not in reports[names[0]]:
            continue
        lines.append(f"{f'{q} [{unit}]':34s}" + "".join(f"{reports[n][f'max_{q}']:>{width}.2e}" for n in names))
    lines.append(f"{'torque / max |torque|':34s}" + "".join(f"{reports[n]['max_torque_relative']:>{width}.2e}"
                                                          for n in names))
    for side in ("so3jax", "basilisk"):
        label = "so3jax wall [s] (compile incl.)" if side == "so3jax" else "Basilisk wall [s]"
        lines.append(f"{label:34s}" + "".join(f"{reports[n]['wall_time_s'][side]:>{width}.2f}" for n in names))
    return "\n".join(lines)


def write_figures(out, mission, differences: dict) -> list:
    """crosscheck.png: each difference against time (:mod:`so3jax.viz.crosscheck`)."""
    from so3jax.results import io
    from so3jax.viz import crosscheck as plots  # here: matplotlib only when drawing

    return io.save_figures(out, {"crosscheck.png": plots.differences_figure(mission, differences,
                                                                            quantities(mission))})
