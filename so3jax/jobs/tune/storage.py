"""A campaign's run folder: the checkpoint a resume continues from, history.csv and its
rows, and best_gains.json."""

from __future__ import annotations

import csv
import dataclasses
import io as _stringio
import json
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.jobs.tune.config import TuneConfig, describe
from so3jax.jobs.tune.cost import CostRefs, Evaluation
from so3jax.jobs.tune.gains import gain_columns, tables
from so3jax.results import io, runfolder

CHECKPOINT = "checkpoint.npz"


def run_description(config: TuneConfig) -> dict:
    """What a checkpoint belongs to: the mission, the [tune] table but the iteration count
    (a resumed run may be extended) and the precision."""
    return io.to_builtin(describe(dataclasses.replace(config, iterations=0)))


def _fingerprint(config: TuneConfig) -> str:
    return runfolder.fingerprint(run_description(config))


def save_checkpoint(path, fingerprint, iteration, state, refs, rows, description=None) -> None:
    leaves = jax.tree.leaves(state) + list(refs)
    io.save_npz(
        path,
        fingerprint=np.array(fingerprint),
        description=np.array(json.dumps(description)),
        iteration=np.array(iteration),
        rows=np.array(json.dumps(rows)),
        **{f"leaf_{i}": np.asarray(leaf) for i, leaf in enumerate(leaves)},
    )


def check_fingerprint(path, fingerprint, description=None) -> None:
    """A one-line ValueError unless the checkpoint was written for this campaign (its
    mission, [tune] table and precision), naming what differs where it can."""
    try:
        with np.load(path) as data:
            found = str(data["fingerprint"])
            previous = json.loads(str(data["description"])) if "description" in data else None
    except Exception as err:  # a truncated or foreign file: zip, pickle, key or JSON errors
        raise runfolder.corrupt(path, err, "delete it to start the run over, or choose another --out") from None
    if found == fingerprint:
        return
    detail = ""
    if isinstance(previous, dict) and isinstance(description, dict):
        changed = [k for k in description if previous.get(k) != description[k]]
        if "precision" in changed:
            detail = f" (precision {previous.get('precision')}, this run {description['precision']})"
        elif changed:
            detail = f" (its {' and '.join(changed)} differ)"
    raise ValueError(f"{path} was written for another configuration{detail}; resume it with its own settings, "
                     "or use a new --out folder")


def load_checkpoint(path, fingerprint, state_template, refs_template, description=None):
    """(iteration, state, refs, rows); leaf shapes and dtypes follow the templates."""
    check_fingerprint(path, fingerprint, description)
    leaves_template, treedef = jax.tree.flatten((state_template, refs_template))
    try:
        with np.load(path) as data:
            iteration, rows = int(data["iteration"]), json.loads(str(data["rows"]))
            leaves = [data[f"leaf_{i}"] for i in range(len(leaves_template))]
    except Exception as err:  # a truncated or foreign file: zip, pickle, key or JSON errors
        raise runfolder.corrupt(path, err, "delete it to start the run over, or choose another --out") from None
    for i, (leaf, template) in enumerate(zip(leaves, leaves_template)):
        if leaf.shape != np.shape(template):
            raise ValueError(f"{path}: checkpoint leaf {i} has shape {leaf.shape}, expected {np.shape(template)}")
    leaves = [jnp.asarray(leaf, np.asarray(template).dtype) for leaf, template in zip(leaves, leaves_template)]
    state, refs = jax.tree.unflatten(treedef, leaves)
    return iteration, state, CostRefs(*refs), rows


def write_history(out: Path, rows: list[dict]) -> None:
    buffer = _stringio.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    io.write_text(out / "history.csv", buffer.getvalue())


def history_row(iteration, evaluation: Evaluation, gains, wall, rollouts, **extra) -> dict:
    return {
        "iteration": iteration,
        "cost": float(evaluation.cost),
        "rmse": float(evaluation.rmse),
        "effort": float(evaluation.effort),
        "diverged": int(evaluation.diverged),
        **extra,
        "wall_s": round(wall, 3),
        "rollouts": rollouts,
        **gain_columns(gains),
    }


def gains_from_row(row, template):
    """The gains recorded in a history row, shaped like template."""
    values = {}
    for name, value in template._asdict().items():
        size = np.size(value)
        values[name] = row[name] if np.ndim(value) == 0 else [row[f"{name}_{i}"] for i in range(size)]
    return type(template)(**{name: jnp.asarray(v, jnp.result_type(template[0])) for name, v in values.items()})


def best_history_row(rows, fresh_batches: bool = False):
    """The row of the lowest finite cost (the first row when none is finite); with a fresh
    batch every iteration (dispersions), whose costs do not compare, the last row."""
    if fresh_batches:
        return rows[-1]
    return min(rows, key=lambda r: r["cost"] if math.isfinite(r["cost"]) else math.inf)


def write_best_gains(out: Path, config: TuneConfig, rows, template) -> None:
    """best_gains.json: the lowest training cost so far (with dispersions: the last
    iterate), and the last good gains."""
    best, last = best_history_row(rows, config.dispersions is not None), rows[-1]
    record = {
        "controller": config.controller,
        **tables(gains_from_row(best, template)),
        "iteration": best["iteration"],
        "training": {key: best[key] for key in ("cost", "rmse", "effort")},
        "last_good": {"iteration": last["iteration"], **tables(gains_from_row(last, template))},
    }
    io.write_json(out / "best_gains.json", record)
