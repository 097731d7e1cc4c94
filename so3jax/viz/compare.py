"""The figure of ``so3jax compare`` (compare.png): the candidates' RMSE over the sweep, and
their paired changes."""

from __future__ import annotations

import numpy as np

from so3jax.viz.styles import style as controller_style


def styles(config) -> dict:
    """Matplotlib keywords per candidate: its law's style, dotted for a law's second candidate, labelled by name."""
    styles, seen = {}, set()
    for name in config.laws:
        controller = config.candidates[name].controller if hasattr(config, "candidates") else name
        style = controller_style(controller)
        if controller in seen:
            style = {k: v for k, v in style.items() if k not in ("ls", "linestyle")} | {"linestyle": ":"}
        seen.add(controller)
        styles[name] = {**style, "label": style["label"] if name == controller else name}
    return styles


def figure(config, columns: dict, pairs: list):
    """RMSE CDF per candidate over the sweep; the paired relative change of each (candidate,
    other) of ``pairs`` (:func:`so3jax.jobs.compare.pairs`). ``config``: the comparison
    (its ``laws``, ``reference`` and, where given, ``candidates``)."""
    import matplotlib.pyplot as plt  # here: importing so3jax sets no backend (tests/test_imports.py)

    fig, (cdf, change) = plt.subplots(1, 2, figsize=(11, 4))
    ref = config.reference
    styles_ = styles(config)
    for law in config.laws:
        flown = ~np.isnan(columns[f"{law}_diverged"])  # a diverged sample keeps the curve below 1
        x = np.sort(columns[f"{law}_rmse"][flown & (columns[f"{law}_diverged"] == 0)])
        cdf.plot(x, np.arange(1, len(x) + 1) / max(int(flown.sum()), 1), **styles_[law])
    cdf.set(xscale="log", xlabel="RMSE [rad/s]", ylabel="share of samples (diverged: never reached)",
            title="RMSE over the dispersed missions")
    cdf.legend()
    data = []
    for law, other in pairs:
        both = (columns[f"{law}_diverged"] == 0) & (columns[f"{other}_diverged"] == 0)
        data.append(100 * (columns[f"{law}_rmse"][both] - columns[f"{other}_rmse"][both])
                    / columns[f"{other}_rmse"][both])
    change.boxplot(data, whis=(5, 95), showfliers=False)
    change.set_xticks(range(1, len(pairs) + 1), [styles_[law]["label"] + ("" if other == ref else f"\nvs {other}")
                                                 for law, other in pairs])
    change.axhline(0.0, color="k", lw=0.8)
    change.set(ylabel=f"RMSE change vs {styles_[ref]['label']} [%]", title="paired by sample (whiskers: 5-95 %)")
    fig.tight_layout()
    return fig
