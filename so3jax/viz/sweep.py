"""A sweep's figures: CDFs and histograms of RMSE and effort, RMSE against inertia scale."""

from __future__ import annotations

import numpy as np

from so3jax.sim import pointing
from so3jax.viz.styles import style


def _log_if_wide(ax, axis: str, values) -> None:
    """Log scale where the values span more than a decade (else log ticks crowd)."""
    if len(values) and values.min() > 0 and values.max() > 10 * values.min():
        getattr(ax, f"set_{axis}scale")("log")


def figures(config, cols: dict, phases: list) -> dict:
    """CDFs and histograms of RMSE and effort per controller; RMSE against inertia scale.
    config: the sweep's ``SweepConfig``; phases: (index, name) of the phases the horizon reaches."""
    from matplotlib.figure import Figure  # here: matplotlib only when drawing
    from matplotlib.ticker import MaxNLocator

    names = config.controllers
    color = {c: {"color": style(c).get("color"), "label": style(c)["label"]} for c in names}
    good = {c: cols[f"{c}_diverged"] == 0 for c in names}
    title = f"{len(cols['index'])} samples, T = {config.T:g} s (diverged samples left out)"
    cdf, hist = Figure(figsize=(10, 3.8), layout="constrained"), Figure(figsize=(10, 3.8), layout="constrained")
    for fig, kind in ((cdf, "cdf"), (hist, "hist")):
        axes = fig.subplots(1, 2)
        for ax, (metric, label) in zip(axes, (("rmse", "RMSE [rad/s]"), ("effort", "effort [N$^2$ m$^2$ s]"))):
            values = {c: np.sort(cols[f"{c}_{metric}"][good[c]]) for c in names}
            pooled = np.concatenate(list(values.values()))
            if not len(pooled):
                continue
            _log_if_wide(ax, "x", pooled)
            low, high = pooled.min(), pooled.max()
            bins = np.geomspace(low, high, 40) if ax.get_xscale() == "log" else np.linspace(low, high, 40)
            for c, v in values.items():
                if kind == "cdf":
                    ax.step(v, np.arange(1, len(v) + 1) / max(len(v), 1), where="post", **color[c])
                else:
                    ax.hist(v, bins=bins, histtype="step", **color[c])
            ax.set_xlabel(label)
            ax.set_ylabel("fraction of samples" if kind == "cdf" else "samples")
            if kind == "hist":
                ax.yaxis.set_major_locator(MaxNLocator(integer=True))  # counts
            ax.grid(alpha=0.3)
            ax.legend()
        fig.suptitle(title)
    panels = [("J0_trace_ratio", "rmse", "capture inertia scale tr(J0)/tr(J0 nominal)", "mission RMSE [rad/s]")]
    if any(name == "detumble" for _, name in phases):
        panels.append(("J2_trace_ratio", "rmse_detumble", "docked inertia scale tr(J2)/tr(J2 nominal)",
                       "detumble RMSE [rad/s]"))
    scatter = Figure(figsize=(5 * len(panels), 3.8), layout="constrained")
    for ax, (x, y, xlabel, ylabel) in zip(scatter.subplots(1, len(panels), squeeze=False)[0], panels):
        for c in names:
            ax.scatter(cols[x][good[c]], cols[f"{c}_{y}"][good[c]], s=6, alpha=0.6, **color[c])
        _log_if_wide(ax, "y", np.concatenate([cols[f"{c}_{y}"][good[c]] for c in names]))
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        ax.legend()
    scatter.suptitle(title)
    out = {"cdf.png": cdf, "histograms.png": hist, "rmse_vs_inertia_scale.png": scatter}
    flight = _flight_figure(config, cols, good, color, title)
    if flight is not None:
        out["flight.png"] = flight
    if config.pointing:
        out["pointing.png"] = _pointing_figure(config, cols, phases, color)
    if config.margins_at:
        out["margins.png"] = _margins_figure(config, cols, color)
    if "fault_case" in cols:
        out["faults.png"] = _faults_figure(config, cols, color)
    return out


def _faults_figure(config, cols: dict, color: dict):
    """Per fault case, the CDF over its samples of each sample's own APE (solid) and RPE
    (dashed) angle at the mission's first level after its last detection (after its fault
    where nothing is detected) [arcsec]; a lost (diverged) sample's above every value (the
    curve ends below 1), the legend counting them."""
    from matplotlib.figure import Figure  # here: matplotlib only when drawing

    level = config.mission.pointing["levels"][0]
    period = next(p for p in ("after_detection", "after_fault")
                  if pointing.column(config.controllers[0], "APE", level, p) in cols)
    labels = sorted(set(cols["fault_case"].tolist()))
    fig = Figure(figsize=(max(6.0, 3.6 * len(labels)), 3.8), layout="constrained")
    for ax, label in zip(fig.subplots(1, len(labels), squeeze=False, sharey=True)[0], labels):
        for c in config.controllers:
            members = (cols["fault_case"] == label) & ~np.isnan(cols[f"{c}_diverged"])
            lost = int((cols[f"{c}_diverged"][members] == 1).sum())
            for index, line in zip(pointing.SAMPLE_COLUMNS, ("-", "--")):
                x = cols[pointing.column(c, index, level, period)][members]
                v = np.sort(x[np.isfinite(x) & (cols[f"{c}_diverged"][members] == 0)])
                if len(v):  # a lost sample's is above every value: the curve ends below 1
                    ax.step(v, np.arange(1, len(v) + 1) / members.sum(), where="post", ls=line, color=color[c]["color"],
                            label=f"{color[c]['label']} {index}" + (f" ({lost} lost)" if lost and index == "APE"
                                                                     else ""))
        ax.set_xscale("log")
        ax.set_title(f"{label} ({int((cols['fault_case'] == label).sum())} samples)")
        ax.set_xlabel(f"quantile at {level:g} {period.replace('_', ' ')} [arcsec]")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    fig.axes[0].set_ylabel("fraction of the case's samples")
    fig.suptitle(f"{len(cols['index'])} samples: each one's APE and RPE through its fault (angle; RPE window "
                 f"{config.mission.pointing['window']:g} s)")
    return fig


