"""A mission's [dispersions] table: its leaves, their draws, each sample's scenario and loop."""

from __future__ import annotations

import csv
import warnings
from pathlib import Path

import jax
import numpy as np
import pytest

from so3jax.dynamics.inertia import InertiaWarning
from so3jax.missions import batched, draw, mission
from tests._host_devices import host_devices_env

ROOT = Path(__file__).resolve().parents[1]
LEAVES = {
    "sensors": {"gyro": {"arw": {"dist": "lognormal", "median": 1e-6, "sigma": 0.3}}},
    "actuator": {"wheels": {"max_torque": {"dist": "uniform", "low": 0.2, "high": 0.3}}},
}


@pytest.fixture(scope="module")
def flight():
    return mission.load(None, ["T=1.0"])


def test_component_leaves_draw_each_element_from_its_distribution(flight):
    _, leaves = draw.parse(LEAVES, flight)
    values, valid = draw.draw_leaves(leaves, 3, 4000)
    torque, arw = values["actuator.wheels.max_torque"], values["sensors.gyro.arw"]
    assert torque.shape == (4000, 4) and arw.shape == (4000,) and valid.all()
    # uniform on [0.2, 0.3]: mean 0.25 +- 4 standard errors, every wheel its own draw
    se = 0.1 / np.sqrt(12 * 4000)
    assert np.all(np.abs(torque.mean(axis=0) - 0.25) < 4 * se) and torque.min() >= 0.2 and torque.max() <= 0.3
    assert np.max(np.abs(np.corrcoef(torque.T) - np.eye(4))) < 4 / np.sqrt(4000)
    # lognormal: log values normal with sigma 0.3 around log(1e-6)
    logs = np.log(arw / 1e-6)
    assert abs(logs.mean()) < 4 * 0.3 / np.sqrt(4000) and abs(logs.std() - 0.3) < 0.03


def test_a_leaf_s_draws_do_not_move_when_another_is_added(flight):
    one = draw.draw_leaves(draw.parse({"sensors": LEAVES["sensors"]}, flight)[1], 0, 16)[0]
    both = draw.draw_leaves(draw.parse(LEAVES, flight)[1], 0, 16)[0]
    np.testing.assert_array_equal(one["sensors.gyro.arw"], both["sensors.gyro.arw"])
    other_seed = draw.draw_leaves(draw.parse(LEAVES, flight)[1], 1, 16)[0]
    assert not np.any(other_seed["sensors.gyro.arw"] == both["sensors.gyro.arw"])


def test_values_outside_the_parameter_domain_reject_the_sample(flight):
    _, leaves = draw.parse({"actuator": {"wheels": {"initial_speed": {"dist": "normal", "mean": 0.0, "std": 1.0}}},
                            "sensors": {"gyro": {"rrw": {"dist": "normal", "mean": 1e-9, "std": 1e-9}}}}, flight)
    values, valid = draw.draw_leaves(leaves, 0, 2000)
    negative = values["sensors.gyro.rrw"] < 0
    assert 0.05 < negative.mean() < 0.3  # P(N(1, 1) < 0) = 0.16
    np.testing.assert_array_equal(valid, ~negative)


def test_the_sampled_loop_carries_the_drawn_values_and_the_filter_keeps_the_nominal(flight):
    _, leaves = draw.parse(LEAVES, flight)
    values, _ = draw.draw_leaves(leaves, 0, 2)
    loop = batched.loop(flight, {k: v[1] for k, v in values.items()}, np.float64)
    np.testing.assert_allclose(np.asarray(loop.sensors.rate.arw), values["sensors.gyro.arw"][1], rtol=1e-15)
    np.testing.assert_allclose(np.asarray(loop.actuator.max_torque), values["actuator.wheels.max_torque"][1],
                               rtol=1e-15)
    assert float(loop.estimator.arw) == 1e-6  # the filter assumes the datasheet's value


@pytest.mark.parametrize(("table", "message"), [
    ({"sensors": {"gyro": {"nope": 1.0}}}, "has no parameter 'nope'"),
    ({"sensors": {"star_tracker": {"every": 2}}}, "only real-valued"),
    ({"actuator": {"saturated": {"max_torque": 1.0}}}, "flies no actuator 'saturated'"),
    ({"gains": {"pd": {"k_R": 1.0}}}, "cannot be dispersed"),
    ({"sensors": {"gyro": {"arw": {"dist": "uniform", "low": -1.0, "high": 1.0}}}}, "outside that domain"),
    ({"seed": 3}, "random"),
    ({"seed": "fixed"}, "mission"),
    ({"inertia": {"J0": {"size": 1.0}}}, "unknown key"),
    ({"initial": {"attitude": {"max_angle_deg": 200.0}}}, "max_angle_deg"),
    ({"deployment": {"tau_J": {"dist": "uniform", "low": -1.0, "high": 1.0}}}, "tau_J"),
])
def test_bad_dispersions_are_one_line_errors(flight, table, message):
    with pytest.raises(ValueError, match=message) as err:
        draw.parse(table, flight)
    assert "\n" not in str(err.value)


UNIFORM = {"dist": "uniform", "low": 0.0, "high": 1.0}


