"""Time-tagged tables read from files (a mission's attitude and inertia histories): a CSV
file whose header line names its columns, or a .npz file of named arrays; one-line
ValueErrors naming the file."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def read_csv_columns(path, columns: tuple) -> dict:
    """{column: values (K,)} float64 of a CSV file whose header line names at least ``columns``,
    in any order."""
    path = Path(path)
    try:
        with open(path) as f:
            header = [name.strip() for name in f.readline().split(",")]
    except OSError as error:
        raise ValueError(f"{path}: cannot be read ({error.strerror or error})") from None
    missing = [name for name in columns if name not in header]
    if missing:
        raise ValueError(f"{path}: the header line names no column {missing[0]!r} "
                         f"(columns {', '.join(columns)} needed), it reads {','.join(header)!r}")
    try:
        table = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2, dtype=np.float64)
    except ValueError as e:
        raise ValueError(f"{path}: not a table of numbers after the header line ({str(e).splitlines()[0]})") from None
    if table.shape[1] != len(header):
        raise ValueError(f"{path}: {table.shape[1]} columns of numbers, {len(header)} named in the header")
    return {name: table[:, header.index(name)] for name in columns}


def read_npz_arrays(path, arrays: dict) -> tuple:
    """The arrays of a .npz file, float64, in the order of ``arrays`` ({name: its shape, as
    the error message states it})."""
    path = Path(path)
    try:
        with np.load(path) as data:
            missing = [name for name in arrays if name not in data.files]
            if missing:
                needed = " and ".join(f"{name} {shape}" for name, shape in arrays.items())
                raise ValueError(f"{path}: no array {missing[0]!r} (arrays {needed} needed)")
            return tuple(np.asarray(data[name], np.float64) for name in arrays)
    except (OSError, EOFError) as error:
        raise ValueError(f"{path}: cannot be read as a .npz file ({error})") from None
