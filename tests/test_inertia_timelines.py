"""Inertia timelines J(t) as mission kinds (so3jax.dynamics.inertia_timelines, [inertia] kind):
J' against central differences, the paper's profile as two events, a scale event mid-blend
in closed form, tables against np.interp and the CSV / .npz files they are read from, bad
tables as one-line errors at parse time, scaled profiles, the flight mission's fingerprint
and batched leaves. Profile evaluations and parsing only: nothing is flown.
"""

import dataclasses
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from so3jax.dynamics import inertia_timelines as timelines
from so3jax.dynamics.inertia import InertiaWarning
from so3jax.dynamics.paper import PAPER_J0, PAPER_J2
from so3jax.dynamics.plant import PaperInertia, inertia_rate
from so3jax.missions import mission as missions
from so3jax.sim.gradients import scale_inertia

J0, J2 = np.asarray(PAPER_J0), np.asarray(PAPER_J2)
A = np.array([[900.0, 6.0, -4.0], [6.0, 800.0, 5.0], [-4.0, 5.0, 600.0]])  # physical inertias
B = np.array([[1900.0, 20.0, 10.0], [20.0, 1750.0, 15.0], [10.0, 15.0, 1250.0]])
C = np.array([[1400.0, -8.0, 3.0], [-8.0, 1300.0, 2.0], [3.0, 2.0, 1000.0]])
NOT_SPD = np.array([[900.0, 0.0, 0.0], [0.0, -800.0, 0.0], [0.0, 0.0, 600.0]])
ZERO = np.zeros((3, 3))


def _J(profile, t):
    return np.asarray(profile(jnp.asarray(float(t)), 0))


def _rate(profile, t):
    return np.asarray(inertia_rate(profile, jnp.asarray(float(t)), 0))


def _central(profile, t, h=1e-3):
    return (_J(profile, t + h) - _J(profile, t - h)) / (2 * h)


def _events(initial, times, targets, time_constants):
    """timelines.events with targets each a matrix or a scale (a number)."""
    scales = [0.0 if np.ndim(x) else float(x) for x in targets]
    matrices = [np.asarray(x, np.float64) if np.ndim(x) else ZERO for x in targets]
    return timelines.events(jnp.asarray(initial), jnp.asarray(times, jnp.float64), jnp.asarray(np.stack(matrices)),
                            jnp.asarray(scales, jnp.float64), jnp.asarray(time_constants, jnp.float64))


def _paper_events():
    return _events(J0, [500.0, 2600.0], [2.0, J2], [300.0, 0.0])


