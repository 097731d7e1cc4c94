"""How many samples a sweep runs per chunk, on any device.

A chunk is one call of the sweep's chunk program: its samples split evenly over the
devices a chunk runs over, at least :data:`MIN_SHARD` per device.

* **On the host (CPU)** the chunk is the configured one (``sweep.chunk``, ``--chunk``)
  padded to a multiple of the device count with at least ``MIN_SHARD`` samples per
  device: the sweep's rule (``padded_chunk``), unchanged. A chunk there sets the progress
  and resume granularity; inside a device the rollout runs in cache-sized sub-batches
  anyway.
* **On an accelerator** (any device that is not the host and reports
  ``memory_stats()['bytes_limit']``, e.g. a GPU) one time step of a chunk costs about the
  same for 1 sample or 10⁴ (the step is a chain of small kernels, launch-bound): the chunk
  is the largest one whose footprint fits a safe share (:data:`SAFE_SHARE`) of a device's
  free memory, capped at the samples rounded up to the device count, so a sweep that fits
  runs as one program per controller.

:func:`chunk_for` is the rule (a pure function of numbers); :func:`device_memory` and
:func:`chunk_on` read the devices. A sweep's footprint per sample on the device is its
chunk program's inputs and outputs per sample (what the sweep's memory check traces) and
:data:`WORKING_BYTES`; :func:`compiled_bytes_per_sample` measures the whole from XLA's
memory analysis.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import jax

MIN_SHARD = 8  # samples per device and chunk, at least (the sweep's MIN_SHARD)
SAFE_SHARE = 0.5  # of a device's free memory a chunk's estimated footprint may take
# Device bytes per sample a sweep's chunk program works in beyond its inputs and outputs
# (the loop's carry and one step's temporaries; no history: record_every = N). XLA:CPU's
# memory analysis of the chunk program at 64 samples, float64: 2.4 kB (the paper's loop,
# PD) and 3.9 kB (the flight loop, PD); an accelerator's fusions keep other temporaries, so
# the figure allows 16x the larger (benchmarks/gpu.py measures it on the device).
WORKING_BYTES = 64 << 10


def host_chunk(configured: int, devices: int, min_shard: int = MIN_SHARD) -> int:
    """The host rule: ``configured`` samples rounded up to a multiple of ``devices``, at
    least ``min_shard`` per device (the sweep's ``padded_chunk``)."""
    return devices * max(min_shard, -(-configured // devices))


def chunk_for(memory_bytes: int | None, bytes_per_sample: float, samples: int, devices: int = 1,
              configured: int = 128, *, share: float = SAFE_SHARE, min_shard: int = MIN_SHARD) -> int:
    """Samples per chunk.

    memory_bytes: free bytes of one device of an accelerator, or None for the host (CPU),
    where the chunk is :func:`host_chunk` of ``configured`` whatever the other figures.
    On an accelerator: the largest multiple of ``devices`` whose shard (chunk / devices
    samples) needs at most ``share * memory_bytes`` at ``bytes_per_sample`` bytes a sample,
    no more than ``samples`` rounded up to a multiple of ``devices`` (and never below
    ``min_shard`` per device: a device that cannot hold that many samples is refused with
    a ValueError). ``configured`` is not used there."""
    if devices < 1 or samples < 1:
        raise ValueError(f"devices and samples must be positive, got {devices} and {samples}")
    if memory_bytes is None:
        return host_chunk(configured, devices, min_shard)
    if not bytes_per_sample > 0:
        raise ValueError(f"bytes_per_sample must be positive, got {bytes_per_sample!r}")
    floor = devices * min_shard
    cap = max(floor, devices * -(-samples // devices))
    per_device = int(share * memory_bytes // bytes_per_sample)
    if per_device < min_shard:
        raise ValueError(f"a device with {memory_bytes} bytes free holds {per_device} samples of "
                         f"{bytes_per_sample:.3g} bytes in its safe share ({share}), fewer than the {min_shard} a "
                         "shard needs")
    return min(cap, devices * per_device)


def device_memory(device) -> int | None:
    """Free bytes of an accelerator device (its allocator's ``bytes_limit`` less
    ``bytes_in_use``); None for the host (a CPU device) or a device that reports no limit."""
    if device.platform == "cpu":
        return None
    try:
        stats = device.memory_stats()
    except Exception:  # a backend without memory statistics
        return None
    if not stats or "bytes_limit" not in stats:
        return None
    return int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))


def chunk_on(devices: Sequence, bytes_per_sample: float, samples: int, configured: int = 128, **kwargs) -> int:
    """:func:`chunk_for` on these devices (e.g. ``mesh.devices.flat``): the host rule when
    any of them is the host, else the least free memory among them."""
    devices = list(devices)
    free = [device_memory(d) for d in devices]
    memory = None if any(m is None for m in free) else min(free)
    return chunk_for(memory, bytes_per_sample, samples, len(devices), configured, **kwargs)


def compiled_bytes_per_sample(fn: Callable, *args, samples: int) -> float:
    """Device bytes per sample of ``jax.jit(fn)`` compiled for ``args`` (arrays or
    ``jax.ShapeDtypeStruct``, a batch of ``samples``), from XLA's memory analysis: its
    arguments, outputs and temporaries, less the buffers outputs share with arguments.
    It compiles: a measurement (benchmarks/gpu.py), not a step of the sweep."""
    stats = jax.jit(fn).lower(*args).compile().memory_analysis()
    total = (stats.argument_size_in_bytes + stats.output_size_in_bytes + stats.temp_size_in_bytes
             - stats.alias_size_in_bytes)
    return total / samples
