"""Tests run in float64 with strict dtype promotion (no silent float32 <-> float64 mixing).

Programs compile with XLA's backend optimizations, its expensive LLVM passes and its CPU fusion
emitters off (``jax_disable_most_optimizations``, ``--xla_cpu_use_fusion_emitters=false`` in
XLA_FLAGS, which the ``so3jax`` child processes the tests start inherit): about half the compile
time that dominates the suite, the same values to round-off. They compile with the ``so3jax``
command's code-generation settings (``configure_cpu_codegen``: a while loop as one CPU kernel,
the call graph flattened after fusion), which the child processes inherit as the command's own:
a third less compile time for a rollout's derivatives, the same values bit for bit. Each
program's machine code is generated in one piece (``--xla_cpu_parallel_codegen_split_count=1``):
the workers already keep every core busy, and split across threads a compilation takes 10-15 %
more CPU time (the same code). A test marked ``optimized`` runs in a fresh interpreter with the
settings the suite was started with (JAX's defaults, as a user's program compiles; its code too
generated in one piece): the marked tests of a file in one such process, their reports read back
through pytest's own serialization. Those are the bit-for-bit comparisons of two differently
built programs (which XLA's default pipeline makes agree), comparisons with XLA's own functions,
and the pinned paper metrics.

Compiled programs are shared through a persistent JAX compilation cache in a temporary
folder made fresh for each run (so a run never reads executables from an earlier one) and
shared by its test processes (xdist's workers, the optimized processes): a program that
test files on both workers compile is compiled once. The ``so3jax`` child processes the
tests start share one of their own inside it (SO3JAX_CACHE_DIR, which the command line
reads): two children that compile the same program (``so3jax paper`` with two seeds, say)
compile it once; a child that forces host devices adds them to the suite's XLA_FLAGS
(tests/_host_devices.py). The children's is apart because the command line bounds its
cache where ``filelock`` is installed, and a bounded cache (JAX's eviction, which reads
every entry's access time at each write) must not be written by processes that keep no
access times. The test processes' cache is unbounded: no eviction scan at each of their
thousands of writes.
"""

import atexit
import gc
import importlib
import json
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile

import jax
import pytest

from so3jax.parallel.xla_flags import configure_cpu_codegen

# What the suite changes in the environment; a test marked ``optimized`` runs with them as started.
SETTINGS = ("XLA_FLAGS", "JAX_DISABLE_MOST_OPTIMIZATIONS")
ONE_PIECE = "--xla_cpu_parallel_codegen_split_count=1"  # the same machine code, less CPU to make it
OPTIMIZED = os.environ.get("SO3JAX_TEST_OPTIMIZED") == "1"  # this process runs marked tests
if not OPTIMIZED and "SO3JAX_TEST_STARTED_WITH" not in os.environ:  # set once: xdist's workers inherit it
    os.environ["SO3JAX_TEST_STARTED_WITH"] = json.dumps({k: os.environ.get(k) for k in SETTINGS})
    fast = f"--xla_cpu_use_fusion_emitters=false {ONE_PIECE}"
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {fast}".strip()
    configure_cpu_codegen()  # the command's code generation (a setting already in XLA_FLAGS wins)
    os.environ["JAX_DISABLE_MOST_OPTIMIZATIONS"] = "1"  # this process's and its children's setting
jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
jax.config.update("jax_disable_most_optimizations", not OPTIMIZED)

if "SO3JAX_TEST_CACHE" not in os.environ:  # made once per run: xdist's workers inherit it
    os.environ["SO3JAX_TEST_CACHE"] = tempfile.mkdtemp(prefix="so3jax-test-xla-cache-")
    atexit.register(shutil.rmtree, os.environ["SO3JAX_TEST_CACHE"], ignore_errors=True)
SESSION_CACHE = os.environ["SO3JAX_TEST_CACHE"]
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


REPORTS = "SO3JAX_TEST_REPORTS"  # the file an optimized process writes its reports to
_optimized_reports: dict = {}  # test file -> {nodeid: [TestReport]} of its marked tests


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    """In an optimized process, each report is also written for the process that started it."""
    report = yield
    if OPTIMIZED and os.environ.get(REPORTS):
        with open(os.environ[REPORTS], "a") as f:
            f.write(json.dumps(item.config.hook.pytest_report_to_serializable(config=item.config, report=report))
                    + "\n")
    return report


def _run_optimized(item) -> dict:
    """{nodeid: [reports]} of the marked tests of item's file, run in one fresh interpreter with
    the settings the suite was started with."""
    marked = [i.nodeid for i in item.session.items if i.path == item.path and i.get_closest_marker("optimized")]
    env = {k: v for k, v in os.environ.items() if k not in SETTINGS}
    env.update({k: v for k, v in json.loads(os.environ["SO3JAX_TEST_STARTED_WITH"]).items() if v is not None})
    env["XLA_FLAGS"] = f"{env.get('XLA_FLAGS', '')} {ONE_PIECE}".strip()
    with tempfile.TemporaryDirectory() as tmp:
        env.update(SO3JAX_TEST_OPTIMIZED="1", **{REPORTS: os.path.join(tmp, "reports.jsonl")})
        proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:xdist",
                               *marked], cwd=item.config.rootpath, env=env, capture_output=True,
                              text=True, timeout=1800)
        written = pathlib.Path(env[REPORTS])
        lines = written.read_text().splitlines() if written.exists() else []
    reports = {}
    for line in lines:
        report = item.config.hook.pytest_report_from_serializable(config=item.config, data=json.loads(line))
        reports.setdefault(report.nodeid, []).append(report)
    tail = f"the optimized process (exit {proc.returncode}) gave no report:\n{(proc.stdout + proc.stderr)[-5000:]}"
    for nodeid in marked:
        if not any(r.when == "teardown" for r in reports.get(nodeid, [])):
            reports[nodeid] = [pytest.TestReport(nodeid, item.location, {}, "failed", tail, "call")]
    return reports


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_protocol(item, nextitem):
    """A test marked ``optimized`` is run (with its file's other marked tests) in a fresh
    interpreter with the settings the suite was started with; its reports are logged here."""
    if OPTIMIZED or item.get_closest_marker("optimized") is None:
        return None
    if item.path not in _optimized_reports:
        _optimized_reports[item.path] = _run_optimized(item)
    item.ihook.pytest_runtest_logstart(nodeid=item.nodeid, location=item.location)
    for report in _optimized_reports[item.path][item.nodeid]:
        item.ihook.pytest_runtest_logreport(report=report)
    item.ihook.pytest_runtest_logfinish(nodeid=item.nodeid, location=item.location)
    return True


_exit_status = [0]


def pytest_sessionfinish(session, exitstatus):
    _exit_status[0] = int(exitstatus)


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    """A test process that reports to another (an xdist worker, its results sent; an optimized
    process, its reports written) ends here, without Python's teardown: JAX's exit handler
    frees every program the process compiled, over 10 s after a worker's share of the suite,
    and xdist's controller waits those 10 s before it kills the worker."""
    if os.environ.get("PYTEST_XDIST_WORKER") or OPTIMIZED:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(_exit_status[0])


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
