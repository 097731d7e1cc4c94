"""Stability margins of a mission's sampled loop (docs/model.md §19): the job ``so3jax margins``
(:mod:`so3jax.commands.margins`) runs, its report, table and figures.

Each controller's loop is flown noise-free and disturbance-free to each time asked
(:func:`so3jax.sim.margins.nominal_state`), linearized over one control period there, broken
at the actuator input (:func:`so3jax.sim.margins.linearize`), and its classical and disk
margins taken (:func:`~so3jax.sim.margins.loop_at_a_time`, :func:`~so3jax.sim.margins.disk_margin`).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from so3jax.dynamics.paper import PHASE_NAMES
from so3jax.results import io
from so3jax.sim import margins, pointing
from so3jax.sim.metrics import reached_phases


def default_times(mission) -> tuple:
    """The last tick of each phase the horizon reaches [s]: the loop as each phase leaves it."""
    scenario = mission.scenario()
    reached = sum(reached_phases(scenario.steps_per_phase))
    ends = [b for _, b in pointing.phase_bounds_of(scenario)[:reached]]
    return tuple(round(end - mission.period, 12) for end in ends)


def check_times(mission, times=None) -> tuple:
    """The times [s] asked (None: :func:`default_times`), each a tick within the horizon, of a
    sampled loop (one-line ValueError otherwise)."""
    if mission.period_steps is None:
        raise ValueError("margins need a sampled loop: this mission's control is continuous (control.mode)")
    times = default_times(mission) if times is None else times
    scenario, loop = mission.scenario(), mission.loop()
    for t in times:
        if not (0 <= t < mission.T):
            raise ValueError(f"--at {t:g} s is outside the horizon [0, {mission.T:g}) s")
        margins.tick_index(scenario, loop, t)
    return tuple(float(t) for t in times)


def phase_of(mission, t: float) -> str:
    """The name of the phase holding at t [s]."""
    bounds = pointing.phase_bounds_of(mission.scenario())
    return next(PHASE_NAMES[p] for p, (a, b) in enumerate(bounds) if a <= t < b or p == len(bounds) - 1)


def at(mission, name: str, t: float, dtype: str = "float64") -> tuple:
    """(Linearization, LoopMargins, DiskMargins) of controller ``name``'s loop at t [s]."""
    scenario, loop = mission.scenario(dtype), mission.loop(dtype)
    controller, gains = mission.controller(name)
    state = margins.nominal_state(scenario, loop, controller, gains, t)
    lin = margins.linearize(scenario, loop, controller, gains, state, margins.tick_index(scenario, loop, t))
    return lin, margins.loop_at_a_time(lin), margins.disk_margin(lin)


def run(mission, times, dtype: str = "float64") -> tuple[dict, dict, float]:
    """Every controller's margins at each time: ({name: report}, {name: {t: Linearization}}, wall [s])."""
    start = time.perf_counter()
    reports, linearizations = {}, {}
    for name in mission.controllers:
        rows, lins = [], {}
        for t in times:
            lin, classical, disk = at(mission, name, t, dtype)
            lins[t] = lin
            rows.append({"t": t, "phase": phase_of(mission, t), "loop_at_a_time": classical.to_dict(),
                         "disk": disk.to_dict()})
        reports[name] = {"stable": all(r["loop_at_a_time"]["stable"] for r in rows), "times": rows}
        linearizations[name] = lins
    return reports, linearizations, time.perf_counter() - start


def _db(x, infinite: str = "inf") -> str:
    """A margin [dB]; None (no crossing: the margin is infinite) as ``infinite``."""
    return infinite if x is None else f"{x:+.1f}"


