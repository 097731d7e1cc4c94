"""sweep and tune check the horizon's steps, the samples and the memory they need before
anything is drawn, compiled or written, as fly and paper check theirs; a sampled mission
keeps the wheels' initial speed within their speed limit, as a flown one must; a file the
system refuses to write is a one-line error of every command."""

from __future__ import annotations

import contextlib
import errno
import json
from pathlib import Path

import jax
import numpy as np
import pytest

from so3jax import commands as cli
from so3jax.jobs.sweep.config import load_config
from so3jax.jobs.tune.config import parse_config
from so3jax.missions import batched, distributions, draw, mission
from so3jax.results import io
from so3jax.sim import memory

ROOT = Path(__file__).resolve().parents[1]
TUNE_CONFIG = str(ROOT / "tuning" / "pd_equal_effort.toml")
FLIGHT_SWEEP = ROOT / "sweeps" / "flight.toml"
WIDE = '{dist="uniform", low=-2000.0, high=2000.0}'  # 2000 rad/s against a 628 rad/s limit

pytestmark = pytest.mark.filterwarnings("ignore::so3jax.dynamics.inertia.InertiaWarning")


def one_line_error(capsys, command: str) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if ": warning: " not in line]
    assert len(lines) == 1 and lines[0].startswith(f"so3jax {command}: error: "), err
    assert "Traceback" not in err
    return lines[0]


# --- the horizon's steps -------------------------------------------------------------------


def test_check_steps_refuses_a_horizon_a_rollout_cannot_count():
    assert memory.check_steps(memory.MAX_STEPS, "T", "shorten --T") == memory.MAX_STEPS
    with pytest.raises(ValueError, match=r"T = 1e\+12 s is 1e\+14 steps, more than the 1073741824 .*; shorten --T"):
        memory.check_steps(10**14, "T = 1e+12 s", "shorten --T")


@pytest.mark.parametrize("argv", [["sweep", "--T", "1e12"], ["tune", TUNE_CONFIG, "--T", "1e12"],
                                  ["fly", "--T", "1e12"], ["paper", "--T", "1e12"],
                                  ["fly", "--set", "T=1e12", "--record-every", "100000000000000"]])
def test_a_horizon_beyond_the_step_counter_is_refused_before_any_folder(argv, in_process, capsys):
    out = in_process / "out"
    assert cli.main([*argv, "--out", str(out)]) == 2
    assert "is 1e+14 steps, more than the 1073741824 a rollout can count" in one_line_error(capsys, argv[0])
    assert not out.exists()


# --- samples and memory --------------------------------------------------------------------


def test_input_shapes_are_those_of_drawn_inputs():
    """The shapes the memory estimate reads, without drawing, are those a draw gives."""
    flight = mission.load(None, ["T=1.0"])
    parsed, leaves = draw.parse({"actuator": {"wheels": {"max_torque": 0.2}}, "sensors": {"gyro": {"arw": 1e-6}}},
                                flight)
    drawn = batched.inputs(draw.draw(parsed, leaves, 0, 3, 2), np.float32)
    shapes = batched.input_shapes(leaves, 3, np.float32)
    got = [(tuple(x.shape), np.dtype(x.dtype)) for x in jax.tree.leaves(drawn)]
    assert got == [(tuple(s.shape), np.dtype(s.dtype)) for s in jax.tree.leaves(shapes)]
    assert batched.samples_bytes(leaves, 3, np.float32) == memory.nbytes(drawn) + memory.nbytes(
        batched.inputs(draw.draw(parsed, leaves, 0, 3, 2), np.float64))


def test_memory_nbytes_does_not_overflow():
    assert memory.nbytes(jax.ShapeDtypeStruct((2**40, 2**30), np.float64)) == 2**73


def test_sweep_samples_beyond_the_sample_keys_are_refused(in_process, capsys):
    out = in_process / "out"
    assert cli.main(["sweep", "--samples", "1000000000000000", "--out", str(out)]) == 2
    line = one_line_error(capsys, "sweep")
    assert "sweep.samples = 1000000000000000 is more than the 4294967296 samples a sampling seed numbers" in line
    assert not out.exists()


