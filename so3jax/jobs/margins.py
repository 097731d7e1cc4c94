"""Stability margins of a mission's sampled loop (docs/model.md §19): the job ``so3jax margins``
(:mod:`so3jax.commands.margins`) runs, its report, table and figures.

Each controller's loop is flown noise-free and disturbance-free to each time asked
(:func:`so3jax.sim.margins.nominal_state`), linearized over one control period there, broken
at the actuator input (:func:`so3jax.sim.margins.linearize`), and its classical and disk
margins taken (:func:`~so3jax.sim.margins.loop_at_a_time`, :func:`~so3jax.sim.margins.disk_margin`).

A mission with ``[[appendages]]`` or ``[[slosh]]``: at each time the report names the free
hub's structural modes (:func:`~so3jax.sim.margins.structural_modes`, the hub's inertia J(t)
of that time), the margins' frequency grid resolves their resonances
(:func:`~so3jax.sim.margins.resolving_omegas`), and the figures mark them. A mission without
them: the report as before, no key added.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

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
    sampled loop, at or after its first fully formed tick (:func:`so3jax.sim.margins.first_formed_tick`);
    one-line ValueError otherwise."""
    if mission.period_steps is None:
        raise ValueError("margins need a sampled loop: this mission's control is continuous (control.mode)")
    times = default_times(mission) if times is None else times
    scenario, loop = mission.scenario(), mission.loop()
    formed = margins.first_formed_tick(loop)
    for t in times:
        if not (0 <= t < mission.T):
            raise ValueError(f"--at {t:g} s is outside the horizon [0, {mission.T:g}) s")
        if margins.tick_index(scenario, loop, t) < formed:
            raise ValueError(f"--at {t:g} s is before t = {formed * mission.period:g} s (tick {formed}), the first "
                             "tick at which the loop is formed: a sensor measuring over a period (the rate-integrating "
                             "gyro) has no reading before it, so the loop lacks that feedback there")
    return tuple(float(t) for t in times)


def phase_of(mission, t: float) -> str:
    """The name of the phase holding at t [s]."""
    bounds = pointing.phase_bounds_of(mission.scenario())
    return next(mission.phase_names[p] for p, (a, b) in enumerate(bounds) if a <= t < b or p == len(bounds) - 1)


class Margins(NamedTuple):
    """A controller's loop at one time, broken at the actuator input."""

    linearization: margins.Linearization  # over one control period, about the noise-free flight
    loop_at_a_time: margins.LoopMargins  # per-axis gain [dB], phase [deg] and delay [s] margins
    disk: margins.DiskMargins  # disk margins per axis and for all axes at once


def structural_modes(mission, t: float, dtype: str = "float64") -> tuple | None:
    """The mission's structural modes at t [s] (:func:`so3jax.sim.margins.structural_modes`),
    None without appendages and slosh."""
    return margins.structural_modes(mission.scenario(dtype), t)


def at(mission, name: str, t: float, dtype: str = "float64") -> Margins:
    """(Linearization, LoopMargins, DiskMargins) of controller ``name``'s loop at t [s]; with
    structural modes, on a frequency grid resolving their resonances (:func:`so3jax.sim.margins.resolving_omegas`)."""
    scenario, loop = mission.scenario(dtype), mission.loop(dtype)
    controller, gains = mission.controller(name)
    state = margins.nominal_state(scenario, loop, controller, gains, t)
    lin = margins.linearize(scenario, loop, controller, gains, state, margins.tick_index(scenario, loop, t))
    modes = margins.structural_modes(scenario, t)
    omegas = margins.resolving_omegas(lin.period, modes) if modes else None
    return Margins(lin, margins.loop_at_a_time(lin, omegas), margins.disk_margin(lin, omegas))


