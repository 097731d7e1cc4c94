"""Stability margins per dispersed sweep sample (so3jax.jobs.sweep.margins): each sample's margins
are those of its mission flown alone (so3jax.jobs.margins.at), a sample's own component value
moves its margins and no other's, and the summary's worst cases name the right samples. One
small sampled loop (no sensors, true state, four wheels), 20 s, three samples: its batched
programs compiled once for the module."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from so3jax.jobs import margins as jobs_margins
from so3jax.jobs.sweep import config as sweep_config
from so3jax.jobs.sweep import engine
from so3jax.jobs.sweep import margins as sweep_margins
from so3jax.missions import batched, draw

ROOT = Path(__file__).parents[1]
pytestmark = pytest.mark.filterwarnings("ignore::so3jax.dynamics.inertia.InertiaWarning")

TIMES = (10.0, 19.9)
DISPERSIONS = {
    "inertia": {"J0": {"scale": {"dist": "uniform", "low": 0.8, "high": 1.2},
                       "products": {"dist": "normal", "mean": 0.0, "std": 10.0}}},
    "deployment": {"tau_J": {"dist": "uniform", "low": 200.0, "high": 400.0}},
    "initial": {"attitude": {"max_angle_deg": 5.0}, "rate": {"norm": {"dist": "uniform", "low": 0.0, "high": 1e-3}}},
    "actuator": {"wheels": {"max_torque": {"dist": "uniform", "low": 0.2, "high": 0.3},
                            "spin_inertia_error": {"dist": "normal", "mean": 0.0, "std": 0.02}}},
}


@dataclasses.dataclass
class Sweep:
    mission: object
    controller: object
    gains: object
    inputs: tuple
    values: dict
    summary: dict
    out: object


CHUNK = 16  # the sweep's chunk on two devices (8 samples each at least): the samples padded to it


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    """``so3jax sweep`` with ``sweep.margins_at``: its chunk's margins of the three samples."""
    table = {"mission": str(ROOT / "missions" / "flight.toml"), "T": 20.0, "controllers": ["pd"],
             "sensors": {"gyro": False, "star_tracker": False}, "estimator": {"kind": "truth"},
             "sweep": {"samples": 3, "chunk": CHUNK, "margins_at": list(TIMES)}, "dispersions": DISPERSIONS}
    config = sweep_config.config_from_dict(table)
    out = tmp_path_factory.mktemp("sweep")
    summary = engine.run_sweep(config, out, progress=False)
    mission = config.mission
    inputs = batched.inputs(draw.draw(config.dispersions, config.leaves, 0, 3, 20), np.float64)
    with np.load(out / "chunks" / "pd-000000000.npz") as chunk:
        values = {k.removeprefix(sweep_margins.PREFIX): chunk[k] for k in chunk.files
                  if k.startswith(sweep_margins.PREFIX)}
    values = {k: v.astype(bool) if k in ("stable", "at_limit") else v for k, v in values.items()}
    return Sweep(mission, mission.controller("pd")[0], mission.gains["pd"], inputs, values, summary, out)


def _margins(sweep, leaves):
    """sample_margins of the three samples with component values ``leaves``, padded to the
    sweep's chunk (its compiled programs)."""
    params, _ = sweep.inputs
    pad = lambda x: np.concatenate([x, np.repeat(x[-1:], CHUNK - 3, axis=0)])
    inputs = (type(params)(*map(pad, params)), {k: pad(v) for k, v in leaves.items()})
    values = sweep_margins.sample_margins(inputs, sweep.gains, controller=sweep.controller, mission=sweep.mission,
                                          times=TIMES)
    return {k: v[:3] for k, v in values.items()}


