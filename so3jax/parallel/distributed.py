"""One computation over several processes (hosts), on JAX's multi-controller runtime.

Every process runs the same command; ``jax.distributed.initialize`` joins them into one
runtime whose ``jax.devices()`` are every process's devices, so a sharded batch spans
all hosts. The coordinator is process 0's address. Under SLURM or Open MPI, JAX reads
the process count and index from the environment itself; elsewhere they are given with
``--coordinator HOST:PORT --num-processes N --process-id I`` (or the environment
variables SO3JAX_COORDINATOR, SO3JAX_NUM_PROCESSES, SO3JAX_PROCESS_ID). On CPUs the
processes exchange arrays with gloo, JAX's CPU collectives.

How a multi-process run ends: process 0 hosts the runtime's coordination service, and
the runtime aborts every process still attached when that service goes away. So every
process first meets the others with its outcome (:func:`agree`: 0, or the exit code of
its error); then (:func:`leave`) the other processes shut their runtime down, all meet
once more, so that process 0 knows none of the others is still attached, and each exits
with ``os._exit``, so that the runtime's shutdown at interpreter exit never runs. Every
process ends with its own one-line error and an exit code that does not depend on which
left first: 2 for an error in its input or setup, 1 when another process stopped or is
gone.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import socket
import sys
import threading
import time
from pathlib import Path

import numpy as np

DEFAULT_TIMEOUT_S = 120


class PeerFailure(RuntimeError):
    """Another process of the run stopped: this one cannot go on (the CLI: exit code 1)."""


# The run this process joined: its command (for messages) and --timeout, which also
# bounds every wait for the other processes.
_run = {"command": None, "timeout": DEFAULT_TIMEOUT_S}
# Whether a collective found a peer's connection closed (that process has exited).
_gone = {"peer": False}

_ENV = {"coordinator": "SO3JAX_COORDINATOR", "num_processes": "SO3JAX_NUM_PROCESSES", "process_id": "SO3JAX_PROCESS_ID"}


def add_arguments(parser):
    g = parser.add_argument_group("several processes (hosts)")
    g.add_argument("--distributed", action="store_true",
                   help="join the other processes of this run (automatic under SLURM or Open MPI with several tasks)")
    g.add_argument("--coordinator", metavar="HOST:PORT", help="process 0's address (implies --distributed)")
    g.add_argument("--num-processes", type=int, metavar="N", help="number of processes (implies --distributed)")
    g.add_argument("--process-id", type=int, metavar="I", help="this process's index, 0 to N-1 (implies --distributed)")
    g.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT_S, metavar="S",
                   help="seconds to wait for the other processes to join, or to answer once joined "
                        f"(default {DEFAULT_TIMEOUT_S})")
    return g


def _setting(args, name):
    value = getattr(args, name, None)
    if value is None and os.environ.get(_ENV[name]):
        text = os.environ[_ENV[name]]
        if name == "coordinator":
            return text
        try:
            return int(text)
        except ValueError:
            raise ValueError(f"{_ENV[name]} must be an integer, got {text!r}") from None
    return value


def _cluster_tasks() -> int:
    for key in ("SLURM_NTASKS", "OMPI_COMM_WORLD_SIZE"):
        try:
            return int(os.environ[key])
        except (KeyError, ValueError):
            continue
    return 1


def requested(args) -> bool:
    """Whether this command runs as one of several processes."""
    explicit = any(_setting(args, name) is not None for name in _ENV)
    return bool(getattr(args, "distributed", False)) or explicit or _cluster_tasks() > 1


def initialize(args) -> None:
    """Join the run's other processes (no-op for a one-process run). A bad setting, or a
    coordinator that cannot be reached within ``--timeout``, is a one-line ValueError."""
    if not requested(args):
        return
    import jax  # here: the CLI imports this module before JAX is configured

    coordinator, n, i = (_setting(args, name) for name in _ENV)
    timeout = getattr(args, "timeout", DEFAULT_TIMEOUT_S)
    if not (timeout > 0):
        raise ValueError(f"--timeout must be positive, got {timeout}")
    if n is not None and n < 1:
        raise ValueError(f"--num-processes must be at least 1, got {n}")
    if i is not None and not (0 <= i < (n or 1 << 30)):
        raise ValueError(f"--process-id must be in 0..{(n or 1) - 1}, got {i}")
    if coordinator is not None and (":" not in coordinator or not coordinator.rsplit(":", 1)[1].isdigit()):
        raise ValueError(f"--coordinator must read HOST:PORT, got {coordinator!r}")
    if _cluster_tasks() == 1 and None in (coordinator, n, i):
        raise ValueError("outside SLURM or Open MPI, a distributed run needs --coordinator, --num-processes "
                         "and --process-id")
    if coordinator is not None and i not in (None, 0):
        _reach(coordinator, i, timeout)  # the runtime aborts the process when it cannot: fail first, in one line
    if i == 0:
        print(f"so3jax: process 0 of {n}: coordinating at {coordinator}, waiting up to {timeout:g} s for the others",
              file=sys.stderr, flush=True)
    _run.update(command=getattr(args, "command", None), timeout=timeout)
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.config.update("jax_enable_recoverability", True)
    # The runtime aborts a process whose peers do not all register in time; the watchdog
    # ends it first, with one line, and the runtime's own deadline is set past it.
    watchdog = threading.Timer(timeout, _not_joined, (getattr(args, "command", None), i, n, coordinator, timeout))
    watchdog.daemon = True
    watchdog.start()
    try:
        jax.distributed.initialize(
            coordinator_address=coordinator,
            num_processes=n,
            process_id=i,
            initialization_timeout=int(timeout) + ABORT_MARGIN_S,
            heartbeat_timeout_seconds=int(timeout),
        )
    except Exception as err:  # the runtime's errors are XlaRuntimeError/RuntimeError with long texts
        first = str(err).strip().splitlines()[0][:300] if str(err).strip() else type(err).__name__
        raise ValueError(
            f"process {i if i is not None else '?'} could not join the run at "
            f"{coordinator or 'the cluster coordinator'} "
            f"within {timeout:g} s ({first}); start process 0 first and check --coordinator"
        ) from None
    finally:
        watchdog.cancel()


# Seconds the runtime's registration deadline lies past --timeout (the watchdog's).
ABORT_MARGIN_S = 10


def _not_joined(command, i, n, coordinator, timeout) -> None:
    """The watchdog: not every process joined within ``timeout``; exit 1 with one line."""
    who = f"process {i} of {n}" if i is not None else "this process"
    print(
        f"so3jax {command or ''}: error: {who}: not every process joined the run at "
        f"{coordinator or 'the cluster coordinator'} within {timeout:g} s; start all {n or ''} processes "
        f"with the same --coordinator and --num-processes, each with its own --process-id (or raise --timeout)",
        file=sys.stderr, flush=True,
    )
    os._exit(1)


def _reach(coordinator: str, i: int, timeout: float) -> None:
    """Wait until the coordinator accepts connections; ValueError after ``timeout`` seconds."""
    host, port = coordinator.rsplit(":", 1)
    deadline = time.monotonic() + timeout
    while True:
        try:
            socket.create_connection((host.strip("[]"), int(port)), timeout=min(5.0, timeout)).close()
            return
        except OSError as err:
            if time.monotonic() >= deadline:
                raise ValueError(
                    f"process {i} could not reach the coordinator at {coordinator} within {timeout:g} s "
                    f"({err.strerror or err}); start process 0 first and check --coordinator"
                ) from None
            time.sleep(0.5)


def writer() -> bool:
    """Whether this process writes the run's shared files (process 0)."""
    import jax  # here: the CLI imports this module before JAX is configured

    return jax.process_index() == 0


