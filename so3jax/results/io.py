"""Result files written atomically (write to a temporary file, then rename), so a
crash or Ctrl-C never leaves a half-written result behind. Every result file goes
through :func:`atomic_path`, which first tells the run folder it lies in
(:func:`so3jax.results.runfolder.writing`: the folder is created and the file listed in its
manifest)."""

from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np

_BEFORE_WRITE: list = []  # callables path -> None: the open run folders list a file before it is written

_UMASK = os.umask(0)
os.umask(_UMASK)


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path next to ``path``; move it into place on success. The run
    folder holding ``path`` lists it before it is written (:func:`before_write`)."""
    path = Path(path)
    for callback in _BEFORE_WRITE:
        callback(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; results are ordinary files
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def before_write(callback) -> None:
    """Call ``callback(path)`` before :func:`atomic_path` writes any file (once per callback)."""
    if callback not in _BEFORE_WRITE:
        _BEFORE_WRITE.append(callback)


def to_builtin(x):
    """Arrays and numpy scalars -> lists and Python numbers, for JSON. A non-finite float
    (NaN: a diverged rollout; infinities) becomes None, JSON's null: JSON has no NaN."""
    if isinstance(x, dict):
        return {str(k): to_builtin(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [to_builtin(v) for v in x]
    if hasattr(x, "tolist"):
        return to_builtin(np.asarray(x).tolist())
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def dumps(obj, **kwargs) -> str:
    """Strict JSON text of obj (to_builtin first: never NaN or Infinity)."""
    return json.dumps(to_builtin(obj), allow_nan=False, **kwargs)


def write_json(path, obj) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(dumps(obj, indent=2) + "\n")


def write_text(path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def save_npz(path, **arrays) -> None:
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, **arrays)


def save_figure(fig, path) -> None:
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=path.suffix.lstrip(".") or "png", dpi=120, bbox_inches="tight")


def save_figures(out, figures: dict) -> list:
    """Save {file name: matplotlib figure} into the folder ``out``, each atomically.
    Returns the paths written."""
    paths = []
    for name, fig in figures.items():
        save_figure(fig, Path(out) / name)
        paths.append(Path(out) / name)
    return paths
