"""Several processes on JAX's runtime, tried with two local processes on the CPU (gloo
collectives, coordinator on 127.0.0.1): the same sweep files as one process with as many
devices as a chunk runs over in either layout, a stopped process reported and the sweep finished by
--resume, the tuned gains of one process, a coordinator that cannot be reached or peers
that never join reported within the timeout, processes that do not share the output
folder told so, an error in one process alone (process 0's or another's) told to the
others. Every process's exit code and stderr are checked: one error line, its last, and no
abort of JAX's runtime, whichever process leaves first. Every process is bounded in time
and stopped by the test."""

import argparse
import json
import os
import re
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from so3jax.parallel import distributed
from tests._host_devices import host_devices_env

SWEEP = ("sweep", "--samples", "24", "--T", "100", "--chunk", "8", "--set", "dt=0.5")
LIMIT_S = 400


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start(args, cwd, devices=1, **popen):
    env = host_devices_env(devices, SO3JAX_CACHE_DIR="")
    return subprocess.Popen([sys.executable, "-m", "so3jax.commands", *args], cwd=cwd, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, **popen)


def _finish(procs, limit=LIMIT_S):
    """(returncode, stdout, stderr) of each process; every one is killed past ``limit`` seconds."""
    out, deadline = [], time.monotonic() + limit
    try:
        for p in procs:
            stdout, stderr = p.communicate(timeout=max(1.0, deadline - time.monotonic()))
            out.append((p.returncode, stdout, stderr))
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.communicate()
    return out


# A traceback, or JAX's runtime aborting the process (a C++ check failure or fatal log line).
ABORT = re.compile(r"Traceback|Check fail|Terminating process|Fatal|^F\d{4} ", re.MULTILINE)


def _clean(stderr):
    assert not ABORT.search(stderr), stderr[-3000:]


def _error(stderr, command="sweep"):
    """The process's one error line, which is the last line of its stderr."""
    _clean(stderr)
    errors = [line for line in stderr.splitlines() if line.startswith(f"so3jax {command}: error: ")]
    assert len(errors) == 1 and stderr.strip().splitlines()[-1] == errors[0], stderr[-3000:]
    return errors[0]


def _pair(out, cwd, *extra):
    port = _port()
    common = (*SWEEP, *extra, "--out", str(out), "--coordinator", f"127.0.0.1:{port}", "--num-processes", "2",
              "--timeout", "60")
    return [_start((*common, "--process-id", str(i)), cwd) for i in (0, 1)]


def _files(out):
    with np.load(out / "samples.npz") as f:
        arrays = {k: f[k] for k in f.files}
    summary = json.loads((out / "summary.json").read_text())
    summary.pop("run")  # wall times, rates
    return (out / "samples.csv").read_text(), arrays, summary


@pytest.fixture(scope="module")
def one_process(tmp_path_factory):
    """The sweep in one process, with one device and with two: {devices: files}."""
    files = {}
    for devices in (1, 2):
        out = tmp_path_factory.mktemp(f"one-{devices}") / "out"
        [(rc, _, stderr)] = _finish([_start((*SWEEP, "--out", str(out)), out.parent, devices=devices)])
        assert rc == 0, stderr
        files[devices] = _files(out)
    return files


@pytest.mark.parametrize("layout, devices", [("chunks", 1), ("mesh", 2)])
def test_two_processes_write_what_one_process_with_a_chunks_devices_writes(one_process, tmp_path, layout, devices):
    """Two processes of one device each: whole chunks ("chunks") run over one device, as in
    one process with one device; "mesh" runs each chunk over both, as one process with two."""
    results = _finish(_pair(tmp_path / "out", tmp_path, "--layout", layout))
    assert [rc for rc, _, _ in results] == [0, 0], results[0][2][-2000:] + results[1][2][-2000:]
    for _, _, stderr in results:
        _clean(stderr)
    ours = [[line for line in stdout.splitlines() if not line.startswith("[Gloo]")] for _, stdout, _ in results]
    assert any("adaptive vs pd" in line for line in ours[0]) and ours[1] == []  # process 0 reports, once
    csv, arrays, summary = _files(tmp_path / "out")
    expected = one_process[devices]
    assert csv == expected[0] and summary == expected[2]
    run = json.loads((tmp_path / "out" / "summary.json").read_text())["run"]
    assert (run["processes"], run["devices"], run["layout"]) == (2, 2, layout)
    assert not (tmp_path / "out" / "chunks" / ".claims").exists()
    for key, value in expected[1].items():
        np.testing.assert_array_equal(arrays[key], value, err_msg=key)