def format_table(reports: dict) -> str:
    """Per controller and time: each axis's gain margins [dB], phase margin [deg], delay margin
    [s] and disk margin, and the multi-loop disk margin."""
    lines = []
    for name, report in reports.items():
        for row in report["times"]:
            classical, disk = row["loop_at_a_time"], row["disk"]
            head = f"{name}, t = {row['t']:g} s ({row['phase']})"
            if not classical["stable"]:
                lines.append(f"{head}: closed loop UNSTABLE (spectral radius {classical['spectral_radius']:.6f})")
                continue
            binds = ": an actuator limit binds here (its channel is open)" if classical["at_limit"] else ""
            lines.append(head + binds)
            lines.append(f"  {'axis':6s}{'GM low [dB]':>12s}{'GM up [dB]':>12s}{'PM [deg]':>10s}{'w_c [rad/s]':>13s}"
                         f"{'delay [s]':>11s}{'disk alpha':>12s}{'disk [dB]':>11s}{'disk [deg]':>11s}")
            for axis, d in zip(classical["axes"], disk["axes"]):
                pm = "inf" if axis["phase_margin_deg"] is None else f"{axis['phase_margin_deg']:.1f}"
                wc = "-" if axis["gain_crossover"] is None else f"{axis['gain_crossover']:.4f}"
                delay = "inf" if axis["delay_margin_s"] is None else f"{axis['delay_margin_s']:.2f}"
                lines.append(f"  {'xyz'[axis['axis']]:6s}{_db(axis['gain_margin_lower_db'], '-inf'):>12s}"
                             f"{_db(axis['gain_margin_upper_db']):>12s}{pm:>10s}{wc:>13s}{delay:>11s}"
                             f"{d['alpha']:>12.3f}{_db(d['gain_margin_upper_db']):>11s}{d['phase_margin_deg']:>11.1f}")
            m = disk["multiloop"]
            lines.append(f"  all axes at once (disk, a lower bound): alpha = {m['alpha']:.3f}, "
                         f"+-{m['gain_margin_upper_db']:.1f} dB, +-{m['phase_margin_deg']:.1f} deg")
    return "\n".join(lines)


def figures(linearizations: dict) -> dict:
    """{file name: figure}: per controller, the Bode plot of each axis's loop L_i (the other
    axes closed) at each time, a column per axis, the 0 dB and -180 deg lines marked (phase
    in [-360, 0) deg)."""
    from matplotlib.figure import Figure  # here: matplotlib only when drawing

    out = {}
    for name, lins in linearizations.items():
        fig = Figure(figsize=(13, 6.5))
        axes = fig.subplots(2, 3, sharex=True, sharey="row")
        for t, lin in lins.items():
            omegas = margins.default_omegas(lin.period, count=800)
            L = margins.axis_response(lin, omegas)
            for i in range(3):
                axes[0, i].semilogx(omegas, 20 * np.log10(np.abs(L[:, i])), label=f"t = {t:g} s")
                axes[1, i].semilogx(omegas, np.mod(np.degrees(np.angle(L[:, i])), 360.0) - 360.0)
        for i in range(3):
            axes[0, i].axhline(0.0, color="k", lw=0.8)
            axes[1, i].axhline(-180.0, color="k", lw=0.8)
            axes[0, i].set_title(f"axis {'xyz'[i]}")
            axes[1, i].set_xlabel("frequency [rad/s]")
            for ax in axes[:, i]:
                ax.grid(alpha=0.3, which="both")
        axes[0, 0].set_ylabel("|L_i| [dB]")
        axes[1, 0].set_ylabel("arg L_i [deg]")
        axes[0, 0].legend(fontsize=7)
        fig.suptitle(f"{name}: each axis's loop at the actuator input, the other axes closed "
                     "(up to the Nyquist frequency)")
        out[f"bode_{name}.png"] = fig
    return out


def write(out: Path, reports: dict, linearizations: dict, config: dict, with_figures: bool) -> list:
    """margins.json (the reports and the mission as flown) and the figures; the figures' paths."""
    io.write_json(Path(out) / "margins.json", {**reports, "config": config})
    return io.save_figures(out, figures(linearizations)) if with_figures else []