def test_sweep_samples_beyond_memory_are_refused_before_drawing(cli_env, capsys, monkeypatch):
    """The estimate traces a rollout for its shapes; nothing is drawn (a draw of 4e9 samples would run for hours)."""
    def drawn(*args, **kwargs):
        raise AssertionError("drew the samples")

    monkeypatch.setattr(draw, "draw", drawn)
    out = cli_env / "out"
    assert cli.main(["sweep", "--T", "1", "--samples", "4000000000", "--max-memory", "1G", "--out", str(out)]) == 2
    line = one_line_error(capsys, "sweep")
    assert "of 4000000000 samples needs about" in line and "lower --chunk or --samples" in line
    assert not out.exists()


def _campaign(**train) -> dict:
    return {"T": 1.0, "tune": {
        "controller": "pd", "iterations": 2, "cost": {"mode": "weighted"},
        "train": {"seeds": [0], "samples": 4, **train}, "validation": {"seeds": [1], "samples": 4},
        "dispersions": {"deployment": {"tau_J": {"dist": "uniform", "low": 200.0, "high": 400.0}}}}}


def test_tune_refuses_dispersed_batches_beyond_memory_or_the_sample_keys():
    parse_config(_campaign())  # the campaign itself is fine
    with pytest.raises(ValueError, match=r"tune.train.samples = 2147483648 dispersed missions needs about 1.\d+ TiB"):
        parse_config(_campaign(samples=2**31))  # 2 iterations: samples 0 .. 2^32 - 1
    table = _campaign(samples=2**31)
    table["tune"]["iterations"] = 3
    with pytest.raises(ValueError, match=r"tune.train.samples draws 6442450944 dispersed missions over the iter"):
        parse_config(table)


# --- the wheels' speed limit in a sampled mission ------------------------------------------


def test_the_flight_sweep_refuses_initial_speeds_beyond_the_least_speed_limit():
    """sweeps/flight.toml disperses max_speed uniform on [500, 700] rad/s."""
    with pytest.raises(ValueError, match=r"dispersions.actuator.wheels.initial_speed must not exceed the least "
                                         r"actuator.wheels.max_speed drawn = 500 in magnitude"):
        load_config(FLIGHT_SWEEP, (f"dispersions.actuator.wheels.initial_speed={WIDE}",))
    load_config(FLIGHT_SWEEP, ())  # its own initial speeds, uniform on [-100, 100] rad/s, keep within


def test_the_sweep_command_refuses_them_in_one_line(in_process, capsys):
    out = in_process / "out"
    argv = ["sweep", str(FLIGHT_SWEEP), "--set", f"dispersions.actuator.wheels.initial_speed={WIDE}"]
    assert cli.main([*argv, "--out", str(out)]) == 2
    assert "must not exceed the least actuator.wheels.max_speed drawn" in one_line_error(capsys, "sweep")
    assert not out.exists()


@pytest.fixture(scope="module")
def flight():
    return mission.load(None, ["T=1.0"])


def _wheels(**values) -> dict:
    return {"actuator": {"wheels": values}}


def test_a_fixed_speed_limit_refuses_a_uniform_beyond_it(flight):
    with pytest.raises(ValueError, match=r"must not exceed the least actuator.wheels.max_speed = 628"):
        draw.parse(_wheels(initial_speed={"dist": "uniform", "low": -700.0, "high": 0.0}), flight)
    with pytest.raises(ValueError, match=r"must not exceed"):
        draw.parse(_wheels(initial_speed=700.0), flight)


def test_initial_speeds_beyond_the_limit_reject_their_sample(flight):
    """A normal's tails beyond the mission's 628 rad/s: those samples rejected, and only they."""
    _, leaves = draw.parse(_wheels(initial_speed={"dist": "normal", "mean": 0.0, "std": 400.0}), flight)
    values, valid = draw.draw_leaves(leaves, 0, 2000)
    over = np.any(np.abs(values["actuator.wheels.initial_speed"]) > 628.0, axis=1)
    assert 0.2 < over.mean() < 0.6  # 1 - P(|N(0, 400)| <= 628)^4 = 0.39
    np.testing.assert_array_equal(valid, ~over)


