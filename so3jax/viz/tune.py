"""A campaign's figure: cost, RMSE, effort and gains over the iterations (history.png)."""

from __future__ import annotations

from pathlib import Path

from so3jax.results import io


def plot_history(out: Path, rows: list[dict], gain_names: list[str]) -> None:
    from matplotlib.figure import Figure  # here: matplotlib only when drawing

    it = [r["iteration"] for r in rows]
    fig = Figure(figsize=(10, 6.5))
    axes = fig.subplots(2, 2, sharex=True)
    for ax, key, label in zip(axes.flat, ("cost", "rmse", "effort"), ("cost [-]", "RMSE [rad/s]", "effort [N² m² s]")):
        ax.plot(it, [r[key] for r in rows], marker=".")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
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
    fig.tight_layout()
    io.save_figure(fig, out / "history.png")
