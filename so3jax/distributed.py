"""One computation over several processes (hosts), on JAX's multi-controller runtime.

Every process runs the same command; ``jax.distributed.initialize`` joins them into one
runtime whose ``jax.devices()`` are every process's devices, so a sharded batch spans
all hosts. The coordinator is process 0's address. Under SLURM or Open MPI, JAX reads
the process count and index from the environment itself; elsewhere they are given with
``--coordinator HOST:PORT --num-processes N --process-id I`` (or the environment
variables SO3JAX_COORDINATOR, SO3JAX_NUM_PROCESSES, SO3JAX_PROCESS_ID). On CPUs the
processes exchange arrays with gloo, JAX's CPU collectives.
"""

from __future__ import annotations

import contextlib
import os
import socket
import sys
import threading
import time
from pathlib import Path

DEFAULT_TIMEOUT_S = 120


class PeerFailure(RuntimeError):
    """Another process of the run stopped: this one cannot go on (the CLI: exit code 1)."""
_ENV = {"coordinator": "SO3JAX_COORDINATOR", "num_processes": "SO3JAX_NUM_PROCESSES", "process_id": "SO3JAX_PROCESS_ID"}


def add_arguments(parser):
    g = parser.add_argument_group("several processes (hosts)")
    g.add_argument("--distributed", action="store_true",
                   help="join the other processes of this run (automatic under SLURM or Open MPI with several tasks)")
    g.add_argument("--coordinator", metavar="HOST:PORT", help="process 0's address (implies --distributed)")
    g.add_argument("--num-processes", type=int, metavar="N", help="number of processes (implies --distributed)")
    g.add_argument("--process-id", type=int, metavar="I", help="this process's index, 0 to N-1 (implies --distributed)")
    g.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT_S, metavar="S",
                   help=f"seconds to wait for the other processes to join, or to answer once joined (default {DEFAULT_TIMEOUT_S})")
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
    import jax

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
        raise ValueError("outside SLURM or Open MPI, a distributed run needs --coordinator, --num-processes and --process-id")
    if coordinator is not None and i not in (None, 0):
        _reach(coordinator, i, timeout)  # the runtime aborts the process when it cannot: fail first, in one line
    if i == 0:
        print(f"so3jax: process 0 of {n}: coordinating at {coordinator}, waiting up to {timeout:g} s for the others",
              file=sys.stderr, flush=True)
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
            f"process {i if i is not None else '?'} could not join the run at {coordinator or 'the cluster coordinator'} "
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
    import jax

    return jax.process_index() == 0


def barrier(name: str) -> None:
    """Wait until every process reaches this point (no-op for one process)."""
    import jax

    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        with collective(name):
            multihost_utils.sync_global_devices(name)


def check_shared(folder) -> None:
    """Every process must see the run folder as process 0 writes it (a shared filesystem):
    process 0 writes a token there that every process reads back. A ValueError on every
    process otherwise (no-op for one process)."""
    import jax

    if jax.process_count() == 1:
        return
    import secrets

    import numpy as np
    from jax.experimental import multihost_utils

    path = Path(folder) / ".so3jax-shared"
    with collective("checking the output folder"):
        token = str(int(multihost_utils.broadcast_one_to_all(np.int32(secrets.randbits(31) if writer() else 0))))
        if writer():
            path.write_text(token)
        barrier("output folder token written")
        try:
            seen = path.read_text() == token
        except OSError:
            seen = False
        seen = np.asarray(multihost_utils.process_allgather(np.array(seen))).reshape(-1)
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
    import jax

    try:
        yield
    except Exception as err:  # the runtime's errors: JaxRuntimeError, or others naming the transport
        text = str(err)
        runtime = isinstance(err, jax.errors.JaxRuntimeError) or "Gloo" in text or "oordination" in text
        if jax.process_count() == 1 or not runtime:
            raise
        first = text.strip().splitlines()[0][:200]
        raise PeerFailure(
            f"process {jax.process_index()} of {jax.process_count()} stopped at {what}: another process is gone "
            f"({first}); what finished is saved: rerun every process with --resume"
        ) from None


# Process 0 hosts the runtime's coordination service: it leaves last, after this grace
# period, so that the others' shutdown requests reach it (with recoverable tasks, which
# let a peer's failure surface as an error rather than an abort, the runtime does not
# hold process 0 back itself).
SHUTDOWN_GRACE_S = 2.0


def finish() -> None:
    """End a multi-process run in order: every process meets, the others leave, process 0
    last. No-op for a one-process run."""
    import jax

    if not jax.distributed.is_initialized():
        return
    barrier("so3jax: finished")
    if writer():
        time.sleep(SHUTDOWN_GRACE_S)
    jax.distributed.shutdown()