def test_a_sample_rejected_for_a_component_value_is_counted_apart(flight):
    """draw's ``outside``: the samples rejected for a component value alone (the inertias were fine)."""
    dispersions, leaves = draw.parse(_wheels(initial_speed={"dist": "normal", "mean": 0.0, "std": 400.0}), flight)
    samples = draw.draw(dispersions, leaves, 0, 200, 20)
    over = np.any(np.abs(samples.leaves["actuator.wheels.initial_speed"]) > 628.0, axis=1)
    assert over.any()
    np.testing.assert_array_equal(samples.outside, over)
    np.testing.assert_array_equal(samples.valid, ~over)


def test_both_dispersed_reject_the_samples_whose_speed_exceeds_their_own_limit(flight):
    table = _wheels(initial_speed={"dist": "normal", "mean": 0.0, "std": 300.0},
                    max_speed={"dist": "uniform", "low": 500.0, "high": 700.0})
    _, leaves = draw.parse(table, flight)
    values, valid = draw.draw_leaves(leaves, 1, 2000)
    speed, limit = values["actuator.wheels.initial_speed"], values["actuator.wheels.max_speed"]
    over = np.any(np.abs(speed) > limit, axis=1)
    assert over.any() and not over.all()
    assert np.any(over & np.all(np.abs(speed) <= 628.0, axis=1))  # the sample's own limit counts, not the mission's
    np.testing.assert_array_equal(valid, ~over)


def test_a_dispersed_limit_below_the_mission_s_initial_speed(flight):
    fast = mission.load(None, ["T=1.0", "actuator.wheels.initial_speed=550.0"])
    with pytest.raises(ValueError, match=r"dispersions.actuator.wheels.max_speed \(the limit of "
                                         r"actuator.wheels.initial_speed\) must be >= 550"):
        draw.parse(_wheels(max_speed={"dist": "uniform", "low": 500.0, "high": 700.0}), fast)
    _, leaves = draw.parse(_wheels(max_speed={"dist": "normal", "mean": 600.0, "std": 50.0}), fast)
    values, valid = draw.draw_leaves(leaves, 0, 1000)
    np.testing.assert_array_equal(valid, np.all(values["actuator.wheels.max_speed"] >= 550.0, axis=1))
    assert not valid.all()


def test_check_magnitude_follows_check_domain_s_rule():
    Fixed, Uniform, Normal, LogNormal = (distributions.Fixed, distributions.Uniform, distributions.Normal,
                                         distributions.LogNormal)
    assert distributions.check_magnitude(Normal(-10.0, 1e3), "x", 10.0, "limit")  # its mean within: tails rejected
    for dist in (Fixed(-11.0), Uniform(-5.0, 11.0), Normal(11.0, 1.0), LogNormal(11.0, 0.1)):
        with pytest.raises(ValueError, match="x must not exceed limit = 10 in magnitude"):
            distributions.check_magnitude(dist, "x", 10.0, "limit")
    assert [distributions.least(d) for d in (Fixed(3.0), Uniform(1.0, 2.0), Normal(4.0, 9.0),
                                             LogNormal(5.0, 1.0))] == [3.0, 1.0, 4.0, 5.0]


# --- a file the system refuses -------------------------------------------------------------


def test_a_full_disk_is_a_one_line_error_and_leaves_the_run_incomplete(cli_env, capsys, monkeypatch):
    """The sweep writes sweep.json before it compiles a rollout: the disk fills there."""
    real = io.atomic_path

    @contextlib.contextmanager
    def full(path):
        with real(path) as tmp:
            if Path(path).name != "manifest.json":
                raise OSError(errno.ENOSPC, "No space left on device", str(path))
            yield tmp

    monkeypatch.setattr(io, "atomic_path", full)
    out = cli_env / "out"
    assert cli.main(["sweep", "--T", "1", "--samples", "8", "--chunk", "8", "--out", str(out)]) == 2
    line = one_line_error(capsys, "sweep")
    assert line == f"so3jax sweep: error: No space left on device: {out / 'sweep.json'}"
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["command"] == "sweep" and manifest["complete"] is False


def test_os_error_reads_in_one_line():
    assert cli.os_error(OSError(errno.EROFS, "Read-only file system", "a/b.npz")) == "Read-only file system: a/b.npz"
    assert cli.os_error(OSError("something else")) == "something else"