def _margins_figure(config, cols: dict, color: dict):
    """Per time of ``sweep.margins_at``, the CDF over the samples of the all-axes disk margin
    [dB] and of the worst axis's phase margin [deg]; an unstable sample's are left out (the
    legend counts them)."""
    from matplotlib.figure import Figure  # here: matplotlib only when drawing

    times = config.margins_at
    fig = Figure(figsize=(max(6.0, 4.2 * len(times)), 6.5), layout="constrained")
    axes = fig.subplots(2, len(times), squeeze=False)
    for k, t in enumerate(times):
        for row, (column, label) in enumerate((("disk_db", "disk margin, all axes [±dB]"),
                                               ("pm_deg", "phase margin, worst axis [deg]"))):
            ax = axes[row, k]
            for c in config.controllers:
                stable = cols[f"{c}_loop_stable_at_{t:g}s"]
                v = np.sort(cols[f"{c}_{column}_at_{t:g}s"][stable == 1])
                if len(v):
                    unstable = int((stable == 0).sum())
                    ax.step(v, np.arange(1, len(v) + 1) / len(v), where="post", color=color[c]["color"],
                            label=f"{color[c]['label']} ({unstable} unstable)" if unstable else color[c]["label"])
            ax.set_xlabel(label)
            ax.set_ylabel("fraction of stable samples")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
        axes[0, k].set_title(f"t = {t:g} s")
    fig.suptitle(f"{len(cols['index'])} samples: stability margins at the actuator input")
    return fig


def _pointing_figure(config, cols: dict, phases: list, color: dict):
    """Per phase, the CDF over the samples of each sample's own APE (solid) and RPE (dashed)
    angle at the mission's first level [arcsec]; a diverged sample's is included (to the
    right of every other where it is infinite or NaN)."""
    from matplotlib.figure import Figure  # here: matplotlib only when drawing

    level = config.mission.pointing["levels"][0]
    fig = Figure(figsize=(max(6.0, 4.2 * len(phases)), 3.8), layout="constrained")
    for ax, (_, phase) in zip(fig.subplots(1, len(phases), squeeze=False)[0], phases):
        for c in config.controllers:
            for index, line in zip(pointing.SAMPLE_COLUMNS, ("-", "--")):
                x = cols[pointing.column(c, index, level, phase)]
                simulated = ~np.isnan(cols[f"{c}_diverged"])
                v = np.sort(np.nan_to_num(x[simulated], nan=np.inf))
                if len(v) and np.isfinite(v).any():
                    ax.step(v, np.arange(1, len(v) + 1) / len(v), where="post", ls=line, color=color[c]["color"],
                            label=f"{color[c]['label']} {index}")
        ax.set_xscale("log")
        ax.set_title(phase)
        ax.set_xlabel(f"each sample's quantile at {level:g} over time [arcsec]")
        ax.set_ylabel("fraction of samples")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    fig.suptitle(f"{len(cols['index'])} samples: each one's APE and RPE (angle; RPE window "
                 f"{config.mission.pointing['window']:g} s)")
    return fig


ARCSEC = 180 / np.pi * 3600  # arcsec per rad
# (x parameter, its label, its scale to the label's unit, y metric, its label and scale, a
# labelled level of y or None): a panel is drawn where the sweep disperses its x parameter
# (per element: the smallest)
FLIGHT_PANELS = (
    ("sensors.star_tracker.sigma", "star-tracker noise sigma [arcsec]", ARCSEC,
     "attitude_estimation_rms", "attitude estimation RMS [arcsec]", ARCSEC, None),
    ("actuator.wheels.max_torque", "smallest wheel torque limit u_max [N m]", 1.0,
     "time_at_torque_limit", "time at a torque limit [s]", 1.0, None),
    ("amplitude", "disturbance amplitude [N m]", 1.0,
     "max_wheel_speed_ratio", "peak wheel speed / its limit [-]", 1.0, (1.0, "speed limit")),
)


def _flight_figure(config, cols: dict, good: dict, color: dict, title: str):
    """Estimation error against star-tracker noise, time at a limit against the torque
    limit, the wheels' peak speed (the momentum they store) against the disturbance: the
    panels whose parameter the sweep disperses (None: none)."""
    from matplotlib.figure import Figure  # here: matplotlib only when drawing

    panels = []
    for x, *rest in FLIGHT_PANELS:
        elements = [cols[k] for k in cols if k == x or k.startswith(f"{x}_")]  # one column, or one per element
        smallest = np.min(elements, axis=0) if elements else None
        if smallest is not None and np.ptp(smallest) > 0 and f"{config.controllers[0]}_{rest[2]}" in cols:
            panels.append((smallest, *rest))
    if not panels:
        return None
    fig = Figure(figsize=(5 * len(panels), 3.8), layout="constrained")
    for ax, (x, xlabel, x_scale, y, ylabel, y_scale, level) in zip(fig.subplots(1, len(panels), squeeze=False)[0],
                                                                     panels):
        for c in config.controllers:
            ax.scatter(x[good[c]] * x_scale, cols[f"{c}_{y}"][good[c]] * y_scale, s=6, alpha=0.6, **color[c])
        if level is not None:
            ax.axhline(level[0], color="0.3", linestyle="--", linewidth=1.0, label=level[1])
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        ax.legend()
    fig.suptitle(title)
    return fig
