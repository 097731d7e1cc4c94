"""Mission files (docs/model.md §8.5): the shipped missions, and one clear error per bad entry."""

import json
import re
from pathlib import Path

import numpy as np
import pytest

from so3jax.missions import mission as missions
from tests.test_cli import run_cli

ROOT = Path(__file__).resolve().parents[1]


def test_the_flight_mission_file_equals_the_defaults():
    shipped, default = missions.load(ROOT / "missions" / "flight.toml"), missions.load()
    assert shipped.describe() == default.describe()
    assert default.period_steps == 10 and default.estimator["kind"] == "mekf" and default.actuator["kind"] == "wheels"
    G = np.asarray(default.actuator["wheels"]["axes"])
    assert set(default.sensors) == {"gyro", "star_tracker"} and default.initial["attitude"].tolist() == [0.0] * 3
    np.testing.assert_allclose(np.degrees(np.arccos(G[:, 2])), 54.74, atol=1e-9)


def test_the_paper_mission_is_the_continuous_wiring():
    m = missions.load(ROOT / "missions" / "paper.toml")
    assert m.period_steps is None and m.sensors == {}
    assert m.estimator["kind"] == "truth" and m.actuator["kind"] == "ideal"


def test_each_sensor_is_its_own_entry():
    """Overriding one sensor's key keeps the other sensor; false leaves a sensor out."""
    m = missions.load(None, ["sensors.gyro.arw=2e-6"])
    assert m.sensors["gyro"]["arw"] == 2e-6 and m.sensors["gyro"]["rrw"] == 1e-9
    assert m.sensors["star_tracker"] == {"sigma": 3e-5, "every": 1}
    assert m.loop().estimator.arw == 2e-6 and m.loop().estimator.sigma_st == 3e-5  # the filter assumes the sensors'
    m = missions.load(None, ["sensors.star_tracker=false", "estimator.kind=truth"])
    assert "star_tracker" not in m.sensors and m.sensors["gyro"]["arw"] == 1e-6
    with pytest.raises(ValueError, match="sensors.gyro must be a table, or false to leave it out"):
        missions.load(None, ["sensors.gyro=true"])
    with pytest.raises(ValueError, match="estimator 'mekf' needs"):
        missions.load(None, ["sensors.gyro=false"])


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("colour=1", "unknown mission key"),
        ("sensors.gyro.arw_typo=1.0", "unknown key"),
        ("sensors.gyro.arw=-1e-6", "sensors.gyro.arw"),
        ("sensors.star_tracker.sigma='big'", "sensors.star_tracker.sigma"),
        ("control.period=0.015", "whole number"),
        ("control.period=0.0", "whole number"),
        ("actuator.wheels.axes=[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.7071067811865476, 0.7071067811865476, 0.0]]",
         "every axis"),
        ("actuator.wheels.axes=[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 2.0]]", "unit"),
        ("actuator.wheels.max_speed=-1.0", "max_speed"),
        ("estimator.kind='kalman'", "estimator.kind"),
        ("estimator.mekf.sigma_b0=-1.0", "estimator.mekf.sigma_b0"),
        ("estimator.raw.sigma_b0=1.0", "unknown key"),
        ("estimator.kind=raw", None),
        ("actuator.saturated.max_torque=[1.0, 2.0]", "actuator.saturated.max_torque"),
        ("actuator.wheels.spin_inertia=[0.1, 0.1]", "one per wheel"),
        ("controller.pd.J_hat=[1.0, 2.0, 3.0]", "controller.pd.J_hat"),
        ("controller.adaptive.log_derivative=approx", "log_derivative"),
        ("controller.pd.gain=1.0", "unknown key"),
        ("initial.attitude=[0.1, 0.2]", "initial.attitude"),
        ("inertia.J=[[1.0, 0.0], [0.0, 1.0]]", "inertia.J"),
        ("actuator.kind='thrusters'", "actuator.kind"),
        ("controllers='pid'", "controllers"),
        ("deployment.tau_J=-50.0", "tau_J"),
        ("gains.pd.k_R=-1.0", "k_R"),
        ("sensors.star_tracker.every=0", "every"),
        ("inertia.J0.nominal=[[1.0, 0.0], [0.0, 1.0]]", "shape"),
    ],
)
def test_bad_entries_get_one_clear_error(override, message):
    if message is None:  # a good entry among the bad ones: the parser is not refusing everything
        missions.load(None, [override])
        return
    with pytest.raises(ValueError, match=message):
        missions.load(None, [override])