@pytest.mark.parametrize(("table", "message"), [
    ({"foo": {"bar": UNIFORM}},
     "dispersions.foo.bar cannot be dispersed: dispersible are inertia.J0/J1/J2, deployment.tau_J, orbit.n, the "
     "parameters of the reference and inertia kinds (the mission's, reference.kind = 'paper' and inertia.kind = "
     "'paper', have none), "),
    ({"reference": {"paper": {"x": UNIFORM}}},
     "dispersions.reference.paper.x cannot be dispersed: reference.kind = 'paper' has no dispersible parameter"),
])
def test_a_key_that_cannot_be_dispersed_is_named_with_the_keys_that_can(flight, table, message):
    """The message names the user's keys (the mission's reference and inertia kinds' own),
    never the module's tables."""
    with pytest.raises(ValueError) as err:
        draw.parse(table, flight)
    assert str(err.value).startswith(message) and "\n" not in str(err.value)
    assert "SCENARIO_LEAVES" not in str(err.value)


def test_a_scenario_key_that_cannot_be_dispersed_lists_the_mission_s_own():
    slews = mission.from_dict(EVENTS)
    for table, known in [({"reference": {"slews": UNIFORM}}, "the parameters of the mission's reference and inertia "
                          "kinds (reference.slews.start, reference.slews.attitudes, reference.slews.times, "
                          "reference.slews.max_rate, reference.slews.max_acceleration, inertia.events.initial, "
                          "inertia.events.times, inertia.events.time_constants, inertia.events.targets), "),
                         ({"inertia": {"events": {"bogus": UNIFORM}}}, "dispersions.inertia.events.bogus cannot be "
                          "dispersed: dispersible are inertia.events.initial, inertia.events.times, "
                          "inertia.events.time_constants, inertia.events.targets")]:
        with pytest.raises(ValueError) as err:
            draw.parse(table, slews)
        assert known in str(err.value) and "SCENARIO_LEAVES" not in str(err.value)