def run(mission, times, dtype: str = "float64") -> tuple[dict, dict, float]:
    """Every controller's margins at each time: ({name: report}, {name: {t: Linearization}}, wall [s])."""
    start = time.perf_counter()
    reports, linearizations = {}, {}
    for name in mission.controllers:
        rows, lins = [], {}
        for t in times:
            lin, classical, disk = at(mission, name, t, dtype)
            lins[t] = lin
            row = {"t": t, "phase": phase_of(mission, t)}
            modes = structural_modes(mission, t, dtype)
            if modes is not None:  # only with appendages or slosh: a rigid mission's report is as it was
                row["modes"] = [mode.to_dict() for mode in modes]
            rows.append({**row, "loop_at_a_time": classical.to_dict(), "disk": disk.to_dict()})
        reports[name] = {"stable": all(r["loop_at_a_time"]["stable"] for r in rows), "times": rows}
        linearizations[name] = lins
    return reports, linearizations, time.perf_counter() - start


def _db(x, infinite: str = "inf") -> str:
    """A margin [dB]; None (no crossing: the margin is infinite) as ``infinite``."""
    return infinite if x is None else f"{x:+.1f}"


def format_modes(modes: list) -> str:
    """One line naming a time's structural modes (a report's ``modes``): frequency [Hz] and damping ratio."""
    named = ", ".join(f"{m['frequency_hz']:.3g} Hz ζ {m['damping_ratio']:.3g}" for m in modes)
    return f"  structural modes: {named or 'none'}"


def format_table(reports: dict) -> str:
    """Per controller and time: each axis's gain margins [dB], phase margin [deg], delay margin
    [s] and disk margin, and the multi-loop disk margin; with appendages or slosh, a line
    naming the structural modes."""
    lines = []
    for name, report in reports.items():
        for row in report["times"]:
            classical, disk = row["loop_at_a_time"], row["disk"]
            head = f"{name}, t = {row['t']:g} s ({row['phase']})"
            if not classical["stable"]:
                lines.append(f"{head}: closed loop UNSTABLE (spectral radius {classical['spectral_radius']:.6f})")
                if "modes" in row:
                    lines.append(format_modes(row["modes"]))
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
            if "modes" in row:
                lines.append(format_modes(row["modes"]))
    return "\n".join(lines)


# The region a loop at a time is asked to keep out of on the Nichols chart: gain and phase
# variations AOCS requirements commonly ask (dB, deg), and the balanced disk covering the same gains.
EXCLUSION_DB, EXCLUSION_DEG = 6.0, 30.0


def _phase_deg(L) -> np.ndarray:
    """arg L [deg] in [-360, 0), the Bode figure's range."""
    return np.mod(np.degrees(np.angle(L)), 360.0) - 360.0


def nichols_curve(L) -> tuple[np.ndarray, np.ndarray]:
    """(phase [deg] in [-360, 0), gain [dB]) of a frequency response, NaN where the phase wraps
    between -360 and 0 deg (so a line is not drawn across the chart)."""
    phase, gain = _phase_deg(L), 20 * np.log10(np.abs(L))
    wraps = np.nonzero(np.abs(np.diff(phase)) > 180.0)[0] + 1
    return np.insert(phase, wraps, np.nan), np.insert(gain, wraps, np.nan)


def phase_crossings(phase, gain) -> np.ndarray:
    """The gains [dB] where a Nichols curve (:func:`nichols_curve`) crosses -180 deg, linearly
    interpolated between its samples: each is minus a gain margin [dB]."""
    d = phase + 180.0
    k = np.nonzero((d[:-1] * d[1:] <= 0) & (d[:-1] != d[1:]))[0]  # NaN (a wrap) compares False
    f = d[k] / (d[k] - d[k + 1])
    return gain[k] + f * (gain[k + 1] - gain[k])


def disk_boundary(alpha: float, count: int = 361) -> tuple[np.ndarray, np.ndarray]:
    """(phase [deg], gain [dB]) of the balanced disk margin alpha's exclusion region on the
    Nichols chart: the loop values L with |S - 1/2| = 1/alpha (S = 1/(1 + L)), the circle
    |L - 1| = rho |L + 1|, rho = 2/alpha > 1, around the critical point (alpha < 2)."""
    rho = 2.0 / alpha
    centre, radius = -(rho**2 + 1) / (rho**2 - 1), 2 * rho / (rho**2 - 1)
    L = centre + radius * np.exp(1j * np.linspace(0.0, 2 * np.pi, count))
    return _phase_deg(L), 20 * np.log10(np.abs(L))


