"""A sweep's results: the per-sample table, divergence, statistics of RMSE [rad/s] and
effort [N^2 m^2 s] per controller and phase, paired comparisons, and their markdown."""

from __future__ import annotations

import math
import re
from typing import Any

import jax.numpy as jnp
import numpy as np

from so3jax.components import registry as components
from so3jax.jobs.sweep import fault_cases, margins, pointing
from so3jax.jobs.sweep.config import SweepConfig, config_to_dict
from so3jax.missions import draw, keys
from so3jax.results import units
from so3jax.sim.flight_metrics import FlightMetrics
from so3jax.sim.metrics import Metrics, cell, finite_values, reported

STAT_NAMES = ("mean", "std", "p50", "p95", "p99", "max")
# The flight metrics a sweep of a sampled loop summarizes (FlightMetrics fields).
FLIGHT = ("attitude_estimation_rms", "bias_estimation_rms", "command_effort", "time_at_torque_limit",
          "time_at_speed_limit", "max_wheel_speed_ratio")


def reached_phases(config: SweepConfig) -> list[tuple[int, str]]:
    """(index, name) of the phases the horizon reaches."""
    steps = config.mission.scenario().steps_per_phase
    names = config.mission.phase_names
    return [(p, names[p]) for p, k in enumerate(steps) if k > 0]


def diverged(config: SweepConfig, r: dict) -> np.ndarray:
    """Non-finite state, or attitude error beyond divergence_angle_deg (NaN counts as beyond)."""
    active = [p for p, _ in reached_phases(config)]
    angle = r["max_angle_phase"][:, active].max(axis=1)
    return (r["diverged"] == 1) | ~(angle <= math.radians(config.divergence_angle_deg))