def test_a_single_controller_name_is_a_one_element_list():
    assert missions.load(None, ["controllers=pd"]).controllers == ("pd",)


def test_fly_command_end_to_end(tmp_path):
    out = tmp_path / "fly"
    proc = run_cli("fly", "--T", "20", "--json", "--out", str(out), "--controllers", "pd,adaptive", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    assert set(report) == {"pd", "adaptive", "units", "config"}
    assert report["units"]["attitude_estimation_rms"] == "rad" and report["units"]["bias_estimation_rms"] == "rad/s"
    for name in ("pd", "adaptive"):
        r = report[name]
        assert r["diverged"] is False and len(r["rmse_phase"]) == 1  # only the capture phase is reached in 20 s
        assert 0 < r["attitude_estimation_rms"] < 1e-4 and 0 < r["bias_estimation_rms"] < 2e-4
        assert 0 <= r["max_wheel_speed_ratio"] < 1
    assert report["config"]["period_steps"] == 10
    with np.load(out / "trajectory.npz") as npz:
        for key in ("t", "R", "Omega", "R_hat", "Omega_hat", "bias", "bias_hat", "tau_cmd", "tau_applied",
                    "wheel_speed",
                    "disturbance", "covariance"):
            assert f"pd/{key}" in npz.files
        assert npz["adaptive/wheel_speed"].shape == (20, 4) and npz["pd/disturbance"].shape == (20, 3)
        P = npz["pd/covariance"]
        assert P.shape == (20, 6, 6) and np.allclose(P, np.swapaxes(P, 1, 2)) and np.all(np.linalg.eigvalsh(P) > 0)
        # the records start blocks of 100 steps: the last at 19 s; the state at T = 20 s stored beside them
        assert npz["pd/t"][-1] == pytest.approx(19.0) and float(npz["pd/final_t"]) == pytest.approx(20.0)
        R, Omega = npz["adaptive/final_R"], npz["adaptive/final_Omega"]
        assert R.shape == (3, 3) and np.allclose(R.T @ R, np.eye(3), atol=1e-12) and Omega.shape == (3,)
        assert npz["adaptive/final_wheel_speed"].shape == (4,)
        assert 0 < np.linalg.norm(R - npz["adaptive/R"][-1]) < 0.1  # a second on from the last record
    for fig in ("attitude", "bias", "torque", "wheel_speeds", "momentum"):
        assert (out / f"{fig}.png").stat().st_size > 10_000
    assert json.loads((out / "metrics.json").read_text())["pd"] == report["pd"]


def test_fly_bad_input_exits_2_without_traceback(tmp_path):
    proc = run_cli("fly", "--set", "control.period=0.015", "--out", str(tmp_path), cwd=tmp_path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "whole number" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1


def test_a_diverged_flight_is_reported_as_diverged_never_as_a_number(tmp_path):
    """A PD with k_Omega Delta_c / J far above 2 diverges under sampled control: null in
    JSON, "diverged" in the table, exit code 1."""
    args = ("fly", "--T", "20", "--controllers", "pd", "--no-figures", "--set", "gains.pd.k_Omega=1e6",
            "--set", "actuator.kind=ideal", "--out", str(tmp_path))
    proc = run_cli(*args, "--json", cwd=tmp_path)
    assert proc.returncode == 1, proc.stderr
    r = json.loads(proc.stdout.strip().splitlines()[-1])["pd"]
    assert r["diverged"] is True and r["rmse"] is None and r["effort"] is None
    table = run_cli(*args, cwd=tmp_path)
    assert "diverged" in table.stdout.splitlines()[1] and "warning: diverged: pd" in table.stderr


def test_estimator_and_actuator_settings_are_per_kind():
    """Each kind reads its own table; the filter's assumed noise may differ from the sensors'."""
    m = missions.load(None, ["estimator.mekf.arw=5e-6", "actuator.kind=saturated", "actuator.saturated.max_torque=0.1"])
    loop = m.loop()
    assert float(loop.estimator.arw) == 5e-6 and float(loop.sensors.rate.arw) == 1e-6
    np.testing.assert_array_equal(np.asarray(loop.actuator.max_torque), [0.1, 0.1, 0.1])
    assert m.actuator == {"kind": "saturated", "saturated": {"max_torque": 0.1}}


def test_initial_state_and_constant_inertia():
    J = [[100.0, 0.0, 0.0], [0.0, 120.0, 0.0], [0.0, 0.0, 90.0]]
    m = missions.load(None, ["initial.attitude=[0.0, 0.0, 0.5]", "initial.rate=[0.01, 0.0, 0.0]",
                             f"inertia.J={J}"])
    s = m.scenario()
    R0 = np.asarray(s.R0)
    np.testing.assert_allclose(R0, [[np.cos(0.5), -np.sin(0.5), 0], [np.sin(0.5), np.cos(0.5), 0], [0, 0, 1]],
                               atol=1e-15)
    np.testing.assert_array_equal(np.asarray(s.Omega0), [0.01, 0.0, 0.0])
    for t in (0.0, 1000.0, 3000.0):
        np.testing.assert_array_equal(np.asarray(s.inertia(t, 1)), J)
    with pytest.raises(ValueError, match="excludes J0"):
        missions.load(None, [f"inertia.J={J}",
                             "inertia.J0.nominal=[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]"])


def test_controller_options_reach_the_law():
    """[controller.pd] J_hat is the PD's nominal inertia: its torque's feedforward changes."""
    import jax.numpy as jnp

    from so3jax.controllers.base import Desired, Feedback

    J = [[100.0, 0.0, 0.0], [0.0, 120.0, 0.0], [0.0, 0.0, 90.0]]
    plain, with_J = (missions.load(None, o).controller("pd") for o in ([], [f"controller.pd.J_hat={J}"]))
    Omega = jnp.array([0.1, -0.2, 0.05])
    feedback, desired = Feedback(jnp.eye(3), Omega), Desired(jnp.eye(3), jnp.zeros(3), jnp.zeros(3))
    (controller0, g0), (controller1, g1) = plain, with_J
    tau0 = controller0.torque(g0, (), feedback, desired, 0.0)[0]
    tau1 = controller1.torque(g1, (), feedback, desired, 0.0)[0]
    gyroscopic = lambda M: np.cross(np.asarray(Omega), np.asarray(M) @ np.asarray(Omega))
    np.testing.assert_allclose(np.asarray(tau1 - tau0), gyroscopic(J) - gyroscopic(np.eye(3)), rtol=1e-12)


def test_two_sensors_of_one_quantity_are_refused():
    from so3jax.components import registry as components

    spec = components.get("sensor", "gyro")
    import dataclasses
    components.register(dataclasses.replace(spec, name="second_gyro"))
    try:
        with pytest.raises(ValueError, match="both measure the rate"):
            missions.load(None, ["sensors.second_gyro={}"])
    finally:
        components.unregister("sensor", "second_gyro")


def test_the_history_records_the_filter_covariance_and_the_disturbance():
    """P's diagonal is the recorded 1-sigma squared; the recorded d_k is the scenario's
    disturbance at the recorded step k (its sinusoid plus noise, docs/model.md §4)."""
    import jax

    from so3jax.jobs import fly
    from so3jax.sim.rollout import disturbance_at

    m = missions.load(None, ["T=2.0", "controllers=pd", "record_every=50"])
    h = fly.fly(m)[0]["pd"].history
    P, std = np.asarray(h.covariance), np.asarray(h.std)
    np.testing.assert_allclose(np.sqrt(np.einsum("mii->mi", P)), std, rtol=1e-12)
    scenario, key = m.scenario(), jax.random.key(m.seed)
    ks = np.round(np.asarray(h.t) / m.dt).astype(int)
    expected = np.stack([np.asarray(disturbance_at(scenario, key, jax.numpy.asarray(k))) for k in ks])
    np.testing.assert_array_equal(np.asarray(h.disturbance), expected)
    sinusoid = 0.1 * np.sin(1e-3 * np.asarray(h.t))[:, None]
    assert np.all(np.abs(np.asarray(h.disturbance) - sinusoid) < 5 * 0.025)


def test_the_initial_attitude_as_a_quaternion():
    """[w, x, y, z] = [cos(a/2), sin(a/2) n]: the rotation vector a n; checked against scipy."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_quat()  # scipy: scalar last
    m = missions.load(None, [f"initial.quaternion={[float(x) for x in (q[3], q[0], q[1], q[2])]}", "controllers=pd"])
    np.testing.assert_allclose(m.initial["attitude"], [0.3, -0.2, 0.5], rtol=1e-12)
    np.testing.assert_allclose(np.asarray(m.scenario().R0), Rotation.from_quat(q).as_matrix(), atol=1e-14)
    with pytest.raises(ValueError, match="unit quaternion"):
        missions.load(None, ["initial.quaternion=[1.0, 0.1, 0.0, 0.0]"])
    with pytest.raises(ValueError, match="give one"):
        missions.load(None, ["initial.quaternion=[1.0, 0.0, 0.0, 0.0]", "initial.attitude=[0.1, 0.0, 0.0]"])


def test_a_mission_is_hashable_by_its_fingerprint_and_a_static_jit_argument():
    import jax

    from so3jax.results import runfolder

    a, b = missions.load(None, ["T=2.0"]), missions.load(None, ["T=2.0"])
    other = missions.load(None, ["T=3.0"])
    assert a is not b and a == b and hash(a) == hash(b) and a != other
    assert a.fingerprint == runfolder.fingerprint(a.describe()) != other.fingerprint
    traces = []

    @jax.jit(static_argnames="mission")
    def horizon(x, *, mission):
        traces.append(mission)
        return x * mission.T

    assert float(horizon(1.0, mission=a)) == 2.0 and float(horizon(1.0, mission=b)) == 2.0
    assert float(horizon(1.0, mission=other)) == 3.0 and len(traces) == 2  # b reuses a's compilation


def test_the_mission_keys_are_declared_params_whose_defaults_are_the_flight_missions():
    from so3jax.missions import keys

    for p in keys.KEYS:
        node = missions.FLIGHT
        for part in p.name.split("."):
            node = node.get(part) if isinstance(node, dict) else None
        assert node == p.default, p.name
    assert missions.TOP_KEYS == ("T", "dt", "seed", "controllers", "record_every", "requirements", "faults",
                                 "appendages", "slosh")
    assert keys.allowed("initial") == ("attitude", "quaternion", "rate")
    with pytest.raises(ValueError, match=r"initial\.rate \(Omega\(0\)\) \[rad/s\] must have shape \(3,\)"):
        missions.load(None, ["initial.rate=[0.0]"])


def test_the_dispersed_and_the_nominal_scenario_are_one_builder():
    """build.scenario of the mission's own values as a sample equals its nominal scenario."""
    import jax
    import jax.numpy as jnp

    from so3jax.missions import build, draw

    m = missions.load(None, ["T=2.0", "initial.attitude=[0.0, 0.0, 0.5]", "initial.rate=[0.01, 0.0, 0.0]"])
    nominal = m.scenario()
    p = draw.RolloutParams(J0=jnp.asarray(m.J0), J1=jnp.asarray(m.J1), J2=jnp.asarray(m.J2), tau_J=jnp.asarray(m.tau_J),
                           n=jnp.asarray(m.n), amplitude=jnp.asarray(m.disturbance["amplitude"]),
                           frequency=jnp.asarray(m.disturbance["frequency"]),
                           noise_std=jnp.asarray(m.disturbance["noise_std"]), R0=jnp.eye(3), Omega0=jnp.zeros(3),
                           seed=jnp.asarray(0))
    sample = build.scenario(m, p)
    assert jax.tree.structure(sample) == jax.tree.structure(nominal)
    for x, y in zip(jax.tree.leaves(sample), jax.tree.leaves(nominal)):
        np.testing.assert_array_equal(x, y)


def test_a_mission_file_means_in_a_job_what_fly_flies(tmp_path):
    """A mission file names only what differs from the flight mission: a sweep (whose own
    default is the paper's mission) naming it flies the flight loop with those changes."""
    (tmp_path / "short.toml").write_text("T = 100.0\n")
    flown, _ = missions.load_job({"mission": "short.toml"}, tmp_path, ("sweep",), missions.PAPER)
    alone = missions.load(tmp_path / "short.toml")
    assert flown.fingerprint == alone.fingerprint and flown.period_steps == 10 and flown.T == 100.0
    paper, _ = missions.load_job({"T": 100.0}, tmp_path, ("sweep",), missions.PAPER)  # no file: the job's base
    assert paper.period_steps is None


OWN = ['phases.names=["a"]', "phases.start=[0.0]"]
BODY = "[[900.0, 0.0, 0.0], [0.0, 800.0, 0.0], [0.0, 0.0, 600.0]]"


@pytest.mark.parametrize("overrides", [
    [f"inertia.J={BODY}"],
    ["inertia.J0.nominal=" + BODY],
    [*OWN, "reference.kind='inertial'", "inertia.kind='events'",
     f"inertia.events={{initial={BODY}, times=[5.0], targets=[1.2], time_constants=[0.0]}}"],
])
def test_overrides_mean_the_same_over_the_flight_file_and_over_the_defaults(overrides, tmp_path):
    """One merge rule: --set over missions/flight.toml is --set over the defaults it equals,
    also where it switches the inertia's form (a constant J, the paper's J0, another kind),
    and a job's tables over a mission file follow it too."""
    over_file = missions.load(ROOT / "missions" / "flight.toml", overrides)
    assert over_file.fingerprint == missions.load(None, overrides).fingerprint
    job = {"mission": str(ROOT / "missions" / "flight.toml"), "inertia": {"J": json.loads(BODY)}}
    constant = missions.load_job(job, tmp_path, ("sweep",))[0]
    assert constant.constant_inertia and constant.fingerprint == missions.load(None, [f"inertia.J={BODY}"]).fingerprint


@pytest.mark.parametrize(("overrides", "table", "kind"), [
    (["momentum.magnetorquers.gain=2e-3"], "momentum", "magnetorquers"),
    (["actuator.saturated.max_torque=0.1"], "actuator", "saturated"),
    (["estimator.raw={}"], "estimator", "raw"),
    ([*OWN, f"inertia.J={BODY}", "reference.slews={attitudes=[[0.1, 0.0, 0.0]], times=[5.0]}"], "reference", "slews"),
    ([*OWN, "reference.kind='inertial'",
      f"inertia.events={{initial={BODY}, times=[5.0], targets=[1.2], time_constants=[0.0]}}"], "inertia", "events"),
])
def test_a_kind_s_table_given_alone_chooses_that_kind(overrides, table, kind):
    """A component table without ``kind`` (``[momentum.magnetorquers]`` alone) flies that kind,
    not the base mission's with the table ignored."""
    m = missions.load(None, overrides)
    assert getattr(m, table)["kind"] == kind


@pytest.mark.parametrize(("overrides", "message"), [
    (["momentum.thrusters.start=60.0", "momentum.magnetorquers.gain=2e-3"],
     r"\[momentum.thrusters\] and \[momentum.magnetorquers\] given without momentum.kind"),
    ([*OWN, "inertia.J0.nominal=" + BODY, f"inertia.events={{initial={BODY}, times=[5.0], targets=[1.2]}}"],
     r"\[inertia.events\] and the paper profile's J0 given without inertia.kind"),
])
def test_tables_of_two_kinds_without_kind_are_a_one_line_error(in_process, capsys, overrides, message):
    from so3jax import commands as cli

    assert cli.main(["fly", "--T", "10", "--out", "o", *[x for s in overrides for x in ("--set", s)]]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("so3jax fly: error: ") and "\n" not in err and re.search(message, err), err
    assert not (in_process / "o").exists()
