"""Gain schedules (so3jax.controllers.scheduled, a mission's [schedule]): equal gains in every
phase fly the unscheduled law bit for bit, in the paper's continuous loop and the flight
loop; each phase's torque is the law's at that phase's gains; "time" interpolates as
numpy.interp; gradients reach the gains of the phases flown and no other; bad input is a
one-line error naming its key. Missions: the shipped files with a constant inertia (their
J0) and an inertial reference, so that their phases move into a 12 s horizon."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from so3jax.controllers import AdaptiveGains, PDGains, adaptive_backstepping, geometric_pd
from so3jax.controllers.base import Desired, Feedback
from so3jax.controllers.scheduled import Scheduled, check_scheduled_gains, gains_slice, schedule_gains
from so3jax.core import so3
from so3jax.jobs.tune.gains import gains_table
from so3jax.missions import config as cfg
from so3jax.missions import mission as missions
from so3jax.sim.rollout import rollout, simulate

PHASES = ("phases.names=['capture', 'deployment', 'detumble']", "phases.start=[0.0, 4.0, 8.0]")
MOVED = ("T=12.0", "record_every=10", "reference.kind='inertial'", "initial.attitude=[0.1, -0.2, 0.3]",
         "initial.rate=[0.01, 0.0, -0.01]")
DIAGONAL = "[" + ", ".join(["1e8"] * 9) + "]"  # a diagonal Gamma (9,)


def own(*overrides):
    """The flight mission (no file) of a constant inertia with the phases moved, then ``overrides``."""
    return missions.load(None, ["inertia.J=[[625.0, 5.5, 3.0], [5.5, 350.0, 4.0], [3.0, 4.0, 900.0]]", *MOVED, *PHASES,
                                *overrides])


def load(path, *overrides):
    """The mission of ``path`` with a constant inertia (the file's J0), then ``overrides``."""
    tables = cfg.read_toml(path)
    tables["inertia"] = {"J": tables["inertia"]["J0"]["nominal"]}
    return missions.from_dict(cfg.override(tables, list(overrides)))


def fly(mission, name):
    controller, gains = mission.controller(name)
    scenario, loop = mission.scenario(), mission.loop()
    return jax.tree.map(np.asarray, simulate(scenario, controller, gains, mission.seed, loop=loop,
                                             record_every=mission.record_every))


# continuous: pd by "time", adaptive by "phase"; sampled: the other way round
SCHEDULES = {
    "missions/paper.toml": ("schedule.pd={by='time', at=[0.0, 6.0, 20.0]}", "schedule.adaptive={by='phase'}",
                            f"gains.adaptive.Gamma=[{DIAGONAL}, {DIAGONAL}, {DIAGONAL}]"),
    "missions/flight.toml": ("schedule.pd={by='phase'}", "schedule.adaptive={by='time', at=[0.0, 6.0]}",
                             f"gains.adaptive.Gamma=[{DIAGONAL}, {DIAGONAL}]"),
}


@pytest.fixture(scope="module", params=sorted(SCHEDULES))
def equal_gains_flights(request):
    """{(scheduled, law): Result} of a mission file, scheduled with equal gains everywhere or not."""
    plain = load(request.param, *MOVED, *PHASES, f"gains.adaptive.Gamma={DIAGONAL}")
    scheduled = load(request.param, *MOVED, *PHASES, *SCHEDULES[request.param])
    assert (scheduled.period_steps is None) == ("paper" in request.param)
    return {(s, name): fly(m, name) for s, m in ((False, plain), (True, scheduled)) for name in ("pd", "adaptive")}


@pytest.mark.optimized  # bit for bit, as XLA's default pipeline builds both programs
@pytest.mark.parametrize("law", ["pd", "adaptive"])
def test_equal_gains_in_every_phase_fly_the_unscheduled_law_bit_for_bit(equal_gains_flights, law):
    plain, scheduled = equal_gains_flights[(False, law)], equal_gains_flights[(True, law)]
    leaves = jax.tree_util.tree_leaves_with_path(plain)
    assert len(leaves) == len(jax.tree.leaves(scheduled)) and leaves
    for (path, a), b in zip(leaves, jax.tree.leaves(scheduled)):
        assert np.array_equal(a, b, equal_nan=True), jax.tree_util.keystr(path)
    assert np.all(np.isfinite(plain.metrics.rmse)) and plain.history.t[-1] > 8.0  # every phase flown


# --- the law at each phase's gains, called directly ---------------------------------------

KNOTS = (0.0, 4.0, 8.0)
PD = PDGains(k_R=jnp.array([0.5, 1.0, 2.0]), k_Omega=jnp.array([20.0, 30.0, 40.0]))
ADAPTIVE = AdaptiveGains(K_r=jnp.array([0.004, 0.005, 0.006]), K_w=jnp.array([60.0, 75.0, 90.0]),
                         Gamma=jnp.array([1e8, 2e8, 3e8])[:, None] * jnp.linspace(1.0, 2.0, 9))


def _feedback_desired():
    R = so3.exp(jnp.array([0.2, -0.1, 0.3]))
    desired = Desired(so3.exp(jnp.array([0.0, 0.1, 0.0])), jnp.array([1e-3, -2e-3, 5e-4]), jnp.array([1e-5, 0.0, 2e-5]))
    return Feedback(R, jnp.array([0.02, -0.01, 0.015])), desired


@pytest.mark.parametrize(("law", "gains"), [(geometric_pd(), PD),
                                            (adaptive_backstepping(projection_bound=1e4), ADAPTIVE)])
def test_the_torque_in_each_phase_is_the_laws_at_that_phases_gains(law, gains):
    scheduled = Scheduled(law, "phase", KNOTS)
    feedback, desired = _feedback_desired()
    state = jax.tree.map(lambda x: 1.5 * x, law.init(gains_slice(gains, 0)))
    for t, phase in ((0.0, 0), (3.99, 0), (4.0, 1), (7.5, 1), (8.0, 2), (100.0, 2), (-1.0, 0)):
        t = jnp.asarray(t)
        tau, dot = scheduled.torque(gains, state, feedback, desired, t)
        expected_tau, expected_dot = law.torque(gains_slice(gains, phase), state, feedback, desired, t)
        assert np.array_equal(tau, expected_tau) and np.array_equal(jnp.asarray(dot), jnp.asarray(expected_dot)), t
        if law.update is not None:
            updated = scheduled.update(gains, state, feedback, desired, t, 0.1)
            assert np.array_equal(updated, law.update(gains_slice(gains, phase), state, feedback, desired, t, 0.1))
    assert (scheduled.update is None) == (law.update is None)
    assert np.array_equal(scheduled.init(gains), law.init(gains_slice(gains, 0)))
    scheduled_torques = [scheduled.torque(gains, state, feedback, desired, jnp.asarray(t))[0] for t in (1.0, 5.0, 9.0)]
    assert not np.array_equal(scheduled_torques[0], scheduled_torques[1])  # the phases' gains differ


def test_time_mode_interpolates_as_numpy_interp_and_keeps_equal_gains_bit_for_bit():
    knots = (0.0, 3.0, 10.0)
    scheduled = Scheduled(adaptive_backstepping(), "time", knots)
    times = jnp.linspace(-2.0, 14.0, 161)
    at = jax.jit(jax.vmap(scheduled.at, in_axes=(None, 0)))
    values = at(ADAPTIVE, times)
    for field in AdaptiveGains._fields:
        table = np.asarray(getattr(ADAPTIVE, field)).reshape(len(knots), -1)
        expected = np.stack([np.interp(np.asarray(times), knots, column) for column in table.T], -1)
        np.testing.assert_allclose(np.asarray(getattr(values, field)).reshape(len(times), -1), expected,
                                   rtol=1e-14, atol=0)
    same = AdaptiveGains(K_r=jnp.asarray(0.005), K_w=jnp.asarray(75.0), Gamma=jnp.linspace(1e8, 2e8, 9))
    held = at(schedule_gains(same, len(knots)), times)
    for value, expected in zip(held, same):
        assert np.array_equal(value, jnp.broadcast_to(expected, times.shape + expected.shape))


def test_a_schedule_is_hashable_equal_by_value_and_checks_its_gains():
    assert Scheduled(geometric_pd(), "phase", [0, 4.0]) == Scheduled(geometric_pd(), "phase", (0.0, 4.0))
    assert hash(Scheduled(geometric_pd(), "phase", [0, 4.0])) == hash(Scheduled(geometric_pd(), "phase", (0.0, 4.0)))
    assert Scheduled(geometric_pd(), "phase", KNOTS) != Scheduled(geometric_pd(), "time", KNOTS)
    assert Scheduled(geometric_pd(), "time", KNOTS).gains_type is PDGains
    shaped = schedule_gains(AdaptiveGains(0.005, 75.0, jnp.ones(9)), 3)
    assert [jnp.shape(g) for g in shaped] == [(3,), (3,), (3, 9)]
    check_scheduled_gains("adaptive", shaped, 3)
    with pytest.raises(ValueError, match="deployment: gain k_R must be positive"):
        check_scheduled_gains("pd", PDGains(jnp.array([1.0, -1.0]), jnp.ones(2)), 2, ("capture", "deployment"))
    with pytest.raises(ValueError, match="scheduled gain k_Omega must have shape"):
        check_scheduled_gains("pd", PDGains(jnp.ones(2), jnp.ones(3)), 2)
    for by, knots, message in (("phases", KNOTS, "by"), ("time", (0.0, 0.0), "increasing"), ("time", (), "non-empty")):
        with pytest.raises(ValueError, match=message):
            Scheduled(geometric_pd(), by, knots)


# --- gradients --------------------------------------------------------------------------------


def test_a_gradient_reaches_the_phases_flown_and_is_zero_for_a_phase_never_reached():
    mission = load("missions/paper.toml", *MOVED, "controllers=['pd']", "schedule.pd={by='phase'}",
                   "phases.names=['capture', 'deployment', 'detumble', 'never']", "phases.start=[0.0, 4.0, 8.0, 100.0]",
                   "gains.pd.k_R=[0.5, 0.6, 0.7, 0.8]")
    controller, gains = mission.controller("pd")
    scenario, loop = mission.scenario(), mission.loop()
    gains = jax.tree.map(jnp.asarray, gains)
    rmse = jax.jit(lambda g: rollout(scenario, controller, g, 0, loop=loop).metrics.rmse)
    jacobian = jax.jacfwd(rmse)(gains)
    for field in PDGains._fields:
        d = np.asarray(getattr(jacobian, field))
        assert np.all(np.isfinite(d)) and np.all(d[:3] != 0.0), (field, d)
        assert d[3] == 0.0, (field, d)


# --- missions: [schedule], scheduled [gains.NAME], gains files ---------------------------


def test_a_missions_schedule_is_its_controller_its_gains_and_part_of_its_fingerprint():
    plain = own()
    m = own("schedule.pd={by='phase'}", "gains.pd.k_R=[0.5, 0.6, 0.7]",
            "schedule.adaptive={by='time', at=[0.0, 100.0]}", "gains.adaptive.Gamma=[1e8, 2e8]")
    controller, gains = m.controller("pd")
    assert controller == Scheduled(geometric_pd(), "phase", (0.0, 4.0, 8.0))
    np.testing.assert_array_equal(gains.k_R, [0.5, 0.6, 0.7])
    np.testing.assert_array_equal(gains.k_Omega, [25.0, 25.0, 25.0])  # the default in every phase
    assert m.controller("adaptive")[0] == Scheduled(adaptive_backstepping(), "time", (0.0, 100.0))
    assert m.describe()["schedule"] == {"pd": {"by": "phase"}, "adaptive": {"by": "time", "at": [0.0, 100.0]}}
    assert "schedule" not in plain.describe() and plain.fingerprint != m.fingerprint
    assert m.controller("pd")[0] == own("schedule.pd={by='phase'}").controller("pd")[0]


def test_scheduled_gains_round_trip_through_a_gains_file(tmp_path):
    m = own("schedule.adaptive={by='phase'}", f"gains.adaptive.Gamma=[{DIAGONAL}, {DIAGONAL}, {DIAGONAL}]",
            "gains.adaptive.K_w=[60.0, 70.0, 80.0]")
    path = tmp_path / "best_gains.json"
    path.write_text(json.dumps({"controller": "adaptive", "gains": gains_table(m.gains["adaptive"])}))
    again = own("schedule.adaptive={by='phase'}", f"gains.adaptive='{path}'")
    for a, b in zip(m.gains["adaptive"], again.gains["adaptive"]):
        assert np.array_equal(a, b)
    with pytest.raises(ValueError, match=r"gains\.adaptive: gains file .*: gains\.K_r: one value per breakpoint \(2"):
        own("schedule.adaptive={by='time', at=[0.0, 5.0]}", f"gains.adaptive='{path}'")


@pytest.mark.parametrize(("overrides", "message"), [
    (("controllers=['pd']", "schedule.adaptive={by='phase'}"), r"schedule\.adaptive: the mission flies no 'adaptive'"),
    (("schedule.pd={by='space'}",), r"schedule\.pd\.by must be one of phase, time"),
    (("schedule.pd={at=[0.0, 1.0]}",), r"schedule\.pd\.by must be one of"),
    (("schedule.pd={by='time'}",), r"schedule\.pd\.at: a schedule by \"time\" needs"),
    (("schedule.pd={by='time', at=[0.0, 5.0, 5.0]}",), r"schedule\.pd\.at \[s\] must be finite and increasing"),
    (("schedule.pd={by='time', at=[]}",), r"schedule\.pd\.at \[s\] must be a non-empty list"),
    (("schedule.pd={by='phase', at=[0.0]}",), r"schedule\.pd\.at: a schedule by \"phase\""),
    (("schedule.pd={by='phase', every=2}",), r"unknown key\(s\) in \[schedule\.pd\]: every"),
    (("schedule.pd={by='inertia'}",), r"schedule\.pd\.at: a schedule by \"inertia\" needs its breakpoints \[kg m\^2\]"),
    (("schedule.pd={by='inertia', at=[0.0, 500.0]}",), r"schedule\.pd\.at: breakpoints of an inertia"),
    (("schedule.pd={by='inertia', at=[600.0, 500.0]}",), r"schedule\.pd\.at \[kg m\^2\] must be finite and increasing"),
    (("schedule.pd={by='inertia', at=[500.0], of='Jxy'}",), r"schedule\.pd\.of must be one of mean, Jxx"),
    (("schedule.pd={by='time', at=[0.0], of='Jxx'}",), r"schedule\.pd\.of: names the moment of a schedule by"),
    (("schedule.pd='phase'",), r"schedule\.pd must be a table"),
    (("schedule.pd={by='phase'}", "gains.pd.k_R=[1.0, 2.0]"), r"gains\.pd\.k_R: one value per phase \(3: capture"),
    (("schedule.pd={by='time', at=[0.0, 1.0]}", "gains.pd.k_R=[1.0, 2.0, 3.0]"),
     r"gains\.pd\.k_R: one value per breakpoint \(2"),
    (("schedule.pd={by='phase'}", "gains.pd.k_R=[1.0, -2.0, 3.0]"),
     r"\[gains\.pd\]: deployment: gain k_R must be positive"),
    (("schedule.adaptive={by='phase'}", "gains.adaptive.Gamma=[[1.0, 2.0], [1.0, 2.0], [1.0, 2.0]]"),
     r"gains\.adaptive\.Gamma must be a number or .*\(3, 9\)"),
])
def test_bad_schedules_are_one_line_errors_naming_the_key(overrides, message):
    with pytest.raises(ValueError, match=message) as err:
        own(*overrides)
    assert "\n" not in str(err.value)


# --- by inertia: the declared inertia's moment --------------------------------------------------


def test_an_inertia_schedule_interpolates_over_the_declared_inertias_closed_form():
    """The flight mission declares the paper's profile: J0 until 500 s, then J1 - (J1 - J0)
    exp(-(t - 500) / tau_J) until 2600 s, then J2 (docs/model.md §4); the schedule's variable is
    that J(t)'s moment and the gains numpy.interp's of it; equal gains give the law's bit for bit."""
    m = missions.load(None, ["schedule.pd={by='inertia', at=[700.0, 1000.0, 1240.0]}", "gains.pd.k_R=[1.0, 2.0, 4.0]",
                             "schedule.adaptive={by='inertia', at=[400.0, 900.0], of='Jzz'}"])
    controller, gains = m.controller("pd")
    J0, J1, J2 = (np.asarray(J, float) for J in (m.J0, m.J1, m.J2))
    times = np.array([0.0, 499.9, 500.0, 650.0, 1200.0, 2599.9, 2600.0, 3999.9])
    blend = np.exp(-np.clip(times - 500.0, 0.0, None) / m.tau_J)[:, None, None]
    J = np.where(times[:, None, None] < 500.0, J0, J1 - (J1 - J0) * blend)
    J = np.where(times[:, None, None] >= 2600.0, J2, J)
    mean = np.trace(J, axis1=1, axis2=2) / 3.0
    x = jax.vmap(controller.variable)(jnp.asarray(times))
    np.testing.assert_allclose(x, mean, rtol=1e-13)
    Jzz = jax.vmap(m.controller("adaptive")[0].variable)(jnp.asarray(times))
    np.testing.assert_allclose(Jzz, J[:, 2, 2], rtol=1e-13)
    k_R = jax.vmap(controller.at, in_axes=(None, 0))(jax.tree.map(jnp.asarray, gains), jnp.asarray(times)).k_R
    np.testing.assert_allclose(k_R, np.interp(mean, [700.0, 1000.0, 1240.0], [1.0, 2.0, 4.0]), rtol=1e-13)
    assert len(set(np.round(np.asarray(k_R), 9))) > 2  # the profile crosses the breakpoints
    assert controller == m.controller("pd")[0] and hash(controller) == hash(m.controller("pd")[0])
    feedback, desired = _feedback_desired()
    same = schedule_gains(PDGains(jnp.asarray(1.5), jnp.asarray(20.0)), 3)
    for t in times:
        t = jnp.asarray(t)
        assert np.array_equal(controller.torque(same, (), feedback, desired, t)[0],
                              geometric_pd().torque(gains_slice(same, 0), (), feedback, desired, t)[0])


def test_a_phase_schedule_switches_at_the_missions_phases():
    assert missions.load(None, ["schedule.pd={by='phase'}"]).controller("pd")[0].knots == (0.0, 500.0, 2600.0)
    with pytest.raises(ValueError, match=r"schedule\.open_loop: the open_loop law has no gains"):
        own("controllers=['open_loop']", "schedule.open_loop={by='phase'}")
