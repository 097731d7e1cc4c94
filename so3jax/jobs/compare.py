"""Control laws side by side, each tuned to one effort budget: the job ``so3jax compare``
(:mod:`so3jax.commands.compare`) runs.

A comparison file is a mission (its ``controllers`` are the laws compared), a ``[tune]``
table every law's campaign shares (``controller`` is set per law; a budget controller in
``[tune.cost]`` gives every law the same effort budget), a sweep's ``[sweep]`` and
``[dispersions]``, and ``[compare]``: ``reference`` (the candidate the others are paired
against, default the first) and ``bootstrap`` (resamples of the confidence intervals).

``[compare.candidates.NAME]`` tables, where given, name what is compared instead of the
mission's laws: ``controller`` (the law, default NAME), and either ``gains`` (fixed gains:
a table or a best_gains.json path, flown as given) or ``tune`` (entries of the shared
``[tune]`` table this candidate's campaign changes, e.g. ``{objective = "cvar"}``), and ``against`` (the candidate it is
paired with, default the reference). So one law can be compared with itself tuned two
ways, or with gains tuned elsewhere. ``tune.dispersions = "sweep"`` tunes over the
comparison's own ``[dispersions]`` (fresh batches of other sampling seeds than the sweep's).

The run tunes each candidate (``OUT/tune/NAME``: its held-out validation; fixed gains are
judged on the same held-out scenarios, ``OUT/held_out/NAME.json``), sweeps the dispersed
mission with every candidate at its gains (``OUT/sweep``; candidates of one law in
further sweeps ``OUT/sweep_2``, ... of the same samples), then pairs each candidate with
the reference sample by sample (``OUT/compare.json``, ``compare.md``, ``compare.png``):
the relative RMSE change (y - x) / x, its mean with a 95 % percentile-bootstrap
interval, the share of samples where it wins with its interval, and the tails (95th
percentiles and their difference, with its interval). Each part resumes with ``--resume``,
under the settings of the run the folder holds (another setting is refused, naming it).
"""

from __future__ import annotations

import copy
import dataclasses
import json
import sys
import warnings
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np

from so3jax.controllers import registry
from so3jax.core import checks
from so3jax.dynamics.inertia import InertiaWarning
from so3jax.jobs.sweep.config import DEFAULT, config_from_dict
from so3jax.jobs.sweep.engine import run_sweep
from so3jax.jobs.tune.campaign import tune
from so3jax.jobs.tune.config import describe as describe_campaign
from so3jax.jobs.tune.config import parse_config
from so3jax.jobs.tune.gains import gains_table, resolve_gains
from so3jax.jobs.tune.validation import held_out
from so3jax.missions import config as cfg
from so3jax.missions import mission as missions
from so3jax.results import io, runfolder
from so3jax.sim import memory, pointing
from so3jax.sim.metrics import cell
from so3jax.viz import compare as plots

JOBS = ("tune", "sweep", "dispersions", "compare")
COMPARE_KEYS = ("reference", "bootstrap", "seed", "candidates")  # the keys of [compare]
CANDIDATE_KEYS = ("controller", "gains", "tune", "against")  # the keys of a [compare.candidates.NAME] table
SWEEP_DISPERSIONS = "sweep"  # tune.dispersions = "sweep": the comparison's own [dispersions]
TAILS = 95.0  # percentile of the tails compared [%]
# bytes per resampled value at the peak of `paired`: the indices, a resampled column and
# the copy np.percentile sorts (8 each), and a margin for the arrays of one value per resample
BOOTSTRAP_BYTES = 32


@dataclasses.dataclass(frozen=True)
class Candidate:
    """A law and its gains: tuned by ``campaign``, or ``gains`` fixed (the campaign then
    names only the held-out scenarios and the effort budget that judge them)."""

    controller: str  # the registered controller's name
    campaign: Any  # tune.TuneConfig
    gains: Any = None  # the controller's gains type, or None: tuned
    against: str | None = None  # the candidate it is paired with (None: the comparison's reference)


@dataclasses.dataclass(frozen=True)
class CompareConfig:
    """The candidates (by default one per law, named after it), the sweep's tables (gains
    added once tuned). ``laws``: the candidates' names, in order."""

    laws: tuple
    candidates: dict  # name -> Candidate
    sweep_table: dict  # mission tables, [sweep], [dispersions]
    base_dir: Path
    reference: str  # the candidate the others are paired with (default: the first)
    bootstrap: int = 2000  # resamples of each 95 % percentile-bootstrap interval
    seed: int = 0  # the resampling seed
    given: dict | None = None  # the [compare.candidates] table as given (None: the mission's laws)

    @property
    def campaigns(self) -> dict:
        return {name: c.campaign for name, c in self.candidates.items()}

    def sweeps(self) -> list:
        """The candidates' names grouped into sweeps of distinct laws, in order."""
        groups = []
        for name, c in self.candidates.items():
            group = next((g for g in groups if all(self.candidates[o].controller != c.controller for o in g)), None)
            if group is None:
                groups.append(group := [])
            group.append(name)
        return groups


