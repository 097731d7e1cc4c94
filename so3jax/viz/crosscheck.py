"""The figures of ``so3jax crosscheck``: |so3jax - Basilisk| of each compared quantity
against time, a panel per quantity, a line per controller; with navigation errors, each
quantity's per-run values of both sides."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from so3jax.viz.styles import style as controller_style

FLOOR = 1e-20  # an exact agreement (0) drawn at this level on the log scale


def differences_figure(mission, differences: dict, quantities) -> Figure:
    """differences: {controller: Differences}; quantities: ((field, unit), ...)."""
    fig = Figure(figsize=(10, 1.4 * len(quantities) + 1.5))
    axes = fig.subplots(len(quantities), 1, sharex=True)
    for ax, (q, unit) in zip(axes, quantities):
        for name, d in differences.items():
            ax.plot(d.t, np.maximum(getattr(d, q), FLOOR), lw=0.8, **controller_style(name))
        ax.set_yscale("log")
        ax.set_ylabel(f"{q.replace('_', ' ')} [{unit}]")
        ax.grid(True, which="major", alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("t [s]")
    fig.align_ylabels(axes)
    axes[0].set_title(f"|so3jax - Basilisk| at each recorded tick ({mission.T:g} s, control period "
                      f"{mission.period:g} s, dt = {mission.dt:g} s)")
    return fig


def runs_figure(mission, runs: dict, quantities) -> Figure:
    """runs: {controller: statistics.Runs}; a panel per quantity, each side's per-run RMS as
    points with its mean and the mean's 95 % interval."""
    fig = Figure(figsize=(10, 3.2 * len(quantities)))
    axes = fig.subplots(len(quantities), 1)
    for ax, (q, unit) in zip(axes, quantities):
        labels = []
        for i, (name, flown) in enumerate(runs.items()):
            for k, side in enumerate(("so3jax", "basilisk")):
                x = 2 * i + k
                values = np.array([r[q] for r in getattr(flown, side)])
                mean, half = values.mean(), 1.96 * values.std(ddof=1) / np.sqrt(len(values))
                ax.plot(np.full(len(values), x) + np.linspace(-0.15, 0.15, len(values)), values, ".", alpha=0.5,
                        color="C0" if side == "so3jax" else "C1")
                ax.errorbar([x + 0.3], [mean], [half], fmt="o", color="k", capsize=3)
                labels.append(f"{name}\n{'so3jax' if side == 'so3jax' else 'Basilisk'}")
        ax.set_xticks(range(len(labels)), labels, fontsize=8)
        ax.set_ylabel(f"RMS {q.replace('_', ' ')} [{unit}]")
        ax.grid(True, axis="y", alpha=0.3)
    axes[0].set_title(f"per-run RMS over {mission.T:g} s, each side its own draws (mean and its 95 % interval)")
    fig.tight_layout()
    return fig