def _mission(inertia, **top):
    """A mission of this [inertia] table (the paper's phases and reference; physical inertias)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", InertiaWarning)  # the tests' inertias are physical
        return missions.from_dict({"T": 300.0, "controllers": ["pd"], "inertia": inertia, **top})


def _event_table(**changes):
    events = {"initial": A.tolist(), "times": [100.0, 200.0], "targets": [1.5, B.tolist()],
              "time_constants": [30.0, 0.0]}
    return {"kind": "events", "events": {**events, **changes}}


# J' = d J / dt


@pytest.mark.parametrize("t", [110.0, 150.0, 239.0, 260.0, 300.0])
def test_events_j_dot_is_the_central_difference_of_j_inside_a_blend(t):
    """Blends from 100 s (to B, tau 40 s) and from 240 s (to 1.2 J(240^-), tau 15 s, mid-blend)."""
    profile = _events(A, [100.0, 240.0, 500.0], [B, 1.2, C], [40.0, 15.0, 0.0])
    rate = _rate(profile, t)
    assert np.abs(rate).max() > 1e-3  # a blend under way
    np.testing.assert_allclose(rate, _central(profile, t), rtol=1e-7, atol=1e-9)


@pytest.mark.parametrize("t", [0.0, 50.0, 99.0, 520.0, 1e4])
def test_events_j_dot_is_zero_before_the_first_event_and_after_a_step(t):
    profile = _events(A, [100.0, 240.0, 500.0], [B, 1.2, C], [40.0, 15.0, 0.0])
    np.testing.assert_array_equal(_rate(profile, t), 0.0)
    np.testing.assert_allclose(_central(profile, t), 0.0, atol=1e-9)
    np.testing.assert_array_equal(_J(profile, t), A if t < 100.0 else C)


@pytest.mark.parametrize("t", [1.0, 7.5, 13.0, 29.9, 31.0])
def test_a_table_s_j_dot_is_its_segment_s_slope(t):
    times = np.array([0.0, 10.0, 30.0, 32.0])
    inertias = np.stack([A, B, C, A])
    profile = timelines.table(times, inertias)
    i = np.searchsorted(times, t) - 1
    slope = (inertias[i + 1] - inertias[i]) / (times[i + 1] - times[i])
    np.testing.assert_allclose(_rate(profile, t), slope, rtol=1e-12)
    np.testing.assert_allclose(_rate(profile, t), _central(profile, t, h=1e-4), rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("t", [-3.0, 33.0, 500.0])
def test_a_table_s_j_dot_is_zero_where_it_is_held(t):
    profile = timelines.table([0.0, 10.0, 32.0], np.stack([A, B, C]))
    np.testing.assert_array_equal(_rate(profile, t), 0.0)


def test_the_linear_kind_s_j_dot_is_the_change_over_its_duration():
    linear = _mission({"kind": "linear", "linear": {"start": A.tolist(), "end": B.tolist(), "times": [20.0, 220.0]}})
    profile = linear.scenario("float64").inertia
    for t in (21.0, 120.0, 219.0):
        np.testing.assert_allclose(_rate(profile, t), (B - A) / 200.0, rtol=1e-12)
        np.testing.assert_allclose(_rate(profile, t), _central(profile, t), rtol=1e-6)
    for t in (5.0, 250.0):
        np.testing.assert_array_equal(_rate(profile, t), 0.0)


def test_j_dot_at_an_event_or_sample_time_is_the_derivative_from_that_time_on():
    """J(t) holds the new segment from its time on (RK4 stages land on whole-step event times),
    so J' there is the right derivative, as the paper's profile gives at t_deploy in phase 1."""
    events = _events(A, [100.0], [B], [40.0])
    np.testing.assert_allclose(_rate(events, 100.0), (B - A) / 40.0, rtol=1e-12)
    table = timelines.table([0.0, 10.0, 30.0], np.stack([A, B, C]))
    np.testing.assert_allclose(_rate(table, 10.0), (C - B) / 20.0, rtol=1e-12)


def test_j_dot_by_forward_mode_of_the_event_time_matches_differences():
    """J(t) is traceable in the events' parameters: d J(300) / d times[0] by jvp against
    central differences (the start of the second, scale, event moves with it)."""
    def J_at_300(t0):
        return _events(A, jnp.stack([t0, jnp.asarray(240.0)]), [B, 1.2], [40.0, 15.0])(jnp.asarray(300.0), 0)

    t0, h = jnp.asarray(100.0), 1e-3
    derivative = jax.jvp(J_at_300, (t0,), (jnp.ones_like(t0),))[1]
    differences = (np.asarray(J_at_300(t0 + h)) - np.asarray(J_at_300(t0 - h))) / (2 * h)
    assert np.abs(differences).max() > 1e-3
    np.testing.assert_allclose(derivative, differences, rtol=1e-6, atol=1e-8)


# the paper's profile, scale events


@pytest.mark.parametrize(("t", "phase"), [(0.0, 0), (250.0, 0), (499.5, 0), (500.5, 1), (800.0, 1), (1700.0, 1),
                                          (2599.5, 1), (2600.5, 2), (3500.0, 2)])
def test_the_paper_s_two_events_are_the_paper_s_profile(t, phase):
    paper = PaperInertia(*(jnp.asarray(x) for x in (J0, 2.0 * J0, J2, 500.0, 300.0)))
    np.testing.assert_allclose(_J(_paper_events(), t), np.asarray(paper(jnp.asarray(t), phase)), rtol=1e-12)
    if phase == 1:
        np.testing.assert_allclose(_rate(_paper_events(), t), inertia_rate(paper, jnp.asarray(t), phase),
                                   rtol=1e-10)


def test_the_paper_s_events_start_and_target_are_j0_2j0_and_j2():
    profile = _paper_events()
    np.testing.assert_array_equal(profile.starts[0], J0)
    np.testing.assert_allclose(profile.targets[0], 2.0 * J0, rtol=1e-15)
    np.testing.assert_array_equal(profile.targets[1], J2)
    w = np.exp(-2100.0 / 300.0)  # the deployment's blend, unfinished at the docking
    np.testing.assert_allclose(profile.starts[1], 2.0 * J0 - (2.0 * J0 - J0) * w, rtol=1e-12)


def test_a_scale_event_during_an_unfinished_blend_targets_the_scale_of_j_then():
    """Blend A -> B from 10 s (tau 100 s), then at 40 s a blend to 1.5 J(40) (tau 20 s), then a
    step to 0.8 J(90) at 90 s: each by hand."""
    profile = _events(A, [10.0, 40.0, 90.0], [B, 1.5, 0.8], [100.0, 20.0, 0.0])
    first = lambda t: B - (B - A) * np.exp(-(t - 10.0) / 100.0)
    at_40 = first(40.0)
    second = lambda t: 1.5 * at_40 - (1.5 * at_40 - at_40) * np.exp(-(t - 40.0) / 20.0)
    np.testing.assert_allclose(_J(profile, 39.999), first(39.999), rtol=1e-13)
    np.testing.assert_allclose(_J(profile, 40.0), at_40, rtol=1e-13)  # a blend: continuous
    np.testing.assert_allclose(profile.targets[1], 1.5 * at_40, rtol=1e-13)
    for t in (41.0, 65.0, 89.0):
        np.testing.assert_allclose(_J(profile, t), second(t), rtol=1e-13)
    for t in (90.0, 91.0, 400.0):
        np.testing.assert_allclose(_J(profile, t), 0.8 * second(90.0), rtol=1e-13)


def test_a_step_event_jumps_at_its_time_and_a_step_scale_scales_the_initial():
    profile = _events(A, [5.0, 50.0], [2.5, B], [0.0, 0.0])
    np.testing.assert_array_equal(_J(profile, 4.999), A)
    np.testing.assert_allclose(_J(profile, 5.0), 2.5 * A, rtol=1e-15)
    np.testing.assert_allclose(_J(profile, 49.9), 2.5 * A, rtol=1e-15)
    np.testing.assert_array_equal(_J(profile, 50.0), B)


def test_the_events_mission_builds_the_profile_of_its_table():
    """[inertia.events] with a scale and a matrix target equals timelines.events by hand."""
    profile = _mission(_event_table()).scenario("float64").inertia
    assert isinstance(profile, timelines.InertiaEvents)
    blend = lambda t: 1.5 * A - (1.5 * A - A) * np.exp(-(t - 100.0) / 30.0)
    for t, J in ((50.0, A), (99.9, A), (100.0, A), (130.0, blend(130.0)), (199.9, blend(199.9)), (200.0, B),
                 (290.0, B)):
        np.testing.assert_allclose(_J(profile, t), J, rtol=1e-13)


# tables and their files


def test_a_table_is_numpy_s_interpolation_entrywise_and_held_outside():
    times = np.array([-10.0, 0.0, 4.0, 25.0, 26.5])
    inertias = np.stack([A, B, C, 1.1 * B, A])
    profile = timelines.table(times, inertias)
    for t in (-50.0, -10.0, -3.7, 0.0, 2.0, 4.0, 11.3, 25.0, 26.0, 26.5, 1e3):
        expected = np.array([[np.interp(t, times, inertias[:, i, j]) for j in range(3)] for i in range(3)])
        np.testing.assert_allclose(_J(profile, t), expected, rtol=1e-14)


def test_the_linear_kind_is_a_table_of_two_samples():
    linear = _mission({"kind": "linear", "linear": {"start": A.tolist(), "end": B.tolist(), "times": [20.0, 220.0]}})
    profile = linear.scenario("float64").inertia
    two = timelines.table(np.array([20.0, 220.0]), np.stack([A, B]))
    for t in (0.0, 20.0, 57.3, 219.0, 220.0, 299.0):
        np.testing.assert_array_equal(_J(profile, t), _J(two, t))
    np.testing.assert_allclose(_J(profile, 120.0), (A + B) / 2, rtol=1e-14)


def _csv(path, times, inertias, columns):
    entry = {"t": lambda k: times[k], "Jxx": lambda k: inertias[k, 0, 0], "Jyy": lambda k: inertias[k, 1, 1],
             "Jzz": lambda k: inertias[k, 2, 2], "Jxy": lambda k: inertias[k, 0, 1],
             "Jxz": lambda k: inertias[k, 0, 2], "Jyz": lambda k: inertias[k, 1, 2]}
    rows = [",".join(columns)] + [",".join(repr(float(entry[c](k))) for c in columns) for k in range(len(times))]
    path.write_text("\n".join(rows) + "\n")
    return path


TABLE_T = np.array([0.0, 12.5, 40.0 + 1.0 / 3.0])
TABLE_J = np.stack([A, B + 1e-7, C / 3.0])


@pytest.mark.parametrize("columns", [("t", "Jxx", "Jyy", "Jzz", "Jxy", "Jxz", "Jyz"),
                                     ("Jyz", "Jzz", "t", "Jxz", "Jxx", "Jxy", "Jyy")])
def test_a_csv_table_reads_back_what_was_written(tmp_path, columns):
    times, inertias = timelines.read_inertia_table(_csv(tmp_path / "J.csv", TABLE_T, TABLE_J, columns))
    assert times.dtype == inertias.dtype == np.float64 and inertias.shape == (3, 3, 3)
    np.testing.assert_array_equal(times, TABLE_T)
    np.testing.assert_array_equal(inertias, TABLE_J)


def test_an_npz_table_reads_back_what_was_written(tmp_path):
    np.savez(tmp_path / "J.npz", t=TABLE_T, J=TABLE_J)
    times, inertias = timelines.read_inertia_table(tmp_path / "J.npz")
    np.testing.assert_array_equal(times, TABLE_T)
    np.testing.assert_array_equal(inertias, TABLE_J)


def test_a_mission_s_table_file_is_relative_to_the_mission_file(tmp_path):
    """kind = "table" from a CSV next to the mission file, from an .npz, and inline: one profile."""
    (tmp_path / "tables").mkdir()
    _csv(tmp_path / "tables" / "J.csv", TABLE_T, TABLE_J, ("Jzz", "Jxy", "t", "Jyy", "Jyz", "Jxx", "Jxz"))
    np.savez(tmp_path / "tables" / "J.npz", t=TABLE_T, J=TABLE_J)
    inline = _mission({"kind": "table", "table": {"times": TABLE_T.tolist(), "inertias": TABLE_J.tolist()}})
    for name in ("J.csv", "J.npz"):
        (tmp_path / "m.toml").write_text(f'T = 300.0\ncontrollers = ["pd"]\n[inertia]\nkind = "table"\n'
                                         f'[inertia.table]\nfile = "tables/{name}"\n')
        profile = missions.load(tmp_path / "m.toml").scenario("float64").inertia
        for t in (-1.0, 5.0, 12.5, 30.0, 100.0):
            np.testing.assert_array_equal(_J(profile, t), _J(inline.scenario("float64").inertia, t))


# parse-time errors: one line, naming what is wrong


TABLE_BAD = [
    (_event_table(times=[200.0, 100.0]), r"inertia\.events\.times.*must increase"),
    (_event_table(times=[100.0, 100.0]), r"inertia\.events\.times.*must increase"),
    (_event_table(targets=[1.5, NOT_SPD.tolist()]), r"inertia\.events\.targets\[1\] is not positive definite"),
    (_event_table(initial=NOT_SPD.tolist()), r"inertia\.events\.initial is not positive definite"),
    (_event_table(targets=[1.5]), "2 times, 1 targets and 2 time constants"),
    (_event_table(time_constants=[30.0]), "2 times, 2 targets and 1 time constants"),
    (_event_table(targets=[0.0, B.tolist()]), r"targets\[0\]: a scale must be positive"),
    (_event_table(targets=[-2.0, B.tolist()]), r"inertia\.events\.targets\[0\]: a scale must be positive, got -2"),
    (_event_table(time_constants=[-1.0, 0.0]), r"inertia\.events\.time_constants"),
    (_event_table(tau=[1.0, 2.0]), r"unknown key.*\[inertia\.events\]: tau"),
    ({**_event_table(), "J0": {"nominal": A.tolist()}}, "kind = 'events' excludes the paper profile's key.*J0"),
    ({**_event_table(), "J": A.tolist()}, "kind = 'events' excludes the paper profile's key.*J"),
    ({"kind": "events", "events": {"times": [1.0], "targets": [2.0]}}, "inertia.events: give initial"),
    ({"kind": "table", "table": {"times": [0.0, 10.0, 20.0], "inertias": [A.tolist(), B.tolist(), NOT_SPD.tolist()]}},
     r"inertia\.table: .*row 3 \(t = 20 s\) is not positive definite"),
    ({"kind": "table", "table": {"times": [0.0, 10.0, 10.0], "inertias": [A.tolist(), B.tolist(), C.tolist()]}},
     r"inertia\.table: .*row 2 \(t = 10 s\) is not before the next"),
    ({"kind": "linear", "linear": {"start": A.tolist(), "end": B.tolist(), "times": [10.0, 5.0]}},
     r"inertia\.linear\.times.*must end after it starts"),
    ({"kind": "fuel"}, r"inertia\.kind must be one of paper, events, linear, table, got 'fuel'"),
]


@pytest.mark.parametrize(("inertia", "message"), TABLE_BAD)
def test_bad_inertia_tables_are_one_line_errors(inertia, message):
    with pytest.raises(ValueError, match=message) as error:
        _mission(inertia)
    assert "\n" not in str(error.value)


def test_a_table_file_missing_a_column_is_a_one_line_error(tmp_path):
    path = tmp_path / "J.csv"
    path.write_text("t,Jxx,Jyy,Jzz,Jxy,Jyz\n0,900,800,600,0,0\n1,900,800,600,0,0\n")
    with pytest.raises(ValueError, match=r"inertia\.table: .*J\.csv: the header line names no column 'Jxz'") as error:
        _mission({"kind": "table", "table": {"file": str(path)}})
    assert "\n" not in str(error.value)


def test_a_table_file_with_a_non_spd_row_names_the_row(tmp_path):
    path = _csv(tmp_path / "J.csv", np.array([0.0, 5.0, 9.0]), np.stack([A, NOT_SPD, B]),
                ("t", "Jxx", "Jyy", "Jzz", "Jxy", "Jxz", "Jyz"))
    with pytest.raises(ValueError, match=r"row 2 \(t = 5 s\) is not positive definite") as error:
        _mission({"kind": "table", "table": {"file": str(path)}})
    assert "\n" not in str(error.value)


def test_an_npz_table_without_its_arrays_is_a_one_line_error(tmp_path):
    np.savez(tmp_path / "J.npz", t=TABLE_T, inertias=TABLE_J)
    with pytest.raises(ValueError, match="no array 'J'") as error:
        _mission({"kind": "table", "table": {"file": str(tmp_path / "J.npz")}})
    assert "\n" not in str(error.value)


# scaled profiles, the mission's description


def test_scale_inertia_scales_an_events_profile_s_j():
    scenario = _mission(_event_table()).scenario("float64")
    scaled = scale_inertia(scenario, jnp.asarray(0.65))
    for t in (0.0, 100.0, 150.0, 199.0, 200.0, 280.0):
        np.testing.assert_allclose(_J(scaled.inertia, t), 0.65 * _J(scenario.inertia, t), rtol=1e-14)
    np.testing.assert_allclose(_J(scaled.inertia, 150.0), 0.65 * (1.5 * A - 0.5 * A * np.exp(-50.0 / 30.0)),
                               rtol=1e-13)


def test_scale_inertia_by_a_batch_of_scales_gives_each_scaled_profile():
    """batch_metrics' training batch: every matrix gets a leading batch axis, J_b(t) = s_b J(t)."""
    scenario = _mission(_event_table()).scenario("float64")
    scales = np.array([0.5, 1.0, 2.0])
    scaled = scale_inertia(scenario, jnp.asarray(scales)).inertia
    assert {k: v.shape for k, v in scaled.matrices().items()} == \
        {"initial": (3, 3, 3), "targets": (3, 2, 3, 3), "starts": (3, 2, 3, 3)}
    for b, s in enumerate(scales):
        one = dataclasses.replace(scaled, **{name: M[b] for name, M in scaled.matrices().items()})
        np.testing.assert_allclose(_J(one, 150.0), s * _J(scenario.inertia, 150.0), rtol=1e-14)


