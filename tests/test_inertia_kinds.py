"""The mission's inertia kinds (docs/model.md §4, (4.1a)): J' against finite differences, the
paper's profile as two events, scale events, tables against numpy's interpolation and the
files they are read from, and bad tables as one-line errors before anything compiles."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from so3jax.dynamics import inertia_timelines as timelines
from so3jax.dynamics.paper import PAPER_J0, PAPER_J2
from so3jax.dynamics.plant import PaperInertia, inertia_rate
from so3jax.missions import mission as missions
from so3jax.sim.gradients import scale_inertia

J0 = np.asarray(PAPER_J0)
J2 = np.asarray(PAPER_J2)
A = np.array([[900.0, 6.0, -4.0], [6.0, 800.0, 5.0], [-4.0, 5.0, 600.0]])  # physical
B = np.array([[1900.0, 20.0, 10.0], [20.0, 1750.0, 15.0], [10.0, 15.0, 1250.0]])
PHASES = ["reference.kind='inertial'", "phases.names=['a']", "phases.start=[0.0]", "controllers=['pd']"]


def paper_events():
    return timelines.events(J0, jnp.asarray([500.0, 2600.0]), jnp.stack([jnp.zeros((3, 3)), jnp.asarray(J2)]),
                            jnp.asarray([2.0, 0.0]), jnp.asarray([300.0, 0.0]))


def central(profile, t, h=1e-3):
    return (np.asarray(profile(t + h, 0)) - np.asarray(profile(t - h, 0))) / (2 * h)


@pytest.mark.parametrize("t", [520.0, 1000.0, 2599.0, 3000.0])
def test_events_j_dot_is_the_derivative_of_j(t):
    profile = paper_events()
    np.testing.assert_allclose(inertia_rate(profile, jnp.asarray(t), 0), central(profile, t), rtol=1e-7, atol=1e-9)


def test_the_paper_s_profile_is_two_events():
    """Away from the switching instants, the events' J(t) is the paper's of the phase holding."""
    paper = PaperInertia(*(jnp.asarray(x) for x in (J0, 2.0 * J0, J2, 500.0, 300.0)))
    events = paper_events()
    for t, phase in ((100.0, 0), (501.0, 1), (1700.0, 1), (2599.5, 1), (2600.5, 2), (3999.0, 2)):
        np.testing.assert_allclose(events(jnp.asarray(t), 0), paper(jnp.asarray(t), phase), rtol=1e-12)


def test_a_scale_event_scales_the_inertia_at_its_time_mid_blend():
    profile = timelines.events(A, jnp.asarray([10.0, 40.0]), jnp.stack([jnp.asarray(B), jnp.zeros((3, 3))]),
                               jnp.asarray([0.0, 1.5]), jnp.asarray([100.0, 20.0]))
    w = np.exp(-30.0 / 100.0)
    at_40 = B - (B - A) * w  # the first blend, unfinished at 40 s
    np.testing.assert_allclose(profile(jnp.asarray(40.0 - 1e-9), 0), at_40, rtol=1e-10, atol=1e-8)
    expected = 1.5 * at_40 - (1.5 * at_40 - at_40) * np.exp(-(70.0 - 40.0) / 20.0)
    np.testing.assert_allclose(profile(jnp.asarray(70.0), 0), expected, rtol=1e-12)


def test_a_table_interpolates_linearly_and_holds_outside():
    times = np.array([0.0, 10.0, 25.0, 40.0])
    inertias = np.stack([A, 1.2 * A, B, 0.9 * B])
    profile = timelines.table(times, inertias)
    for t in (-5.0, 0.0, 3.0, 10.0, 17.5, 39.0, 60.0):
        expected = np.array([[np.interp(t, times, inertias[:, i, j]) for j in range(3)] for i in range(3)])
        np.testing.assert_allclose(profile(jnp.asarray(t), 0), expected, rtol=1e-14)
    np.testing.assert_allclose(inertia_rate(profile, jnp.asarray(17.5), 0), (B - 1.2 * A) / 15.0, rtol=1e-12)
    np.testing.assert_array_equal(inertia_rate(profile, jnp.asarray(50.0), 0), 0.0)


def test_linear_is_a_table_of_two_and_files_read_back(tmp_path):
    linear = missions.load(None, [*PHASES, "T=10.0", "inertia.kind='linear'", f"inertia.linear.start={A.tolist()}",
                                  f"inertia.linear.end={B.tolist()}", "inertia.linear.times=[2.0, 8.0]"])
    times, inertias = np.array([2.0, 8.0]), np.stack([A, B])
    columns = ["Jzz", "t", "Jxy", "Jxx", "Jyz", "Jyy", "Jxz"]  # any order
    value = {"t": times, "Jxx": inertias[:, 0, 0], "Jyy": inertias[:, 1, 1], "Jzz": inertias[:, 2, 2],
             "Jxy": inertias[:, 0, 1], "Jxz": inertias[:, 0, 2], "Jyz": inertias[:, 1, 2]}
    np.savetxt(tmp_path / "J.csv", np.stack([value[c] for c in columns], 1), delimiter=",",
               header=",".join(columns), comments="", fmt="%.17g")
    np.savez(tmp_path / "J.npz", t=times, J=inertias)
    for name in ("J.csv", "J.npz"):
        read = timelines.read_inertia_table(tmp_path / name)
        np.testing.assert_array_equal(read[0], times)
        np.testing.assert_array_equal(read[1], inertias)
        (tmp_path / "m.toml").write_text(f'T = 10.0\n[inertia]\nkind = "table"\n[inertia.table]\nfile = "{name}"\n')
        table = missions.load(tmp_path / "m.toml", PHASES)
        for t in (1.0, 4.0, 9.0):
            np.testing.assert_array_equal(table.scenario().inertia(jnp.asarray(t), 0),
                                          linear.scenario().inertia(jnp.asarray(t), 0))


def test_scaling_an_events_profile_scales_j():
    m = missions.load(None, [*PHASES, "T=60.0", "inertia.kind='events'", f"inertia.events.initial={A.tolist()}",
                             "inertia.events.times=[10.0, 30.0]", f"inertia.events.targets=[1.3, {B.tolist()}]",
                             "inertia.events.time_constants=[5.0, 0.0]"])
    scenario = m.scenario()
    scaled = scale_inertia(scenario, jnp.asarray(0.7))
    for t in (5.0, 12.0, 45.0):
        np.testing.assert_allclose(scaled.inertia(jnp.asarray(t), 0), 0.7 * scenario.inertia(jnp.asarray(t), 0),
                                   rtol=1e-14)
    assert m.describe()["inertia"]["kind"] == "events" and "inertia" not in missions.load().describe()
    assert missions.load().fingerprint[:16] == "b3ac0d8154f6eeb6"  # the flight mission's, unchanged


def test_batched_leaves_evaluate_each_profile():
    """Leaves with a trailing batch axis (a natively batched rollout) give each profile's J(t)."""
    one = paper_events()
    two = timelines.events(A, jnp.asarray([100.0, 900.0]), jnp.stack([jnp.asarray(B), jnp.asarray(B)]),
                           jnp.asarray([0.0, 0.8]), jnp.asarray([50.0, 0.0]))
    batch = jax.tree.map(lambda a, b: jnp.stack([a, b], -1), one, two)
    for t in (50.0, 300.0, 1000.0, 3000.0):
        J = batch(jnp.asarray(t), 0)
        np.testing.assert_allclose(J[..., 0], one(jnp.asarray(t), 0), rtol=1e-14)
        np.testing.assert_allclose(J[..., 1], two(jnp.asarray(t), 0), rtol=1e-14)