def test_a_stopped_process_is_reported_and_resume_finishes_the_sweep(one_process, tmp_path):
    out = tmp_path / "out"
    procs = _pair(out, tmp_path)
    deadline = time.monotonic() + LIMIT_S
    while not list((out / "chunks").glob("*.npz")) and time.monotonic() < deadline and procs[0].poll() is None:
        time.sleep(0.2)
    procs[1].kill()  # mid-sweep: the adaptive controller still has to compile and run
    (rc, _, stderr), (killed, _, _) = _finish(procs)
    assert (rc, killed) == (1, -9), stderr[-3000:]
    line = _error(stderr)
    assert "so3jax sweep: error: process 0 of 2 stopped at " in line and "rerun every process with --resume" in line
    assert not (out / "summary.json").exists()

    results = _finish(_pair(out, tmp_path, "--resume"))
    assert [rc for rc, _, _ in results] == [0, 0], results[0][2][-2000:] + results[1][2][-2000:]
    for _, _, stderr in results:
        _clean(stderr)
    csv, arrays, summary = _files(out)
    assert csv == one_process[1][0] and summary == one_process[1][2]  # whole chunks, each over one device


def test_a_coordinator_that_cannot_be_reached_is_reported_within_the_timeout(tmp_path):
    args = (*SWEEP, "--out", str(tmp_path / "out"), "--coordinator", f"127.0.0.1:{_port()}", "--num-processes", "2",
            "--process-id", "1", "--timeout", "3")
    [(rc, _, stderr)] = _finish([_start(args, tmp_path)], limit=120)  # killed (-9) past the limit
    assert rc == 2, stderr[-2000:]
    assert "process 1 could not reach the coordinator" in _error(stderr)
    assert not (tmp_path / "out").exists()  # nothing written


def test_a_process_whose_peers_never_join_stops_at_the_timeout_with_one_line(tmp_path):
    args = (*SWEEP, "--out", str(tmp_path / "out"), "--coordinator", f"127.0.0.1:{_port()}", "--num-processes", "2",
            "--process-id", "0", "--timeout", "3")
    [(rc, _, stderr)] = _finish([_start(args, tmp_path)], limit=120)  # killed (-9) past the limit
    assert rc == 1, stderr[-2000:]
    assert "process 0 of 2: not every process joined the run" in _error(stderr)
    assert not (tmp_path / "out").exists()


def test_processes_that_do_not_share_the_output_folder_are_told(tmp_path):
    port = _port()
    procs = [_start((*SWEEP, "--out", str(tmp_path / f"out{i}"), "--coordinator", f"127.0.0.1:{port}",
                     "--num-processes", "2", "--timeout", "60", "--process-id", str(i)), tmp_path) for i in (0, 1)]
    for i, (rc, _, stderr) in enumerate(_finish(procs, limit=200)):
        assert rc == 2, stderr[-2000:]
        line = _error(stderr)
        assert f"process(es) 1 of 2 do not see {tmp_path / f'out{i}'} as process 0 writes it" in line
        assert line.endswith("every process must share the output folder (a shared filesystem)")
    assert not list(tmp_path.glob("out*/chunks/*.npz"))