def test_the_flight_mission_keeps_its_fingerprint_and_describes_no_inertia_kind():
    default = missions.load()
    assert default.fingerprint[:16] == "0c0035dff0fddc4a"
    assert "inertia" not in default.describe()
    assert missions.from_dict({"inertia": {"kind": "paper"}}).fingerprint == default.fingerprint


def test_an_events_mission_describes_its_inertia_table():
    events = _mission(_event_table())
    described = events.describe()["inertia"]
    assert described["kind"] == "events"
    assert described["events"]["times"] == [100.0, 200.0]
    assert described["events"]["targets"] == [1.5, B.tolist()]
    assert described["events"]["time_constants"] == [30.0, 0.0]
    assert events.fingerprint != _mission(_event_table(time_constants=[31.0, 0.0])).fingerprint


# batched leaves


def test_batched_leaves_evaluate_each_profile():
    """Leaves (3, 3, B), (K, B), (K, 3, 3, B), two profiles stacked along a new last axis,
    as the natively batched loop evaluates them."""
    one = _events(A, [100.0, 240.0], [B, 1.2], [40.0, 15.0])
    two = _events(C, [50.0, 300.0], [0.7, A], [0.0, 25.0])
    batch = jax.tree.map(lambda a, b: jnp.stack([a, b], -1), one, two)
    assert batch.initial.shape == (3, 3, 2) and batch.times.shape == (2, 2) and batch.targets.shape == (2, 3, 3, 2)
    for t in (0.0, 75.0, 150.0, 260.0, 320.0, 1000.0):
        J = _J(batch, t)
        assert J.shape == (3, 3, 2)
        np.testing.assert_allclose(J[..., 0], _J(one, t), rtol=1e-14)
        np.testing.assert_allclose(J[..., 1], _J(two, t), rtol=1e-14)
        J_dot = _rate(batch, t)
        np.testing.assert_allclose(J_dot[..., 0], _rate(one, t), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(J_dot[..., 1], _rate(two, t), rtol=1e-12, atol=1e-15)
