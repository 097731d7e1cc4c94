"""``so3jax compare``: control laws side by side, each tuned to one effort budget.

A comparison file is a mission (its ``controllers`` are the laws compared), a ``[tune]``
table every law's campaign shares (``controller`` is set per law; a budget controller in
``[tune.cost]`` gives every law the same effort budget), a sweep's ``[sweep]`` and
``[dispersions]``, and ``[compare]``: ``reference`` (the law the others are paired
against, default the first) and ``bootstrap`` (resamples of the confidence intervals).

The run tunes each law (``OUT/tune/LAW``: its held-out validation), sweeps the dispersed
mission with every law at its tuned gains (``OUT/sweep``), then pairs each law with the
reference sample by sample (``OUT/compare.json``, ``compare.md``, ``compare.png``): the
relative RMSE change (y - x) / x, its mean with a 95 % percentile-bootstrap interval, the
share of samples where the law wins with its interval, and the tails (95th percentiles
and their difference, with its interval). Each part resumes with ``--resume``.
"""

from __future__ import annotations

import copy
import dataclasses
import sys
import warnings
from pathlib import Path

import numpy as np

from so3jax import config as cfg
from so3jax import io, runfolder
from so3jax import mission as missions
from so3jax.controllers import registry
from so3jax.metrics import cell
from so3jax.scenario import InertiaWarning

JOBS = ("tune", "sweep", "dispersions", "compare")
TAILS = 95.0  # percentile of the tails compared [%]


@dataclasses.dataclass(frozen=True)
class CompareConfig:
    """The laws, each law's campaign, the sweep's tables (gains added once tuned)."""

    laws: tuple
    campaigns: dict  # law -> tune.TuneConfig
    sweep_table: dict  # mission tables, [sweep], [dispersions]
    base_dir: Path
    reference: str
    bootstrap: int = 2000
    seed: int = 0


def parse(table: dict, base_dir=Path(".")) -> CompareConfig:
    """A checked CompareConfig: every campaign and the sweep parse before any work."""
    from so3jax.sweep.config import config_from_dict
    from so3jax.tune.config import parse_config

    if not isinstance(table, dict):
        raise ValueError(f"a comparison must be a table, got {cfg.short(table)}")  # noqa: TRY004 (bad input)
    table = copy.deepcopy(table)
    jobs = {k: table.pop(k) for k in JOBS if k in table}
    if "tune" not in jobs or not isinstance(jobs["tune"], dict):
        raise ValueError("a comparison needs a [tune] table: the campaign every law shares")
    if "controller" in jobs["tune"]:
        raise ValueError("tune.controller: a comparison tunes each of the mission's controllers; list them in controllers")
    options = cfg.table(jobs, "compare", ("reference", "bootstrap", "seed"))
    mission, _ = missions.load_job(table, base_dir, (), missions.PAPER)
    laws = mission.controllers
    for law in laws:
        if not registry.get(law).tunable:
            raise ValueError(f"controllers: {law!r} has no gains to tune; compare the tunable laws "
                             f"({', '.join(registry.names(tunable=True))})")
    if len(laws) < 2:
        raise ValueError(f"controllers: a comparison needs at least two laws, got {list(laws)}")
    reference = cfg.choice(options.get("reference", laws[0]), "compare.reference", laws)
    bootstrap = cfg.number(options.get("bootstrap", 2000), "compare.bootstrap", low=100, integer=True)
    seed = cfg.number(options.get("seed", 0), "compare.seed", low=0, high=2**32 - 1, integer=True)
    campaigns = {law: parse_config({**table, "tune": {**jobs["tune"], "controller": law}}, base_dir) for law in laws}
    sweep_table = {**table, **{k: jobs[k] for k in ("sweep", "dispersions") if k in jobs}}
    config_from_dict(sweep_table, base_dir)  # the sweep's errors before any tuning
    return CompareConfig(tuple(laws), campaigns, sweep_table, Path(base_dir), reference, bootstrap, seed)


def load_config(path, overrides=()) -> CompareConfig:
    table = cfg.read_toml(path)
    for key, value in overrides:
        cfg.set_dotted(table, key, value)
    return parse(table, Path(path).parent)


def describe(config: CompareConfig) -> dict:
    from so3jax.tune.config import describe as describe_campaign

    return {"laws": list(config.laws), "reference": config.reference, "bootstrap": config.bootstrap,
            "seed": config.seed, "campaigns": {law: describe_campaign(c) for law, c in config.campaigns.items()},
            "sweep": io.to_builtin(config.sweep_table)}


