"""XLA:CPU settings so3jax relies on for speed, added to ``XLA_FLAGS`` by
:func:`configure_xla` (the ``so3jax`` command calls it; importing the library never
does). They take effect only when made before JAX starts its backend (before the
first computation). A setting the user already made in ``XLA_FLAGS`` always wins;
``SO3JAX_KEEP_XLA_FLAGS=1`` disables all of this.
"""

from __future__ import annotations

import os

# XLA:CPU runs the body of a while loop as a sequence of separately dispatched
# kernels; loops whose cost-analysis footprint is below this threshold are instead
# compiled into one function. The default (1 kB) excludes every rollout. Raising it
# is what makes a scan of RK4 steps cheap on CPU: one trajectory of the paper's
# scenario runs at ~1.3 us/step (PD) with it, ~9 without (benchmarks/throughput.py,
# 2-core AMD EPYC). Flattening the call graph after fusion (inlining the computations
# the loop body calls, as TORAX does on CPU) makes the batched step 10-15 % faster:
# both cores, batch 4096, float64, interleaved with Numba, so3jax / Numba is PD
# 2.07-2.24x with it and 1.73-1.93x without, adaptive 2.07-2.13x and 1.76-1.84x; one
# trajectory runs at the same speed. It also compiles a rollout in about a third less
# time: the flight loop (T = 0.3 s), CPU seconds with against without, primal 1.8 / 2.6,
# jacfwd 4.7 / 7.7, grad 8.3 / 11.8 (jaxlib 0.10.2, 2-core AMD EPYC, two rounds).
BACKEND_OPTIONS_FLAG = (
    "--xla_backend_extra_options="
    "xla_cpu_small_while_loop_byte_threshold=1000000000,xla_cpu_flatten_after_fusion=true"
)


def _add(flag: str, key: str) -> None:
    if os.environ.get("SO3JAX_KEEP_XLA_FLAGS") == "1":
        return
    flags = os.environ.get("XLA_FLAGS", "")
    if key not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {flag}".strip()


# On CPUs with AVX-512, XLA vectorizes 256 bits wide unless told otherwise; the batched
# step runs ~25 % faster 512 bits wide (native batch of 256, float64, an AMD EPYC).
WIDE_VECTOR_FLAG = "--xla_cpu_prefer_vector_width=512"


def _has_avx512() -> bool:
    try:
        with open("/proc/cpuinfo") as f:
            return " avx512f" in f.read()
    except OSError:
        return False


def configure_cpu_codegen() -> None:
    """Whole while loops as single CPU kernels, call graph flattened after fusion
    (BACKEND_OPTIONS_FLAG); 512-bit vectors where the CPU has them (WIDE_VECTOR_FLAG)."""
    _add(BACKEND_OPTIONS_FLAG, "xla_backend_extra_options")
    if _has_avx512():
        _add(WIDE_VECTOR_FLAG, "xla_cpu_prefer_vector_width")


def usable_cores() -> int:
    """CPU cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


# With several host devices, XLA:CPU ends the process when a device's thread waits at a
# collective (the devices' rendezvous) for longer than 40 s, logging "may be stuck" after
# 20 s. On a machine running more busy threads than it has cores, a device's thread can be
# off its core that long while the others wait; the limits are raised to an hour and ten
# minutes. jaxlib 0.10 knows these flags (XLA aborts on a flag it does not know: older
# versions keep their defaults).
COLLECTIVE_FLAGS = {
    "xla_cpu_collective_call_terminate_timeout_seconds": 3600,
    "xla_cpu_collective_call_warn_stuck_timeout_seconds": 600,
}


def _knows_collective_flags() -> bool:
    import jaxlib  # here: importing jaxlib starts no backend

    try:
        return tuple(int(x) for x in jaxlib.__version__.split(".")[:2]) >= (0, 10)
    except ValueError:
        return False


def use_every_core() -> None:
    """One XLA host device per core, so sharded batches use the whole CPU; collectives
    between them wait as long as a loaded machine needs (:data:`COLLECTIVE_FLAGS`)."""
    _add(f"--xla_force_host_platform_device_count={usable_cores()}", "xla_force_host_platform_device_count")
    if _knows_collective_flags():
        for key, seconds in COLLECTIVE_FLAGS.items():
            _add(f"--{key}={seconds}", key)


def configure_xla(every_core: bool = False) -> None:
    """The ``so3jax`` command's XLA:CPU settings for this process: whole while loops as
    single CPU kernels (:func:`configure_cpu_codegen`) and, with ``every_core``, one host
    device per core (:func:`use_every_core`). Call it before JAX's first computation;
    the paper's pinned metrics (tests/data/paper_metrics_pinned.json) are these settings'."""
    configure_cpu_codegen()
    if every_core:
        use_every_core()
