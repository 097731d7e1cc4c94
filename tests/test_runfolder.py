"""Output folders: checked before the work without creating anything, locked while a run
writes, stale locks reported, listed in a manifest; a tuning checkpoint that cannot be
read is a one-line error naming it."""

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from so3jax.jobs import tune
from so3jax.results import runfolder

ROOT = Path(__file__).resolve().parents[1]
HOLD = ("import sys, time\nfrom so3jax.results import runfolder\nwith runfolder.claim(sys.argv[1], 'sweep') as run:\n"
        "    run.start()\n    print('locked', flush=True)\n    time.sleep(120)\n")


def cli(*args, cwd):
    """``so3jax ARGS`` in a child process (the session's compilation cache: tests/conftest.py)."""
    return subprocess.run([sys.executable, "-m", "so3jax.commands", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=600)


@pytest.fixture
def holder(tmp_path):
    """Another process holding the lock of tmp_path / 'out'."""
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(out)], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        assert proc.stdout.readline().strip() == "locked"
        yield out, proc
    finally:
        proc.kill()
        proc.wait(timeout=30)


def test_fingerprint_depends_on_every_value_and_not_on_key_order():
    a = runfolder.fingerprint({"T": 10.0, "seeds": (0, 1)})
    assert a == runfolder.fingerprint({"seeds": [0, 1], "T": 10.0})
    assert a != runfolder.fingerprint({"T": 10.0, "seeds": (0, 2)})
    assert len(a) == 16 and int(a, 16) >= 0


@pytest.mark.parametrize("where", ["file", "under_a_file", "proc"])
def test_an_unwritable_output_folder_is_an_error_before_the_work(tmp_path, where):
    (tmp_path / "f").write_text("x")
    out = {"file": tmp_path / "f", "under_a_file": tmp_path / "f" / "sub", "proc": Path("/proc/so3jax-out")}[where]
    with pytest.raises(ValueError, match="choose another --out"):
        with runfolder.claim(out, "paper"):
            pytest.fail("the block must not run")


def test_the_cli_refuses_an_unwritable_out_with_one_line_and_exit_2(tmp_path):
    (tmp_path / "f").write_text("x")
    proc = cli("paper", "--T", "1", "--out", str(tmp_path / "f"), cwd=tmp_path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines() == [
        f"so3jax paper: error: output folder {tmp_path / 'f'} is a file; choose another --out"]


def test_the_lock_is_held_during_the_block_and_released_after_it_even_on_error(tmp_path):
    with runfolder.claim(tmp_path, "sweep"):
        owner = json.loads((tmp_path / runfolder.LOCK).read_text())
        assert owner["pid"] == os.getpid() and owner["host"] == socket.gethostname() and owner["command"] == "sweep"
    assert not (tmp_path / runfolder.LOCK).exists()
    with pytest.raises(RuntimeError), runfolder.claim(tmp_path, "tune"):
        raise RuntimeError
    assert not (tmp_path / runfolder.LOCK).exists()


def test_checking_a_new_folder_creates_nothing_and_a_block_that_writes_nothing_leaves_nothing(tmp_path):
    out = tmp_path / "a" / "b"
    assert runfolder.check_writable(out) == out and not (tmp_path / "a").exists()
    with runfolder.claim(out, "paper", {"T": 1.0}) as run:
        assert run.out == out and not (tmp_path / "a").exists()
    assert not (tmp_path / "a").exists()


def test_the_first_file_makes_the_folder_and_the_manifest_says_complete_only_at_the_end(tmp_path):
    from so3jax.results.io import write_text

    out = tmp_path / "out"
    with runfolder.claim(out, "fly", {"T": 2.0, "out": out}):
        write_text(out / "metrics.json", "{}")
        manifest = runfolder.read_manifest(out)
        assert manifest["complete"] is False and manifest["files"] == ["metrics.json"]
        assert manifest["settings"] == {"T": 2.0, "out": str(out)} and (out / runfolder.LOCK).exists()
        write_text(out / "sub" / "x.txt", "x")  # a file in a subfolder: the run owns the subfolder
    manifest = runfolder.read_manifest(out)
    assert manifest["complete"] is True and manifest["files"] == ["metrics.json", "sub/"] and manifest["finished"]
    assert manifest["fingerprint"] == runfolder.fingerprint({"T": 2.0, "out": str(out)})
    assert not (out / runfolder.LOCK).exists()


def test_a_run_replaces_the_earlier_runs_files_and_a_resumed_run_keeps_them(tmp_path, capsys):
    from so3jax.results.io import write_text

    with runfolder.claim(tmp_path, "sweep"):
        for name in ("a.txt", "chunks/c.npz"):
            write_text(tmp_path / name, name)
    (tmp_path / "mine.txt").write_text("the user's")
    with runfolder.claim(tmp_path, "sweep", resume=True):
        write_text(tmp_path / "b.txt", "b")
    assert runfolder.read_manifest(tmp_path)["files"] == ["a.txt", "chunks/", "b.txt"]
    assert (tmp_path / "chunks" / "c.npz").exists() and "left as they are" not in capsys.readouterr().err
    with runfolder.claim(tmp_path, "sweep"):
        write_text(tmp_path / "b.txt", "b")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.txt", "manifest.json", "mine.txt"]
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"so3jax sweep: warning: {tmp_path} holds files no so3jax run lists, left as they are: mine.txt"]