def test_the_sweep_reports_each_sample_s_margins(sweep):
    """summary.json's worst cases and samples.csv's columns come from the chunks' margins."""
    entry = sweep.summary["margins"]["pd"]["times"]
    assert [e["t"] for e in entry] == list(TIMES) and all(e["stable"] == 3 for e in entry)
    worst = int(np.argmin(sweep.values["disk_db"][:, 1]))
    assert entry[1]["worst"]["disk_db"] == {"value": float(sweep.values["disk_db"][worst, 1]), "sample": worst,
                                            "axis": None}
    with np.load(sweep.out / "samples.npz") as table:
        np.testing.assert_array_equal(table["pd_disk_db_at_19.9s"], sweep.values["disk_db"][:, 1])
        np.testing.assert_array_equal(table["pd_pm_deg_at_10s"], sweep.values["phase_margin_deg"][:, 0].min(axis=1))
    column_units = sweep.summary["units"]["columns"]
    assert [column_units[f"pd_{k}_at_10s"] for k in ("loop_stable", "disk_db", "gm_lower_db", "pm_deg", "delay_s")] == [
        "-", "dB", "dB", "deg", "s"]
    assert "Stability margins of pd's loop" in (sweep.out / "summary.md").read_text()
    assert (sweep.out / "margins.png").exists()


def _alone(mission, inputs, i: int):
    """Sample i of ``inputs`` as a mission of its own: its inertias, time constant, initial
    state and wheel values written into the mission."""
    params, leaves = inputs
    p = type(params)(*(np.asarray(x[i]) for x in params))
    actuator = dict(mission.actuator, wheels=dict(mission.actuator["wheels"]))
    for key, value in leaves.items():
        actuator["wheels"][key.split(".")[-1]] = np.asarray(value[i])
    return dataclasses.replace(
        mission, J0=p.J0, J1=p.J1, J2=p.J2, J1_scale=None, tau_J=float(p.tau_J), n=float(p.n),
        disturbance={"amplitude": float(p.amplitude), "frequency": float(p.frequency),
                     "noise_std": float(p.noise_std)},
        initial={"attitude": Rotation.from_matrix(p.R0).as_rotvec(), "rate": p.Omega0}, actuator=actuator)


def test_each_sample_s_margins_are_its_mission_s_flown_alone(sweep):
    v = sweep.values
    assert v["stable"].shape == v["disk_db"].shape == (3, 2) and v["phase_margin_deg"].shape == (3, 2, 3)
    assert v["stable"].all() and not v["at_limit"].any()
    assert np.all(np.isfinite(v["disk_db"])) and len(np.unique(v["disk_db"])) == 6  # the samples differ
    for i in range(3):
        alone = _alone(sweep.mission, sweep.inputs, i)
        for k, t in enumerate(TIMES):
            _, classical, disk = jobs_margins.at(alone, "pd", t)
            assert classical.stable and not classical.at_limit
            np.testing.assert_allclose(v["spectral_radius"][i, k], classical.spectral_radius, rtol=1e-12)
            for name, value in (("disk_alpha", disk.multiloop.alpha), ("disk_db", disk.multiloop.gain_margin_upper_db),
                                ("disk_phase_deg", disk.multiloop.phase_margin_deg)):
                np.testing.assert_allclose(v[name][i, k], value, rtol=1e-9, err_msg=name)
            for name in ("gain_margin_upper_db", "phase_margin_deg", "delay_margin_s"):
                np.testing.assert_allclose(v[name][i, k], [getattr(a, name) for a in classical.axes], rtol=1e-9,
                                           err_msg=name)
            # the lower margin as its gain factor in (0, 1): one near 0 (-84 dB, |L_i| ~ 2e4 as omega -> 0) moves
            # by up to 1e-5 of itself for 1e-16 of A, which batching changes
            lower = lambda db: 10.0 ** (np.asarray(db) / 20.0)
            np.testing.assert_allclose(lower(v["gain_margin_lower_db"][i, k]),
                                       lower([a.gain_margin_lower_db for a in classical.axes]), rtol=1e-9, atol=1e-9)


