"""A sweep's output folder: chunk files and their claims, the run description that a
resume is checked against (sweep.json), and the final outputs (samples.csv / .npz,
summary.json / .md, figures)."""

from __future__ import annotations

import csv
import io
import json
import math
import os
import re
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from so3jax.jobs.sweep.config import SweepConfig, config_to_dict
from so3jax.jobs.sweep.summary import columns, format_summary, reached_phases, summary_row
from so3jax.missions import draw
from so3jax.parallel import distributed
from so3jax.results import runfolder
from so3jax.results.io import save_figure, save_npz, to_builtin, write_json, write_text
from so3jax.sim.metrics import Metrics
from so3jax.viz.sweep import figures


def claim_chunk(claims: Path, controller: str, first: int) -> bool:
    """Whether this process takes the chunk (controller, first): the first process to create
    its claim file in the folder ``claims`` does (O_EXCL, atomic on a shared filesystem)."""
    try:
        os.close(os.open(claims / f"{controller}-{first:09d}", os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return False
    return True


_CHUNK = re.compile(r"(\w+)-(\d{9})\.npz")  # a chunk file: controller-first sample


def chunk_path(out: Path, controller: str, first: int) -> Path:
    return out / "chunks" / f"{controller}-{first:09d}.npz"


def load_chunks(out: Path, controllers, n_samples: int, fingerprint: str) -> dict:
    """{controller: {field: array (n_samples, ...)}, plus 'done' (bool)} from OUT/chunks; every
    chunk must carry this sweep's fingerprint."""
    results = {}
    remedy = "delete it and rerun with --resume to recompute it"
    for path in sorted((out / "chunks").glob("*.npz")):
        match = _CHUNK.fullmatch(path.name)
        if not match or match.group(1) not in controllers:
            continue
        try:
            with np.load(path) as f:
                chunk = {key: f[key] for key in f.files}
            missing = {"fingerprint", "index", *Metrics._fields} - set(chunk)
            if missing:
                raise KeyError(", ".join(sorted(missing)))
        except Exception as err:  # a truncated or foreign file: zip, pickle or key errors
            raise runfolder.corrupt(path, err, remedy) from None
        if str(chunk["fingerprint"]) != fingerprint:
            raise ValueError(f"{path} belongs to another sweep (fingerprint {chunk['fingerprint']}, "
                             f"this one {fingerprint}); use another --out")
        keep = chunk["index"] < n_samples
        index = chunk["index"][keep]
        r = results.setdefault(match.group(1), {"done": np.zeros(n_samples, bool)})
        for field in (key for key in chunk if key not in ("fingerprint", "index")):
            value = chunk[field][keep]
            if field not in r:
                r[field] = np.full((n_samples,) + value.shape[1:], np.nan)
            r[field][index] = value
        r["done"][index] = True
    return results


def _controllers_in(out: Path) -> set:
    """The controllers whose chunk files OUT/chunks holds."""
    return {m.group(1) for path in (out / "chunks").glob("*.npz") if (m := _CHUNK.fullmatch(path.name))}


def _fingerprint(config: SweepConfig) -> dict:
    """What fixes each sample's results (chunk size, controller subset, sample count do not)."""
    d = config_to_dict(config)
    d["sweep"] = {k: v for k, v in d["sweep"].items() if k not in ("chunk", "samples", "limit_share")}
    reported = ("controllers", "requirements", "pointing") + (() if config.pointing else ("record_every",))
    d["mission"] = {k: v for k, v in config.mission.describe().items() if k not in reported}
    d["precision"] = str(jnp.dtype(jnp.result_type(float)))
    return d


def prepare_out(out: Path, config: SweepConfig, resume: bool) -> str:
    """Check the run description in OUT/sweep.json against this sweep's; returns its fingerprint."""
    description = to_builtin(_fingerprint(config))
    description["fingerprint"] = runfolder.fingerprint(description)
    stamp = out / "sweep.json"
    has_chunks = any((out / "chunks").glob("*.npz"))
    dropped = sorted(_controllers_in(out) - set(config.controllers)) if resume else []
    if dropped:  # their chunks would stay in a folder whose results leave them out
        raise ValueError(f"--resume: {out} holds chunks of {', '.join(dropped)}, which this sweep does not fly; "
                         "resume with those controllers too, or use another --out")
    if resume and stamp.exists():
        try:
            previous = json.loads(stamp.read_text())
        except (OSError, ValueError) as err:
            raise runfolder.corrupt(stamp, err, "delete the folder or choose another --out") from None
        changed = sorted(k for k in set(previous) | set(description)
                         if k != "fingerprint" and previous.get(k) != description.get(k))
        if changed:
            raise ValueError(f"--resume: {out} holds a sweep with other settings ({', '.join(changed)}); "
                             "use another --out")
    elif resume and has_chunks:
        raise ValueError(f"--resume: {stamp} is missing, so the chunks in {out} cannot be matched to this sweep; "
                         "use another --out")
    elif not resume and has_chunks:
        if runfolder.incomplete(out) is None and (out / "summary.json").exists():
            raise ValueError(f"{out} holds a finished sweep; choose another --out, or delete {out} to run it again")
        raise ValueError(f"{out} holds an unfinished sweep: pass --resume to finish it, or choose another --out")
    if distributed.writer():
        write_json(stamp, description)
    return description["fingerprint"]


def write_csv(path: Path, cols: dict) -> None:
    """One row per sample: an empty cell where a value does not exist (a rejected sample's
    metrics, a controller not simulated), "nan" for a diverged rollout's metrics."""
    flags = sorted((k for k in cols if k.endswith("_nonfinite")), key=len, reverse=True)  # NaN where not simulated
    owner = {k: next((f for f in flags if k.startswith(f.removesuffix("nonfinite"))), None) for k in cols}
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow(cols)
    for i in range(len(cols["index"])):
        row = summary_row(cols, i)

        def text(key, v):
            if not (isinstance(v, float) and math.isnan(v)):
                return v
            flag = owner[key]
            return "nan" if flag is not None and not math.isnan(row[flag]) else ""

        writer.writerow([text(k, v) for k, v in row.items()])
    write_text(path, buffer.getvalue())


def write_outputs(out: Path, config: SweepConfig, samples: draw.Samples, results: dict, summary: dict) -> None:
    cols = columns(config, samples, results)
    write_csv(out / "samples.csv", cols)
    save_npz(out / "samples.npz", **cols)
    write_json(out / "summary.json", summary)
    write_text(out / "summary.md", format_summary(summary))
    for name, fig in figures(config, cols, reached_phases(config)).items():
        save_figure(fig, out / name)
