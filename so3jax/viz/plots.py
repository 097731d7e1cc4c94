"""Matplotlib figures of rollouts (the paper's Figs. 1-5, plus the attitude error).

Each figure ends at the horizon T [s] when given (else at the last sample): x axis
[0, T], and only the phases that start before T shaded."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from matplotlib.figure import Figure

from so3jax.viz.styles import style

AXES = ("x", "y", "z")
PHASE_COLORS = ("#f2f2f2", "#e3ecf7", "#f7ebe3", "#e8f5e3")


class Phases(NamedTuple):
    """The mission's phases for a figure: start times [s] after the first, and every phase's name."""

    times: tuple
    names: tuple


def shade_phases(ax, phase_times, t_end):
    """Shade the mission phases behind a time plot that ends at t_end [s] (the horizon),
    each labelled: ``phase_times`` the start times [s] after the first (labels "phase k")
    or :class:`Phases` (labels its names); phases starting at or after t_end are left
    out, and the x axis is [0, t_end]."""
    times = getattr(phase_times, "times", phase_times)
    names = getattr(phase_times, "names", None) or [f"phase {p + 1}" for p in range(len(times) + 1)]
    bounds = (0.0,) + tuple(p for p in times if p < t_end) + (t_end,)
    for p, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
        ax.axvspan(a, b, color=PHASE_COLORS[p % len(PHASE_COLORS)], zorder=0, lw=0)
        ax.text((a + b) / 2, 1.0, names[p], transform=ax.get_xaxis_transform(), ha="center", va="bottom",
                fontsize=8)
    ax.set_xlim(0.0, t_end)


def _end(histories, T):
    """The figure's last time [s]: the horizon T, or the last sample without one."""
    return float(T) if T is not None else float(next(iter(histories.values())).t[-1])


def principal_moments(J):
    """Eigenvalues of J (M, 3, 3) [kg m^2], ascending (M, 3); NaN where J is not finite."""
    J = np.asarray(J, dtype=float)
    moments = np.full(J.shape[:-1], np.nan)
    finite = np.isfinite(J).all(axis=(-2, -1))
    moments[finite] = np.linalg.eigvalsh(J[finite])
    return moments


def inertia_figure(t, J, phase_times, T=None):
    """Fig. 1: principal moments (eigenvalues) and products of inertia (off-diagonal
    entries) of J(t) [kg m^2]; J: (M, 3, 3); up to the horizon T [s]."""
    fig = Figure(figsize=(11, 3.8))
    moments, off = fig.subplots(1, 2, sharex=True)
    for i, lam in enumerate(principal_moments(J).T):
        moments.plot(t, lam, label=f"λ{i + 1}")
    for i, j in ((0, 1), (0, 2), (1, 2)):
        off.plot(t, J[:, i, j], label=f"J{AXES[i]}{AXES[j]}")
    for ax, title in ((moments, "principal moments (eigenvalues, λ1 ≤ λ2 ≤ λ3)"), (off, "products of inertia")):
        shade_phases(ax, phase_times, float(t[-1]) if T is None else float(T))
        ax.set(xlabel="t [s]", ylabel="[kg m²]")
        ax.set_title(title, pad=14)
        ax.legend(fontsize=8)
    fig.suptitle("Inertia J(t)")
    return fig


def _per_axis(histories, phase_times, series, ylabel, title, t_max=None, reference=None, T=None):
    """One subplot per body axis; series(history) -> (M, 3); up to min(T, t_max) [s]."""
    t_end = _end(histories, T) if t_max is None else min(_end(histories, T), t_max)
    fig = Figure(figsize=(10, 7.5))
    axes = fig.subplots(3, 1, sharex=True)
    for i, ax in enumerate(axes):
        for name, h in histories.items():
            keep = slice(None) if t_max is None else h.t < t_end
            ax.plot(h.t[keep], series(h)[keep, i], lw=1.0, **style(name))
        if reference is not None:
            h = next(iter(histories.values()))
            keep = slice(None) if t_max is None else h.t < t_end
            ax.plot(h.t[keep], reference(h)[keep, i], ls=":", color="k", lw=1.5, label="desired")
        shade_phases(ax, phase_times, t_end)
        ax.set_ylabel(f"{ylabel} {AXES[i]}")
    axes[0].legend(fontsize=8, loc="upper right")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title)
    return fig


def rate_figure(histories, phase_times, T=None):
    """Fig. 2: Omega against Omega_d [rad/s]."""
    return _per_axis(
        histories, phase_times, lambda h: h.Omega, "Ω [rad/s]", "Angular velocity", reference=lambda h: h.Omega_d, T=T
    )


def phases_before(phase_times, t_end) -> str:
    """The phases shown up to t_end [s]: "phase 1" or "phases 1–n"."""
    n = 1 + sum(p < t_end for p in phase_times)
    return "phase 1" if n == 1 else f"phases 1–{n}"


def rate_error_figure(histories, phase_times, t_max, T=None):
    """Fig. 3: Omega - Omega_d [rad/s] up to t_max [s] (the paper's: docking, so phases
    1-2, capture and deployment)."""
    t_end = min(_end(histories, T), float(t_max))
    return _per_axis(
        histories, phase_times, lambda h: h.Omega - h.Omega_d, "Ω − Ω_d [rad/s]",
        f"Angular velocity tracking error in {phases_before(phase_times, t_end)} (t < {t_end:g} s)", t_max, T=T,
    )


def torque_figure(histories, phase_times, T=None):
    """Fig. 4: control torque per axis [N m]."""
    return _per_axis(histories, phase_times, lambda h: h.tau, "τ [N m]", "Control torque", T=T)


def _scalar_figure(histories, phase_times, series, ylabel, title, log=False, T=None):
    fig = Figure(figsize=(10, 3.5))
    ax = fig.subplots()
    for name, h in histories.items():
        ax.plot(h.t, series(h), lw=1.0, **style(name))
    shade_phases(ax, phase_times, _end(histories, T))
    if log:
        ax.set_yscale("log")
    ax.set(xlabel="t [s]", ylabel=ylabel)
    ax.set_title(title, pad=14)
    ax.legend(fontsize=8)
    return fig


def torque_norm_figure(histories, phase_times, T=None):
    """Fig. 5: |tau| [N m]."""
    return _scalar_figure(
        histories, phase_times, lambda h: np.linalg.norm(h.tau, axis=-1), "|τ| [N m]", "Torque norm", T=T
    )


def attitude_error_figure(histories, phase_times, T=None):
    """Attitude error angle |log(R_d^T R)| [deg]."""
    return _scalar_figure(
        histories, phase_times, lambda h: np.degrees(h.angle), "|log(R_dᵀR)| [deg]", "Attitude error", log=True, T=T
    )
