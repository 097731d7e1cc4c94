"""A run folder never mixes runs: a resume under other settings is refused before anything
is written (naming the settings), a refused resume leaves the folder byte for byte as it
was, the manifest's start time is the run's, and a comparison's bootstrap too large for
the memory is refused before any work. No compilation."""

import itertools
import json
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from so3jax import commands as cli
from so3jax.jobs import compare
from so3jax.missions import keys
from so3jax.results import io, runfolder
from so3jax.sim import memory

ROOT = Path(__file__).resolve().parents[1]


def snapshot(folder: Path) -> dict:
    """Every file under ``folder``, by relative path, with its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def finished_run(out: Path, command: str, settings: dict) -> dict:
    """A complete run of ``settings`` in ``out`` (one file); its snapshot."""
    with runfolder.claim(out, command, settings):
        io.write_text(out / "result.txt", "result")
    return snapshot(out)


def test_changed_settings_are_named_by_their_dotted_path():
    before = {"T": 1.0, "tune": {"validation": {"seeds": [1, 2]}, "iterations": 3}, "gone": 0}
    after = {"T": 1.0, "tune": {"validation": {"seeds": [1, 3]}, "iterations": 3}, "new": 0}
    assert runfolder.changed_settings(before, after) == ["gone", "new", "tune.validation.seeds"]
    assert runfolder.changed_settings(before, json.loads(json.dumps(before))) == []


def test_a_resume_under_other_settings_is_refused_and_leaves_the_folder_as_it_was(tmp_path):
    out = tmp_path / "c"
    before = finished_run(out, "compare", {"T": 1.0, "held_out": {"seeds": [1]}})
    with pytest.raises(ValueError, match=r"^--resume: .* holds a so3jax compare run with other settings "
                                         r"\(held_out\.seeds\); resume it with its own settings"):
        with runfolder.claim(out, "compare", {"T": 1.0, "held_out": {"seeds": [2]}}, resume=True, may_change=()):
            pytest.fail("the block must not run")
    assert snapshot(out) == before


def test_a_resume_refused_inside_its_block_before_writing_leaves_the_folder_as_it_was(tmp_path):
    """As a part's own check refuses it (a checkpoint, the memory) after the run took its folder."""
    out = tmp_path / "c"
    settings = {"T": 1.0}
    before = finished_run(out, "compare", settings)
    with pytest.raises(ValueError, match="refused"):
        with runfolder.claim(out, "compare", settings, resume=True) as run:
            run.start()
            raise ValueError("refused")
    assert snapshot(out) == before
    assert runfolder.read_manifest(out)["complete"] is True


def test_a_resume_may_change_only_what_the_job_names(tmp_path):
    out = tmp_path / "s"
    finished_run(out, "sweep", {"sweep": {"samples": 8, "seed": 0}})
    more = {"sweep": {"samples": 16, "seed": 0}}
    with runfolder.claim(out, "sweep", more, resume=True, may_change=("sweep.samples",)):
        io.write_text(out / "more.txt", "more")
    manifest = runfolder.read_manifest(out)
    assert manifest["settings"] == more and manifest["complete"] and manifest["files"] == ["result.txt", "more.txt"]
    before = snapshot(out)
    with pytest.raises(ValueError, match=r"other settings \(sweep\.seed\)"):
        with runfolder.claim(out, "sweep", {"sweep": {"samples": 16, "seed": 1}}, resume=True,
                             may_change=("sweep.samples",)):
            pass
    assert snapshot(out) == before


def test_started_is_when_the_run_started_and_a_resume_keeps_it(tmp_path, monkeypatch):
    clock = itertools.count()
    monkeypatch.setattr(runfolder, "_now", lambda: f"t{next(clock)}")
    out = tmp_path / "f"
    with runfolder.claim(out, "fly", {"T": 1.0}):  # t0
        runfolder._now()  # t1: the computation, before the first file
        io.write_text(out / "metrics.json", "{}")
    first = runfolder.read_manifest(out)
    assert first["started"] == "t0" and first["finished"] == "t2"
    with runfolder.claim(out, "fly", {"T": 1.0}, resume=True):  # t3
        io.write_text(out / "more.json", "{}")
    resumed = runfolder.read_manifest(out)
    assert resumed["started"] == "t0" and resumed["finished"] == "t4"


def _comparison(validation_seeds, bootstrap=200) -> compare.CompareConfig:
    """A fixed-gains candidate (judged on the held-out seeds) and a tuned one."""
    return compare.parse({"mission": "../missions/paper.toml", "T": 1.0,
                          "inertia": {"J0": {"nominal": [list(row) for row in keys.BODY_J0]}},  # dispersed as a body
                          "compare": {"bootstrap": bootstrap,
                                      "candidates": {"fixed": {"controller": "pd", "gains": "paper"},
                                                     "tuned": {"controller": "pd"}}},
                          "sweep": {"samples": 8, "chunk": 8},
                          "tune": {"iterations": 1, "train": {"seeds": [0]},
                                   "validation": {"seeds": validation_seeds}}},
                         ROOT / "comparisons")


def test_compare_resume_with_other_held_out_seeds_is_refused_before_any_work(tmp_path, monkeypatch):
    def no_work(*args, **kwargs):
        raise AssertionError("a refused resume must do no work")

    monkeypatch.setattr(compare, "tune", no_work)
    monkeypatch.setattr(compare, "held_out", no_work)
    out = tmp_path / "c"
    with runfolder.claim(out, "compare", compare.describe(_comparison([1]))):
        io.write_json(out / "held_out" / "fixed.json", {"tuned": {"gains": {}}})
        io.write_json(out / "compare.json", {})
    before = snapshot(out)
    with pytest.raises(ValueError, match=r"other settings \(campaigns\.fixed\.tune\.validation\.seeds, "
                                         r"campaigns\.tuned\.tune\.validation\.seeds\)"):
        compare.run(_comparison([2]), out, resume=True)
    assert snapshot(out) == before


def test_the_bootstrap_bound_is_the_memory_available(monkeypatch):
    monkeypatch.setattr(memory, "available", lambda: compare.BOOTSTRAP_BYTES * 8 * 1000)
    compare.check_bootstrap(1000, 8)
    with pytest.raises(ValueError, match=r"^compare\.bootstrap = 1001 \(resamples of 8 samples\) needs about .* "
                                         r"more than the .* available; lower compare\.bootstrap to at most 1000$"):
        compare.check_bootstrap(1001, 8)


def test_the_bootstrap_estimate_holds_the_pairing_s_peak():
    x = np.random.default_rng(0).lognormal(0.0, 0.3, 1000)
    tracemalloc.start()
    try:
        compare.paired(x, 0.9 * x, 2000, np.random.default_rng(1))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    estimate = compare.BOOTSTRAP_BYTES * 2000 * 1000
    assert estimate / 2 < peak <= estimate


def test_a_huge_bootstrap_is_one_line_and_exit_2_before_anything_is_written(tmp_path, capsys, monkeypatch):
    def no_work(*args, **kwargs):
        raise AssertionError("a refused comparison must do no work")

    monkeypatch.setattr(compare, "tune", no_work)
    out = tmp_path / "c"
    code = cli.main(["compare", str(ROOT / "comparisons" / "paper.toml"), "--out", str(out),
                     "--set", "sweep.samples=8", "--set", "compare.bootstrap=1000000000000"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and not out.exists() and "Traceback" not in "\n".join(err)
    assert err[-1].startswith("so3jax compare: error: compare.bootstrap = 1000000000000 (resamples of 8 samples)")