def sweep_folder(index: int) -> str:
    """The folder of the index-th sweep (0: ``sweep``, then ``sweep_2``, ...)."""
    return "sweep" if index == 0 else f"sweep_{index + 1}"


def parse(table: dict, base_dir=Path(".")) -> CompareConfig:
    """A checked CompareConfig: every campaign and the sweep parse before any work."""
    if not isinstance(table, dict):
        raise ValueError(f"a comparison must be a table, got {checks.short(table)}")  # noqa: TRY004 (bad input)
    table = copy.deepcopy(table)
    jobs = {k: table.pop(k) for k in JOBS if k in table}
    if "tune" not in jobs or not isinstance(jobs["tune"], dict):
        raise ValueError("a comparison needs a [tune] table: the campaign every law shares")
    if "controller" in jobs["tune"]:
        raise ValueError("tune.controller: a comparison tunes each of the mission's controllers; "
                         "list them in controllers")
    options = checks.table(jobs, "compare", COMPARE_KEYS)
    mission, _ = missions.load_job(table, base_dir, (), missions.PAPER)
    given = options.get("candidates")
    if given is None:
        for controller in mission.controllers:
            if not registry.get(controller).tunable:
                raise ValueError(f"controllers: {controller!r} has no gains to tune; compare the tunable laws "
                                 f"({', '.join(registry.names(tunable=True))})")
        entries = {controller: {} for controller in mission.controllers}
        where = "controllers"
    else:
        if not isinstance(given, dict) or not all(isinstance(v, dict) for v in given.values()):
            raise ValueError(f"compare.candidates must hold a table per candidate, got {checks.short(given)}")
        entries, where = given, "compare.candidates"
    if len(entries) < 2:
        raise ValueError(f"{where}: a comparison needs at least two laws, got {list(entries)}")
    shared = jobs["tune"]
    if shared.get("dispersions") == SWEEP_DISPERSIONS:  # train on the distribution the sweep judges (other seeds)
        shared = {**shared, "dispersions": jobs.get("dispersions", DEFAULT["dispersions"])}
    candidates = {name: _candidate(name, entry, table, shared, mission, base_dir) for name, entry in entries.items()}
    laws = tuple(candidates)
    reference = checks.choice(options.get("reference", laws[0]), "compare.reference", laws)
    for name, c in candidates.items():
        if c.against is not None and checks.choice(c.against, f"compare.candidates.{name}.against", laws) == name:
            raise ValueError(f"compare.candidates.{name}.against: a candidate is paired with another one")
    bootstrap = checks.number(options.get("bootstrap", 2000), "compare.bootstrap", low=100, integer=True)
    seed = checks.number(options.get("seed", 0), "compare.seed", low=0, high=2**32 - 1, integer=True)
    sweep_table = {**table, **{k: jobs[k] for k in ("sweep", "dispersions") if k in jobs}}
    judged = config_from_dict(sweep_table, base_dir)  # the sweep's errors before any tuning
    check_bootstrap(bootstrap, judged.samples)
    if jobs["tune"].get("dispersions") == SWEEP_DISPERSIONS:
        for name, c in candidates.items():
            for part in ("train", "validation"):
                if getattr(c.campaign, part).seeds[0] == judged.seed:
                    raise ValueError(f"tune.{part}.seeds: the sampling seed of the sweep ({judged.seed}) would tune "
                                     f"{name} on the missions that judge it; choose another")
    return CompareConfig(laws, candidates, sweep_table, Path(base_dir), reference, bootstrap, seed, given)


def check_bootstrap(resamples: int, samples: int) -> None:
    """Refuse (ValueError, one line) before any work a bootstrap whose ``resamples`` of the
    sweep's ``samples`` would not fit in the memory available."""
    per_resample = BOOTSTRAP_BYTES * samples  # [bytes]
    memory.check(resamples * per_resample, None, f"compare.bootstrap = {resamples} (resamples of {samples} samples)",
                 f"lower compare.bootstrap to at most {memory.available() // per_resample}")