def _grid(lin, modes) -> np.ndarray:
    """The figures' frequencies [rad/s]: 800 log-spaced up to the Nyquist frequency, with points
    resolving each structural mode's resonance (:func:`so3jax.sim.margins.resolving_omegas`)."""
    return margins.resolving_omegas(lin.period, modes, count=800)


def _mark_modes(ax, modes, label: bool):
    """A thin dotted vertical line at each structural mode's frequency [rad/s], labelled in Hz."""
    for omega, zeta in modes:
        ax.axvline(omega, color="0.35", ls=":", lw=0.8)
        if label:
            ax.text(omega, 0.98, f" {omega / (2 * np.pi):.3g} Hz, ζ {zeta:.2g}", transform=ax.get_xaxis_transform(),
                    rotation=90, va="top", ha="right", fontsize=7, color="0.25")


def _bode(name: str, lins: dict, modes: dict | None = None):
    """Each axis's loop L_i (the other axes closed) at each time, a column per axis, the 0 dB
    and -180 deg lines marked (phase in [-360, 0) deg); modes {t: ((omega_r, zeta_r), ...)}:
    each structural mode's frequency a dotted line, labelled on the gain, the grid resolving
    its resonance."""
    from matplotlib.figure import Figure  # here: matplotlib only when drawing

    modes = modes or {}
    fig = Figure(figsize=(13, 6.5))
    axes = fig.subplots(2, 3, sharex=True, sharey="row")
    for t, lin in lins.items():
        omegas = _grid(lin, modes.get(t, ()))
        L = margins.axis_response(lin, omegas)
        for i in range(3):
            axes[0, i].semilogx(omegas, 20 * np.log10(np.abs(L[:, i])), label=f"t = {t:g} s")
            axes[1, i].semilogx(omegas, _phase_deg(L[:, i]))
    marked = sorted({tuple(m) for ms in modes.values() for m in ms})
    for i in range(3):
        _mark_modes(axes[0, i], marked, label=True)
        _mark_modes(axes[1, i], marked, label=False)
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
                 "(up to the Nyquist frequency" + ("; dotted: the structural modes)" if marked else ")"))
    return fig


