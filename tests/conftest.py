"""Tests run in float64 with strict dtype promotion (no silent float32 <-> float64 mixing).

In-process programs compile with XLA's backend optimizations and expensive LLVM passes off
(``jax_disable_most_optimizations``): about a third less of the compile time that dominates the
suite, the same values to round-off. A test marked ``optimized`` runs with JAX's default
settings, as a library user gets them: a bit-for-bit comparison of two differently built
programs (which XLA's optimizations make agree), a comparison with XLA's own functions, and the
goals' derivatives (XLA's simplifications drop a NaN tangent at a frequency off the peak from
jnp.max's derivative, the tangent times the 0/1 indicator of the maximum). So do the ``so3jax``
child processes, the pinned paper metrics among them (the command's configure_xla).

Compiled programs are shared through a persistent JAX compilation cache in a temporary
folder made fresh for each test process (so a run never reads executables from an
earlier one), and the ``so3jax`` child processes the tests start share one of their own
inside it (SO3JAX_CACHE_DIR, which the command line reads): two children that compile the
same program (``so3jax paper`` with two seeds, say) compile it once. The children's is
apart because the command line bounds its cache where ``filelock`` is installed, and a
bounded cache (JAX's eviction, which reads every entry's access time at each write) must
not be written by processes that keep no access times. The test processes' own caches are
unbounded: no eviction scan at each of their thousands of writes.
"""

import atexit
import gc
import importlib
import os
import shutil
import tempfile

import jax
import pytest

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
FEWEST_OPTIMIZATIONS = {"now": True}  # jax_disable_most_optimizations, as last set here
jax.config.update("jax_disable_most_optimizations", True)

SESSION_CACHE = tempfile.mkdtemp(prefix="so3jax-test-xla-cache-")
atexit.register(shutil.rmtree, SESSION_CACHE, ignore_errors=True)
jax.config.update("jax_compilation_cache_dir", SESSION_CACHE)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
os.environ["SO3JAX_CACHE_DIR"] = os.path.join(SESSION_CACHE, "children")  # the child processes' cache
os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"


MAPS_BEFORE_RELEASE = 30_000  # the kernel's default vm.max_map_count: 65 530


def _memory_maps() -> int:
    """The memory maps of this process (0 where /proc does not tell)."""
    try:
        with open("/proc/self/maps") as maps:
            return sum(1 for _ in maps)
    except OSError:
        return 0


@pytest.fixture(scope="module", autouse=True)
def release_compiled_programs():
    """After a test file, JAX's in-memory caches are cleared once this process holds more
    than MAPS_BEFORE_RELEASE memory maps. Each compiled program maps its code, and a test
    worker that kept every program of its share of the suite would pass the kernel's limit
    (vm.max_map_count), where LLVM aborts the process. A program compiled again after a
    release comes from the persistent cache."""
    yield
    if _memory_maps() > MAPS_BEFORE_RELEASE:
        jax.clear_caches()
        gc.collect()


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """XLA's default optimizations for a test marked ``optimized`` (and the module fixtures its
    setup builds), the fewest for the others. The setting is not part of JAX's in-memory cache
    keys, so those caches are cleared where it changes (the persistent cache's keys hold it)."""
    fewest = item.get_closest_marker("optimized") is None
    if fewest != FEWEST_OPTIMIZATIONS["now"]:
        jax.clear_caches()
        jax.config.update("jax_disable_most_optimizations", fewest)
        FEWEST_OPTIMIZATIONS["now"] = fewest


@pytest.fixture
def same_xla_optimizations() -> dict:
    """The environment a child process reads to compile with this test's XLA optimizations."""
    return {"JAX_DISABLE_MOST_OPTIMIZATIONS": "1" if FEWEST_OPTIMIZATIONS["now"] else "0"}


@pytest.fixture
def cli_env(monkeypatch, tmp_path):
    """so3jax.commands.main in this process, from tmp_path: no persistent cache, XLA_FLAGS untouched."""
    monkeypatch.setenv("SO3JAX_CACHE_DIR", "")
    monkeypatch.setenv("SO3JAX_KEEP_XLA_FLAGS", "1")
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.fixture
def in_process(cli_env, monkeypatch):
    """cli_env, failing the test where a rollout is traced or compiled."""
    def compiled(*args, **kwargs):
        raise AssertionError("reached compilation")

    monkeypatch.setattr(importlib.import_module("so3jax.sim.rollout"), "_rollout", compiled)
    return cli_env
