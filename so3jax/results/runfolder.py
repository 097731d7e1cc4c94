"""Output folders of every command: one run's files each, checked before any work, locked
while a run writes into them, listed in a manifest, and tied to the run they belong to by
one fingerprint.

``claim(out, command, settings)`` is the one entry point. Entering it checks ``out``
without creating anything: a file, or a folder neither it nor its nearest existing
parent lets this process write, is a one-line ValueError; so is a folder that holds
another command's run. The folder is created only when the run writes its first file:
every result goes through :func:`so3jax.results.io.atomic_path`, which calls :func:`writing`,
so a run refused by any check (bad values, memory, horizon) leaves nothing behind.

While a run writes, ``out/.so3jax.lock`` (pid, host, command) keeps a second run out (a
lock left by a process that died on this host is reported and taken over), and
``out/manifest.json`` records the run: command, settings and their fingerprint, start
(entering the claim, before the work) and finish times, the files it wrote (a name
ending in "/" is a folder it owns), and ``complete``, false from its first file until the
block ends without an error. A run that starts writing into a folder holding another
run's manifest removes the files it lists, as a set (saying so when that manifest is
incomplete: an interrupted or stopped run) and names, in one warning line, the files no
manifest lists, which it leaves alone.
A resumed run (``resume=True``, same command) keeps the listed files and goes on with
their manifest, which it leaves as it is until it writes a file: a resume refused before
then leaves the folder as it was. Where the job names the settings a resume may change
(``may_change``), a resume under any other changed setting is refused before the block,
naming them, so the manifest always describes the files the folder holds.
"""

from __future__ import annotations

import contextlib
import glob
import hashlib
import json
import os
import shutil
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path

from so3jax.results import io

LOCK = ".so3jax.lock"
MANIFEST = "manifest.json"
_OWN = (LOCK, MANIFEST, ".so3jax-shared")  # the folder's machinery, never a run's result
_ACTIVE: list = []  # the runs inside a claim block in this process
_GUARD = threading.RLock()