def columns(config: SweepConfig, samples: draw.Samples, results: dict) -> dict:
    """Per-sample table: parameters, then each controller's metrics: NaN where not
    simulated, and every metric NaN where the state became non-finite (``nonfinite``)."""
    p = samples.params
    cols: dict[str, Any] = {
        "index": np.arange(len(p.seed)),
        "status": np.where(samples.valid, "simulated", "rejected"),
        "draws": samples.draws,
        "disturbance_seed": p.seed,
    }
    entries = {"xx": (0, 0), "yy": (1, 1), "zz": (2, 2), "xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}
    for i, name in enumerate(("J0", "J1", "J2")):
        J = getattr(p, name)
        cols[f"{name}_scale"] = samples.scale[:, i]
        cols.update({f"{name}_{e}": J[:, a, b] for e, (a, b) in entries.items()})
    nominal = {name: np.trace(np.asarray(getattr(config.dispersions, name).nominal)) for name in ("J0", "J2")}
    cols["J0_trace_ratio"] = np.trace(p.J0, axis1=1, axis2=2) / nominal["J0"]
    cols["J2_trace_ratio"] = np.trace(p.J2, axis1=1, axis2=2) / nominal["J2"]
    moments = [np.linalg.eigvalsh(getattr(p, name)) for name in ("J0", "J1", "J2")]
    cols["physical"] = np.all([m[:, 0] + m[:, 1] >= m[:, 2] * (1 - 1e-9) for m in moments], axis=0)
    cols.update(tau_J=p.tau_J, n=p.n, amplitude=p.amplitude, frequency=p.frequency, noise_std=p.noise_std)
    cols["initial_angle_deg"] = np.degrees(np.linalg.norm(samples.attitude_error, axis=1))
    cols.update({f"attitude_error_{a}": samples.attitude_error[:, i] for i, a in enumerate("xyz")})
    cols.update({f"Omega0_{a}": p.Omega0[:, i] for i, a in enumerate("xyz")})
    for key, value in samples.leaves.items():  # dispersed component parameters
        flat = value.reshape(len(value), -1)
        cols.update({key: flat[:, 0]} if value.ndim == 1
                    else {f"{key}_{i + 1}": flat[:, i] for i in range(flat.shape[1])})
    phases = reached_phases(config)
    n = len(p.seed)
    flight = flight_fields(results)
    for c in config.controllers:
        r = results.get(c, {})
        done = r.get("done", np.zeros(n, bool))
        nonfinite = done & (r.get("diverged", np.zeros(n)) == 1)
        for field in Metrics._fields:
            if field == "diverged":
                continue
            shape = (n, len(config.mission.phase_names)) if field.endswith("_phase") else n
            value = r.get(field, np.full(shape, np.nan))
            value = reported(value, nonfinite)
            if field.endswith("_phase"):
                cols.update({f"{c}_{field.removesuffix('_phase')}_{name}": value[:, i] for i, name in phases})
            else:
                cols[f"{c}_{field}"] = value
        for field in flight:
            cols[f"{c}_{field}"] = reported(r.get(field, np.full(n, np.nan)), nonfinite)
        cols[f"{c}_nonfinite"] = np.where(done, r.get("diverged", np.zeros(n)) == 1, np.nan)
        cols[f"{c}_diverged"] = np.where(done, diverged(config, r) if r else False, np.nan)
        if "time_at_torque_limit" in r:
            at_limit = np.maximum(r["time_at_torque_limit"], r["time_at_speed_limit"]) > config.limit_share * config.T
            cols[f"{c}_at_limit"] = np.where(done, at_limit, np.nan)
    cols.update(pointing.columns(config, results, n))
    cols.update(fault_cases.columns(config, samples, results))
    cols.update(margins.columns(config, results, n))
    return cols


# The units of samples.csv's parameter columns (a dispersed component parameter's is its
# declared unit; a controller's metric's its metric's, a phase's that of the per-phase metric).
PARAMETER_UNITS = {"index": "-", "status": "-", "draws": "-", "disturbance_seed": "-", "physical": "-",
                   "fault_case": "-", "J0_trace_ratio": "-", "J2_trace_ratio": "-", "initial_angle_deg": "deg",
                   **{f"attitude_error_{a}": "rad" for a in "xyz"}, **{f"Omega0_{a}": "rad/s" for a in "xyz"},
                   **{key: keys.KEY[path].unit for key, path in (("tau_J", "deployment.tau_J"), ("n", "orbit.n"),
                      ("amplitude", "disturbance.amplitude"), ("frequency", "disturbance.frequency"),
                      ("noise_std", "disturbance.noise_std"))},
                   **{f"{J}_scale": "-" for J in ("J0", "J1", "J2")},
                   **{f"{J}_{e}": "kg m^2" for J in ("J0", "J1", "J2") for e in ("xx", "yy", "zz", "xy", "xz", "yz")}}
_FLAGS = ("nonfinite", "diverged", "at_limit", "loop_stable")  # 1, 0 (NaN: not simulated)


def column_units(config: SweepConfig, names) -> dict:
    """{column: unit} of samples.csv's columns ``names``: parameters, dispersed component
    parameters, then each controller's metrics, pointing [arcsec] and margins [dB, deg, s]."""
    leaves = {leaf.key: leaf for leaf in config.leaves}
    phases = [name for _, name in reached_phases(config)]
    out = {}
    for name in names:
        key = next((k for k in leaves if name == k or name.rsplit("_", 1)[0] == k), None)
        controller = next((c for c in config.controllers if name.startswith(c + "_")), None)
        if name in PARAMETER_UNITS:
            out[name] = PARAMETER_UNITS[name]
        elif key == "inertia.events.targets" and len(leaves[key].shape) == 1:
            out[name] = "-"  # scales of the inertia at the event
        elif key is not None and key.startswith("faults."):
            out[name] = draw.FAULT_UNITS[key.split(".")[2]]
        elif key is not None and key.split(".")[0] in draw.FLEXIBLE_LEAVES:  # appendages.I.k, slosh.J.c, ...
            out[name] = draw.FLEXIBLE_LEAVES[key.split(".")[0]][key.split(".")[2]]
        elif key is not None:
            table, component, param = key.split(".")
            kind = "sensor" if table == "sensors" else table
            out[name] = next(p.unit for p in components.get(kind, component).params if p.name == param) or "-"
        elif controller is not None:
            out[name] = _metric_unit(name[len(controller) + 1:], phases)
        else:
            raise KeyError(f"samples.csv column {name!r} has no unit")
    return out


def _metric_unit(metric: str, phases: list) -> str:
    base = re.sub(r"_at_[^_]+s$", "", metric)  # margins: <margin>_at_<t>s
    phase = next((p for p in phases if base.endswith("_" + p)), None)
    if base in units.METRICS:
        return units.METRICS[base]
    if phase is not None and base.removesuffix("_" + phase) + "_phase" in units.METRICS:
        return units.METRICS[base.removesuffix("_" + phase) + "_phase"]
    if base.endswith("_arcsec"):
        return "arcsec"
    if base in _FLAGS:
        return "-"
    for suffix, unit in (("_db", "dB"), ("_deg", "deg"), ("_s", "s")):
        if base.endswith(suffix):
            return unit
    raise KeyError(f"samples.csv column of metric {metric!r} has no unit")


def flight_fields(results: dict) -> list[str]:
    """The flight metrics the results hold (those of a sampled loop; none otherwise)."""
    held = set().union(*(r.keys() for r in results.values())) if results else set()
    return [field for field in FlightMetrics._fields if field in held]


def _stats(x) -> dict:
    """Statistics over the finite values of x (None without any), and their number."""
    x, _ = finite_values(x)
    if not len(x):
        return {**dict.fromkeys(STAT_NAMES), "samples": 0}
    p50, p95, p99 = np.percentile(x, [50, 95, 99])
    return {"mean": x.mean(), "std": x.std(), "p50": p50, "p95": p95, "p99": p99, "max": x.max(), "samples": len(x)}


def summary_row(cols: dict, i: int) -> dict:
    return {k: (v[i].item() if hasattr(v[i], "item") else v[i]) for k, v in cols.items()}


def summarize(config: SweepConfig, samples: draw.Samples, results: dict) -> dict:
    """Statistics of RMSE [rad/s] and effort [N^2 m^2 s] per controller and phase over the
    samples that did not diverge (each with its number of samples; None where there is
    none); counts and parameters of diverged and rejected samples; paired comparisons (every
    pair of controllers in config order, on the samples where neither diverged); the unit of
    each samples.csv column and of each summarized metric; with faults, their cases
    (:mod:`~so3jax.jobs.sweep.fault_cases`)."""
    cols = columns(config, samples, results)
    phases = reached_phases(config)
    summary: dict[str, Any] = {
        "config": dict(config_to_dict(config), mission=config.mission.describe()),
        "precision": str(jnp.dtype(jnp.result_type(float))),
        "samples": {
            "requested": config.samples,
            "simulated": int(samples.valid.sum()),
            "rejected": int((~samples.valid).sum()),
            "rejected_indices": np.flatnonzero(~samples.valid).tolist(),
            "rejected_component": int(0 if samples.outside is None else samples.outside.sum()),
            "rejected_for": draw.rejections(samples),
            "redraws": int((samples.draws[samples.valid] - 1).sum()),
            "nonphysical_inertia": int((samples.valid & ~cols["physical"]).sum()),
        },
        "units": {"columns": column_units(config, cols), "metrics": units.table(("rmse", "effort", *FLIGHT))},
        "controllers": {},
        "paired": {},
    }
    simulated = {c: ~np.isnan(cols[f"{c}_diverged"]) for c in config.controllers}
    bad = {c: cols[f"{c}_diverged"] == 1 for c in config.controllers}
    for c in config.controllers:
        good = simulated[c] & ~bad[c]
        entry = {
            "simulated": int(simulated[c].sum()),
            "diverged": int(bad[c].sum()),
            "nonfinite": int((cols[f"{c}_nonfinite"] == 1).sum()),
            "diverged_samples": [summary_row(cols, i) for i in np.flatnonzero(bad[c])],
        }
        for metric in ("rmse", "effort"):
            entry[metric] = {"mission": _stats(cols[f"{c}_{metric}"][good])}
            entry[metric].update({name: _stats(cols[f"{c}_{metric}_{name}"][good]) for _, name in phases})
        if f"{c}_attitude_estimation_rms" in cols:
            entry["flight"] = {metric: _stats(cols[f"{c}_{metric}"][good]) for metric in FLIGHT}
            flagged = cols[f"{c}_at_limit"] == 1
            entry["at_limit"] = {"share": config.limit_share, "samples": int(flagged.sum()),
                                 "indices": np.flatnonzero(flagged).tolist()}
        summary["controllers"][c] = entry
    for j, b in enumerate(config.controllers):
        for a in config.controllers[:j]:
            paired = simulated[a] & simulated[b]
            both = paired & ~bad[a] & ~bad[b]
            pair = {
                "samples": int(both.sum()),
                f"diverged_only_{a}": int((paired & bad[a] & ~bad[b]).sum()),
                f"diverged_only_{b}": int((paired & bad[b] & ~bad[a]).sum()),
            }
            for metric in ("rmse", "effort"):
                x, y = cols[f"{a}_{metric}"][both], cols[f"{b}_{metric}"][both]
                pair[metric] = {
                    f"{b}_better_fraction": float(np.mean(y < x)) if len(x) else None,
                    "relative_change": dict(zip(("mean", "p5", "p50", "p95"), _quantiles((y - x) / x))),
                }
            if f"{a}_attitude_estimation_rms" in cols:  # flight metrics: differences in their units
                pair["flight_difference"] = {
                    metric: dict(zip(("mean", "p5", "p50", "p95"),
                                     _quantiles(cols[f"{b}_{metric}"][both] - cols[f"{a}_{metric}"][both])))
                    for metric in FLIGHT
                }
            summary["paired"][f"{b}_vs_{a}"] = pair
    if config.pointing:
        summary["pointing"] = pointing.summarize(config, results, simulated)
    if fault_cases.applies(config):
        summary["faults"] = fault_cases.summarize(config, samples, results, cols, simulated, bad)
    if config.margins_at:
        summary["margins"] = margins.summary_of(config, results, simulated)
    return summary


def _quantiles(x):
    x, _ = finite_values(x)
    if not len(x):
        return (None,) * 4
    return (float(np.mean(x)), *map(float, np.percentile(x, [5, 50, 95])))


def format_summary(summary: dict) -> str:
    """Markdown tables of the summary."""
    lines = []
    s = summary["samples"]
    reasons = "; ".join(f"{n} for {why}" for why, n in s.get("rejected_for", {}).items())
    lines.append(
        f"{s['requested']} samples: {s['simulated']} simulated, {s['rejected']} rejected"
        f"{f' ({reasons})' if reasons else ''}, {s['redraws']} redraws, {s['nonphysical_inertia']} with a "
        "non-physical inertia (triangle inequality)"
    )
    for metric, label in (("rmse", "RMSE [rad/s]"), ("effort", "effort [N^2 m^2 s]")):
        lines += ["", f"| {label} | phase | " + " | ".join(STAT_NAMES) + " | samples |",
                  "|---|---|" + "---:|" * (len(STAT_NAMES) + 1)]
        for c, entry in summary["controllers"].items():
            for phase, st in entry[metric].items():
                none = "diverged" if entry["diverged"] else "—"  # no sample left: all diverged, or none simulated
                cells = [none if st[k] is None else cell(st[k], ".4g") for k in STAT_NAMES]
                lines.append(f"| {c} | {phase} | " + " | ".join(cells) + f" | {st.get('samples', '')} |")
    flight = [c for c, e in summary["controllers"].items() if "flight" in e]
    if flight:
        lines += ["", "| flight metric | controller | " + " | ".join(STAT_NAMES) + " | samples |",
                  "|---|---|" + "---:|" * (len(STAT_NAMES) + 1)]
        for metric in FLIGHT:
            for c in flight:
                st = summary["controllers"][c]["flight"][metric]
                cells = ["—" if st[k] is None else cell(units.shown(metric, st[k]), ".4g") for k in STAT_NAMES]
                lines.append(f"| {metric} [{units.shown_unit(metric)}] | {c} | " + " | ".join(cells)
                             + f" | {st['samples']} |")
    lines += ["", "| controller | simulated | diverged | non-finite |" + (" at a limit |" if flight else ""),
              "|---|---:|---:|---:|" + ("---:|" if flight else "")]
    for c, e in summary["controllers"].items():
        limit = f" {e['at_limit']['samples']} |" if "at_limit" in e else (" |" if flight else "")
        lines.append(f"| {c} | {e['simulated']} | {e['diverged']} | {e['nonfinite']} |" + limit)
    if flight:
        share = summary["controllers"][flight[0]]["at_limit"]["share"]
        lines.append(f"\nat a limit: a torque or speed limit binding over more than {100 * share:g} % of the horizon")
    for name, pair in summary["paired"].items():
        b, a = name.split("_vs_")
        lines.append("")
        lines.append(f"{b} vs {a} on {pair['samples']} paired samples (neither diverged):")
        for metric in ("rmse", "effort"):
            frac = pair[metric][f"{b}_better_fraction"]
            q = pair[metric]["relative_change"]
            if frac is None:
                continue
            lines.append(
                f"- {metric}: {b} lower in {100 * frac:.1f} % of samples; change {b}/{a} - 1: "
                f"median {100 * q['p50']:+.1f} %, 5-95 % [{100 * q['p5']:+.1f} %, {100 * q['p95']:+.1f} %], "
                f"mean {100 * q['mean']:+.1f} %"
            )
        for metric, q in pair.get("flight_difference", {}).items():
            if q["mean"] is not None:
                q = {k: units.shown(metric, v) for k, v in q.items()}
                lines.append(f"- {metric} [{units.shown_unit(metric)}]: {b} - {a} median {q['p50']:.4g}, "
                             f"5-95 % [{q['p5']:.4g}, {q['p95']:.4g}], mean {q['mean']:.4g}")
    lines += pointing.format_lines(summary)
    lines += fault_cases.format_lines(summary)
    lines += margins.format_summary(summary)
    return "\n".join(lines) + "\n"