def test_an_error_in_process_0_alone_stops_the_others(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    owner = {"pid": os.getpid(), "host": socket.gethostname(), "command": "sweep", "since": time.time()}
    (out / ".so3jax.lock").write_text(json.dumps(owner))  # process 0 alone takes the lock: it fails there
    (rc0, _, err0), (rc1, _, err1) = _finish(_pair(out, tmp_path), limit=200)
    assert (rc0, rc1) == (2, 1), err0[-2000:] + err1[-2000:]
    assert f"{out} is in use by so3jax sweep (process {os.getpid()} on" in _error(err0)
    assert _error(err1) == ("so3jax sweep: error: process 1 of 2 stopped at checking the output folder: "
                            "process(es) 0 of 2 stopped with an error (see its message)")


def test_an_error_in_another_process_alone_stops_process_0(tmp_path):
    port = _port()
    common = (*SWEEP, "--out", str(tmp_path / "out"), "--coordinator", f"127.0.0.1:{port}", "--num-processes", "2",
              "--timeout", "60", "--process-id")
    procs = [_start((*common, "0"), tmp_path), _start((*common, "1", "--set", "bogus=1"), tmp_path)]
    (rc0, _, err0), (rc1, _, err1) = _finish(procs, limit=200)
    assert (rc0, rc1) == (1, 2), err0[-2000:] + err1[-2000:]
    assert _error(err1).startswith(
        "so3jax sweep: error: unknown config key(s): bogus; allowed: mission, sweep, dispersions")
    assert _error(err0) == ("so3jax sweep: error: process 0 of 2 stopped at checking the output folder: "
                            "process(es) 1 of 2 stopped with an error (see its message)")


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"coordinator": "localhost", "num_processes": 2, "process_id": 0}, "HOST:PORT"),
        ({"coordinator": "127.0.0.1:1", "num_processes": 2, "process_id": 2}, "--process-id must be in 0..1"),
        ({"coordinator": "127.0.0.1:1", "num_processes": 0, "process_id": 0}, "--num-processes must be at least 1"),
        ({"num_processes": 2}, "needs --coordinator, --num-processes and --process-id"),
        ({"coordinator": "127.0.0.1:1", "num_processes": 2, "process_id": 0, "timeout": 0},
         "--timeout must be positive"),
    ],
)
def test_bad_settings_are_one_line_errors_before_joining(settings, message, monkeypatch):
    for key in ("SLURM_NTASKS", "OMPI_COMM_WORLD_SIZE", "SO3JAX_COORDINATOR", "SO3JAX_NUM_PROCESSES",
                "SO3JAX_PROCESS_ID"):
        monkeypatch.delenv(key, raising=False)
    args = argparse.Namespace(**{"distributed": True, "coordinator": None, "num_processes": None, "process_id": None,
                                 "timeout": 60, **settings})
    with pytest.raises(ValueError, match=message):
        distributed.initialize(args)


def test_one_process_runs_need_no_setting(monkeypatch):
    for key in ("SLURM_NTASKS", "OMPI_COMM_WORLD_SIZE", "SO3JAX_COORDINATOR", "SO3JAX_NUM_PROCESSES",
                "SO3JAX_PROCESS_ID"):
        monkeypatch.delenv(key, raising=False)
    args = argparse.Namespace(distributed=False, coordinator=None, num_processes=None, process_id=None, timeout=60)
    assert not distributed.requested(args)
    monkeypatch.setenv("SLURM_NTASKS", "4")
    assert distributed.requested(args)


CAMPAIGN = ('T = 5.0\n[tune]\ncontroller = "pd"\niterations = 2\n[tune.train]\nseeds = [0, 1]\n'
            '[tune.validation]\nseeds = [10]\n[tune.cost]\nmode = "weighted"\n')


@pytest.mark.slow  # a minute of compilation: with -m slow
def test_two_processes_tune_to_the_gains_of_one_process(tmp_path):
    campaign = tmp_path / "campaign.toml"
    campaign.write_text(CAMPAIGN)
    [(rc, _, stderr)] = _finish([_start(("tune", str(campaign), "--out", str(tmp_path / "one")), tmp_path, devices=2)])
    assert rc == 0, stderr[-2000:]
    port = _port()
    common = ("tune", str(campaign), "--out", str(tmp_path / "two"), "--coordinator", f"127.0.0.1:{port}",
              "--num-processes", "2", "--timeout", "60")
    results = _finish([_start((*common, "--process-id", str(i)), tmp_path) for i in (0, 1)])
    assert [r[0] for r in results] == [0, 0], results[0][2][-2000:] + results[1][2][-2000:]
    for _, _, stderr in results:
        _clean(stderr)
    one, two = (json.loads((tmp_path / name / "best_gains.json").read_text()) for name in ("one", "two"))
    assert one["iteration"] == two["iteration"]
    for key, value in one["gains"].items():  # the batch mean is reduced across processes: round-off only
        np.testing.assert_allclose(two["gains"][key], value, rtol=1e-12, err_msg=key)
    assert "| pd (tuned) |" in results[0][1] and "| pd (tuned) |" not in results[1][1]  # process 0 reports
