"""A fault sweep's cases (docs/model.md §8.7): the samples grouped by the wheels their faults
strike, each sample's pointing over its own post-fault periods, and per case and controller
the missions lost, those indices' spread and the mission's requirements.

A sample's periods start at its own times (a dispersed fault time is the sample's):
"after fault" at its earliest fault, t_f = min_k t_k; "after detection", where the loop
detects a wheel or a thruster failed off (``[fdir]``), at its last detection, max_k (t_k + tau). Each runs
to the end of the reached phases. Over such a period a sample's APE and RPE are its temporal
quantiles at the mission's first pointing level, as :func:`so3jax.jobs.sweep.pointing.columns`
gives them per phase (NaN for a diverged sample, or an RPE whose period holds no whole
window). A case's requirements are those of the mission checked on the case's samples
alone, as :func:`so3jax.jobs.sweep.pointing.summarize` checks them on all.
"""

from __future__ import annotations

import numpy as np

from so3jax.jobs.sweep import pointing as sweep_pointing
from so3jax.missions import faults as fault_list
from so3jax.results.io import to_builtin
from so3jax.sim import pointing

PERIODS = ("after_fault", "after_detection")  # samples.csv's period suffixes
STATS = ("p50", "p95", "max")  # of a period's index over a case's samples that did not diverge


def applies(config) -> bool:
    """Whether the sweep has fault cases: a mission with faults whose pointing is recorded."""
    return bool(config.mission.faults) and config.pointing


def per_sample(samples, i: int, fault: dict, param: str) -> np.ndarray:
    """(N,) fault i's ``param`` in each sample: drawn (``faults.I.PARAM``) or the mission's."""
    n = len(samples.params.seed)
    return np.broadcast_to(samples.leaves.get(f"faults.{i}.{param}", fault[param]), (n,))


def fault_times(config, samples) -> np.ndarray:
    """(N, F) each sample's fault times [s]: drawn (``faults.I.time``) or the mission's."""
    return np.stack([per_sample(samples, i, f, "time").astype(float) for i, f in enumerate(config.mission.faults)],
                    axis=1)


def period_starts(config, samples) -> dict:
    """{period: (N,) its start [s] per sample}: "after_fault", and "after_detection" where
    the loop detects a wheel or a thruster failed off."""
    m = config.mission
    times = fault_times(config, samples)
    out = {"after_fault": times.min(axis=1)}
    detected = [i for i, f in enumerate(m.faults) if fault_list.lost(f) or "thruster" in f]
    if detected and m.fdir["detection"] == "latency":
        out["after_detection"] = (times[:, detected] + m.fdir["latency"]).max(axis=1)
    return out


def cases(config, samples) -> np.ndarray:
    """(N,) each sample's case: the wheels its wheel faults strike and the thrusters that fail
    ("wheel 1", "wheels 1, 3", "wheel 2, thruster +x"); "all" for a mission with neither."""
    m = config.mission
    n = len(samples.params.seed)
    struck = [per_sample(samples, i, f, "wheel").astype(int) for i, f in enumerate(m.faults) if "wheel" in f]
    thrusters = sorted({f["thruster"] for f in m.faults if "thruster" in f})
    labels = []
    for w in (np.stack(struck, axis=1).tolist() if struck else [[]] * n):
        w = sorted(set(w))
        parts = [("wheel " if len(w) == 1 else "wheels ") + ", ".join(map(str, w))] if w else []
        parts += [("thruster " if len(thrusters) == 1 else "thrusters ") + ", ".join(thrusters)] if thrusters else []
        labels.append(", ".join(parts) or "all")
    return np.array(labels, dtype=object)


def _index(index: str, t, e, start: float, end: float, level: float, window: float) -> float:
    """One sample's temporal index [arcsec] over [start, end) of its errors e (M, 3) [rad]."""
    bounds = (start, end)
    if index in pointing.WINDOWED and pointing.whole_windows(bounds, window) < 1:
        return np.nan
    x = pointing.index_samples(index, t, e[None], bounds, window if index in pointing.WINDOWED else None)
    return float(pointing.quantile(x[0, :, 3], level) * pointing.ARCSEC) if x.shape[1] else np.nan