def test_the_paper_mission_s_structured_dispersions_keep_the_recorded_samples():
    """sweeps/default.toml's dispersions on its mission (missions/paper.toml on a rigid body's J0)
    draw the samples that sweeps/default/samples.csv records, within 1e-12 of each column's
    largest magnitude (a small product of inertia is the difference of large terms: its own
    relative round-off differs between CPUs' vector units)."""
    from so3jax.jobs import sweep

    config = sweep.load_config(ROOT / "sweeps" / "default.toml")
    d, leaves = draw.parse(config.table, config.mission)
    assert leaves == ()
    rows = list(csv.DictReader(open(ROOT / "sweeps" / "default" / "samples.csv")))
    s = draw.draw_samples(d, 0, len(rows), 20)
    p = s.params
    got = {"tau_J": p.tau_J, "n": p.n, "amplitude": p.amplitude, "frequency": p.frequency, "noise_std": p.noise_std,
           "disturbance_seed": p.seed, "draws": s.draws}
    for J in ("J0", "J1", "J2"):
        M = getattr(p, J)
        pairs = {"xx": (0, 0), "yy": (1, 1), "zz": (2, 2), "xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}
        for name, (i, j) in pairs.items():
            got[f"{J}_{name}"] = M[:, i, j]
    for axis, name in enumerate("xyz"):
        got[f"Omega0_{name}"], got[f"attitude_error_{name}"] = p.Omega0[:, axis], s.attitude_error[:, axis]
    for key, values in got.items():
        recorded = np.array([float(r[key]) for r in rows])
        np.testing.assert_allclose(values, recorded, rtol=1e-12, atol=1e-12 * np.max(np.abs(recorded)), err_msg=key)


FLIGHT_SWEEP = {
    "mission": str(ROOT / "missions" / "flight.toml"),
    "T": 1.0, "controllers": ["pd"], "gains": {"pd": {"k_R": 50.0, "k_Omega": 400.0}},  # wheels at their limits
    "initial": {"rate": [0.02, -0.01, 0.015]},
    "record_every": 10,  # pointing errors at every tick
    "requirements": [{"index": "AKE", "axis": "angle", "level": 0.9, "limit": 1e6, "interpretation": "ensemble"},
                     {"index": "APE", "axis": "angle", "level": 0.5, "limit": 1e-3, "interpretation": "mixed"}],
    "sweep": {"samples": 8, "chunk": 8},  # pointing: on for the mission's requirements
    "dispersions": {**LEAVES, "inertia": {"J0": {"scale": {"dist": "uniform", "low": 0.8, "high": 1.2}}}},
}
FLIGHT_SWEEP["dispersions"]["actuator"] = {"wheels": {
    **LEAVES["actuator"]["wheels"],
    "misalignment": {"dist": "normal", "mean": 0.0, "std": 0.05},  # the plant's spin axes, the controller's nominal
    "spin_inertia_error": {"dist": "normal", "mean": 0.0, "std": 0.1},
}}


@pytest.fixture(scope="module")
def flight_sweep(tmp_path_factory):
    """(config, output folder, summary) of FLIGHT_SWEEP run on one device, one chunk."""
    from so3jax.jobs import sweep

    cfg = sweep.config_from_dict(FLIGHT_SWEEP)
    out = tmp_path_factory.mktemp("flight") / "out"
    return cfg, out, sweep.run_sweep(cfg, out, progress=False)


def samples(out: Path) -> dict:
    with np.load(out / "samples.npz") as f:
        return {k: f[k] for k in f.files}


def test_a_flight_sweep_flies_each_sample_s_drawn_values(flight_sweep):
    """A sweep of the flight mission dispersing a sensor, actuator leaves (torque limits,
    misalignment, spin-inertia errors) and an inertia leaf: each sample's metrics, flight
    metrics and pointing errors equal those of the mission written with that sample's values
    and flown on its own (the filter assuming the nominal gyro), and differ between samples;
    the mission's requirements are checked over the samples."""
    from so3jax.jobs import fly
    from so3jax.jobs.sweep import pointing as sweep_pointing
    from so3jax.results.io import to_builtin
    from so3jax.sim import pointing

    cfg, out, summary = flight_sweep
    assert cfg.pointing  # the mission declares requirements
    t = samples(out)
    with np.load(out / "chunks" / "pd-000000000.npz") as f:
        e_p, e_k = f["pointing_performance"], f["pointing_knowledge"]
    assert e_p.shape == e_k.shape == (8, 10, 3)
    assert (out / "pointing.png").exists()
    checked = summary["pointing"]["pd"]["requirements"]
    assert [q["passed"] for q in checked] == [True, False]
    assert sweep_pointing.failed(summary) == [f"pd: {checked[1]['requirement']}"]
    x = pointing.magnitudes(e_p)[..., 3].ravel()  # mixed APE at 0.5: the 40th smallest of 80
    assert checked[1]["value"] == pytest.approx(np.sort(x)[39] * pointing.ARCSEC, rel=1e-12)
    assert len(np.unique(t["pd_effort"])) == 8 and len(np.unique(t["pd_rmse"])) == 8
    assert (out / "flight.png").exists()  # time at a torque limit against the dispersed limit
    column_units = summary["units"]["columns"]  # pointing [arcsec]; a dispersed leaf's declared unit
    assert {column_units[k] for k in column_units if k.endswith("_arcsec")} == {"arcsec"}
    assert column_units["actuator.wheels.max_torque_1"] == "N m" and set(column_units) == set(t)
    for i in (0, 5):
        J = {name: [[t[f"{name}_{a}{b}" if f"{name}_{a}{b}" in t else f"{name}_{b}{a}"][i] for b in "xyz"]
                    for a in "xyz"]
             for name in ("J0", "J1", "J2")}
        per_wheel = lambda key: to_builtin([t[f"actuator.wheels.{key}_{w}"][i] for w in range(1, 5)])
        overrides = [f"sensors.gyro.arw={float(t['sensors.gyro.arw'][i])!r}", "estimator.mekf.arw=1e-6",
                     f"actuator.wheels.max_torque={per_wheel('max_torque')}",
                     f"actuator.wheels.spin_inertia_error={per_wheel('spin_inertia_error')}",
                     "actuator.wheels.misalignment="
                     + repr(to_builtin([[t[f"actuator.wheels.misalignment_{3 * w + a + 1}"][i] for a in range(3)]
                                        for w in range(4)])),
                     *(f"inertia.{name}.nominal={to_builtin(J[name])}" for name in ("J0", "J1", "J2")),
                     f"deployment.tau_J={float(t['tau_J'][i])!r}"]
        tables = {k: v for k, v in FLIGHT_SWEEP.items() if k not in ("sweep", "dispersions")}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", InertiaWarning)  # the drawn J0 and J1 = 2 J0, as in the sweep
            result = fly.fly(mission.from_dict(_with(tables, overrides)))[0]["pd"]
        for key in ("rmse", "effort"):
            np.testing.assert_allclose(float(result.metrics._asdict()[key]), t[f"pd_{key}"][i], rtol=1e-12, err_msg=key)
        for key, value in result.flight._asdict().items():
            np.testing.assert_allclose(float(value), t[f"pd_{key}"][i], rtol=1e-12, atol=1e-15, err_msg=key)
        alone = pointing.signals(result.history)
        np.testing.assert_allclose(alone.performance, e_p[i], rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose(alone.knowledge, e_k[i], rtol=1e-7, atol=1e-13)  # arcsec-level errors
        np.testing.assert_allclose(alone.t, sweep_pointing.times(cfg, 10), rtol=1e-12, atol=1e-15)
        assert t["pd_time_at_torque_limit"][i] > 0  # the limits bind: the dispersed limits matter


def test_a_flight_sweep_s_samples_do_not_depend_on_the_devices_and_chunks(flight_sweep, tmp_path):
    """The same flight sweep over 4 forced host devices, in chunks of 32 (8 per device, the
    samples padded): in a subprocess (XLA flags must precede JAX) compiling with this process's
    optimizations. Each sample's loop is built per trajectory inside the batched program: the
    values equal the one-device run's to round-off, 1e-12 relative, and 1e-16 absolute for the
    round-off-sized ones (the orthogonality error, the MEKF's arcsecond-level attitude error)."""
    import json
    import subprocess
    import sys

    child = ("import json, sys, pathlib; from so3jax import configure_xla; configure_xla(); import jax; "
             "jax.config.update('jax_enable_x64', True); from so3jax.jobs import sweep; "
             "d = json.loads(sys.argv[1]); d['sweep']['chunk'] = 32; "
             "sweep.run_sweep(sweep.config_from_dict(d), pathlib.Path(sys.argv[2]), progress=False); "
             "print(jax.device_count())")
    env = host_devices_env(4)
    proc = subprocess.run([sys.executable, "-c", child, json.dumps(FLIGHT_SWEEP), str(tmp_path / "out")], env=env,
                          capture_output=True, text=True, timeout=600, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.split()[-1] == "4"
    one, four = samples(flight_sweep[1]), samples(tmp_path / "out")
    assert sorted(one) == sorted(four)
    for key, values in one.items():
        if values.dtype.kind == "f":
            np.testing.assert_allclose(four[key], values, rtol=1e-12, atol=1e-16, err_msg=key)
        else:
            np.testing.assert_array_equal(four[key], values, err_msg=key)


def _with(tables: dict, overrides: list) -> dict:
    from so3jax.missions import config as cfg

    d = cfg.read_toml(tables["mission"])
    d = mission.merge_tables(d, {k: v for k, v in tables.items() if k != "mission"})
    for item in overrides:
        cfg.set_dotted(d, *cfg.parse_override(item))
    return d


EVENTS = {"T": 12.0, "controllers": ["pd"], "record_every": 10,
          "control": {"mode": "continuous"}, "sensors": {"gyro": False, "star_tracker": False},
          "estimator": {"kind": "truth"}, "actuator": {"kind": "ideal"},  # the smallest loop: a quick compile
          "momentum": {"kind": "none"},
          "phases": {"names": ["mission"], "start": [0.0]},
          "inertia": {"kind": "events", "events": {"initial": [[900.0, 0.0, 0.0], [0.0, 800.0, 0.0], [0.0, 0.0, 600.0]],
                                                   "times": [2.0, 6.0], "targets": [1.5, 0.8],
                                                   "time_constants": [0.0, 1.5]}},
          "reference": {"kind": "slews", "slews": {"attitudes": [[0.1, 0.0, 0.0], [0.1, 0.1, 0.0]],
                                                   "times": [3.0, 8.0], "max_rate": 0.05,
                                                   "max_acceleration": 0.05}}}  # each slew 4 s
OFFSET = {"dist": "uniform", "low": -3.0, "high": 3.0, "relative": "offset"}  # [s]: some slews overlap
BODY = {"scale": {"dist": "lognormal", "median": 1.0, "sigma": 0.1},  # an inertia drawn as inertia.J0 is
        "second_moments": {"dist": "lognormal", "median": 1.0, "sigma": 0.1}, "rotation_deg": 5.0}
EVENT_DISPERSIONS = {"inertia": {"events": {"initial": BODY, "times": {"dist": "uniform", "low": 1.0, "high": 7.0},
                                            "time_constants": {"dist": "uniform", "low": 0.0, "high": 3.0},
                                            "targets": {"dist": "lognormal", "median": 1.0, "sigma": 0.2}}},
                     "reference": {"slews": {"times": OFFSET, "attitudes": {"dist": "normal", "mean": 0.0, "std": 0.02,
                                                                            "relative": "offset"}}}}


def test_dispersed_slews_and_inertia_events_fly_each_sample_s_own():
    """Slew times and attitudes (offsets from the mission's) and inertia-event times, time
    constants, scales and the initial inertia (a rigid body's) drawn per sample; a sample
    whose slews overlap or whose event times do not increase is rejected, as the mission
    file's checks refuse them. Each sample's R_d,
    Omega_d, Omega_d' (its own slews, evaluated lane by lane in a batch) and J(t) are those
    of the mission written with its values, and the batch flies each sample's own: a batch
    of one sample's values repeated gives that sample's metrics (the same compiled program)."""
    from so3jax.missions import build
    from so3jax.missions import mission as missions

    m = missions.from_dict(EVENTS)
    parsed, leaves = draw.parse(EVENT_DISPERSIONS, m)
    samples = draw.draw(parsed, leaves, 0, 16, 20, mission=m)
    slews, events = samples.leaves["reference.slews.times"], samples.leaves["inertia.events.times"]
    offsets = slews - np.array([3.0, 8.0])
    assert np.all(np.abs(offsets) <= 3.0) and len(np.unique(offsets)) == 32
    overlap = np.diff(slews, axis=1)[:, 0] < 3.9  # 0.1 rad (+- 0.02 per axis) per slew: about 4 s each
    assert np.any(overlap) and not np.any(samples.valid & overlap)
    assert not np.any(samples.valid & (np.diff(events, axis=1)[:, 0] <= 0))
    valid = np.flatnonzero(samples.valid)  # a sweep flies the valid samples alone
    assert len(valid) >= 3
    inputs = jax.tree.map(lambda x: x[valid], batched.inputs(samples, np.float64))
    scenarios = jax.vmap(lambda p, v: build.scenario(batched.scenario_values(m, v), p))(*inputs)
    batch_last = lambda tree: jax.tree.map(lambda x: np.moveaxis(x, 0, -1), tree)  # a batched rollout's layout

    @jax.jit
    def evaluate(reference, inertia):  # R_d, Omega_d, Omega_d', J at the times t, time first
        at = lambda f: jax.vmap(lambda s: f(s, 0))(np.linspace(0.0, 12.0, 25))
        return at(reference.attitude), at(reference.rate), at(reference.rate_dot), at(inertia)

    together = evaluate(batch_last(scenarios.reference), batch_last(scenarios.inertia))
    for j, i in enumerate(valid):
        own = {"reference": {"kind": "slews", "slews": dict(
                   EVENTS["reference"]["slews"], times=slews[i].tolist(),
                   attitudes=samples.leaves["reference.slews.attitudes"][i].tolist())},
               "inertia": {"kind": "events", "events": {
                   "initial": samples.leaves["inertia.events.initial"][i].tolist(),
                   "times": events[i].tolist(),
                   "targets": samples.leaves["inertia.events.targets"][i].tolist(),
                   "time_constants": samples.leaves["inertia.events.time_constants"][i].tolist()}}}
        alone = build.scenario(missions.from_dict({**EVENTS, **own}))
        expected = evaluate(alone.reference, alone.inertia)
        for name, got, want, tol in zip(("R_d", "Omega_d", "Omega_d'", "J"), together, expected,
                                        (1e-14, 1e-15, 1e-15, 1e-10)):  # exp's round-off; J ~ 1e3 kg m^2
            np.testing.assert_allclose(got[..., j], want, rtol=0, atol=tol, err_msg=name)
    controller, gains = m.controller("pd")
    fly = jax.jit(batched.sample_metrics, static_argnames=("controller", "mission"))
    batch = fly(inputs, gains, controller=controller, mission=m)
    assert len(np.unique(np.asarray(batch["rmse"]))) == len(valid)
    repeated = jax.tree.map(lambda x: np.repeat(x[1:2], len(valid), axis=0), inputs)
    one = fly(repeated, gains, controller=controller, mission=m)
    for name in ("rmse", "effort", "max_torque", "max_angle_phase"):
        np.testing.assert_allclose(one[name][0], batch[name][1], rtol=1e-12, err_msg=name)


@pytest.mark.parametrize("kind", ["linear", "table"])
def test_a_dispersed_inertia_table_gives_each_sample_its_own(kind):
    """inertia.linear (its start) and inertia.table (its inertias): each inertia drawn as a
    rigid body's (the second-moments form), the times around the mission's; each sample's
    J(t), its table evaluated lane by lane in a batch, is the mission's written with its
    values."""
    from so3jax.missions import build
    from so3jax.missions import mission as missions

    J = np.asarray(EVENTS["inertia"]["events"]["initial"])
    given = ({"start": J.tolist(), "end": (1.5 * J).tolist(), "times": [2.0, 8.0]} if kind == "linear"
             else {"times": [2.0, 5.0, 8.0], "inertias": [J.tolist(), (1.2 * J).tolist(), (0.9 * J).tolist()]})
    drawn = "start" if kind == "linear" else "inertias"
    mission = {**EVENTS, "reference": {"kind": "inertial"}, "inertia": {"kind": kind, kind: given}}
    m = missions.from_dict(mission)
    table = {"inertia": {kind: {drawn: BODY, "times": {**OFFSET, "low": -1.0, "high": 1.0}}}}
    samples = draw.draw(*draw.parse(table, m), 0, 4, 20, mission=m)
    inertias = samples.leaves[f"inertia.{kind}.{drawn}"]
    moments = np.linalg.eigvalsh(inertias)
    assert samples.valid.all() and np.all(moments[..., 0] + moments[..., 1] >= moments[..., 2])  # bodies
    assert len(np.unique(inertias[..., 0, 0])) == inertias[..., 0, 0].size
    np.testing.assert_allclose(inertias, np.swapaxes(inertias, -1, -2), rtol=1e-15)
    inputs = batched.inputs(samples, np.float64)
    profiles = jax.vmap(lambda p, v: build.scenario(batched.scenario_values(m, v), p).inertia)(*inputs)
    lanes = jax.tree.map(lambda x: np.moveaxis(x, 0, -1), profiles)
    t = np.linspace(0.0, 10.0, 11)
    got = jax.jit(lambda profile: jax.vmap(lambda s: profile(s, 0))(t))(lanes)
    for i in range(4):
        own = {**given, drawn: inertias[i].tolist(), "times": samples.leaves[f"inertia.{kind}.times"][i].tolist()}
        alone = build.scenario(missions.from_dict({**mission, "inertia": {"kind": kind, kind: own}})).inertia
        np.testing.assert_allclose(got[..., i], jax.vmap(lambda s: alone(s, 0))(t), rtol=1e-14)


def test_a_dispersed_attitude_table_gives_each_sample_its_own_times():
    """reference.table: its times around the mission's (a sample whose times do not increase
    rejected); each sample's R_d, Omega_d, Omega_d', its table evaluated lane by lane in a
    batch, are those of the mission written with its times."""
    from so3jax.missions import build
    from so3jax.missions import mission as missions

    half = np.sqrt(0.5)
    mission = {**EVENTS, "inertia": {"J": EVENTS["inertia"]["events"]["initial"]},
               "reference": {"kind": "table", "table": {
                   "times": [0.0, 1.0, 2.0, 3.0], "quaternions": [[1.0, 0.0, 0.0, 0.0], [0.99, 0.1, 0.0, 0.0],
                                                                 [0.98, 0.1, 0.1, 0.0], [half, 0.0, 0.0, half]]}}}
    mission["reference"]["table"]["quaternions"] = (np.asarray(mission["reference"]["table"]["quaternions"])
                                                    / np.linalg.norm(mission["reference"]["table"]["quaternions"],
                                                                     axis=1, keepdims=True)).tolist()
    m = missions.from_dict(mission)
    table = {"reference": {"table": {"times": {**OFFSET, "low": -0.9, "high": 0.9}}}}
    samples = draw.draw(*draw.parse(table, m), 0, 12, 20, mission=m)
    times = samples.leaves["reference.table.times"]
    np.testing.assert_array_equal(samples.valid, np.all(np.diff(times, axis=1) > 0, axis=1))
    valid = np.flatnonzero(samples.valid)
    assert 2 <= len(valid) < 12
    inputs = jax.tree.map(lambda x: x[valid], batched.inputs(samples, np.float64))
    references = jax.vmap(lambda p, v: build.scenario(batched.scenario_values(m, v), p).reference)(*inputs)

    @jax.jit
    def evaluate(reference):
        at = lambda f: jax.vmap(lambda s: f(s, 0))(np.linspace(-0.5, 3.5, 17))
        return at(reference.attitude), at(reference.rate), at(reference.rate_dot)

    got = evaluate(jax.tree.map(lambda x: np.moveaxis(x, 0, -1), references))
    for j, i in enumerate(valid):
        own = {**mission["reference"]["table"], "times": times[i].tolist()}
        alone = build.scenario(missions.from_dict({**mission, "reference": {"kind": "table", "table": own}}))
        for x, y in zip(got, evaluate(alone.reference)):
            np.testing.assert_allclose(x[..., j], y, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("table, message", [
    ({"inertia": {"events": {"initial": {"dist": "uniform", "low": 0.0, "high": 1.0}}}},
     r"unknown key\(s\) in \[dispersions.inertia.events.initial\]: dist, high, low"),  # an inertia's form
    ({"inertia": {"events": {"start": 1.0}}},
     r"^dispersions\.inertia\.events\.start cannot be dispersed: dispersible are inertia\.events\.initial, "),
    ({"inertia": {"events": {"times": {"dist": "uniform", "low": -1.0, "high": 1.0}}}}, r"must be >= 0"),
])
def test_bad_event_dispersions_are_one_line_errors(table, message):
    from so3jax.missions import mission as missions

    with pytest.raises(ValueError, match=message):
        draw.parse(table, missions.from_dict(EVENTS))
    matrix_targets = dict(EVENTS["inertia"]["events"], targets=[EVENTS["inertia"]["events"]["initial"], 0.8])
    with pytest.raises(ValueError, match="all are scales of the inertia at their event, or all inertias"):
        draw.parse({"inertia": {"events": {"targets": 1.0}}},
                   missions.from_dict({**EVENTS, "inertia": {"kind": "events", "events": matrix_targets}}))
    with pytest.raises(ValueError, match="not 'events'"):
        draw.parse({"inertia": {"events": {"times": 1.0}}}, missions.from_dict({"T": 10.0}))


@pytest.mark.parametrize("name", ["spin_inertia", "max_torque", "max_speed"])
def test_a_limit_divided_by_is_refused_at_zero_when_dispersed(name):
    """A wheel parameter the loop divides by (or its check refuses at 0): its domain excludes 0,
    so a dispersion that can draw 0 is refused before anything is drawn, as fly refuses it."""
    flight = mission.load(None, ["actuator.wheels.initial_speed=0.0"])
    with pytest.raises(ValueError, match=f"dispersions.actuator.wheels.{name}"):
        draw.parse({"actuator": {"wheels": {name: 0.0}}}, flight)
    with pytest.raises(ValueError, match=f"actuator.wheels.{name} .* must be > 0"):
        mission.load(None, [f"actuator.wheels.{name}=0.0"])


def test_each_rejected_sample_is_counted_for_its_reason():
    """Slews that overlap and event times that do not increase reject their samples, each
    counted for that reason (the first it fails, in REJECTED's order), none for a value
    outside its domain; a sample counted for overlapping slews is one the mission file's
    checks refuse."""
    from so3jax.missions import mission as missions

    m = missions.from_dict(EVENTS)
    samples = draw.draw(*draw.parse(EVENT_DISPERSIONS, m), 0, 16, 20, mission=m)
    reasons = draw.rejections(samples)
    overlap, order = draw.REJECTED["overlap"], draw.REJECTED["order"]
    assert reasons[overlap] > 0 and set(reasons) <= {overlap, order}
    assert sum(reasons.values()) == np.sum(~samples.valid) and np.all((samples.reason == "") == samples.valid)
    events = samples.leaves["inertia.events.times"]
    assert reasons.get(order, 0) == np.sum((samples.reason != overlap) & (np.diff(events, axis=1)[:, 0] <= 0))
    i = int(np.flatnonzero(samples.reason == overlap)[0])
    slews = dict(EVENTS["reference"]["slews"], times=samples.leaves["reference.slews.times"][i].tolist(),
                 attitudes=samples.leaves["reference.slews.attitudes"][i].tolist())
    with pytest.raises(ValueError, match="ends at .* after slew 1 starts"):
        missions.from_dict({**EVENTS, "reference": {"kind": "slews", "slews": slews}})


def test_an_orbit_below_the_least_altitude_rejects_its_sample_for_that_reason(flight):
    """A normal's tail above MAX_MEAN_MOTION (orbits below 100 km): those samples rejected, each
    counted for its orbit; a distribution that draws only such orbits is refused before drawing."""
    from so3jax.dynamics.orbit import MAX_MEAN_MOTION

    dispersions, leaves = draw.parse({"orbit": {"n": {"dist": "normal", "mean": 1.15e-3, "std": 5e-5}}}, flight)
    samples = draw.draw(dispersions, leaves, 0, 400, 20, mission=flight)
    low = samples.params.n > MAX_MEAN_MOTION
    assert 0 < low.sum() < 100  # P(z > 1.22) = 0.11
    np.testing.assert_array_equal(samples.valid, ~low)
    assert draw.rejections(samples) == {draw.REJECTED["orbit"]: int(low.sum())}
    with pytest.raises(ValueError, match=r"^dispersions.orbit.n \(the upper end of .*\) = 0.002 rad/s is a circular "
                                         r"orbit of radius 4636 km, altitude -1742 km: below the least altitude"):
        draw.parse({"orbit": {"n": {"dist": "uniform", "low": 1e-3, "high": 2e-3}}}, flight)
    leo = mission.load(ROOT / "missions" / "leo.toml", ["T=1.0"])  # flies on its orbit: n > 0
    with pytest.raises(ValueError, match=r"dispersions.orbit.n \(environment.gravity_gradient.* fly on the orbit\) "
                                         "must be > 0"):
        draw.parse({"orbit": {"n": 0.0}}, leo)
    samples = draw.draw(*draw.parse({"orbit": {"n": {"dist": "normal", "mean": 2e-5, "std": 2e-5}}}, leo),
                        0, 64, 20, mission=leo)
    np.testing.assert_array_equal(samples.valid, samples.params.n > 0)
    assert 0 < draw.rejections(samples)[draw.REJECTED["orbit"]] < 64


def test_a_sweep_whose_every_sample_is_rejected_is_an_error_before_compiling(cli_env, capsys):
    """Every slew too slow to end before the next starts: exit code 2, one line counting the
    samples per reason, no output folder (after the memory estimate's trace, before the
    samples' programs compile)."""
    from so3jax import commands as cli

    slow = 'dispersions.reference.slews.max_rate={dist="uniform", low=1e-4, high=2e-4}'
    argv = ["sweep", str(Path(__file__).parents[1] / "sweeps" / "imaging.toml"), "--samples", "8", "--chunk", "8",
            "--T", "20", "--controllers", "pd", "--set", slow, "--out", "o"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("so3jax sweep: error: [dispersions]: every one of the 8 samples is rejected (8 for "
                   f"{draw.REJECTED['overlap']}): narrow the dispersions")
    assert not (cli_env / "o").exists()


FAULT_DISPERSIONS = {"faults": {"0": {"time": {"dist": "uniform", "low": 2.0, "high": 15.0},
                                      "wheel": {"dist": "choice", "values": [1, 2, 3, 4]}},
                                "1": {"time": {"dist": "uniform", "low": 0.0, "high": 12.0},
                                      "end": {"dist": "uniform", "low": 2.0, "high": 12.0}},
                                "2": {"step": {"dist": "normal", "mean": 0.0, "std": 1e-4, "relative": "offset"}}}}


def test_dispersed_faults_fly_each_sample_as_its_mission_alone():
    """faults.I.time, which wheel fails, an outage's end and a bias step drawn per sample (a
    leaf of each sample's loop): each sample's metrics are those of its mission, written with its
    values, flown alone (one compiled program for those); a sample whose outage ends at or
    before its time is rejected for that reason."""
    from test_faults import faulted

    import so3jax as sj

    base = faulted(time=5.0, end=10.0, latency=0.5)
    m = mission.from_dict(base)
    parsed, leaves = draw.parse(FAULT_DISPERSIONS, m)
    samples = draw.draw(parsed, leaves, 0, 8, 20, mission=m)
    start, end = samples.leaves["faults.1.time"], samples.leaves["faults.1.end"]
    np.testing.assert_array_equal(samples.reason == draw.REJECTED["outage"], end <= start)
    assert np.any(end <= start) and np.all(samples.valid == (end > start))
    valid = np.flatnonzero(samples.valid)[:3]
    assert len(valid) == 3 and len(set(samples.leaves["faults.0.wheel"][valid])) > 1
    inputs = jax.tree.map(lambda x: x[valid], batched.inputs(samples, np.float64))
    controller, gains = m.controller("pd")
    batch = batched.sample_metrics(inputs, gains, controller=controller, mission=m)
    assert len(np.unique(np.asarray(batch["rmse"]))) == len(valid)
    for j, i in enumerate(valid):
        own = [dict(f) for f in base["faults"]]
        own[0]["time"], own[1]["time"], own[1]["end"] = (float(samples.leaves[k][i]) for k in
                                                         ("faults.0.time", "faults.1.time", "faults.1.end"))
        own[2]["step"] = samples.leaves["faults.2.step"][i].tolist()
        own[0]["wheel"] = int(samples.leaves["faults.0.wheel"][i])
        alone = mission.from_dict({**base, "faults": own})
        result = sj.simulate(alone.scenario(), controller, gains, alone.seed, loop=alone.loop())
        expected = {**result.metrics._asdict(), **result.flight._asdict()}
        for name in ("rmse", "effort", "max_torque", "max_angle_phase"):
            np.testing.assert_allclose(batch[name][j], expected[name], rtol=1e-12, atol=0, err_msg=name)


@pytest.mark.parametrize(("table", "message"), [
    ({"faults": {"3": {"time": 1.0}}}, "no fault '3' \\(its \\[\\[faults\\]\\] entries are 0 to 2\\)"),
    ({"faults": {"0": {"factor": 0.5}}}, "fails off \\(no factor\\)"),
    ({"faults": {"1": {"step": 0.5}}}, "disperses time, end, not 'step'"),
    ({"faults": {"0": {"time": {"dist": "uniform", "low": -2.0, "high": -1.0}}}}, "must be >= 0"),
    ({"faults": {"time": 1.0}}, "must name a fault's value"),
    ({"faults": {"0": {"wheel": {"dist": "choice", "values": [1, 5]}}}}, "draws a wheel's index, 1 to 4"),
    ({"faults": {"0": {"wheel": {"dist": "uniform", "low": 1, "high": 4}}}}, "draws a wheel's index, 1 to 4"),
    ({"faults": {"0": {"wheel": {"dist": "choice", "values": []}}}}, "values must be a list of numbers"),
])
def test_bad_fault_dispersions_are_one_line_errors(table, message):
    from test_faults import faulted

    with pytest.raises(ValueError, match=message) as err:
        draw.parse(table, mission.from_dict(faulted()))
    assert "\n" not in str(err.value)


def test_a_degraded_wheel_s_factor_is_drawn_in_its_domain():
    """A factor in [0, 1): a sample drawing 1 or more (or below 0) is rejected for its domain."""
    from test_faults import BASE

    m = mission.from_dict({**BASE, "faults": [{"time": 3.0, "wheel": 2, "mode": "degraded", "factor": 0.5}]})
    _, leaves = draw.parse({"faults": {"0": {"factor": {"dist": "normal", "mean": 0.9, "std": 0.1}}}}, m)
    values, valid = draw.draw_leaves(leaves, 0, 400)
    factor = values["faults.0.factor"]
    assert np.any(factor >= 1.0)
    np.testing.assert_array_equal(valid, (factor >= 0.0) & (factor < 1.0))
    loop = batched.loop(m, {"faults.0.factor": factor[0]}, np.float64)
    np.testing.assert_array_equal(np.asarray(loop.faults.wheel_factor), [factor[0]])


def test_two_failed_wheels_drawn_apart_leave_two_wheels_and_reject_the_sample():
    """Two wheels of the pyramid failing off, each drawn among the four: with detection on,
    a sample whose two failures strike different wheels keeps two wheels (rank 2) and is
    rejected for it; one whose failures strike the same wheel keeps three and flies. With
    detection "never" every sample flies (unaware, as fly flies it); values uniform over
    the choice within confidence bounds."""
    from test_faults import BASE

    two = [{"time": 3.0, "wheel": 1, "mode": "off"}, {"time": 4.0, "wheel": 1, "mode": "off"}]
    table = {"faults": {str(i): {"wheel": {"dist": "choice", "values": [1, 2, 3, 4]}} for i in range(2)}}
    n = 2000
    for fdir, rejected in (({"latency": 1.0}, True), ({"detection": "never"}, False)):
        m = mission.from_dict({**BASE, "faults": two, "fdir": fdir})
        parsed, leaves = draw.parse(table, m)
        samples = draw.draw(parsed, leaves, 0, n, 20, mission=m)
        a, b = samples.leaves["faults.0.wheel"], samples.leaves["faults.1.wheel"]
        np.testing.assert_array_equal(samples.reason == draw.REJECTED["wheels"], (a != b) & rejected)
        counts = np.array([np.sum(a == k) for k in (1, 2, 3, 4)])
        assert np.all(np.abs(counts - n / 4) < 4.5 * np.sqrt(n * 0.25 * 0.75))  # binomial, 4.5 sigma
