"""Output folders of every command: checked before any work, locked while a run writes
into them, and tied to the run they belong to by one fingerprint.

``claim(out, command)`` is the one entry point: it makes sure ``out`` is a folder this
process can write (a one-line ValueError otherwise, before anything compiles) and holds
``out/.so3jax.lock`` (pid, host, command) until the run ends. A second run into the same
folder gets an error naming the owner; a lock left by a process that died on this host is
reported and taken over.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import socket
import sys
import tempfile
import time
from pathlib import Path

LOCK = ".so3jax.lock"


def fingerprint(description) -> str:
    """A short hash of a run's description (anything JSON can write, after to_builtin)."""
    from so3jax.io import to_builtin

    text = json.dumps(to_builtin(description), sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def check_writable(out) -> Path:
    """Create ``out`` if needed and prove it writable; ValueError (one line) otherwise."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"output folder {out} is a file; choose another --out")
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=out, prefix=".write-probe.")
        os.close(fd)
        os.unlink(probe)
    except OSError as err:
        raise ValueError(f"output folder {out} is not writable ({err.strerror or err}); choose another --out") from None
    return out


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's live process
        return True
    return True


def _acquire(path: Path, owner: dict) -> None:
    text = json.dumps(owner)
    for _ in range(3):
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                held = json.loads(path.read_text())
                pid, host = int(held["pid"]), str(held["host"])
            except (OSError, ValueError, KeyError, TypeError):
                if not path.exists():
                    continue  # released meanwhile
                raise ValueError(f"{path} is not a valid lock file; remove it if no so3jax run uses {path.parent}") from None
            if host == owner["host"] and not _alive(pid):
                print(
                    f"so3jax: warning: {path.parent} was locked by process {pid}, which is gone; taking the lock over",
                    file=sys.stderr,
                )
                with contextlib.suppress(FileNotFoundError):
                    path.unlink()
                continue
            since = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(held.get("since", 0)))
            raise ValueError(
                f"{path.parent} is in use by so3jax {held.get('command', '?')} (process {pid} on {host}, since {since}); "
                f"wait for it or choose another --out (remove {path} only if that process is gone)"
            ) from None
        with os.fdopen(fd, "w") as f:
            f.write(text)
        return
    raise ValueError(f"could not lock {path.parent}: another process keeps taking it; choose another --out")


@contextlib.contextmanager
def claim(out, command: str, *, lock: bool = True):
    """Check ``out`` (created, writable) and hold its lock while the block runs; yields the Path.

    ``lock=False`` only checks the folder (processes other than the writer of a
    multi-process run).
    """
    out = check_writable(out)
    if not lock:
        yield out
        return
    path = out / LOCK
    owner = {"pid": os.getpid(), "host": socket.gethostname(), "command": command, "since": time.time()}
    _acquire(path, owner)
    try:
        yield out
    finally:
        with contextlib.suppress(OSError, ValueError):
            if json.loads(path.read_text()).get("pid") == owner["pid"]:
                path.unlink()


def corrupt(path, err: Exception, remedy: str) -> ValueError:
    """The one-line error for a result file that cannot be read back."""
    return ValueError(f"{path} cannot be read ({type(err).__name__}: {err}); {remedy}")