def active() -> bool:
    """Whether this process is one of several joined processes."""
    import jax  # here: the CLI imports this module before JAX is configured

    return jax.distributed.is_initialized() and jax.process_count() > 1


def _exchange(value: int, what: str):
    """Every process's int32 ``value`` (>= 0), in process order: one all-gather, the
    only collective the meeting points (barrier, check_shared, agree) use, so that a
    process that stopped with an error (see :func:`agree`) meets the others at whichever
    of them they are. A negative value is that process's error: PeerFailure here."""
    values = _allgather(value)
    failed = [k for k, v in enumerate(values) if v < 0]
    if failed and value >= 0:
        who = ", ".join(str(k) for k in failed)
        theirs = "its message" if len(failed) == 1 else "their messages"
        raise PeerFailure(f"process {_me()} stopped at {what}: process(es) {who} of {len(values)} "
                          f"stopped with an error (see {theirs})")
    return values


def _allgather(value: int):
    """Every process's int32 ``value``, in process order."""
    from jax.experimental import multihost_utils  # here: the CLI imports this module before JAX is configured

    return np.asarray(multihost_utils.process_allgather(np.int32(value))).reshape(-1)


def _me() -> str:
    import jax  # here: the CLI imports this module before JAX is configured

    return f"{jax.process_index()} of {jax.process_count()}"


def barrier(name: str) -> None:
    """Wait until every process reaches this point (no-op for one process); PeerFailure
    where another process stopped with an error or is gone."""
    if active():
        with collective(name):
            _exchange(0, name)


def check_shared(folder) -> None:
    """Every process must see the run folder as process 0 writes it (a shared filesystem):
    process 0 writes a token there that every process reads back. A ValueError on every
    process otherwise (no-op for one process)."""
    if not active():
        return

    what = "checking the output folder"
    path = Path(folder) / ".so3jax-shared"
    with collective(what):
        token = str(int(_exchange(secrets.randbits(31) if writer() else 0, what)[0]))
        if writer():
            path.write_text(token)
        _exchange(0, what)
        try:
            seen = path.read_text() == token
        except OSError:
            seen = False
        seen = _exchange(int(seen), what).astype(bool)
    if writer():
        path.unlink(missing_ok=True)
    if not seen.all():
        blind = ", ".join(str(i) for i in np.flatnonzero(~seen))
        raise ValueError(f"process(es) {blind} of {len(seen)} do not see {folder} as process 0 writes it: "
                         "every process must share the output folder (a shared filesystem)")


