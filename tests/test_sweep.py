"""Monte Carlo sweeps: sampling, the sharded chunk runner, resume, rejection, divergence.

Every in-process run shares one horizon and step (T = 2700 s at dt = 0.5 s: all three
mission phases in 5400 steps) and one shard size (8), so each controller compiles once.
"""

import csv
import dataclasses
import io
import json
import subprocess
import sys
import warnings
from pathlib import Path

import jax
import numpy as np
import pytest

import so3jax as sj
from so3jax.jobs import sweep
from so3jax.jobs.sweep import engine  # run_sweep's chunk loop: where it finds run_chunk and save_npz
from so3jax.missions import build, distributions, draw
from tests._host_devices import host_devices_env

ROOT = Path(__file__).resolve().parents[1]
# The paper's own inertias dispersed by the matrix form (tests/data/sweep_reference_samples.csv records them)
PAPER_INERTIAS = (
    "inertia.J0.nominal=[[625.0, 5.5, 3.0], [5.5, 350.0, 4.0], [3.0, 4.0, 1000.0]]",
    "dispersions.inertia.J0={scale={dist='lognormal', median=1.0, sigma=0.1}, rotation_deg=10.0, "
    "axis_scale={dist='uniform', low=0.9, high=1.1}, products={dist='normal', mean=0.0, std=10.0}}",
    "dispersions.inertia.J1={scale={dist='uniform', low=1.8, high=2.2}, products={dist='normal', mean=0.0, std=10.0}}",
    "dispersions.inertia.J2={scale={dist='lognormal', median=1.0, sigma=0.1}, rotation_deg=10.0, "
    "axis_scale={dist='uniform', low=0.9, high=1.1}, products={dist='normal', mean=0.0, std=20.0}}",
)
SETTINGS = ("sweep.samples=11", "T=2700.0", "dt=0.5", "sweep.chunk=8", *PAPER_INERTIAS)
METRIC_COLUMNS = ("rmse", "rmse_unrotated", "effort", "rmse_capture", "effort_deployment", "max_angle_detumble",
                  "diverged")


def config(*overrides):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sj.InertiaWarning)
        return sweep.load_config(None, SETTINGS + overrides)


def run(cfg, out, **kwargs):
    return sweep.run_sweep(cfg, out, progress=False, **kwargs)


def table(out):
    with np.load(Path(out) / "samples.npz") as f:
        return {k: f[k] for k in f.files}


def assert_same_results(a, b, controllers, rtol=0.0):
    """Bit for bit by default; rtol for runs with another chunking (round-off only)."""
    for c in controllers:
        for col in METRIC_COLUMNS:
            np.testing.assert_allclose(a[f"{c}_{col}"], b[f"{c}_{col}"], rtol=rtol, atol=0.0, err_msg=f"{c}_{col}")


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """Both controllers, 11 samples, chunks of 8 (the last one padded), one device."""
    out = tmp_path_factory.mktemp("reference")
    summary = run(config(), out)
    return out, summary


# --- configuration and sampling ---------------------------------------------------------


def test_default_config_file_is_the_builtin_default():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sj.InertiaWarning)
        from_file = sweep.load_config(ROOT / "sweeps" / "default.toml")
        assert from_file == sweep.load_config(None)
        mission_tables = {k: v for k, v in sweep.DEFAULT.items() if k not in ("sweep", "dispersions")}
        assert sweep.config_from_dict(dict(mission_tables, **sweep.config_to_dict(from_file))) == from_file
    paper = sj.load_mission(ROOT / "missions" / "paper.toml", ["inertia.J0.nominal=" + repr(mission_tables["inertia"]
                                                                                          ["J0"]["nominal"])])
    assert from_file.mission.describe() == paper.describe() and from_file.mission.J0[2, 2] == 900.0