# --- paired statistics ---------------------------------------------------------------


def _interval(values) -> list:
    """The 95 % percentile interval [2.5 %, 97.5 %] of bootstrap replicates."""
    return [float(v) for v in np.percentile(values, [2.5, 97.5])]


def paired(x, y, resamples: int, rng: np.random.Generator) -> dict:
    """y against x on the same samples (both finite): the relative change (y - x) / x (mean
    with its interval, median), the share of samples where y < x (with its interval) and
    the tails: each one's 95th percentile and their difference (with its interval)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    n = len(x)
    if n == 0:
        return {"samples": 0}
    change, wins = (y - x) / x, (y < x).astype(float)
    index = rng.integers(0, n, size=(resamples, n))
    tails = np.percentile(y[index], TAILS, axis=1) - np.percentile(x[index], TAILS, axis=1)
    return {
        "samples": n,
        "relative_change": {"mean": float(change.mean()), "ci95": _interval(change[index].mean(axis=1)),
                            "median": float(np.median(change))},
        "wins": {"share": float(wins.mean()), "ci95": _interval(wins[index].mean(axis=1))},
        "tails": {f"p{TAILS:g}_reference": float(np.percentile(x, TAILS)), f"p{TAILS:g}": float(np.percentile(y, TAILS)),
                  "difference": float(np.percentile(y, TAILS) - np.percentile(x, TAILS)), "ci95": _interval(tails)},
    }


def judge(config: CompareConfig, reports: dict, columns: dict) -> dict:
    """Each law's held-out validation, its sweep statistics, and its pairing with the reference."""
    rng = np.random.default_rng(config.seed)
    ok = {law: (columns[f"{law}_diverged"] == 0) & np.isfinite(columns[f"{law}_rmse"]) for law in config.laws}
    out = {"reference": config.reference, "laws": {}}
    for law in config.laws:
        rmse = columns[f"{law}_rmse"][ok[law]]
        effort = columns[f"{law}_effort"][ok[law]]
        entry = {
            "gains": reports[law]["tuned"]["gains"],
            "held_out": {k: reports[law]["tuned"][k] for k in ("mean_rmse", "mean_effort", "diverged_count")},
            "budget_effort": reports[law].get("budget", {}).get("mean_effort"),
            "sweep": {"samples": int(ok[law].sum()), "diverged": int((columns[f"{law}_diverged"] == 1).sum()),
                      "rmse_median": float(np.median(rmse)) if len(rmse) else None,
                      f"rmse_p{TAILS:g}": float(np.percentile(rmse, TAILS)) if len(rmse) else None,
                      "effort_median": float(np.median(effort)) if len(effort) else None},
        }
        if law != config.reference:
            both = ok[law] & ok[config.reference]
            entry["against_reference"] = paired(columns[f"{config.reference}_rmse"][both], columns[f"{law}_rmse"][both],
                                                config.bootstrap, rng)
        out["laws"][law] = entry
    return out