def test_a_sample_s_component_value_moves_its_margins_only(sweep):
    """Sample 1's wheels with half the spin inertia error and a torque limit below its command:
    its margins move (the limit binds, its channel opens); samples 0 and 2 keep theirs, bit for bit.
    Sample 0's spin inertia error NaN: its flight and margins NaN, the others' kept."""
    params, leaves = sweep.inputs
    changed = {k: v.copy() for k, v in leaves.items()}
    changed["actuator.wheels.max_torque"][1] = 1e-4
    changed["actuator.wheels.spin_inertia_error"][1] *= 0.5
    again = _margins(sweep, changed)
    assert again["at_limit"][1].all() and not again["at_limit"][[0, 2]].any()
    for name, value in again.items():
        np.testing.assert_array_equal(value[[0, 2]], sweep.values[name][[0, 2]], err_msg=name)
    for name in ("spectral_radius", "disk_db", "phase_margin_deg"):
        assert not np.array_equal(again[name][1], sweep.values[name][1], equal_nan=True), name
    # sample 0's flight gone non-finite: no margins, no verdict; the others' as they were
    changed = {k: v.copy() for k, v in leaves.items()}
    changed["actuator.wheels.spin_inertia_error"][0] = np.nan
    again = _margins(sweep, changed)
    assert not again["stable"][0].any() and np.isnan(again["disk_db"][0]).all()
    assert np.isnan(again["phase_margin_deg"][0]).all()
    for name, value in again.items():
        np.testing.assert_array_equal(value[1:], sweep.values[name][1:], err_msg=name)


def _values():
    """Four samples at two times, sample 1 unstable at the first."""
    stable = np.array([[True, True], [False, True], [True, True], [True, True]])
    disk = np.array([[5.0, 4.0], [np.nan, 1.0], [2.5, 7.0], [3.0, 6.0]])
    per_axis = lambda x: np.broadcast_to(np.asarray(x, float)[..., None], (4, 2, 3)).copy()
    lower, upper = per_axis([[-8, -9], [np.nan, -9], [-9, -9], [-10, -9]]), per_axis(np.full((4, 2), 40.0))
    lower[3, 0, 2] = -2.0  # the lower gain margin nearest 0 dB: sample 3, axis z
    upper[1, 0] = np.nan
    upper[2, 0, 0], upper[0, 1, 1] = 30.0, 12.0
    phase = per_axis([[60, 50], [np.nan, 45], [70, 50], [55, 50]])
    phase[2, 0, 1] = math.inf  # no gain crossover: never the worst
    delay = per_axis([[20, 30], [np.nan, 30], [10, 30], [25, 30]])
    return {"stable": stable, "at_limit": np.zeros((4, 2), bool), "disk_db": disk, "gain_margin_lower_db": lower,
            "gain_margin_upper_db": upper, "phase_margin_deg": phase, "delay_margin_s": delay}