@pytest.mark.parametrize(
    "override, message",
    [
        ("bogus=1", "unknown config key"),
        ("sweep.bogus=1", "unknown key"),
        ("dispersions.inertia.J0.wobble=1", "unknown key"),
        ('dispersions.deployment.tau_J={dist="gamma", k=1.0}', "unknown distribution"),
        ('dispersions.deployment.tau_J={dist="uniform", low=1.0}', "takes exactly"),
        ('dispersions.orbit.n={dist="normal", mean=1e-3, std=-1.0}', "std"),
        ("T=10.005", "not a multiple of dt"),
        ('controllers=["pd", "lqr"]', "controllers"),
        ("dispersions.initial.attitude.max_angle_deg=170.0", "divergence_angle_deg"),
        ("inertia.J2.nominal=[[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]]", "positive definite"),
        ("gains.pd.k_R=-1.0", "positive"),
        ("sweep.chunk=0", "chunk"),
        ("dispersions.sensors.gyro.arw=1e-6", "flies no sensors 'gyro'"),
        ("mission=3", "mission must be the path"),
    ],
)
def test_bad_config_is_a_clear_error(override, message):
    with pytest.raises(ValueError, match=message):
        config(override)


def test_overrides_and_distributions():
    cfg = config('dispersions.inertia.J0.scale={dist="normal", mean=1.0, std=0.05}', "seed=7",
                 'dispersions.seed="mission"', "dispersions.orbit.n=1e-3")
    d = cfg.dispersions
    assert d.J0.scale == distributions.Normal(1.0, 0.05) and d.disturbance_seed == 7
    assert d.n == distributions.Fixed(1e-3)
    assert cfg.samples == 11 and cfg.dt == 0.5


def test_samples_depend_only_on_seed_and_index():
    d = config().dispersions
    few = draw.draw_samples(d, 3, 5, 20)
    many = draw.draw_samples(d, 3, draw.BLOCK + 9, 20)  # two sampler blocks
    fewer_draws = draw.draw_samples(d, 3, 5, 4)
    for a, b, c in zip(jax.tree.leaves(few), jax.tree.leaves(many), jax.tree.leaves(fewer_draws)):
        np.testing.assert_array_equal(a, b[:5])
        np.testing.assert_array_equal(a, c)  # none needed more than 4 draws
    other = draw.draw_samples(d, 4, 5, 20)
    assert not np.array_equal(few.params.J0, other.params.J0)


def test_every_dispersion_is_sampled_within_its_law():
    s = draw.draw_samples(config().dispersions, 0, 400, 20)
    p = s.params
    assert s.valid.all()
    for name, value in p._asdict().items():
        distinct = np.unique(value.reshape(len(value), -1), axis=0).shape[0]
        assert distinct == (1 if name == "frequency" else 400), name  # the default keeps the frequency fixed
    assert 200 <= p.tau_J.min() and p.tau_J.max() <= 400
    assert 1.0381e-3 <= p.n.min() and p.n.max() <= 1.1314e-3
    angles = np.linalg.norm(s.attitude_error, axis=1)
    assert angles.max() <= np.radians(30.0) + 1e-12
    R = jax.vmap(sj.so3.exp)(s.attitude_error)
    np.testing.assert_allclose(p.R0, R, atol=1e-14)
    assert np.linalg.norm(p.Omega0, axis=1).max() <= 0.005
    np.testing.assert_allclose(np.log(s.scale[:, 0]).std(), 0.1, rtol=0.15)
    # J1 grows J0 by its scale, plus its products-of-inertia noise
    diag = np.einsum("nii->ni", p.J1) / np.einsum("nii->ni", p.J0)
    np.testing.assert_allclose(diag, np.repeat(s.scale[:, 1:2], 3, axis=1), rtol=1e-12)
    for J in (p.J0, p.J1, p.J2):
        np.testing.assert_array_equal(J, np.swapaxes(J, 1, 2))
        assert np.linalg.eigvalsh(J).min() > 0


def test_haar_angle_law():
    """Rotations uniform on SO(3) up to a maximum angle: P(angle < a) = (a - sin a) / (m - sin m)."""
    d = dataclasses.replace(draw.Dispersions(), initial_angle_deg=120.0)
    angle = np.linalg.norm(draw.draw_samples(d, 0, 4000, 1).attitude_error, axis=1)
    m = np.radians(120.0)
    for a in (0.5, 1.0, 1.5, 2.0):
        assert abs(np.mean(angle < a) - (a - np.sin(a)) / (m - np.sin(m))) < 0.02


