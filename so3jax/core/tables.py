"""The one reader of the data files a mission or a command names (a mission's attitude and
inertia histories, telemetry): a CSV file whose header line names its columns, or a .npz
file of named arrays; one-line ValueErrors naming the file for a missing, unreadable,
truncated or corrupt one."""

from __future__ import annotations

import io
import zipfile
import zlib
from pathlib import Path

import numpy as np

_ZIP_MAGIC, _NPY_MAGIC = b"PK", b"\x93NUMPY"  # the first bytes of a .npz (a zip archive) and of a .npy file


def read_csv_columns(path, columns: tuple) -> dict:
    """{column: values (K,)} float64 of a CSV file (UTF-8, a byte-order mark allowed) whose
    header line names at least ``columns``, in any order, each name once."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except OSError as error:
        raise ValueError(f"{path}: cannot be read ({error.strerror or error})") from None
    except UnicodeDecodeError as error:
        raise ValueError(f"{path}: not a CSV text file (not UTF-8 at byte {error.start})") from None
    first, _, rest = text.partition("\n")
    header = [name.strip() for name in first.split(",")]
    missing = [name for name in columns if name not in header]
    if missing:
        raise ValueError(f"{path}: the header line names no column {missing[0]!r} "
                         f"(columns {', '.join(columns)} needed), it reads {','.join(header)!r}")
    repeated = next((name for name in header if header.count(name) > 1), None)
    if repeated is not None:
        raise ValueError(f"{path}: the header line names the column {repeated!r} {header.count(repeated)} times")
    rows = [(number, line) for number, line in enumerate(rest.splitlines(), start=2) if line.strip()]
    for number, line in rows:
        if line.count(",") + 1 != len(header):
            raise ValueError(f"{path}: line {number} holds {line.count(',') + 1} values, the header names "
                             f"{len(header)} columns (a truncated file?)")
    try:
        table = np.loadtxt(io.StringIO(rest), delimiter=",", ndmin=2, dtype=np.float64)
    except ValueError as error:
        raise ValueError(f"{path}: not a table of numbers after the header line "
                         f"({str(error).splitlines()[0]})") from None
    if table.shape[0] == 0:
        raise ValueError(f"{path}: no rows of numbers after the header line")
    return {name: table[:, header.index(name)] for name in columns}


def read_npz(path, what: str = "a .npz file of named arrays") -> dict:
    """{name: array} of every array of a .npz file, read whole; one-line ValueError naming
    the file (``what``: what it should be) where it is missing, unreadable, not a .npz archive
    (a text file, a single .npy array), truncated or corrupt, or holds Python objects."""
    path = Path(path)
    try:
        with open(path, "rb") as file:
            magic = file.read(len(_NPY_MAGIC))
            if magic.startswith(_ZIP_MAGIC):
                file.seek(0)
                with np.load(file, allow_pickle=False) as data:
                    return {name: np.asarray(data[name]) for name in data.files}
    except FileNotFoundError:
        raise ValueError(f"{path}: no such file; expected {what}") from None
    except OSError as error:
        raise ValueError(f"{path}: cannot be read ({error.strerror or error}); expected {what}") from None
    except (ValueError, EOFError, zipfile.BadZipFile, zlib.error) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        problem = "holds an array of Python objects" if "pickle" in reason else f"truncated or corrupt ({reason})"
        raise ValueError(f"{path}: {problem}; expected {what}") from None
    found = "a single .npy array" if magic == _NPY_MAGIC else "not a .npz (zip) archive"
    raise ValueError(f"{path}: {found}; expected {what}")


def read_npz_arrays(path, arrays: dict) -> tuple:
    """The arrays of a .npz file (:func:`read_npz`), float64, in the order of ``arrays``
    ({name: its shape, as the error message states it})."""
    path = Path(path)
    needed = " and ".join(f"{name} {shape}" for name, shape in arrays.items())
    data = read_npz(path, f"a .npz file of the arrays {needed}")
    missing = [name for name in arrays if name not in data]
    if missing:
        raise ValueError(f"{path}: no array {missing[0]!r} (arrays {needed} needed)")
    out = []
    for name in arrays:
        if data[name].dtype.kind not in "fiu":
            raise ValueError(f"{path}: the array {name!r} holds {data[name].dtype} values, not numbers")
        out.append(data[name].astype(np.float64))
    return tuple(out)