def _candidate(name: str, entry: dict, table: dict, shared: dict, mission, base_dir) -> Candidate:
    """A candidate of ``[compare.candidates]`` (or a mission's law, ``entry`` empty)."""
    where = f"compare.candidates.{name}"
    entry = checks.table({"t": entry}, "t", CANDIDATE_KEYS, where)
    controller = checks.choice(entry.get("controller", name), f"{where}.controller", registry.names(tunable=True))
    if "gains" in entry and "tune" in entry:
        raise ValueError(f"{where}: fixed gains are not tuned; give gains or tune, not both")
    changes = entry.get("tune", {})
    if not isinstance(changes, dict) or "controller" in changes:
        raise ValueError(f"{where}.tune must be a table of [tune] entries (the law is {where}.controller), "
                         f"got {checks.short(changes)}")
    tuned = {**missions.merge_tables(shared, changes), "controller": controller}
    campaign = parse_config({**table, "tune": tuned}, base_dir)
    if campaign.estimator:
        raise ValueError(f"{where}: tune.estimator: a comparison sweeps the laws' gains with the mission's estimator")
    gains = None
    if "gains" in entry:
        spec = entry["gains"]
        if isinstance(spec, str) and spec not in ("mission", "paper"):
            spec = str((Path(base_dir) / spec).resolve())
        try:
            gains = resolve_gains(controller, spec, jnp.result_type(float), mission=mission)
        except (OSError, ValueError) as err:
            raise ValueError(f"{where}.gains: {err}") from None
    return Candidate(controller, campaign, gains, entry.get("against"))


def load_config(path, overrides=()) -> CompareConfig:
    table = cfg.read_toml(path)
    for key, value in overrides:
        cfg.set_dotted(table, key, value)
    return parse(table, Path(path).parent)


def describe(config: CompareConfig) -> dict:
    out = {"laws": list(config.laws), "reference": config.reference, "bootstrap": config.bootstrap,
           "seed": config.seed, "campaigns": {law: describe_campaign(c) for law, c in config.campaigns.items()},
           "sweep": io.to_builtin(config.sweep_table)}
    if config.given is not None:
        out["candidates"] = {name: {"controller": c.controller,
                                    "gains": None if c.gains is None else gains_table(c.gains),
                                    "against": c.against} for name, c in config.candidates.items()}
    return out


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
        "tails": {f"p{TAILS:g}_reference": float(np.percentile(x, TAILS)),
                  f"p{TAILS:g}": float(np.percentile(y, TAILS)),
                  "difference": float(np.percentile(y, TAILS) - np.percentile(x, TAILS)), "ci95": _interval(tails)},
    }


# compare.json's units (so3jax.results.units): RMSE [rad/s], effort [N^2 m^2 s]; a paired
# relative change and a share of wins are ratios; an interval (ci95) has its value's unit.
UNITS = {"mean_rmse": "rad/s", "mean_effort": "N^2 m^2 s", "budget_effort": "N^2 m^2 s", "rmse_median": "rad/s",
         f"rmse_p{TAILS:g}": "rad/s", "effort_median": "N^2 m^2 s", "relative_change": "-", "share": "-",
         f"p{TAILS:g}": "rad/s", f"p{TAILS:g}_reference": "rad/s", "difference": "rad/s"}


def judge(config: CompareConfig, reports: dict, columns: dict, requirements: dict | None = None) -> dict:
    """Each law's held-out validation, its sweep statistics, its pairing with the reference,
    and the mission's pointing requirements checked over its sweep ({law: [requirement]})."""
    rng = np.random.default_rng(config.seed)
    ok = {law: (columns[f"{law}_diverged"] == 0) & np.isfinite(columns[f"{law}_rmse"]) for law in config.laws}
    out = {"reference": config.reference, "units": UNITS, "laws": {}}
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
        ref = paired_with(config, law)
        if ref is not None:
            both = ok[law] & ok[ref]
            entry["against_reference"] = paired(columns[f"{ref}_rmse"][both], columns[f"{law}_rmse"][both],
                                                config.bootstrap, rng)
            if ref != config.reference:
                entry["paired_with"] = ref
        if requirements and law in requirements:
            entry["requirements"] = requirements[law]
        out["laws"][law] = entry
    return out


def paired_with(config: CompareConfig, name: str) -> str | None:
    """The candidate ``name`` is paired with: its own ``against``, else the reference (None for the reference)."""
    candidate = getattr(config, "candidates", {}).get(name)
    against = candidate.against if candidate is not None else None
    if against is not None:
        return against
    return None if name == config.reference else config.reference