# --- the rollouts see the sampled values ---------------------------------------------------


def test_each_dispersed_value_reaches_the_rollout():
    """Changing any one parameter of a sample changes its simulated motion."""
    cfg = config()
    base = jax.tree.map(lambda x: x[0], draw.draw_samples(cfg.dispersions, 0, 1, 20).params)
    changed = {name: 1.1 * value for name, value in base._asdict().items() if value.dtype.kind == "f"}
    changed.update(R0=draw.rotation_matrix(np.array([0.0, 0.1, 0.0])) @ base.R0, Omega0=base.Omega0 + 1e-3,
                   seed=base.seed + 1)
    variants = [base] + [base._replace(**{name: changed[name]}) for name in base._fields]
    batch = jax.tree.map(lambda *xs: np.stack(xs), *(variants + [base] * (-len(variants) % 8)))
    gains = jax.tree.map(np.asarray, cfg.gains["pd"])
    halves = [jax.tree.map(lambda x: x[:8], batch), jax.tree.map(lambda x: x[8:], batch)]
    m = [sweep.run_chunk((half, {}), gains, "pd", cfg.mission, sweep.batch_mesh()) for half in halves]
    rmse, effort = (np.concatenate([x[k] for x in m]) for k in ("rmse", "effort"))
    for i, name in enumerate(base._fields, start=1):
        assert rmse[i] != rmse[0] and effort[i] != effort[0], f"{name} does not change the motion"


def test_sample_parameters_map_onto_the_mission():
    cfg = config()
    p = jax.tree.map(lambda x: x[0], draw.draw_samples(cfg.dispersions, 0, 1, 20).params)
    expected = sj.paper_scenario(
        2700.0,
        0.5,
        tau_J=float(p.tau_J),
        n=float(p.n),
        J0=p.J0,
        J1=p.J1,
        J2=p.J2,
        disturbance_amplitude=float(p.amplitude),
        disturbance_frequency=float(p.frequency),
        noise_std=float(p.noise_std),
    )
    expected = dataclasses.replace(expected, R0=jax.numpy.asarray(p.R0), Omega0=jax.numpy.asarray(p.Omega0))
    got = build.scenario(cfg.mission, jax.tree.map(jax.numpy.asarray, p))
    assert jax.tree.structure(got) == jax.tree.structure(expected)
    for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(expected)):
        np.testing.assert_allclose(a, b, rtol=1e-15, atol=0)


# --- reproducibility, outputs ------------------------------------------------------------


def test_outputs(reference):
    out, summary = reference
    for name in ("samples.csv", "samples.npz", "summary.json", "summary.md", "cdf.png", "histograms.png",
                 "rmse_vs_inertia_scale.png"):
        assert (out / name).stat().st_size > 100, name
    assert json.loads((out / "summary.json").read_text())["samples"] == summary["samples"]
    t = table(out)
    assert len(t["index"]) == 11 and set(t["status"]) == {"simulated"}
    header = (out / "samples.csv").read_text().splitlines()[0].split(",")
    assert header == list(t)
    column_units = json.loads((out / "summary.json").read_text())["units"]["columns"]  # every column's unit
    assert list(column_units) == header
    assert [column_units[k] for k in ("J0_xx", "tau_J", "pd_rmse", "pd_max_angle_capture", "adaptive_diverged")] == [
        "kg m^2", "s", "rad/s", "rad", "-"]
    for c in ("pd", "adaptive"):
        for metric in ("rmse", "effort"):
            assert set(summary["controllers"][c][metric]) == {"mission", "capture", "deployment", "detumble"}
            stats = summary["controllers"][c][metric]["mission"]
            assert set(stats) == {"mean", "std", "p50", "p95", "p99", "max", "samples"} and stats["samples"] == 11
            assert stats["max"] == pytest.approx(t[f"{c}_{metric}"].max())
    pair = summary["paired"]["adaptive_vs_pd"]
    better = np.mean(t["adaptive_rmse"] < t["pd_rmse"])
    assert pair["samples"] == 11 and pair["rmse"]["adaptive_better_fraction"] == pytest.approx(better)
    assert "| pd | detumble |" in (out / "summary.md").read_text()