@contextlib.contextmanager
def collective(what: str):
    """Context: a JaxRuntimeError inside a multi-process step becomes a PeerFailure that
    names this process and ``what`` it was computing (one line, no traceback)."""
    import jax  # here: the CLI imports this module before JAX is configured

    try:
        yield
    except Exception as err:  # the runtime's errors: JaxRuntimeError, or others naming the transport
        text = str(err)
        runtime = isinstance(err, jax.errors.JaxRuntimeError) or "Gloo" in text or "oordination" in text
        if jax.process_count() == 1 or not runtime:
            raise
        if "by peer" in text:  # gloo: "Connection closed by peer", "Connection reset by peer"
            _gone["peer"] = True
        first = text.strip().splitlines()[0][:200]
        raise PeerFailure(
            f"process {_me()} stopped at {what}: another process is gone "
            f"({first}); what finished is saved: rerun every process with --resume"
        ) from None


def agree(code: int) -> int:
    """The last meeting of a multi-process run: every process brings its outcome (0, or
    the exit code of the error it has reported) and returns it. A process that succeeded
    while another stopped with an error gets a PeerFailure instead; a process that stopped
    with an error meets the others wherever they wait (a barrier, the folder check, this)
    so that they stop too. A wait past --timeout ends the process with ``code`` (1 for 0).
    No-op for one process."""
    if not active():
        return code
    with _deadline(code or 1, "the other processes did not reach the end of the run"):
        try:
            with collective("the end of the run"):
                _exchange(-code if code else 0, "the end of the run")
        except PeerFailure:
            if code == 0:
                raise
    return code


def _shutdown(code: int) -> None:
    """Detach from the runtime in order. The other processes shut their runtime down
    while process 0's coordination service is up (the runtime aborts a process whose
    shutdown cannot reach it), then every process meets once more over gloo, which needs
    no service: past that meeting none of the others is attached, and process 0 may go.
    Process 0 skips it when its only peer's connection has closed (that process exited);
    a peer gone during it leaves process 0 waiting until the service sees none of the
    others attached. Every wait ends at --timeout."""
    import jax  # here: the CLI imports this module before JAX is configured

    if jax.process_index() != 0:
        with contextlib.suppress(Exception):  # an error that did not abort: this process leaves anyway
            jax.distributed.shutdown()
    elif _gone["peer"] and jax.process_count() == 2:
        return
    with _deadline(code, "the other processes did not leave the run"):
        try:
            _allgather(0)
        except Exception:  # a process gone: gloo's error
            if jax.process_index() == 0:
                _wait_detached()


def _wait_detached() -> None:
    """Process 0: wait until the coordination service sees none of the others attached
    (a process that shut down at once, one that exited after its heartbeat timeout)."""
    import jax  # here: the CLI imports this module before JAX is configured
    from jax.experimental import multihost_utils  # here: the CLI imports this module before JAX is configured

    devices = jax.devices()
    while True:
        try:  # returns once every attached process is here: none of the others is
            with multihost_utils.live_devices(devices) as live:
                pass
            if {d.process_index for d in live} == {0}:
                time.sleep(SHUTDOWN_GRACE_S)  # the last shutdown's answer on its way
                return
        except multihost_utils.ProcessFailureError:
            continue  # processes left during the call: ask again
        except Exception:  # the runtime's errors: ask again until the deadline
            pass
        time.sleep(0.2)


# Seconds process 0 stays up once its service sees none of the others attached (only
# where a process is gone; otherwise the last meeting orders the exit).
SHUTDOWN_GRACE_S = 1.0


def leave(code: int) -> int:
    """End this process with exit ``code``: in a multi-process run, after :func:`agree`,
    stdout and stderr flushed, detached in order (see :func:`_shutdown`), ``os._exit`` —
    the runtime's own shutdown at interpreter exit, which aborts a process whose
    coordinator left first, never runs. Returns ``code`` for a one-process run."""
    import jax  # here: the CLI imports this module before JAX is configured

    if not jax.distributed.is_initialized():
        return code
    sys.stdout.flush()
    sys.stderr.flush()
    _shutdown(code)
    os._exit(code)


def finish() -> None:
    """End a multi-process run that goes on in Python afterwards: every process meets
    (:func:`agree`), then detaches in order, process 0 last. No-op for one process."""
    import jax  # here: the CLI imports this module before JAX is configured

    if not jax.distributed.is_initialized():
        return
    agree(0)
    _shutdown(0)
    if jax.process_index() == 0:
        jax.distributed.shutdown()


@contextlib.contextmanager
def _deadline(code: int, what: str):
    """Context: past --timeout, report ``what`` in one line and end the process with ``code``."""
    def expire():
        print(f"so3jax {_run['command'] or ''}: error: process {_me()}: {what} within {_run['timeout']:g} s",
              file=sys.stderr, flush=True)
        os._exit(code)

    timer = threading.Timer(_run["timeout"], expire)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