def markdown(result: dict) -> str:
    """The comparison's table."""
    ref = result["reference"]
    lines = [
        f"| law | tuned gains | held-out RMSE [rad/s] | held-out effort [N² m² s] | sweep RMSE median "
        f"| sweep RMSE p{TAILS:g} "
        f"| RMSE change vs {ref} (mean, 95 % CI) | wins vs {ref} (95 % CI) | diverged |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for law, e in result["laws"].items():
        gains = ", ".join(f"{k} = {cell(v, '.4g') if np.ndim(v) == 0 else v}" for k, v in e["gains"].items())
        pair = e.get("against_reference")
        if pair and pair["samples"]:
            rc, w = pair["relative_change"], pair["wins"]
            other = f"vs {e['paired_with']}: " if "paired_with" in e else ""
            change = f"{other}{100 * rc['mean']:+.1f} % [{100 * rc['ci95'][0]:+.1f}, {100 * rc['ci95'][1]:+.1f}]"
            wins = f"{other}{100 * w['share']:.0f} % [{100 * w['ci95'][0]:.0f}, {100 * w['ci95'][1]:.0f}]"
        else:
            change = wins = "(reference)" if law == ref else "—"
        s, h = e["sweep"], e["held_out"]
        lines.append(f"| {law} | {gains} | {cell(h['mean_rmse'], '.4e')} | {cell(h['mean_effort'], '.2f')} "
                     f"| {cell(s['rmse_median'], '.4e')} | {cell(s[f'rmse_p{TAILS:g}'], '.4e')} | {change} | {wins} "
                     f"| {s['diverged']} of {s['samples'] + s['diverged']} |")
    checked = [(law, q) for law, e in result["laws"].items() for q in e.get("requirements", [])]
    if checked:
        lines += ["", "Pointing requirements over the sweep's samples:"]
        lines += [f"- {law}: {pointing.outcome(q)}" for law, q in checked]
    return "\n".join(lines) + "\n"


def pairs(config: CompareConfig) -> list:
    """(candidate, the candidate it is paired with) of every candidate but the reference, in order."""
    return [(law, paired_with(config, law)) for law in config.laws if paired_with(config, law) is not None]


# --- the run --------------------------------------------------------------------------


def run(config: CompareConfig, out: Path, *, resume: bool = False) -> dict:
    """Tune every candidate (or judge its fixed gains on the held-out scenarios), sweep them
    at their gains, pair them: the comparison's report."""
    out = Path(out)
    with runfolder.claim(out, "compare", describe(config), resume=resume, may_change=()) as folder:
        folder.start()  # the folder (a previous comparison's files gone, unless resumed) before its parts claim theirs
        reports = {}
        for i, (name, c) in enumerate(config.candidates.items()):
            if c.gains is None:
                print(f"so3jax compare: tuning {name} ({i + 1} of {len(config.laws)})", file=sys.stderr)
                reports[name] = tune(c.campaign, out / "tune" / name, resume=resume)
                continue
            path = out / "held_out" / f"{name}.json"
            if not (resume and path.exists()):
                print(f"so3jax compare: {name}'s fixed gains on the held-out scenarios", file=sys.stderr)
                io.write_json(path, held_out(c.campaign, c.gains))
            reports[name] = json.loads(path.read_text())
        columns, checked = {}, {}
        for i, group in enumerate(config.sweeps()):
            cols, requirements = _sweep(config, group, {name: reports[name]["tuned"]["gains"] for name in group},
                                        out / sweep_folder(i), resume, columns)
            columns.update(cols)
            checked.update(requirements)
        result = io.to_builtin(judge(config, reports, columns, checked))
        io.write_json(out / "compare.json", result)
        io.write_text(out / "compare.md", markdown(result))
        io.save_figure(plots.figure(config, columns, pairs(config)), out / "compare.png")
    return result


def _sweep(config: CompareConfig, names: list, gains: dict, out: Path, resume: bool, seen: dict) -> tuple:
    """Sweep candidates of distinct laws at their gains into ``out``: (the samples' columns,
    each law's renamed after its candidate; {candidate: the mission's pointing requirements
    checked over the samples}); ``seen``: the columns of the comparison's other sweeps,
    whose samples these must equal."""
    candidates = {config.candidates[name].controller: name for name in names}  # controller -> candidate
    table = copy.deepcopy(config.sweep_table)
    table["controllers"] = list(candidates)
    table["gains"] = {**table.get("gains", {}), **{c: gains[name] for c, name in candidates.items()}}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InertiaWarning)  # reported when the comparison was read
        sweep = config_from_dict(table, config.base_dir)
    print(f"so3jax compare: sweeping {sweep.samples} dispersed missions ({', '.join(names)})", file=sys.stderr)
    summary = run_sweep(sweep, out, resume=resume)
    requirements = {candidates[c]: e["requirements"] for c, e in summary.get("pointing", {}).items()
                    if e["requirements"]}
    columns = {}
    with np.load(out / "samples.npz") as saved:
        for key in saved.files:
            c = next((c for c in candidates if key.startswith(c + "_")), None)
            columns[key if c is None else candidates[c] + key[len(c):]] = saved[key]
    for key in ("index", "disturbance_seed", "J0_scale"):  # one set of samples for every sweep
        if key in seen and key in columns and not np.array_equal(seen[key], columns[key], equal_nan=True):
            raise RuntimeError(f"{out}: its samples differ from the first sweep's ({key})")
    return columns, requirements
