"""The figure of ``so3jax crosscheck``: |so3jax - Basilisk| of each compared quantity
against time, a panel per quantity, a line per controller."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from so3jax.viz.styles import style as controller_style

FLOOR = 1e-20  # an exact agreement (0) drawn at this level on the log scale


def differences_figure(mission, differences: dict, quantities) -> Figure:
    """differences: {controller: Differences}; quantities: ((field, unit), ...)."""
    fig = Figure(figsize=(10, 8))
    axes = fig.subplots(len(quantities), 1, sharex=True)
    for ax, (q, unit) in zip(axes, quantities):
        for name, d in differences.items():
            ax.plot(d.t, np.maximum(getattr(d, q), FLOOR), lw=0.8, **controller_style(name))
        ax.set_yscale("log")
        ax.set_ylabel(f"{q.replace('_', ' ')} [{unit}]")
        ax.grid(True, which="major", alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("t [s]")
    axes[0].set_title(f"|so3jax - Basilisk| at each recorded tick ({mission.T:g} s, control period "
                      f"{mission.period:g} s, dt = {mission.dt:g} s)")
    return fig