EVENTS = [*PHASES, "T=60.0", "inertia.kind='events'", f"inertia.events.initial={A.tolist()}"]


@pytest.mark.parametrize(("overrides", "message"), [
    (["inertia.events.times=[30.0, 10.0]", "inertia.events.targets=[1.1, 1.2]"], "must increase"),
    (["inertia.events.times=[10.0]", f"inertia.events.targets=[{(-A).tolist()}]"], r"targets\[0\] is not positive"),
    (["inertia.events.times=[10.0, 20.0]", "inertia.events.targets=[1.1]"], "2 times, 1 targets"),
    (["inertia.events.times=[10.0]", "inertia.events.targets=[0.0]"], "a scale must be positive"),
    (["inertia.events.times=[10.0]", "inertia.events.targets=[1.1]", f"inertia.J0.nominal={A.tolist()}"],
     "excludes the paper profile's key"),
    (["inertia.events.times=[10.0]", "inertia.events.targets=[1.1]", "inertia.events.tau=[1.0]"], "unknown key"),
    (["inertia.kind='fuel'"], "inertia.kind must be one of"),
    (["inertia.kind='table'", "inertia.table.times=[0.0, 1.0]",
      f"inertia.table.inertias=[{A.tolist()}, {(-B).tolist()}]"], r"row 2 \(t = 1 s\) is not positive"),
])
def test_bad_inertia_tables_are_one_line_errors(overrides, message):
    base = PHASES + ["T=60.0"] if "table" in overrides[0] else EVENTS
    with pytest.raises(ValueError, match=message) as error:
        missions.load(None, base + overrides)
    assert "\n" not in str(error.value)


def test_a_table_file_without_a_column_is_a_one_line_error(tmp_path):
    (tmp_path / "J.csv").write_text("t,Jxx,Jyy,Jzz,Jxy,Jxz\n0,1,1,1,0,0\n1,1,1,1,0,0\n")
    with pytest.raises(ValueError, match="names no column 'Jyz'") as error:
        missions.load(None, [*PHASES, "T=10.0", "inertia.kind='table'", f"inertia.table.file='{tmp_path / 'J.csv'}'"])
    assert "\n" not in str(error.value)
