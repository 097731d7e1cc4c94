"""The sweep's chunk policy on any device (so3jax.parallel.chunks), with fake device
memory; and the rollout's unrolled step scan in the flight loop (the paper loop's:
tests/test_rollout.py)."""

import itertools
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import so3jax as sj
from so3jax.jobs.sweep import engine
from so3jax.missions import mission
from so3jax.parallel import chunks

GIB = 1 << 30


class FakeDevice:
    """A device as chunk_on reads one: its platform and its memory statistics."""

    def __init__(self, platform="gpu", limit=None, in_use=0):
        self.platform, self.limit, self.in_use = platform, limit, in_use

    def memory_stats(self):
        if self.limit is None:
            return None
        return {"bytes_limit": self.limit, "bytes_in_use": self.in_use}


CASES = list(itertools.product(
    (GIB // 4, 16 * GIB, 100 * GIB),  # free device memory
    (2_000, 64 << 10, 3 << 20),  # bytes per sample
    (1, 7, 1024, 100_000),  # samples
    (1, 2, 3, 8),  # devices
))


@pytest.mark.parametrize(("memory", "per_sample", "samples", "devices"), CASES)
def test_accelerator_chunk_fits_and_is_the_largest(memory, per_sample, samples, devices):
    """On an accelerator: a multiple of the device count, at least the minimum shard per
    device, its shard within the safe share of one device's memory, never above the samples
    rounded up to the device count (or the minimum), and the largest such."""
    floor = devices * chunks.MIN_SHARD
    if chunks.SAFE_SHARE * memory // per_sample < chunks.MIN_SHARD:
        with pytest.raises(ValueError, match="fewer than"):
            chunks.chunk_for(memory, per_sample, samples, devices)
        return
    chunk = chunks.chunk_for(memory, per_sample, samples, devices)
    cap = max(floor, devices * -(-samples // devices))
    assert chunk % devices == 0 and chunk >= floor
    assert chunk // devices * per_sample <= chunks.SAFE_SHARE * memory
    assert chunk <= cap
    bigger = chunk + devices
    assert bigger > cap or bigger // devices * per_sample > chunks.SAFE_SHARE * memory


def test_the_default_sweep_is_one_chunk_on_a_large_device():
    """1024 samples at 64 KiB each on an 80 GB device: one chunk of 1024; 10^5 samples too."""
    assert chunks.chunk_for(80 * GIB, chunks.WORKING_BYTES, 1024) == 1024
    assert chunks.chunk_for(80 * GIB, chunks.WORKING_BYTES, 100_000) == 100_000
    assert chunks.chunk_for(GIB, chunks.WORKING_BYTES, 100_000) == GIB // 2 // chunks.WORKING_BYTES


@pytest.mark.parametrize("configured", [1, 7, 8, 16, 100, 128, 129, 1000, 4096])
@pytest.mark.parametrize("devices", [1, 2, 3, 4, 16])
def test_host_rule_is_the_sweeps(configured, devices):
    """On the host (memory None, or a CPU device) the chunk is the sweep's padded_chunk,
    whatever the samples and bytes per sample."""
    expected = engine.padded_chunk(configured, devices)
    assert chunks.MIN_SHARD == engine.MIN_SHARD
    for samples, per_sample in ((1, 1), (1024, 64 << 10), (10**6, 1 << 30)):
        assert chunks.chunk_for(None, per_sample, samples, devices, configured) == expected
        cpu = [FakeDevice("cpu", limit=GIB)] * devices  # a CPU device reporting a limit stays the host
        assert chunks.chunk_on(cpu, per_sample, samples, configured) == expected


def test_chunk_on_reads_the_devices():
    """The least free memory among the devices (limit less in use); a device without
    statistics, or any host device among them, gives the host rule."""
    devices = [FakeDevice(limit=16 * GIB), FakeDevice(limit=16 * GIB, in_use=12 * GIB)]
    assert chunks.device_memory(devices[1]) == 4 * GIB
    assert chunks.chunk_on(devices, 1 << 20, 10**6) == chunks.chunk_for(4 * GIB, 1 << 20, 10**6, 2)
    assert chunks.chunk_on(devices, 1 << 20, 10**6) == 2 * 2048
    assert chunks.chunk_on([FakeDevice(limit=None)], 1 << 20, 10**6, 100) == engine.padded_chunk(100, 1)
    assert chunks.chunk_on([devices[0], FakeDevice("cpu")], 1 << 20, 10**6, 100) == engine.padded_chunk(100, 2)
    assert chunks.device_memory(jax.devices("cpu")[0]) is None


def test_the_sweep_wiring_on_a_fake_accelerator(monkeypatch):
    """The chunk run_sweep takes (engine.device_chunk): on the host the sweep's chunk; on a
    device with 80 GiB free the default sweep's 1024 samples in one chunk, at WORKING_BYTES
    and the traced inputs and outputs a sample."""
    from so3jax.jobs.sweep import load_config

    policy_chunk = engine.device_chunk

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sj.InertiaWarning)
        config = load_config(None, ("T=0.05", 'controllers=["pd"]'))
    mesh = engine.batch_mesh()
    assert policy_chunk(config, mesh) == (engine.padded_chunk(config.chunk, mesh.size), None)
    monkeypatch.setattr(chunks, "device_memory", lambda device: 80 * GIB)
    chunk, per_sample = policy_chunk(config, mesh)
    assert chunk == config.samples == 1024
    assert chunks.WORKING_BYTES + 100 < per_sample < chunks.WORKING_BYTES + 10_000


def test_bad_figures_are_refused():
    with pytest.raises(ValueError, match="positive"):
        chunks.chunk_for(GIB, 1000, 0)
    with pytest.raises(ValueError, match="bytes_per_sample"):
        chunks.chunk_for(GIB, 0, 10)


def test_compiled_bytes_per_sample_counts_arguments_and_outputs():
    """XLA's figure for a program of (n, 1000) float64 in and out: at least 16 kB a sample."""
    n = 16
    per_sample = chunks.compiled_bytes_per_sample(lambda x: jnp.sin(x) * 2.0,
                                                  jax.ShapeDtypeStruct((n, 1000), jnp.float64), samples=n)
    assert 16_000 <= per_sample < 64_000


# --- the flight loop's unrolled step scan ------------------------------------------------------

FLIGHT_STEPS = 30  # 3 control ticks of 10 steps, in one block (the sweep's record_every = N)


@pytest.fixture(scope="module")
def flight():
    """simulate(the flight mission, PD, two seeds) over FLIGHT_STEPS, by unroll (compiled as asked)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sj.InertiaWarning)
        m = mission.load(None, [f"T={FLIGHT_STEPS * 0.01!r}"])
        scenario, loop = m.scenario(), m.loop()
    assert scenario.n_steps == FLIGHT_STEPS and loop.period_steps == 10
    results = {}

    def run(unroll):
        if unroll not in results:
            results[unroll] = jax.tree.map(np.asarray, sj.simulate(
                scenario, sj.geometric_pd(), sj.PAPER_PD_GAINS, jnp.array([3, 11]), loop=loop,
                record_every=FLIGHT_STEPS, unroll=unroll))
        return results[unroll]

    return run


@pytest.mark.parametrize("unroll", [3, 10])
def test_unrolled_flight_loop_equals_unroll_1(flight, unroll):
    """The step scan unrolled 3 times within each control period of 10 steps (a remainder of
    1) or 10 (the whole period) gives unroll 1's values to 1e-13 relative: metrics, histories,
    final state, flight metrics (the orthogonality error, round-off itself, to 1e-13 absolute)."""
    base, got = flight(1), flight(unroll)
    assert got.flight is not None
    for (path, a), b in zip(jax.tree_util.tree_flatten_with_path(got)[0], jax.tree.leaves(base)):
        name = jax.tree_util.keystr(path)
        scale = 1.0 if "orthogonality_error" in name else np.nanmax(np.abs(b), initial=0.0)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-13 * scale, equal_nan=True, err_msg=name)
