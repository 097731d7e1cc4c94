"""The figure of ``so3jax identify`` (residuals.png)."""

from __future__ import annotations


def residuals_figure(fit):
    """Each residual series of a fit against time, per axis."""
    import matplotlib  # here: importing so3jax sets no backend (tests/test_imports.py)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # here: importing so3jax sets no backend (tests/test_imports.py)

    series = {k: v for k, v in fit["residuals"].items() if k != "t"}
    fig, axes = plt.subplots(len(series), 1, figsize=(8, 2.6 * len(series)), sharex=True, squeeze=False)
    for ax, (name, values) in zip(axes[:, 0], series.items()):
        for i, label in enumerate("xyz"):
            ax.plot(fit["residuals"]["t"], values[:, i], lw=0.6, label=label)
        ax.set_ylabel(name)
        ax.legend(loc="upper right", fontsize=8, ncol=3)
    axes[-1, 0].set_xlabel("t [s]")
    axes[0, 0].set_title("identification residuals (measured - fitted)")
    return fig
