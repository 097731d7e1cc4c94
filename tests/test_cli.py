"""``so3jax paper`` end to end, as a user runs it (a subprocess with its own JAX)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from so3jax import commands as cli

ROOT = Path(__file__).resolve().parents[1]


def run_cli(*args, cwd, **env_vars):
    """``so3jax ARGS`` in a fresh interpreter (works installed or from the source tree)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]), **env_vars}
    return subprocess.run(
        [sys.executable, "-m", "so3jax.commands", *args], cwd=cwd, capture_output=True, text=True, timeout=600, env=env
    )


def test_paper_json_and_figures(tmp_path):
    out = tmp_path / "paper"
    proc = run_cli("paper", "--T", "40", "--json", "--out", str(out), "--record-every", "50", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    assert set(report) == {"pd", "adaptive", "units", "config"}
    assert report["units"]["rmse"] == "rad/s" and report["units"]["max_angle_phase"] == "rad"
    for name in ("pd", "adaptive"):
        m = report[name]
        assert set(m) >= {"rmse", "rmse_unrotated", "effort", "rmse_phase", "effort_phase", "rms_angle_phase",
                          "max_angle_phase", "max_torque", "orthogonality_error", "diverged"}
        assert len(m["rmse_phase"]) == 3 and m["diverged"] is False
        # only phase 1 is reached in 40 s: the others have no value
        assert m["rmse_phase"][0] > 0 and m["rmse_phase"][1] is None and m["effort_phase"][1:] == [None, None]
        np.testing.assert_allclose(m["effort"], m["effort_phase"][0], rtol=1e-12)
    assert report["config"]["n_steps"] == 4000 and report["config"]["precision"] == "float64"
    assert json.loads((out / "metrics.json").read_text())["pd"] == report["pd"]
    for fig in ("fig1_inertia", "fig2_angular_velocity", "fig3_tracking_error", "fig4_torque", "fig5_torque_norm"):
        assert (out / f"{fig}.png").stat().st_size > 10_000
    assert "warning" not in proc.stderr  # the paper's own inertias: no triangle-inequality warning


def test_paper_table_and_float32(tmp_path):
    proc = run_cli("paper", "--T", "10", "--precision", "float32", "--no-figures", "--out", str(tmp_path), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "paper PD" in proc.stdout and "-31.0 %" in proc.stdout  # the paper's own RMSE ratio, recomputed
    assert json.loads((tmp_path / "metrics.json").read_text())["config"]["precision"] == "float32"


def test_paper_rejects_a_bad_horizon(tmp_path):
    proc = run_cli("paper", "--T", "10.005", "--no-figures", "--out", str(tmp_path), cwd=tmp_path)
    assert proc.returncode != 0
    assert "not a multiple of dt" in proc.stderr


def test_compilations_are_cached_and_reused(tmp_path):
    """The second identical run loads its executables from the persistent cache: same
    results, and the cache holds one entry per compiled program."""
    cache = tmp_path / "cache"
    args = ("paper", "--T", "2", "--json", "--no-figures", "--out", str(tmp_path / "p"))
    env = {"SO3JAX_CACHE_DIR": str(cache), "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0"}
    first = run_cli(*args, cwd=tmp_path, **env)
    assert first.returncode == 0, first.stderr
    entries = sorted(p.name for p in cache.iterdir())
    assert any(name.startswith("jit__simulate_jit") for name in entries)
    second = run_cli(*args, cwd=tmp_path, **env)
    assert second.returncode == 0, second.stderr
    assert sorted(p.name for p in cache.iterdir()) == entries  # nothing compiled anew
    strip = lambda out: {k: v for k, v in json.loads(out.strip().splitlines()[-1]).items() if k != "config"}
    assert strip(second.stdout) == strip(first.stdout)


# --- bad input: one line, exit code 2, before anything compiles ------------------------

TUNE_CONFIG = str(ROOT / "tuning" / "pd_equal_effort.toml")


@pytest.mark.parametrize(
    "argv,message",
    [
        (["paper", "--tau-J", "-50"], "deployment.tau_J [s] must be positive"),
        (["paper", "--tau-J", "0"], "deployment.tau_J [s] must be positive"),
        (["paper", "--T", "0"], "T (horizon) must be a positive"),
        (["paper", "--T", "-1"], "T (horizon) must be a positive"),
        (["paper", "--dt", "0"], "dt must be a positive"),
        (["paper", "--dt", "-0.01"], "dt must be a positive"),
        (["paper", "--T", "1", "--dt", "2"], "not a multiple of dt"),
        (["paper", "--record-every", "0"], "record_every must be an integer in [1, inf]"),
        (["paper", "--record-every", "-5"], "record_every must be an integer in [1, inf]"),
        (["paper", "--seed", "-1"], "seed must be an integer in [0, 2147483647]"),
        (["paper", "--set", "controllers=pd"], "so3jax paper compares pd and adaptive"),
        (["fly", "--T", "0"], "T (horizon) must be a positive"),
        (["fly", "--record-every", "0"], "record_every must be an integer in [1, inf]"),
        (["fly", "--seed", "-1"], "seed must be an integer in [0, 2147483647]"),
        (["fly", "--set", "deployment.tau_J=0.0"], "deployment.tau_J [s] must be positive"),
        (["fly", "--set", "inertia.J2.nominal=[[1.0, 2.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]"],
         "inertia J2 (inertia.J2) is not symmetric"),
        (["fly", "--set", "inertia.J1.scale=-1.0"], "inertia.J1.scale must be a finite number in [0.0, inf]"),
        (["sweep", "--samples", "0"], "samples must be an integer in [1, inf]"),
        (["sweep", "--chunk", "0"], "chunk must be an integer in [1, inf]"),
        (["sweep", "--seed", "-1"], "seed must be an integer in [0, 4294967295]"),
        (["sweep", "--set", "dispersions.deployment.tau_J=-50.0"], "deployment.tau_J [s] must be > 0"),
        (["sweep", "--set", "dispersions.deployment.tau_J=0.0"], "deployment.tau_J [s] must be > 0"),
        (["sweep", "--set", 'dispersions.deployment.tau_J={dist="uniform", low=400.0, high=200.0}'],
         "uniform needs low <= high"),
        (["sweep", "--set", 'dispersions.disturbance.noise_std={dist="normal", mean=0.025, std=-1.0}'],
         "std / sigma >= 0"),
        (["sweep", "--set", "dispersions.inertia.J0.scale=0.0"], "inertia.J0.scale must be > 0"),
        (["sweep", "--set", "deployment.tau_J=0.0"], "deployment.tau_J [s] must be positive"),
        (["tune", TUNE_CONFIG, "--iterations", "0"], "'tune.iterations' must be a positive integer"),
        (["tune", TUNE_CONFIG, "--T", "0"], "T (horizon) must be a positive"),
        (["tune", TUNE_CONFIG, "--set", "deployment.tau_J=0.0"], "deployment.tau_J [s] must be positive"),
        (["tune", TUNE_CONFIG, "--set", "tune.record_every=0"], "'tune.record_every' must be a positive integer"),
    ],
)
def test_bad_arguments_are_one_line_errors(argv, message, in_process, capsys):
    out = in_process / "out"
    code = cli.main([*argv, "--out", str(out)] + (["--no-figures"] if argv[0] in ("paper", "fly") else []))
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if ": warning: " not in line]
    assert code == 2 and len(lines) == 1, err
    assert lines[0].startswith(f"so3jax {argv[0]}: error: ") and message in lines[0], err
    assert "Traceback" not in err


def test_warnings_are_one_line_each_and_shown_once(in_process, capsys):
    """A mission J0 that breaks the triangle inequality (a warning), then a bad dispersion
    of J1's scale (an error)."""
    code = cli.main(["sweep", "--set", "inertia.J0.nominal=[[100.0, 0, 0], [0, 120.0, 0], [0, 0, 300.0]]",
                     "--set", "dispersions.inertia.J0={scale={dist='lognormal', median=1.0, sigma=0.1}}",
                     "--set", "dispersions.inertia.J1.scale=0.0", "--out", str(in_process / "s")])
    err = capsys.readouterr().err.splitlines()
    assert code == 2
    assert err[0].startswith("so3jax sweep: warning: inertia J0, J1 break the triangle inequality")
    assert "check the matrix" in err[0]
    assert err[1:] == ["so3jax sweep: error: inertia.J1.scale must be > 0: 0.0 is outside that domain"]
    show = cli._warning_printer("fly")
    for _ in range(3):
        show(UserWarning("the same advice"), UserWarning, "so3jax/x.py", 1)
    assert capsys.readouterr().err == "so3jax fly: warning: the same advice\n"


@pytest.mark.parametrize("command", [None, "paper", "fly", "tune", "sweep"])
def test_help_shows_no_markup(command, capsys):
    with pytest.raises(SystemExit) as exit_:
        cli.main(["--help"] if command is None else [command, "--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    assert "usage: so3jax" in text
    for mark in ("`", "\u00a7", "``"):
        assert mark not in text, (command, mark)


@pytest.mark.parametrize("argv", [["fly", "--T", "abc"], ["paper", "--seed", "1.5"], ["bogus"], [],
                                  ["sweep", "--no-such-flag"], ["paper", "--precision", "float16"]])
def test_argument_errors_are_one_line(argv, capsys):
    """argparse's own errors (type, choice, unknown flag): one line, exit 2, no usage block."""
    with pytest.raises(SystemExit) as exit_:
        cli.main(argv)
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("so3jax") and ": error: " in err[0] and "--help" in err[0]


@pytest.mark.parametrize("argv", [["fly"], ["paper"], ["sweep"], ["identify", "telemetry.npz"], ["tune", "c.toml"],
                                  ["compare", "c.toml"]])
def test_an_empty_output_folder_is_refused(argv, tmp_path, monkeypatch, capsys):
    """--out "" would name the current directory: one line, exit 2, nothing written there."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_:
        cli.main([*argv, "--out", ""])
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "argument --out: must name a folder" in err[0]
    assert list(tmp_path.iterdir()) == []


def _single_valued(command: str):
    """The options of ``so3jax COMMAND`` that take one value (not --set's KEY=VALUE list)."""
    from so3jax.commands.common import _Given

    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices[command]
    return [(a.option_strings[0], a.choices[0] if a.choices else "2") for a in sub._actions
            if a.option_strings and isinstance(a, _Given) and a.nargs is None]


@pytest.mark.parametrize("command", [c.__name__.rsplit(".", 1)[-1] for c in cli.COMMANDS])
def test_an_option_given_twice_is_refused_or_accumulates(command, in_process, capsys):
    """Every command: a single-valued option given twice is a one-line error (not the last
    kept silently); a list option's values accumulate (``margins --at 1.0 --at 5.0``)."""
    options = _single_valued(command)
    assert options
    for option, value in options:
        with pytest.raises(SystemExit) as exit_:
            cli.build_parser().parse_args([command, option, value, option, value])
        err = capsys.readouterr().err.strip()
        assert exit_.value.code == 2 and err.startswith(f"so3jax {command}: error: {option} is given twice"), err
        assert "\n" not in err
    if command == "margins":
        assert cli.build_parser().parse_args(["margins", "--at", "1.0", "--at", "5.0", "10.0"]).at == [1.0, 5.0, 10.0]
    assert not any(in_process.iterdir())