def columns(config, samples, results: dict) -> dict:
    """Each sample's case ("fault_case"), and each controller's per-sample temporal APE and
    RPE angle [arcsec] at the mission's first level over each of its post-fault periods
    (NaN where not simulated)."""
    if not applies(config):
        return {}
    n = len(samples.params.seed)
    _, bounds, _ = sweep_pointing.phases(config)
    end = bounds[-1][1]
    level, window = config.mission.pointing["levels"][0], config.mission.pointing["window"]
    starts = period_starts(config, samples)
    cols = {"fault_case": cases(config, samples)}
    for c in config.controllers:
        r = results.get(c, {})
        done = r.get("done", np.zeros(n, bool))
        t, e, _ = sweep_pointing.signals(config, r, done) if done.any() else (None, None, None)
        for name, start in starts.items():
            for index in pointing.SAMPLE_COLUMNS:
                value = np.full(n, np.nan)
                for j, i in enumerate(np.flatnonzero(done)):
                    value[i] = _index(index, t, e[j], start[i], end, level, window)
                cols[pointing.column(c, index, level, name)] = value
    return cols


def summarize(config, samples, results: dict, cols: dict, simulated: dict, lost: dict) -> dict:
    """{case: {controller: {"samples", "lost", period: {index: stats over the case's samples
    that did not diverge}, "requirements": the mission's, checked on the case's samples}}}."""
    if not applies(config):
        return {}
    m = config.mission
    level = m.pointing["levels"][0]
    case = cols["fault_case"]
    periods = list(period_starts(config, samples))
    all_bounds, _, _ = sweep_pointing.phases(config)
    out = {}
    for label in sorted(set(case.tolist())):
        entry = {}
        for c in config.controllers:
            members = simulated[c] & (case == label)
            kept = members & ~lost[c]
            row = {"samples": int(members.sum()), "lost": int((members & lost[c]).sum())}
            for name in periods:
                row[name] = {index: _stats(cols[pointing.column(c, index, level, name)][kept])
                             for index in pointing.SAMPLE_COLUMNS}
            if members.any() and m.requirements:
                t, e_p, e_k = sweep_pointing.signals(config, results[c], members)
                row["requirements"] = to_builtin(pointing.check(m.requirements, t, e_p, e_k, all_bounds,
                                                                diverged_worst=True))
            entry[c] = row
        out[label] = entry
    return {"level": level, "cases": out}


def _stats(x) -> dict:
    """p50, p95, max [arcsec] of the finite values (None without any)."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if not len(x):
        return dict.fromkeys(STATS)
    p50, p95 = np.percentile(x, [50, 95])
    return {"p50": float(p50), "p95": float(p95), "max": float(x.max())}


def format_lines(summary: dict) -> list[str]:
    """Markdown: per case and controller, the missions lost, APE and RPE after the fault (and
    after its detection) [arcsec], and the requirements passed of those checked."""
    faults = summary.get("faults")
    if not faults:
        return []
    level = faults["level"]
    first = next(iter(next(iter(faults["cases"].values())).values()))
    periods = [p for p in PERIODS if p in first]
    head = " | ".join(f"{index} {p.replace('_', ' ')} p50 / p95 / max" for p in periods
                      for index in pointing.SAMPLE_COLUMNS)
    lines = ["", f"Fault cases (each sample's temporal index at {level:g} over its own period [arcsec]; "
             "lost: diverged):", "", f"| case | controller | samples | lost | {head} | requirements passed |",
             "|---|---|---:|---:|" + "---:|" * (len(periods) * len(pointing.SAMPLE_COLUMNS)) + "---:|"]
    for label, entry in faults["cases"].items():
        for c, row in entry.items():
            cells = [" / ".join("—" if row[p][index][k] is None else f"{row[p][index][k]:.4g}" for k in STATS)
                     for p in periods for index in pointing.SAMPLE_COLUMNS]
            checked = row.get("requirements", [])
            passed = f"{sum(q['passed'] for q in checked)} of {len(checked)}" if checked else "—"
            lines.append(f"| {label} | {c} | {row['samples']} | {row['lost']} | " + " | ".join(cells)
                         + f" | {passed} |")
    return lines