def test_the_summary_s_worst_cases_name_their_samples():
    index = np.array([10, 11, 12, 13])  # the sweep's sample numbers of the rows
    summary = sweep_margins.summarize(_values(), (1.0, 2.0), ("capture", "capture"), index)
    first, second = summary["times"]
    assert (first["t"], first["phase"], first["stable"], first["samples"]) == (1.0, "capture", 3, 4)
    assert first["stable_share"] == 0.75 and first["unstable_samples"] == [11] and second["stable_share"] == 1.0
    worst = first["worst"]
    assert worst["disk_db"] == {"value": 2.5, "sample": 12, "axis": None}  # unstable sample 11 has none
    assert worst["gain_margin_lower_db"] == {"value": -2.0, "sample": 13, "axis": 2}
    assert worst["gain_margin_upper_db"] == {"value": 30.0, "sample": 12, "axis": 0}
    assert worst["phase_margin_deg"] == {"value": 55.0, "sample": 13, "axis": 0}
    assert worst["delay_margin_s"] == {"value": 10.0, "sample": 12, "axis": 0}
    assert second["worst"]["disk_db"] == {"value": 1.0, "sample": 11, "axis": None}
    assert second["worst"]["gain_margin_upper_db"] == {"value": 12.0, "sample": 10, "axis": 1}
    assert second["worst"]["phase_margin_deg"]["sample"] == 11
    for q in summary["quantiles"]:
        assert first["disk_db_quantiles"][f"p{100 * q:g}"] == pytest.approx(np.quantile([5.0, 2.5, 3.0], q))
    lines = sweep_margins.format_lines(summary)
    assert lines[2].startswith("| 1 | capture | 3/4 | 0 |")
    assert "2.50 (#12)" in lines[7] and "-2.00 (#13, z)" in lines[7]
    assert lines[-1] == "Unstable samples (no margins): t = 1 s: 11"
    nothing = sweep_margins.summarize({k: v[1:2, :1] for k, v in _values().items()}, (1.0,), ("capture",))
    assert nothing["times"][0]["worst"]["disk_db"] == {"value": None, "sample": None, "axis": None}
    assert nothing["times"][0]["disk_db_quantiles"]["p50"] is None


SCENARIO_LEAVES = {"T": 8.0, "controllers": ["pd"], "control": {"period": 0.1},
                   "sensors": {"gyro": False, "star_tracker": False}, "estimator": {"kind": "truth"},
                   "actuator": {"kind": "ideal"}, "momentum": {"kind": "none"},  # the smallest sampled loop
                   "phases": {"names": ["mission"], "start": [0.0]},
                   "inertia": {"kind": "events", "events": {"initial": [[900.0, 0.0, 0.0], [0.0, 800.0, 0.0],
                                                                        [0.0, 0.0, 600.0]],
                                                            "times": [2.0], "targets": [1.5], "time_constants": [0.0]}},
                   "reference": {"kind": "slews", "slews": {"attitudes": [[0.02, 0.0, 0.0]], "times": [1.0],
                                                            "max_rate": 0.05, "max_acceleration": 0.05}}}


def test_dispersed_reference_and_inertia_leaves_give_each_sample_its_margins():
    """Slew times and inertia-event times and targets dispersed (reference- and inertia-kind
    leaves): each sample's margins are those of the mission written with its values."""
    from so3jax.missions import mission as missions

    m = missions.from_dict(SCENARIO_LEAVES)
    offset = {"dist": "uniform", "low": -0.5, "high": 0.5, "relative": "offset"}  # [s]
    table = {"reference": {"slews": {"times": offset}},
             "inertia": {"events": {"times": offset, "targets": {"dist": "uniform", "low": 1.2, "high": 1.8}}}}
    samples = draw.draw(*draw.parse(table, m), 0, 2, 20, mission=m)
    assert samples.valid.all()
    inputs = batched.inputs(samples, np.float64)
    controller, gains = m.controller("pd")
    values = sweep_margins.sample_margins(inputs, gains, controller=controller, mission=m, times=(4.0,))
    assert values["stable"].all() and values["disk_db"][0, 0] != values["disk_db"][1, 0]
    leaves = samples.leaves
    own = {"reference": {"kind": "slews", "slews": dict(SCENARIO_LEAVES["reference"]["slews"],
                                                        times=leaves["reference.slews.times"][0].tolist())},
           "inertia": {"kind": "events", "events": dict(SCENARIO_LEAVES["inertia"]["events"],
                                                        times=leaves["inertia.events.times"][0].tolist(),
                                                        targets=leaves["inertia.events.targets"][0].tolist())}}
    _, classical, disk = jobs_margins.at(missions.from_dict({**SCENARIO_LEAVES, **own}), "pd", 4.0)
    np.testing.assert_allclose(values["spectral_radius"][0, 0], classical.spectral_radius, rtol=1e-12)
    np.testing.assert_allclose(values["disk_db"][0, 0], disk.multiloop.gain_margin_upper_db, rtol=1e-9)