def markdown(result: dict) -> str:
    """The comparison's table."""
    ref = result["reference"]
    lines = [
        f"| law | tuned gains | held-out RMSE [rad/s] | held-out effort [N² m² s] | sweep RMSE median | sweep RMSE p{TAILS:g} "
        f"| RMSE change vs {ref} (mean, 95 % CI) | wins vs {ref} (95 % CI) | diverged |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for law, e in result["laws"].items():
        gains = ", ".join(f"{k} = {cell(v, '.4g') if np.ndim(v) == 0 else v}" for k, v in e["gains"].items())
        pair = e.get("against_reference")
        if pair and pair["samples"]:
            rc, w = pair["relative_change"], pair["wins"]
            change = f"{100 * rc['mean']:+.1f} % [{100 * rc['ci95'][0]:+.1f}, {100 * rc['ci95'][1]:+.1f}]"
            wins = f"{100 * w['share']:.0f} % [{100 * w['ci95'][0]:.0f}, {100 * w['ci95'][1]:.0f}]"
        else:
            change = wins = "(reference)" if law == ref else "—"
        s, h = e["sweep"], e["held_out"]
        lines.append(f"| {law} | {gains} | {cell(h['mean_rmse'], '.4e')} | {cell(h['mean_effort'], '.2f')} "
                     f"| {cell(s['rmse_median'], '.4e')} | {cell(s[f'rmse_p{TAILS:g}'], '.4e')} | {change} | {wins} "
                     f"| {s['diverged']} of {s['samples'] + s['diverged']} |")
    return "\n".join(lines) + "\n"


def figure(config: CompareConfig, columns: dict):
    """RMSE CDF per law over the sweep; the paired relative change against the reference."""
    import matplotlib.pyplot as plt

    fig, (cdf, change) = plt.subplots(1, 2, figsize=(11, 4))
    ref = config.reference
    others = [law for law in config.laws if law != ref]
    for law in config.laws:
        flown = ~np.isnan(columns[f"{law}_diverged"])  # a diverged sample keeps the curve below 1
        x = np.sort(columns[f"{law}_rmse"][flown & (columns[f"{law}_diverged"] == 0)])
        cdf.plot(x, np.arange(1, len(x) + 1) / max(int(flown.sum()), 1), **registry.style(law))
    cdf.set(xscale="log", xlabel="RMSE [rad/s]", ylabel="share of samples (diverged: never reached)",
            title="RMSE over the dispersed missions")
    cdf.legend()
    data = []
    for law in others:
        both = (columns[f"{law}_diverged"] == 0) & (columns[f"{ref}_diverged"] == 0)
        data.append(100 * (columns[f"{law}_rmse"][both] - columns[f"{ref}_rmse"][both]) / columns[f"{ref}_rmse"][both])
    change.boxplot(data, whis=(5, 95), showfliers=False)
    change.set_xticks(range(1, len(others) + 1), [registry.get(law).label for law in others])
    change.axhline(0.0, color="k", lw=0.8)
    change.set(ylabel=f"RMSE change vs {registry.get(ref).label} [%]", title="paired by sample (whiskers: 5-95 %)")
    fig.tight_layout()
    return fig


# --- the run --------------------------------------------------------------------------


def run(config: CompareConfig, out: Path, *, resume: bool = False) -> dict:
    """Tune every law, sweep them at their tuned gains, pair them: the comparison's report."""
    from so3jax.sweep.config import config_from_dict
    from so3jax.sweep.engine import run_sweep
    from so3jax.tune.campaign import tune

    out = Path(out)
    with runfolder.claim(out, "compare", describe(config), resume=resume) as folder:
        folder.start()  # the folder (a previous comparison's files gone, unless resumed) before its parts claim theirs
        reports = {}
        for law in config.laws:
            print(f"so3jax compare: tuning {law} ({config.laws.index(law) + 1} of {len(config.laws)})", file=sys.stderr)
            reports[law] = tune(config.campaigns[law], out / "tune" / law, resume=resume)
        table = copy.deepcopy(config.sweep_table)
        table["gains"] = {**table.get("gains", {}), **{law: reports[law]["tuned"]["gains"] for law in config.laws}}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", InertiaWarning)  # reported when the comparison was read
            sweep = config_from_dict(table, config.base_dir)
        print(f"so3jax compare: sweeping {sweep.samples} dispersed missions", file=sys.stderr)
        run_sweep(sweep, out / "sweep", resume=resume)
        with np.load(out / "sweep" / "samples.npz") as saved:
            columns = {k: saved[k] for k in saved.files}
        result = io.to_builtin(judge(config, reports, columns))
        io.write_json(out / "compare.json", result)
        io.write_text(out / "compare.md", markdown(result))
        io.save_figure(figure(config, columns), out / "compare.png")
    return result


def _command(args) -> int:
    overrides = [cfg.parse_override(text) for text in args.set]
    with warnings.catch_warnings():
        warnings.simplefilter("once", InertiaWarning)
        config = load_config(args.config, overrides)
    out = Path(args.out) if args.out else Path("results/compare") / Path(args.config).stem
    result = run(config, out, resume=args.resume)
    print(markdown(result))
    print(f"results in {out}/")
    return 0


def register(subparsers) -> None:
    from so3jax.cli import add_precision_argument

    parser = subparsers.add_parser(
        "compare", help="tune control laws to one effort budget, then pair them over a dispersed sweep",
        description="Control laws side by side: each tuned to one effort budget, judged on held-out seeds and a sweep.")
    parser.add_argument("config", help="comparison file (TOML): a mission whose controllers are compared, [tune], "
                        "[sweep], [dispersions], [compare]; e.g. comparisons/paper.toml")
    parser.add_argument("--out", help="run folder (default results/compare/NAME for NAME.toml)")
    parser.add_argument("--resume", action="store_true", help="finish the comparison in --out, keeping what it holds")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override an entry with a TOML value: a mission key (T=100.0), tune.*, sweep.*, compare.*")
    add_precision_argument(parser)
    parser.set_defaults(func=_command)
