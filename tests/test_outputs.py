"""A result is one run's: an output folder never mixes runs (an earlier run's files are
replaced as a set, the user's own files are kept and named), a partial run is marked as
such in its manifest and seen by the next run, and a refused run writes nothing. In
process, through so3jax.commands.main, with tiny horizons (one fly compilation, shared)."""

import json
from pathlib import Path

import pytest

from so3jax import commands as cli
from so3jax.jobs import tune
from so3jax.results import io, runfolder

ROOT = Path(__file__).resolve().parents[1]
FLY = ("fly", "--T", "1", "--controllers", "pd", "--record-every", "10", "--json")


def fly(out, *extra) -> int:
    return cli.main([*FLY, "--out", str(out), *extra])


def manifest(out) -> dict:
    return json.loads((out / runfolder.MANIFEST).read_text())


def warnings_of(err: str) -> list[str]:
    return [line for line in err.splitlines() if ": warning: " in line]


def test_a_no_figures_run_after_a_figures_run_leaves_no_png(tmp_path, capsys):
    out = tmp_path / "fly"
    assert fly(out) == 0
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert "attitude.png" in pngs
    first = manifest(out)
    assert first["command"] == "fly" and first["complete"] is True
    assert sorted(first["files"]) == sorted(["metrics.json", "trajectory.npz", "telemetry/", *pngs])
    assert fly(out, "--no-figures") == 0
    assert not list(out.glob("*.png"))
    second = manifest(out)
    assert second["complete"] is True and sorted(second["files"]) == ["metrics.json", "telemetry/", "trajectory.npz"]
    assert second["settings"]["no_figures"] is True and second["fingerprint"] != first["fingerprint"]
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", "metrics.json", "telemetry", "trajectory.npz"]
    assert warnings_of(capsys.readouterr().err) == []


def test_a_users_own_files_are_left_and_named_in_one_line(tmp_path, capsys):
    out = tmp_path / "fly"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    (out / "old.png").write_bytes(b"no manifest lists it")
    assert fly(out, "--no-figures") == 0
    assert (out / "notes.txt").read_text() == "mine" and (out / "old.png").exists()
    assert warnings_of(capsys.readouterr().err) == [
        f"so3jax fly: warning: {out} holds files no so3jax run lists, left as they are: notes.txt, old.png"
    ]
    assert manifest(out)["files"] == ["metrics.json", "trajectory.npz", "telemetry/"]


def test_a_run_interrupted_while_writing_figures_is_marked_and_replaced_by_the_next(tmp_path, capsys, monkeypatch):
    import matplotlib.pyplot as plt

    def first_figure_then_ctrl_c(folder, figures):
        name, fig = next(iter(figures.items()))
        io.save_figure(fig, Path(folder) / name)
        plt.close("all")
        raise KeyboardInterrupt

    out = tmp_path / "fly"
    monkeypatch.setattr(io, "save_figures", first_figure_then_ctrl_c)
    assert fly(out) == 130
    partial = manifest(out)
    assert partial["complete"] is False and partial["finished"] is None
    assert partial["files"] == ["metrics.json", "trajectory.npz", "telemetry/", "attitude.png"]
    assert not (out / runfolder.LOCK).exists()
    monkeypatch.undo()
    capsys.readouterr()

    assert fly(out, "--no-figures") == 0
    assert warnings_of(capsys.readouterr().err) == [
        f"so3jax fly: warning: {out} holds an interrupted so3jax fly run (started {partial['started']}); replacing it"
    ]
    assert not list(out.glob("*.png")) and manifest(out)["complete"] is True


def test_a_manifest_left_incomplete_is_seen_and_its_files_removed(tmp_path, capsys):
    """As a killed writer leaves it: manifest complete=false, a stray temporary file."""
    out = tmp_path / "fly"
    out.mkdir()
    (out / "torque.png").write_bytes(b"half a run")
    (out / ".torque.png.abc123.tmp").write_bytes(b"a write that was killed")
    stale = {"command": "fly", "settings": {}, "fingerprint": "0", "started": "then", "finished": None,
             "complete": False, "files": ["torque.png", "../outside.txt"]}
    (out / runfolder.MANIFEST).write_text(json.dumps(stale))
    (tmp_path / "outside.txt").write_text("never a run's to remove")
    assert fly(out, "--no-figures") == 0
    assert "holds an interrupted so3jax fly run (started then); replacing it" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", "metrics.json", "telemetry", "trajectory.npz"]
    assert (tmp_path / "outside.txt").exists()


REFUSED = {
    "fly horizon": ("fly", "--T", "1e9"),
    "fly memory": ("fly", "--T", "1", "--max-memory", "1K"),
    "fly bad value": ("fly", "--T", "1", "--set", "control.period=-1"),
    "paper horizon": ("paper", "--T", "0"),
    "paper memory": ("paper", "--T", "1", "--max-memory", "1K"),
    "sweep memory": ("sweep", "--samples", "8", "--T", "1", "--max-memory", "1K"),
    "sweep bad value": ("sweep", "--samples", "0", "--T", "1"),
    "tune horizon": ("tune", str(ROOT / "tuning" / "pd_equal_effort.toml"), "--T", "0"),
    "tune bad value": ("tune", str(ROOT / "tuning" / "pd_equal_effort.toml"), "--set",
                       "tune.optimizer.learning_rate=-1"),
}


@pytest.mark.parametrize("argv", REFUSED.values(), ids=REFUSED.keys())
def test_a_refused_run_creates_no_folder(tmp_path, capsys, argv):
    out = tmp_path / "new" / "out"
    assert cli.main([*argv, "--out", str(out)]) == 2
    assert not (tmp_path / "new").exists()
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"so3jax {argv[0]}: error: ") and "Traceback" not in "\n".join(err)


def test_a_folder_holding_another_commands_run_is_refused_and_left_as_it_is(tmp_path, capsys):
    out = tmp_path / "run"
    with runfolder.claim(out, "fly"):
        io.write_text(out / "metrics.json", "{}")
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    for argv in (("paper", "--T", "1"), ("sweep", "--samples", "8", "--T", "1", "--resume")):
        assert cli.main([*argv, "--out", str(out)]) == 2
        assert capsys.readouterr().err.strip().splitlines()[-1] == (
            f"so3jax {argv[0]}: error: {out} holds a complete so3jax fly run; choose another --out, "
            f"or delete {out} to reuse it")
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_gains_from_a_tune_run_that_did_not_finish_are_noticed(tmp_path):
    with pytest.raises(KeyboardInterrupt), runfolder.claim(tmp_path, "tune"):
        io.write_json(tmp_path / "best_gains.json", {"controller": "pd", "gains": {"k_R": 1.0, "k_Omega": 2.0}})
        raise KeyboardInterrupt
    with pytest.warns(UserWarning, match="did not finish"):
        gains = tune.resolve_gains("pd", str(tmp_path / "best_gains.json"), "float64")
    assert float(gains.k_R) == 1.0