def fingerprint(description) -> str:
    """A short hash of a run's description (anything JSON can write, after to_builtin)."""

    text = json.dumps(io.to_builtin(description), sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def check_writable(out) -> Path:
    """Prove that ``out`` can be written, creating nothing that is not already there:
    the folder itself when it exists, else its nearest existing parent (where it would
    be created). ValueError (one line) otherwise."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"output folder {out} is a file; choose another --out")
    existing = Path(os.path.abspath(out))
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(f"output folder {out} cannot be made: {existing} is a file; choose another --out")
    try:
        fd, probe = tempfile.mkstemp(dir=existing, prefix=".write-probe.")
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
                raise ValueError(f"{path} is not a valid lock file; "
                                 f"remove it if no so3jax run uses {path.parent}") from None
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
                f"{path.parent} is in use by so3jax {held.get('command', '?')} "
                f"(process {pid} on {host}, since {since}); "
                f"wait for it or choose another --out (remove {path} only if that process is gone)"
            ) from None
        with os.fdopen(fd, "w") as f:
            f.write(text)
        return
    raise ValueError(f"could not lock {path.parent}: another process keeps taking it; choose another --out")


def read_manifest(out) -> dict | None:
    """The manifest of the run in folder ``out``; None where there is none. A manifest
    that cannot be read is a one-line ValueError."""
    path = Path(out) / MANIFEST
    try:
        manifest = json.loads(path.read_text())
        if not (isinstance(manifest["command"], str) and isinstance(manifest["complete"], bool)
                and all(isinstance(name, str) for name in manifest["files"])):
            raise TypeError("command, complete or files of the wrong type")
    except FileNotFoundError:
        return None
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise corrupt(path, err, f"delete it, or {Path(out)} with it, or choose another --out") from None
    return manifest


def incomplete(out) -> dict | None:
    """The manifest of folder ``out`` where it records a run that did not finish."""
    manifest = read_manifest(out)
    return manifest if manifest is not None and not manifest["complete"] else None


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")


def changed_settings(previous, current, prefix: str = "") -> list:
    """The dotted names of the settings that differ between two settings tables (a
    list compared as a whole), sorted."""
    if not (isinstance(previous, dict) and isinstance(current, dict)):
        return [] if previous == current else [prefix or "settings"]
    names = []
    for key in sorted(set(previous) | set(current)):
        name = f"{prefix}.{key}" if prefix else key
        if key not in previous or key not in current:
            names.append(name)
        else:
            names += changed_settings(previous[key], current[key], name)
    return names


def _listed(names: list, limit: int = 6) -> str:
    """Names joined by commas, at most ``limit`` of them."""
    more = f" and {len(names) - limit} more" if len(names) > limit else ""
    return ", ".join(names[:limit]) + more


def _owned_name(name: str) -> bool:
    """A manifest entry naming something directly in the folder (never outside it)."""
    bare = name[:-1] if name.endswith("/") else name
    return bool(bare) and bare not in (".", "..") and "/" not in bare and "\\" not in bare and bare not in _OWN


class Run:
    """One run's hold on its output folder (see the module docstring); ``out`` is the Path."""

    def __init__(self, out: Path, command: str, settings, resume: bool, writer: bool, may_change=None):

        self.out, self.command, self.resume, self.writer = out, command, resume, writer
        self.may_change = None if may_change is None else tuple(may_change)
        self.started = _now()  # the run starts here, before its work; its first file may come much later
        settings = {k: v for k, v in dict(settings or {}).items() if not callable(v)}
        self.settings = json.loads(json.dumps(io.to_builtin(settings), default=str))  # paths as text
        self.root = os.path.abspath(out)
        self.manifest = None  # this run's, once it writes
        self.saved = False  # whether the folder's manifest is this run's
        self.locked = None  # the lock's owner record, while this run holds it

    def check(self) -> None:
        """Refuse a folder that holds another command's run, or (resuming, where the job
        names the settings a resume may change) a run of other settings (ValueError, one line)."""
        previous = read_manifest(self.out) if self.out.is_dir() else None
        if previous is None:
            return
        if previous["command"] != self.command:
            state = "a complete" if previous["complete"] else "an incomplete"
            raise ValueError(f"{self.out} holds {state} so3jax {previous['command']} run; choose another --out, "
                             f"or delete {self.out} to reuse it")
        if self.resume and self.may_change is not None:
            changed = [name for name in changed_settings(previous.get("settings"), self.settings)
                       if not any(name == key or name.startswith(key + ".") for key in self.may_change)]
            if changed:
                raise ValueError(f"--resume: {self.out} holds a so3jax {self.command} run with other settings "
                                 f"({_listed(changed)}); resume it with its own settings, or choose another --out")

    def lock(self) -> None:
        if self.writer and self.locked is None:
            owner = {"pid": os.getpid(), "host": socket.gethostname(), "command": self.command, "since": time.time()}
            _acquire(self.out / LOCK, owner)
            self.locked = owner

    def start(self) -> Path:
        """Create the folder, lock it and open this run's manifest (complete: false),
        replacing the files of the manifest the folder holds; once, on the run's first file. A resumed
        run keeps them, and the folder's manifest until its first file (:meth:`record`). Other processes
        of a multi-process run (not the writer) do nothing here."""
        with _GUARD:
            if self.manifest is not None or not self.writer:
                return self.out
            try:
                self.out.mkdir(parents=True, exist_ok=True)
            except OSError as err:
                raise ValueError(f"output folder {self.out} cannot be made ({err.strerror or err}); "
                                 "choose another --out") from None
            self.lock()
            self.check()
            previous = read_manifest(self.out)
            resumed = previous is not None and self.resume and previous["command"] == self.command
            if resumed:
                files = [name for name in previous["files"] if _owned_name(name)]
            else:
                self._replace(previous)
                files = []
            started = previous.get("started", self.started) if resumed else self.started
            self.manifest = {"command": self.command, "settings": self.settings,
                             "fingerprint": fingerprint(self.settings), "started": started, "finished": None,
                             "complete": False, "files": files}
            if not resumed:
                self._save()
            return self.out

    def _replace(self, previous: dict | None) -> None:
        """Remove the files of the run ``previous`` describes; name the ones no manifest lists."""
        listed = [name for name in previous["files"] if _owned_name(name)] if previous else []
        if previous is not None:
            if not previous["complete"]:
                self._say(f"{self.out} holds an interrupted so3jax {previous['command']} run "
                          f"(started {previous.get('started', '?')}); replacing it")
            self._save({**previous, "complete": False})  # seen as incomplete until its files are gone
        for name in listed:
            path = self.out / name.rstrip("/")
            if name.endswith("/") and path.is_dir() and not path.is_symlink():
                shutil.rmtree(path)
            else:
                with contextlib.suppress(FileNotFoundError, IsADirectoryError):
                    path.unlink()
            for tmp in self.out.glob(f".{glob.escape(name.rstrip('/'))}.*.tmp"):  # a write that was killed
                tmp.unlink(missing_ok=True)
        others = sorted(p.name + ("/" if p.is_dir() else "") for p in self.out.iterdir()
                        if p.name not in _OWN and not p.name.startswith(".write-probe."))
        if others:
            self._say(f"{self.out} holds files no so3jax run lists, left as they are: {', '.join(others)}")

    def _say(self, text: str) -> None:
        print(f"so3jax {self.command}: warning: {text}", file=sys.stderr, flush=True)

    def _save(self, manifest: dict | None = None) -> None:
        """Write this run's manifest (or ``manifest``, another run's) into the folder."""
        io.write_json(self.out / MANIFEST, self.manifest if manifest is None else manifest)
        self.saved = manifest is None

    def record(self, path) -> None:
        """List ``path`` (inside the folder) in the manifest, starting the run first."""
        parts = Path(os.path.relpath(os.path.abspath(path), self.root)).parts
        name = parts[0] + ("/" if len(parts) > 1 else "")
        if not self.writer or not _owned_name(name):
            return
        with _GUARD:
            self.start()
            listed = name in self.manifest["files"]
            if not listed:
                self.manifest["files"].append(name)
            if not (listed and self.saved):  # a resumed run's manifest is the folder's from its first file
                self._save()

    def finish(self) -> None:
        """Mark the manifest complete (where this run wrote anything)."""
        with _GUARD:
            if self.manifest is not None:
                self.manifest.update(complete=True, finished=_now())
                self._save()

    def release(self) -> None:
        if self.locked is not None:
            path = self.out / LOCK
            with contextlib.suppress(OSError, ValueError):
                if json.loads(path.read_text()).get("pid") == self.locked["pid"]:
                    path.unlink()
            self.locked = None


def writing(path) -> None:
    """Called by :func:`so3jax.results.io.atomic_path` (registered below) before it writes ``path``: each run whose
    folder holds it starts (folder, lock, manifest) and lists it (a run inside another's
    folder, as ``compare`` holds its campaigns and sweep, lists its files; the outer run
    lists the inner folder)."""
    name = os.path.basename(path)
    if name in _OWN:
        return
    target = os.path.abspath(path)
    with _GUARD:
        for run in _ACTIVE:
            if target.startswith(run.root + os.sep):
                run.record(target)


@contextlib.contextmanager
def claim(out, command: str, settings=None, *, resume: bool = False, lock: bool = True, may_change=None):
    """Check ``out`` and hold it for the block's run; yields the :class:`Run` (``.out`` is
    the Path). ``settings`` (a dict, e.g. ``vars(args)``) go to the manifest;
    ``resume=True`` continues the run of the same command the folder holds; ``may_change``
    (dotted names of settings, e.g. ``("sweep.samples",)``; None: the job checks its own
    files) are those a resume may change, any other changed setting refuses it. The folder is
    created, locked and listed when the block writes its first file (or calls
    ``run.start()``); the manifest is marked complete when the block ends without an error.

    ``lock=False``: a process of a multi-process run other than the writer, which only
    checks the folder (the writer keeps its lock and manifest).
    """
    out = check_writable(out)
    run = Run(out, command, settings, resume, lock, may_change)
    try:
        if out.is_dir():
            run.lock()  # an existing folder is held from the start; a new one when it is made
        run.check()
        with _GUARD:
            _ACTIVE.append(run)
        try:
            yield run
            run.finish()
        finally:
            with _GUARD:
                _ACTIVE.remove(run)
    finally:
        run.release()


def corrupt(path, err: Exception, remedy: str) -> ValueError:
    """The one-line error for a result file that cannot be read back."""
    return ValueError(f"{path} cannot be read ({type(err).__name__}: {err}); {remedy}")


io.before_write(writing)
