"""A design campaign's report: design.json, design.md (the goals before and after, on the
training batch and the held-out one, the verdict), best_gains.json (a gains file) and
history.png (each start's largest hard and soft goal over the iterations)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from so3jax.jobs.tune.validation import gain_text
from so3jax.results import io

UNITS = {"limit": "the goal's unit", "initial": "-", "best": "-", "initial_value": "the goal's unit",
         "best_value": "the goal's unit", "best_g": "-", "score": "-", "wall_s": "s", "T": "s"}


def _g(x) -> str:
    return "inf" if x is None or not math.isfinite(x) else f"{x:.3f}"


def _value(x, unit: str) -> str:
    return "—" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.4g} {unit}"


def markdown(report: dict) -> str:
    """design.md: the verdict, then per goal g = value / limit before and after, training and held out."""
    training, held = report["training"], report["held_out"]
    holds = "every hard goal holds" if report["verdict"] == "met" else "not every hard goal holds"
    schedule = report.get("schedule")
    per = {"phase": "phase", "time": "breakpoint in time", "inertia": "breakpoint of the declared inertia"}
    scheduled = "" if not schedule else f", gains per {per[schedule['by']]}"
    lines = [f"# Design campaign: {report['controller']}{scheduled}", "",
             f"Verdict on the held-out batch ({held['samples']} dispersed missions, sampling seed "
             f"{held['sampling_seed']}): **{holds}**"
             + ("" if report["verdict"] == "met" else f" (unmet: {', '.join(report['unmet_hard'])})") + ".", "",
             f"Training: {training['samples']} dispersed missions (sampling seed {training['sampling_seed']}), "
             f"{training['iterations']} iterations x {training['starts']} start(s); best design: start "
             f"{report['best']['start']}, iteration {report['best']['iteration']}"
             + (", every hard goal met on the training batch" if report["met_on_training"]
                else ", no start met every hard goal on the training batch: the best compromise") + ".", "",
             "g = value / limit (a margin floor: alpha_req / alpha); a hard goal holds where g <= 1.", "",
             "| goal | kind | hard | limit | g training, initial | g training, best | g held-out, initial "
             "| g held-out, best | held-out value, best |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|"]
    for row in report["goals"]:
        t, h = row["training"], row["held_out"]
        lines.append(f"| {row['name']} | {row['kind']} | {'yes' if row['hard'] else 'no'} | {row['limit']:g} "
                     f"{row['unit']} | {_g(t['initial'])} | {_g(t['best'])} | {_g(h['initial'])} | {_g(h['best'])} "
                     f"| {_value(h['best_value'], row['unit'])} |")
    lines += ["", "Binding at the best design: " + (", ".join(report["binding"]) or "none") + "."]
    if report["conflicts"]:
        lines += ["", "Hard goals that cannot be improved together there (their gradients point against each other, "
                  "or every iterate of the run that improved one lost the other): "
                  + "; ".join(" and ".join(pair) for pair in report["conflicts"]) + "."]
    gains = report["gains"]
    lines += ["", "| gains | " + " | ".join(gains["initial"]) + " |", "|---|" + "---:|" * len(gains["initial"]),
              "| initial | " + " | ".join(gain_text(v) for v in gains["initial"].values()) + " |",
              "| best | " + " | ".join(gain_text(gains["best"][k]) for k in gains["initial"]) + " |", "",
              "Starts: " + "; ".join(f"{s['start']}: best at iteration {s['iteration']}, "
                                     f"{'feasible' if s['feasible'] else 'infeasible'}, score {s['score']:.4g}"
                                     for s in report["starts"]) + ".", "",
              f"Wall time: design {report['wall_s']['design']:.1f} s, held-out check "
              f"{report['wall_s']['held_out']:.1f} s (horizon {report['T']:g} s)."]
    return "\n".join(lines) + "\n"


def history_figure(rows: list[dict], names: list[str], hard: list[bool]):
    """Each start's largest hard goal and largest soft goal over the iterations."""
    from matplotlib.figure import Figure  # here: matplotlib only when drawing
    from matplotlib.ticker import MaxNLocator

    fig = Figure(figsize=(9, 4))
    axes = fig.subplots(1, 2, sharex=True)
    starts = sorted({r["start"] for r in rows})
    for ax, kind, title in ((axes[0], True, "largest hard goal g"), (axes[1], False, "largest soft goal g")):
        chosen = [n for n, h in zip(names, hard) if h == kind]
        if not chosen:
            ax.set_visible(False)
            continue
        for s in starts:
            mine = [r for r in rows if r["start"] == s]
            worst = [max(r[f"g[{n}]"] for n in chosen) for r in mine]
            ax.plot([r["iteration"] for r in mine], worst, marker=".", label=f"start {s}")
        if kind:
            ax.axhline(1.0, color="k", ls="--", lw=0.8, label="limit")
        ax.set_yscale("log")
        ax.set_title(title)
        ax.set_xlabel("iteration")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def write(out: Path, config, report: dict, rows: list[dict]) -> None:
    """design.json, design.md, best_gains.json and history.png in ``out``."""
    io.write_json(out / "design.json", {**report, "units": UNITS})
    io.write_text(out / "design.md", markdown(report))
    io.write_json(out / "best_gains.json", {"controller": config.controller, "gains": report["gains"]["best"],
                                            "design": {"verdict": report["verdict"], **report["best"]}})
    names = [g["name"] for g in report["goals"]]
    hard = [g["hard"] for g in report["goals"]]
    finite = [r for r in rows if all(np.isfinite(r[f"g[{n}]"]) for n in names)]
    if finite:
        io.save_figure(history_figure(finite, names, hard), out / "history.png")