def test_another_commands_run_or_an_unreadable_manifest_is_refused_before_anything_is_written(tmp_path):
    from so3jax.results.io import write_text

    with runfolder.claim(tmp_path, "tune"):
        write_text(tmp_path / "history.csv", "x")
    before = sorted(tmp_path.iterdir())
    with pytest.raises(ValueError, match=f"{tmp_path} holds a complete so3jax tune run; choose another --out"):
        with runfolder.claim(tmp_path, "sweep", resume=True):
            pytest.fail("the block must not run")
    (tmp_path / runfolder.MANIFEST).write_text('{"command": "tune"')
    with pytest.raises(ValueError, match=r"manifest\.json cannot be read .*choose another --out"):
        with runfolder.claim(tmp_path, "tune"):
            pass
    assert sorted(tmp_path.iterdir()) == before


def test_a_second_run_into_a_locked_folder_is_refused(holder):
    out, proc = holder
    with pytest.raises(ValueError, match=rf"in use by so3jax sweep \(process {proc.pid} on {socket.gethostname()}"):
        with runfolder.claim(out, "sweep"):
            pytest.fail("the block must not run")
    assert json.loads((out / runfolder.LOCK).read_text())["pid"] == proc.pid  # the owner keeps its lock


def test_two_commands_against_one_out_the_second_gets_one_line_and_exit_2(holder):
    out, proc = holder
    result = cli("sweep", "--samples", "8", "--T", "10", "--out", str(out), cwd=out.parent)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    error = result.stderr.strip().splitlines()[-1]  # warnings about the config may come first
    assert error.startswith("so3jax sweep: error: ") and f"in use by so3jax sweep (process {proc.pid}" in error
    assert not (out / "sweep.json").exists()


def test_a_stale_lock_from_a_dead_process_is_reported_and_taken_over(tmp_path, capsys):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    pid = int(dead.stdout)
    lock = tmp_path / runfolder.LOCK
    lock.write_text(json.dumps({"pid": pid, "host": socket.gethostname(), "command": "tune", "since": 0}))
    with runfolder.claim(tmp_path, "tune"):
        assert json.loads(lock.read_text())["pid"] == os.getpid()
    assert f"locked by process {pid}, which is gone" in capsys.readouterr().err


def test_a_lock_from_another_host_is_not_broken(tmp_path):
    lock = tmp_path / runfolder.LOCK
    lock.write_text(json.dumps({"pid": 1, "host": "elsewhere.invalid", "command": "sweep", "since": 0}))
    with pytest.raises(ValueError, match="process 1 on elsewhere.invalid"):
        with runfolder.claim(tmp_path, "sweep"):
            pass
    lock.write_text("not json")
    with pytest.raises(ValueError, match="not a valid lock file"):
        with runfolder.claim(tmp_path, "sweep"):
            pass


def _campaign():
    return tune.parse_config(
        {"T": 10.0, "tune": {"controller": "pd", "iterations": 1, "train": {"seeds": [0]},
                             "validation": {"seeds": [1]}}}
    )


def test_a_corrupt_checkpoint_names_the_file_and_the_remedy(tmp_path):
    (tmp_path / tune.CHECKPOINT).write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(ValueError, match=r"checkpoint\.npz cannot be read .*delete it to start the run over"):
        tune.tune(_campaign(), tmp_path, resume=True, progress=False)


def test_tune_refuses_a_locked_run_folder(holder):
    out, proc = holder
    with pytest.raises(ValueError, match=f"process {proc.pid}"):
        tune.tune(_campaign(), out, progress=False)
    assert not (out / tune.CHECKPOINT).exists()


def test_a_shipped_campaign_runs_into_results_and_a_failed_run_claims_no_gains(tmp_path):
    shipped = ROOT / "tuning" / "pd_equal_effort"
    before = {p.name: p.read_bytes() for p in shipped.iterdir()}
    proc = cli("tune", str(ROOT / "tuning" / "pd_equal_effort.toml"), "--T", "1", "--iterations", "1",
               "--set", "tune.initial_gains={k_R=1e12, k_Omega=25.0}", cwd=tmp_path)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    run = tmp_path / "results" / "tune" / "pd_equal_effort"
    assert "non-finite cost" in proc.stderr and "no gains were written" in proc.stderr
    assert (run / "history.csv").exists() and not (run / "best_gains.json").exists()
    assert {p.name: p.read_bytes() for p in shipped.iterdir()} == before
