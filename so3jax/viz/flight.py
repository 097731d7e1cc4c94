"""Figures of the flight loop (docs/model.md §8): estimation, torques, wheels, momentum and its management.

Each takes {controller name: History of the sampled wiring with NumPy leaves}, the phase start times [s]
and the horizon T [s]; it returns a matplotlib figure.
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from so3jax.core import so3
from so3jax.viz.plots import AXES, shade_phases
from so3jax.viz.styles import style as controller_style


def _frame(ax, phase_times, T, ylabel):
    shade_phases(ax, phase_times, T)
    ax.set_ylabel(ylabel)


def _angle(R):
    """|log(R)^vee| [rad] of (M, 3, 3) rotations."""
    return np.asarray(so3.angle(np.moveaxis(np.asarray(R), 0, -1)))


def attitude_figure(histories, phase_times, T):
    """True vs estimated attitude error |log(R_d^T R)|, |log(R_d^T R_hat)|, and the
    estimation error |log(R_hat^T R)| [deg]. The truth is drawn thin in the law's line
    style on top of its estimate, a wide faint solid band of the same colour."""
    fig = Figure(figsize=(10, 6.5))
    top, bottom = fig.subplots(2, 1, sharex=True)
    for name, h in histories.items():
        style = controller_style(name)
        estimated = _angle(np.einsum("mji,mjk->mik", h.R_d, h.R_hat))
        top.plot(h.t, np.degrees(estimated), lw=4.0, alpha=0.3, ls="-", color=style.get("color"), zorder=2,
                 label=f"{style['label']} (estimated)")
        top.plot(h.t, np.degrees(h.angle), lw=0.8, zorder=3, **{**style, "label": f"{style['label']} (true)"})
        bottom.plot(h.t, np.degrees(_angle(np.einsum("mji,mjk->mik", h.R_hat, h.R))), lw=1.0, **style)
    top.set_yscale("log")
    bottom.set_yscale("log")
    _frame(top, phase_times, T, "|log(R_dᵀR)| [deg]")
    _frame(bottom, phase_times, T, "|log(R̂ᵀR)| [deg]")
    top.legend(fontsize=8)
    bottom.set_xlabel("t [s]")
    top.set_title("Attitude error: true (thin) and as estimated (wide, faint)", pad=14)
    bottom.set_title("Attitude estimation error", pad=14)
    return fig


def bias_figure(histories, phase_times, T):
    """Gyro bias b and its estimate b_hat with the filter's 3-sigma bound, per axis [deg/h];
    the y range follows the values after the first 2 % of the horizon (the filter's
    initial sigma would dwarf them)."""
    to_deg_h = np.degrees(1.0) * 3600.0
    fig = Figure(figsize=(10, 7.5))
    axes = fig.subplots(3, 1, sharex=True)
    for i, ax in enumerate(axes):
        shown = []
        for n, (name, h) in enumerate(histories.items()):
            style = controller_style(name)
            bias, estimate, bound = (x * to_deg_h for x in (h.bias[:, i], h.bias_hat[:, i], 3.0 * h.std[:, 3 + i]))
            if n == 0:
                ax.plot(h.t, bias, color="k", lw=1.2, label="true bias")
            ax.plot(h.t, estimate, lw=1.0, **style)
            ax.fill_between(h.t, estimate - bound, estimate + bound, color=style.get("color"), alpha=0.15, lw=0)
            late = h.t >= 0.02 * T
            shown += [bias[late], estimate[late] - bound[late], estimate[late] + bound[late]]
        shown = np.concatenate(shown)
        shown = shown[np.isfinite(shown)]
        if shown.size:  # else (no sample past 2 % of T, or none finite) matplotlib's own range
            low, high = np.min(shown), np.max(shown)
            pad = 0.1 * max(high - low, 1e-12)
            ax.set_ylim(low - pad, high + pad)
        _frame(ax, phase_times, T, f"b {AXES[i]} [deg/h]")
    axes[0].legend(fontsize=8, loc="upper right")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle("Gyro bias and its estimate (shaded: ±3σ of the filter)")
    return fig


def torque_figure(histories, phase_times, T):
    """Commanded (dotted) and delivered (solid) control torque per axis [N m]."""
    fig = Figure(figsize=(10, 7.5))
    axes = fig.subplots(3, 1, sharex=True)
    for i, ax in enumerate(axes):
        for name, h in histories.items():
            style = controller_style(name)
            ax.plot(h.t, h.tau_cmd[:, i], lw=0.8, ls=":", color=style.get("color"), label=f"{style['label']} commanded")
            ax.plot(h.t, h.tau[:, i], lw=1.0, color=style.get("color"), label=f"{style['label']} applied")
        _frame(ax, phase_times, T, f"τ {AXES[i]} [N m]")
    axes[0].legend(fontsize=8, loc="upper right")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle("Commanded and applied torque")
    return fig


def wheel_speed_figure(histories, phase_times, T, max_speed):
    """Wheel speeds [rad/s] (the actuator's state) with their limits +-Omega_max (dashed)."""
    names = list(histories)
    fig = Figure(figsize=(10, 3.2 * len(names)))
    axes = fig.subplots(len(names), 1, sharex=True, squeeze=False)
    for ax, name in zip(axes[:, 0], names):
        h = histories[name]
        for i in range(h.actuator.shape[1]):
            ax.plot(h.t, h.actuator[:, i], lw=1.0, label=f"wheel {i + 1}")
        for n, limit in enumerate(np.unique(max_speed)):
            ax.axhline(limit, color="k", ls="--", lw=0.8, label="speed limit ±Ω_max" if n == 0 else None)
            ax.axhline(-limit, color="k", ls="--", lw=0.8)
        _frame(ax, phase_times, T, "Ω_w [rad/s]")
        ax.set_title(controller_style(name)["label"], pad=14)
        ax.legend(fontsize=8, loc="upper right", ncol=4)
    axes[-1, 0].set_xlabel("t [s]")
    fig.suptitle("Wheel speeds")
    return fig


def momentum_figure(histories, phase_times, T, capacity):
    """Wheel momentum h_w in the body frame per axis [N m s], and the wheels' capacity
    h_max (the largest |h_w| along a body axis, dashed)."""
    fig = Figure(figsize=(10, 7.5))
    axes = fig.subplots(3, 1, sharex=True)
    for i, ax in enumerate(axes):
        for name, h in histories.items():
            ax.plot(h.t, h.momentum[:, i], lw=1.0, **controller_style(name))
        ax.axhline(capacity[i], color="k", ls="--", lw=0.8, label="capacity ±h_max")
        ax.axhline(-capacity[i], color="k", ls="--", lw=0.8)
        _frame(ax, phase_times, T, f"h_w {AXES[i]} [N m s]")
    axes[0].legend(fontsize=8, loc="upper right")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle("Wheel angular momentum (body frame)")
    return fig


def wheel_figures(histories, phase_times, T, w: dict) -> dict:
    """Wheel speeds against their limits, and the wheels' momentum against the array's
    capacity (the largest |h_w| along a body axis) [N m s]; w: the wheels' parameters."""
    capacity = np.abs(np.asarray(w["axes"]).T) @ (w["spin_inertia"] * w["max_speed"])
    return {"wheel_speeds.png": wheel_speed_figure(histories, phase_times, T, w["max_speed"]),
            "momentum.png": momentum_figure(histories, phase_times, T, capacity)}


# what a momentum manager holds between its ticks, by registered name: (symbol, unit)
MANAGED = {"thrusters": ("thruster torque", "N m"), "magnetorquers": ("dipole m", "A m²")}


def momentum_management_figure(kind: str, histories, phase_times, T):
    """The momentum manager's held input per body axis (thrusters: the torque fired [N m];
    magnetorquers: the dipole [A m²]) and the wheels' |h_w| [N m s] it keeps down."""
    what, unit = MANAGED.get(kind, ("input", ""))
    fig = Figure(figsize=(10, 9))
    axes = fig.subplots(4, 1, sharex=True)
    for i, ax in enumerate(axes[:3]):
        for name, h in histories.items():
            ax.plot(h.t, h.managed[:, i], lw=0.8, **controller_style(name))
        _frame(ax, phase_times, T, f"{what} {AXES[i]} [{unit}]")
    for name, h in histories.items():
        axes[3].plot(h.t, np.linalg.norm(h.momentum, axis=1), lw=1.0, **controller_style(name))
    _frame(axes[3], phase_times, T, "|h_w| [N m s]")
    axes[0].legend(fontsize=8, loc="upper right")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(f"Momentum management ({kind})")
    return fig


# figures of an actuator's own state, by registered actuator name:
# f(histories, phase_times, T, the actuator's parameters) -> {file name: Figure}
ACTUATOR_FIGURES = {"wheels": wheel_figures}


def actuator_figures(kind: str, histories, phase_times, T, values: dict) -> dict:
    """{file name: Figure} of the actuator's own state ({} for an actuator without figures)."""
    draw = ACTUATOR_FIGURES.get(kind)
    return {} if draw is None else draw(histories, phase_times, T, values)