def test_same_results_whatever_the_chunk_size_and_device_count(reference, tmp_path):
    """4 forced host devices with 10 samples per device, against 1 device with 8 (equal to
    round-off): in a subprocess (XLA flags must precede JAX), through the command line."""
    env = host_devices_env(4)
    args = [sys.executable, "-m", "so3jax.commands", "sweep", *[f"--set={s}" for s in SETTINGS], "--chunk", "40",
            "--controllers", "pd"]
    proc = subprocess.run([*args, "--out", str(tmp_path)], check=False, cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "on 4 device(s)" in proc.stderr and "| pd | mission |" in proc.stdout
    assert json.loads((tmp_path / "summary.json").read_text())["run"]["chunk"] == 40
    assert_same_results(table(reference[0]), table(tmp_path), ["pd"], rtol=1e-12)


def test_resume_finishes_without_recomputing(reference, tmp_path, monkeypatch):
    save, chunks = engine.save_npz, []

    def save_then_stop(path, **arrays):
        save(path, **arrays)
        if "chunks" in Path(path).parts:
            chunks.append(Path(path).name)
            raise KeyboardInterrupt

    monkeypatch.setattr(engine, "save_npz", save_then_stop)
    with pytest.raises(KeyboardInterrupt):
        run(config(), tmp_path)
    assert chunks == ["pd-000000000.npz"] and not (tmp_path / "summary.json").exists()
    monkeypatch.setattr(engine, "save_npz", save)

    with pytest.raises(ValueError, match="--resume"):
        run(config(), tmp_path)
    with pytest.raises(ValueError, match="other settings"):
        run(config("sweep.seed=1"), tmp_path, resume=True)

    # a resume refuses what it cannot match to this sweep, before computing anything
    stamp = tmp_path / "sweep.json"
    description = stamp.read_text()
    stamp.unlink()
    with pytest.raises(ValueError, match="sweep.json is missing"):
        run(config("sweep.seed=1"), tmp_path, resume=True)
    stamp.write_text(description)
    chunk = tmp_path / "chunks" / "pd-000000000.npz"
    good = chunk.read_bytes()
    chunk.write_bytes(good[:200])
    with pytest.raises(ValueError, match=r"pd-000000000\.npz cannot be read .*delete it and rerun with --resume"):
        run(config(), tmp_path, resume=True)
    with np.load(io.BytesIO(good)) as f:
        arrays = dict(f)
    np.savez(chunk, **{**arrays, "fingerprint": np.array("0123456789abcdef")})
    with pytest.raises(ValueError, match="belongs to another sweep"):
        run(config(), tmp_path, resume=True)
    chunk.write_bytes(good)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    with pytest.raises(ValueError, match="holds chunks of pd, which this sweep does not fly"):
        run(config('controllers=["adaptive"]'), tmp_path, resume=True)  # pd's chunks would be left out of the results
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == before

    run_chunk, computed = engine.run_chunk, []
    monkeypatch.setattr(engine, "run_chunk",
                        lambda inputs, *a: computed.append(len(inputs[0].seed)) or run_chunk(inputs, *a))
    summary = run(config(), tmp_path, resume=True)
    assert computed == [8, 8, 8]  # pd: samples 8-10 (padded); adaptive: 0-7, 8-10
    assert summary["run"]["computed_samples"] == 3 + 11
    assert_same_results(table(reference[0]), table(tmp_path), ["pd", "adaptive"])

    computed.clear()
    run(config("sweep.samples=13"), tmp_path, resume=True)  # more samples: extends the sweep
    assert computed == [8, 8]
    extended = {k: v[:11] for k, v in table(tmp_path).items()}
    assert_same_results(table(reference[0]), extended, ["pd", "adaptive"])


# --- impossible and diverged samples -----------------------------------------------------


def test_impossible_samples_are_redrawn_or_rejected_never_simulated(tmp_path, monkeypatch):
    wild = 'dispersions.inertia.J0.products={dist="normal", mean=0.0, std=400.0}'
    run_chunk, seen = engine.run_chunk, []
    monkeypatch.setattr(engine, "run_chunk", lambda inputs, *a: seen.append(inputs[0]) or run_chunk(inputs, *a))

    summary = run(config(wild, "sweep.samples=12", "sweep.max_draws=1", 'controllers=["pd"]'), tmp_path / "reject")
    t = table(tmp_path / "reject")
    rejected = t["status"] == "rejected"
    assert 0 < rejected.sum() < 12 and summary["samples"]["rejected"] == rejected.sum()
    assert summary["samples"]["rejected_indices"] == np.flatnonzero(rejected).tolist()
    assert summary["samples"]["rejected_component"] == 0  # all for their inertias
    assert np.isnan(t["pd_rmse"][rejected]).all() and np.isfinite(t["pd_rmse"][~rejected]).all()
    def inertias(name):
        e = {k: t[f"{name}_{k}"] for k in ("xx", "yy", "zz", "xy", "xz", "yz")}
        rows = [[e["xx"], e["xy"], e["xz"]], [e["xy"], e["yy"], e["yz"]], [e["xz"], e["yz"], e["zz"]]]
        return np.stack([np.stack(r, -1) for r in rows], -2)

    smallest = np.min([np.linalg.eigvalsh(inertias(name)).min(axis=1) for name in ("J0", "J1", "J2")], axis=0)
    np.testing.assert_array_equal(smallest <= 0, rejected)  # a rejected sample's last draw is shown
    simulated = np.concatenate([np.concatenate([p.J0, p.J1, p.J2]) for p in seen])
    assert np.linalg.eigvalsh(simulated).min() > 0  # only positive definite inertias reached the rollouts
    assert summary["controllers"]["pd"]["simulated"] == 12 - rejected.sum()

    summary = run(config(wild, "sweep.samples=12", "sweep.max_draws=30", 'controllers=["pd"]'), tmp_path / "redraw")
    assert summary["samples"]["rejected"] == 0 and summary["samples"]["redraws"] > 0
    assert (table(tmp_path / "redraw")["draws"] > 1).any()


def test_diverged_samples_are_flagged_and_reported(tmp_path):
    spin = 'dispersions.initial.rate={norm={dist="lognormal", median=0.1, sigma=4.0}}'  # from gentle to a blow-up
    summary = run(config(spin, "sweep.samples=8", 'controllers=["pd"]'), tmp_path)
    t = table(tmp_path)
    nonfinite, diverged = t["pd_nonfinite"] == 1, t["pd_diverged"] == 1
    assert len(t["index"]) == 8  # nothing dropped
    assert nonfinite.any() and (diverged & ~nonfinite).any() and (~diverged).any()
    assert np.all(diverged[nonfinite])
    entry = summary["controllers"]["pd"]
    assert entry["diverged"] == diverged.sum() and entry["nonfinite"] == nonfinite.sum()
    listed = entry["diverged_samples"]
    assert [row["index"] for row in listed] == np.flatnonzero(diverged).tolist()
    assert {"tau_J", "J0_xx", "Omega0_x", "disturbance_seed", "pd_max_angle_capture"} <= set(listed[0])
    assert entry["rmse"]["mission"]["max"] == pytest.approx(t["pd_rmse"][~diverged].max())  # statistics leave them out
    assert entry["rmse"]["mission"]["samples"] == entry["effort"]["capture"]["samples"] == (~diverged).sum()
    assert "| pd | 8 | " in (tmp_path / "summary.md").read_text()
    # a non-finite rollout never reads as a number: NaN in the table, null in JSON, "nan" in the CSV
    metric_columns = [k for k in t if k.startswith("pd_") and k not in ("pd_nonfinite", "pd_diverged")]
    assert all(np.isnan(t[k][nonfinite]).all() for k in metric_columns)  # max |tau| before the blow-up too
    saved = json.loads((tmp_path / "summary.json").read_text(), parse_constant=lambda c: pytest.fail(f"{c} in JSON"))
    for row in saved["controllers"]["pd"]["diverged_samples"]:
        assert row["pd_diverged"] == 1
        if row["pd_nonfinite"] == 1:
            assert all(row[k] is None for k in metric_columns)
    with open(tmp_path / "samples.csv") as f:
        rows = list(csv.DictReader(f))
    for i in np.flatnonzero(nonfinite):
        assert rows[i]["pd_rmse"] == rows[i]["pd_max_torque"] == "nan" and rows[i]["status"] == "simulated"
    assert all(float(rows[i]["pd_rmse"]) > 0 for i in np.flatnonzero(~nonfinite))


def test_statistics_are_over_finite_samples_and_null_without_any():
    """Summaries from made-up results (no rollout): sample 1 non-finite, sample 2 rejected;
    then every sample non-finite."""
    cfg = config("sweep.samples=3", 'controllers=["pd", "adaptive"]')
    samples = draw.draw_samples(cfg.dispersions, 0, 3, 20)
    samples = samples._replace(valid=np.array([True, True, False]))
    n, phases = 3, len(sweep.PHASE_NAMES)

    def results(rmse, nonfinite):
        r = {f: np.full((n, phases) if f.endswith("_phase") else n, 0.5) for f in sweep.Metrics._fields}
        r["rmse"] = np.asarray(rmse, float)
        r["diverged"] = np.asarray(nonfinite, float)
        r["max_angle_phase"] = np.where(np.asarray(nonfinite)[:, None] == 1, np.nan, np.full((n, phases), 0.1))
        r["done"] = np.array([True, True, False])
        return r

    summary = sweep.summarize(cfg, samples, {"pd": results([1e-3, np.nan, np.nan], [0, 1, 0]),
                                             "adaptive": results([2e-3, 3e-3, np.nan], [0, 0, 0])})
    pd = summary["controllers"]["pd"]
    assert summary["samples"]["rejected"] == 1 and pd["simulated"] == 2 and pd["diverged"] == pd["nonfinite"] == 1
    assert pd["rmse"]["mission"]["mean"] == 1e-3 and pd["rmse"]["mission"]["samples"] == 1
    assert summary["controllers"]["adaptive"]["rmse"]["mission"]["mean"] == pytest.approx(2.5e-3)
    pair = summary["paired"]["adaptive_vs_pd"]
    assert pair["samples"] == 1 and pair["diverged_only_pd"] == 1
    assert pair["rmse"]["relative_change"]["p50"] == pytest.approx(1.0)

    summary = sweep.summarize(cfg, samples, {"pd": results([np.nan] * 3, [1, 1, 0]),
                                             "adaptive": results([np.nan] * 3, [1, 1, 0])})
    stats = summary["controllers"]["pd"]["rmse"]["mission"]
    assert stats == {**dict.fromkeys(sweep.STAT_NAMES), "samples": 0}
    assert summary["paired"]["adaptive_vs_pd"]["rmse"]["relative_change"]["mean"] is None
    text = sweep.format_summary(summary)
    assert "| pd | mission | " + " | ".join(["diverged"] * len(sweep.STAT_NAMES)) + " | 0 |" in text
    assert "nan" not in text.lower() and "lower in" not in text


def test_flight_metrics_are_summarized_and_samples_at_a_limit_flagged():
    """Made-up flight results (no rollout), T = 10 s, limit_share 0.05 (0.5 s): a sample is
    flagged where its time at either limit exceeds 0.5 s; flight statistics skip diverged
    samples; paired differences are in the metrics' units."""
    from so3jax.sim.flight_metrics import FlightMetrics

    cfg = config("sweep.samples=4", 'controllers=["pd", "adaptive"]', "T=10.0", "sweep.limit_share=0.05")
    samples = draw.draw_samples(cfg.dispersions, 0, 4, 20)
    n, phases = 4, len(sweep.PHASE_NAMES)

    def results(torque, speed, estimation, nonfinite=(0, 0, 0, 0)):
        r = {f: np.full((n, phases) if f.endswith("_phase") else n, 0.5) for f in sweep.Metrics._fields}
        r.update({f: np.full(n, 0.0) for f in FlightMetrics._fields})
        r["diverged"] = np.asarray(nonfinite, float)
        r["max_angle_phase"] = np.full((n, phases), 0.1)
        r.update(time_at_torque_limit=np.asarray(torque, float), time_at_speed_limit=np.asarray(speed, float),
                 attitude_estimation_rms=np.asarray(estimation, float), done=np.ones(n, bool))
        return r

    res = {"pd": results([0.0, 0.5, 0.6, 0.0], [0.0, 0.0, 0.0, 2.0], [1e-5, 2e-5, 3e-5, 4e-5]),
           "adaptive": results([0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], [2e-5, 3e-5, 4e-5, 5e-5], (0, 0, 0, 1))}
    summary = sweep.summarize(cfg, samples, res)
    pd, adaptive = summary["controllers"]["pd"], summary["controllers"]["adaptive"]
    assert pd["at_limit"] == {"share": 0.05, "samples": 2, "indices": [2, 3]}  # 0.5 s is not more than 5 %
    assert adaptive["at_limit"]["samples"] == 0
    assert pd["flight"]["attitude_estimation_rms"]["mean"] == pytest.approx(2.5e-5)
    assert adaptive["flight"]["attitude_estimation_rms"]["samples"] == 3  # the non-finite sample left out
    assert adaptive["flight"]["attitude_estimation_rms"]["max"] == pytest.approx(4e-5)
    difference = summary["paired"]["adaptive_vs_pd"]["flight_difference"]
    assert difference["attitude_estimation_rms"]["mean"] == pytest.approx(1e-5)
    assert difference["time_at_torque_limit"]["p50"] == pytest.approx(-0.5)  # over samples 0-2
    cols = sweep.columns(cfg, samples, res)
    np.testing.assert_array_equal(cols["pd_at_limit"], [0, 0, 1, 1])
    text = sweep.format_summary(summary)
    assert "| pd | 4 | 0 | 0 | 2 |" in text and "more than 5 % of the horizon" in text
    assert "| time_at_torque_limit [s] | pd |" in text


def test_the_flight_sweep_file_disperses_the_flight_hardware():
    """sweeps/flight.toml: the flight mission with its sensors', wheels' and the scenario's
    dispersions (parsed only; tests/test_dispersed.py flies such a sweep)."""
    cfg = sweep.load_config(Path(__file__).resolve().parents[1] / "sweeps" / "flight.toml")
    assert cfg.mission.period_steps == 10 and cfg.mission.actuator["kind"] == "wheels"
    assert {leaf.key for leaf in cfg.leaves} == {
        "sensors.gyro.arw", "sensors.gyro.rrw", "sensors.gyro.bias0", "sensors.star_tracker.sigma",
        "actuator.wheels.max_torque", "actuator.wheels.max_speed", "actuator.wheels.initial_speed",
        "actuator.wheels.misalignment", "actuator.wheels.spin_inertia_error"}
    default = sweep.load_config(None)
    assert cfg.dispersions == default.dispersions  # the scenario dispersed as sweeps/default.toml does it


def test_results_match_the_recorded_samples(reference):
    """Every number of samples.csv within 1e-12 relative of tests/data/sweep_reference_samples.csv,
    recorded by the stage-by-stage evaluation of each sample's reference and inertia (a
    rollout of one trajectory evaluates them so); the orthogonality error, itself round-off,
    within 1e-12 absolute."""
    out, _ = reference
    read = lambda path: list(csv.DictReader(path.open()))
    got, recorded = read(out / "samples.csv"), read(ROOT / "tests" / "data" / "sweep_reference_samples.csv")
    assert len(got) == len(recorded) == 11 and got[0].keys() == recorded[0].keys()
    for row, want in zip(got, recorded):
        for key, value in want.items():
            try:
                expected = float(value)
            except ValueError:
                assert row[key] == value, key
                continue
            rtol, atol = (0.0, 1e-12) if key.endswith("orthogonality_error") else (1e-12, 0.0)
            np.testing.assert_allclose(float(row[key]), expected, rtol=rtol, atol=atol,
                                       err_msg=f"{key} of sample {want['index']}")