def _nichols(name: str, lins: dict, modes: dict | None = None):
    """Each axis's loop L_i (the other axes closed) at each time on the Nichols chart: gain
    [dB] against phase [deg] in [-360, 0), a panel per axis, the critical point (-180 deg,
    0 dB), the +-6 dB / +-30 deg rectangle around it and the balanced disk covering +-6 dB;
    each crossing of -180 deg marked (its gain is minus a gain margin), the gain range wide
    enough to hold them (within +-120 dB); up to just below the Nyquist frequency. modes
    {t: ((omega_r, zeta_r), ...)}: the loop's point at each structural mode's frequency marked
    (a cross, labelled in Hz), the grid resolving its resonance."""
    from matplotlib.figure import Figure  # here: matplotlib only when drawing
    from matplotlib.patches import Rectangle

    modes = modes or {}
    fig = Figure(figsize=(13, 5.5))
    axes = fig.subplots(1, 3, sharex=True, sharey=True)
    alpha = margins.alpha_of_db(EXCLUSION_DB)
    disk, disk_deg = disk_boundary(alpha), margins.Disk.of(alpha, 0.0).phase_margin_deg
    low, high = -40.0, 40.0
    for t, lin in lins.items():
        # below the Nyquist frequency: there L is real, a curve drawn to it jumps to 0 or -180 deg
        L = margins.axis_response(lin, _grid(lin, modes.get(t, ()))[:-1])
        at_modes = [(omega, margins.axis_response(lin, [omega])[0]) for omega, _ in modes.get(t, ())
                    if omega < np.pi / lin.period]
        for i in range(3):
            phase, gain = nichols_curve(L[:, i])
            (line,) = axes[i].plot(phase, gain, label=f"t = {t:g} s")
            crossings = phase_crossings(phase, gain)
            axes[i].plot(np.full(len(crossings), -180.0), crossings, "o", ms=4, color=line.get_color())
            low, high = (crossings - 10.0).min(initial=low), (crossings + 10.0).max(initial=high)
            for omega, L_r in at_modes:
                x, y = _phase_deg(L_r[i]), 20 * np.log10(np.abs(L_r[i]))
                axes[i].plot([x], [y], "x", ms=6, mew=1.2, color=line.get_color())
                axes[i].annotate(f"{omega / (2 * np.pi):.3g} Hz", (x, y), textcoords="offset points", xytext=(4, 4),
                                 fontsize=7, color=line.get_color())
    for i, ax in enumerate(axes):
        ax.add_patch(Rectangle((-180.0 - EXCLUSION_DEG, -EXCLUSION_DB), 2 * EXCLUSION_DEG, 2 * EXCLUSION_DB,
                               facecolor="tab:red", alpha=0.15, edgecolor="none",
                               label=f"±{EXCLUSION_DB:g} dB, ±{EXCLUSION_DEG:g}°"))
        ax.plot(*disk, color="tab:red", ls="--", lw=1.0,
                label=f"disk α = {alpha:.2f} (±{EXCLUSION_DB:g} dB, ±{disk_deg:.1f}°)")
        ax.plot([-180.0], [0.0], "k+", ms=10, mew=1.5, label="critical point")
        ax.axhline(0.0, color="k", lw=0.6)
        ax.axvline(-180.0, color="k", lw=0.6)
        ax.set_title(f"axis {'xyz'[i]}")
        ax.set_xlabel("arg L_i [deg]")
        ax.set_xlim(-360.0, 0.0)
        ax.set_xticks(np.arange(-360.0, 1.0, 60.0))
        ax.set_xticks(np.arange(-330.0, 0.0, 60.0), minor=True)
        ax.set_ylim(max(low, -120.0), min(high, 120.0))
        ax.grid(alpha=0.3, which="both")
    axes[0].set_ylabel("|L_i| [dB]")
    axes[-1].legend(fontsize=7, loc="upper right")  # phases past -90 deg at high gain: seldom a loop's
    fig.subplots_adjust(top=0.84)
    fig.suptitle(f"{name}: Nichols chart of each axis's loop at the actuator input, the other axes closed\n"
                 f"(dots: crossings of -180°, at minus the gain margins; clear of the shaded region: gain margins "
                 f"beyond ±{EXCLUSION_DB:g} dB, phase margin beyond {EXCLUSION_DEG:g}°)")
    return fig


# The units of the keys a report's ``modes`` adds (only with appendages or slosh).
MODE_UNITS = {"frequency_hz": "Hz", "damping_ratio": "-"}


def report_modes(reports: dict) -> dict:
    """{controller: {t: ((omega_r [rad/s], zeta_r), ...)}} of the reports' ``modes`` (empty where none)."""
    return {name: {row["t"]: tuple((m["frequency"], m["damping_ratio"]) for m in row["modes"])
                   for row in report["times"] if row.get("modes")}
            for name, report in reports.items()}


def figures(linearizations: dict, modes: dict | None = None) -> dict:
    """{file name: figure}: per controller, the Bode plot (``bode_NAME.png``) and the Nichols
    chart (``nichols_NAME.png``) of each axis's loop L_i (the other axes closed) at each time;
    modes: {controller: {t: ((omega_r, zeta_r), ...)}} (:func:`report_modes`), each structural
    mode marked and its resonance resolved."""
    out, modes = {}, modes or {}
    for name, lins in linearizations.items():
        out[f"bode_{name}.png"] = _bode(name, lins, modes.get(name))
        out[f"nichols_{name}.png"] = _nichols(name, lins, modes.get(name))
    return out


def write(out: Path, reports: dict, linearizations: dict, config: dict, with_figures: bool) -> list:
    """margins.json (the reports and the mission as flown) and the figures; the figures' paths."""
    modes = report_modes(reports)
    flexible = any("modes" in row for report in reports.values() for row in report["times"])
    units = {**margins.UNITS, **MODE_UNITS} if flexible else margins.UNITS
    io.write_json(Path(out) / "margins.json", {**reports, "units": units, "config": config})
    return io.save_figures(out, figures(linearizations, modes)) if with_figures else []
