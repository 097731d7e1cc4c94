"""A sweep's pointing errors (docs/model.md §18): the ECSS indices over the simulated samples
in the three statistical interpretations, the mission's requirements checked on them, and
each sample's own (temporal) APE and RPE.

The samples' attitude errors e_P, e_K are recorded at the start of every block of the
mission's ``record_every`` steps (:func:`so3jax.missions.batched.pointing_errors`), the
grid ``fly`` records on. Over S samples: temporal, the worst sample's quantile over its
times; ensemble, the worst time's quantile over the samples; mixed, the quantile of every
sample's every time. A diverged sample's errors count as +inf (larger than every other:
:func:`so3jax.sim.pointing.statistic`'s ``diverged_worst``), so that an ensemble or mixed
requirement at P_C tolerates a share 1 - P_C of diverged samples and a temporal one none.
"""

from __future__ import annotations

import numpy as np

from so3jax.dynamics.scenario import steps_for_horizon
from so3jax.results.io import to_builtin
from so3jax.sim import pointing
from so3jax.sim.metrics import reached_phases
from so3jax.sim.rollout import block_steps

FIELDS = ("pointing_performance", "pointing_knowledge")  # a chunk's recorded errors (S, M, 3) rad


def times(config, n_records: int) -> np.ndarray:
    """(M,) [s]: the record times t_m = m b dt, b the rollout's block of ``record_every`` steps."""
    m = config.mission
    block = block_steps(steps_for_horizon(m.T, m.dt), m.record_every, m.period_steps)
    return np.arange(n_records) * (block * m.dt)


def phases(config) -> tuple:
    """((t_start, t_end) per phase, reached phases' bounds, their names)."""
    scenario = config.mission.scenario()
    bounds = pointing.phase_bounds_of(scenario)
    reached = sum(reached_phases(scenario.steps_per_phase))
    return bounds, bounds[:reached], config.mission.phase_names[:reached]


def signals(config, r: dict, simulated) -> tuple:
    """(t, e_P, e_K or None) of the simulated samples, (S, M, 3) rad."""
    e_p = r["pointing_performance"][simulated]
    e_k = r["pointing_knowledge"][simulated] if "pointing_knowledge" in r else None
    return times(config, e_p.shape[1]), e_p, e_k


def columns(config, results: dict, n: int) -> dict:
    """Each controller's per-sample temporal APE and RPE angle [arcsec] per reached phase, at
    the mission's first level (NaN where not simulated or a diverged sample's is)."""
    if not config.pointing:
        return {}
    _, bounds, names = phases(config)
    level, window = config.mission.pointing["levels"][0], config.mission.pointing["window"]
    cols = {}
    for c in config.controllers:
        r = results.get(c, {})
        done = r.get("done", np.zeros(n, bool))
        for index in pointing.SAMPLE_COLUMNS:
            for b, phase in zip(bounds, names):
                value = np.full(n, np.nan)
                usable = index not in pointing.WINDOWED or pointing.whole_windows(b, window) >= 1
                if done.any() and usable:
                    t, e, _ = signals(config, r, done)
                    x = pointing.index_samples(index, t, e, b, window if index in pointing.WINDOWED else None)
                    if x.shape[1]:
                        value[done] = pointing.quantile(x[..., 3], level, axis=1) * pointing.ARCSEC
                cols[pointing.column(c, index, level, phase)] = value
    return cols


def summarize(config, results: dict, simulated: dict) -> dict:
    """{controller: {"report": the indices per phase in every interpretation, "requirements":
    each checked}} over each controller's simulated samples (``simulated``: bool per sample),
    JSON-ready; {} where the sweep records no pointing."""
    if not config.pointing:
        return {}
    all_bounds, bounds, names = phases(config)
    m = config.mission
    out = {}
    for c in config.controllers:
        r = results.get(c, {})
        if not simulated[c].any():
            continue
        t, e_p, e_k = signals(config, r, simulated[c])
        report = pointing.report(t, e_p, e_k, bounds, window=m.pointing["window"], levels=m.pointing["levels"],
                                 phase_names=names, indices=pointing.reported(e_k),
                                 interpretations=pointing.INTERPRETATIONS, diverged_worst=True)
        checked = pointing.check(m.requirements, t, e_p, e_k, all_bounds, diverged_worst=True)
        out[c] = {"samples": int(simulated[c].sum()), "report": to_builtin(report), "requirements": to_builtin(checked)}
    return out


def failed(summary: dict) -> list[str]:
    """'controller: requirement' of every requirement that failed."""
    return [f"{c}: {q['requirement']}" for c, entry in summary.get("pointing", {}).items()
            for q in entry["requirements"] if not q["passed"]]


def format_lines(summary: dict) -> list[str]:
    """Markdown: per controller, the angle of each index per phase at each level in the three
    interpretations [arcsec], then each requirement passed or FAILED."""
    entries = summary.get("pointing", {})
    if not entries:
        return []
    first = next(iter(entries.values()))["report"]
    lines = ["", f"Pointing over the simulated samples [arcsec, angle], window {first['window']:g} s "
             "(temporal: the worst sample's quantile over time; ensemble: the worst time's quantile over the samples; "
             "mixed: over both; a diverged sample counts as infinite):", "",
             "| controller | phase | index | level | temporal | ensemble | mixed |",
             "|---|---|---|---:|---:|---:|---:|"]
    for c, entry in entries.items():
        for phase in entry["report"]["phases"]:
            cells = {}
            for row in phase["rows"]:
                cells.setdefault((row["index"], row["level"]), {})[row["interpretation"]] = row
            for (index, level), rows in cells.items():
                text = [_arcsec(rows[i]["angle"], rows[i]["samples"]) for i in pointing.INTERPRETATIONS]
                lines.append(f"| {c} | {phase['name']} | {index} | {level:g} | " + " | ".join(text) + " |")
    checked = [(c, q) for c, entry in entries.items() for q in entry["requirements"]]
    if checked:
        lines += ["", "Requirements:"]
        lines += [f"- {c}: {pointing.outcome(q)}" for c, q in checked]
    return lines


def _arcsec(x, samples: int) -> str:
    """A value [arcsec]; None: no sample ("—") or, over samples, infinite (diverged samples)."""
    return f"{x:.4g}" if x is not None else "inf" if samples else "—"
