"""A campaign's figure: cost, RMSE, effort and gains over the iterations (history.png)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from so3jax.results import io


def budget_line(ax, budget) -> None:
    """The effort budget [N² m² s] as a labelled horizontal line (one per scenario: their mean)."""
    values = np.ravel(np.asarray(budget, dtype=float))
    label = "effort budget" if values.size == 1 else "effort budget (mean over scenarios)"
    ax.axhline(float(np.mean(values)), color="k", ls="--", lw=0.8, label=label)
    ax.legend(fontsize=7)


def history_figure(rows: list[dict], gain_names: list[str], budget=None):
    """Cost, RMSE, effort and gains over the iterations of history rows; ``budget``: the
    equal-effort cost's effort budget [N² m² s] (a scalar or one per scenario), None for none."""
    from matplotlib.figure import Figure  # here: matplotlib only when drawing
    from matplotlib.ticker import MaxNLocator

    it = [r["iteration"] for r in rows]
    fig = Figure(figsize=(10, 6.5))
    axes = fig.subplots(2, 2, sharex=True)
    for ax, key, label in zip(axes.flat, ("cost", "rmse", "effort"), ("cost [-]", "RMSE [rad/s]", "effort [N² m² s]")):
        ax.plot(it, [r[key] for r in rows], marker=".", label=key)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    if budget is not None:
        budget_line(axes.flat[2], budget)
    ax = axes.flat[3]
    from_zero = [name for name in gain_names if rows[0][name] == 0]  # a nonnegative gain starting at 0
    for name in gain_names:
        if name not in from_zero:
            ax.plot(it, [r[name] / rows[0][name] for r in rows], label=name)
    ax.set_yscale("log")
    ax.set_ylabel("gain / initial gain")
    ax.legend(fontsize=7, ncol=2, loc="upper left")
    if from_zero:
        values = ax.twinx()
        for name in from_zero:
            values.plot(it, [r[name] for r in rows], ls="--", color="k", label=f"{name} (right axis)")
        values.set_ylabel("gain from 0")
        values.legend(fontsize=7, loc="upper right")
    ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("iteration")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    fig.tight_layout()
    return fig


def plot_history(out: Path, rows: list[dict], gain_names: list[str], budget=None) -> None:
    """history.png in out: :func:`history_figure` of the rows."""
    io.save_figure(history_figure(rows, gain_names, budget), out / "history.png")
