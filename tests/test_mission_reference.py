"""The mission's [reference] table (so3jax.components.references): each kind's R_d against
its closed form (the orbit frame against the circular orbit's nadir and velocity), Omega_d
against finite differences of R_d, the paper's kind as today, and bad tables one line."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from so3jax.missions import mission as missions

N = 1.1e-3  # rad/s


def _reference(*overrides):
    m = missions.load(None, ["T=100", f"orbit.n={N}", *overrides])
    return m, m.scenario("float64").reference


def _attitude(reference, t):
    phase = int(np.searchsorted(np.asarray(reference.phase_times), t, side="right") - 1)
    return np.asarray(reference.attitude(np.float64(t), phase)), np.asarray(reference.rate(t, phase))


def _rate_by_differences(reference, t, h=1e-3):
    (R_minus, _), (R, _), (R_plus, _) = (_attitude(reference, t + d) for d in (-h, 0.0, h))
    W = R.T @ (R_plus - R_minus) / (2 * h)
    return np.array([W[2, 1], W[0, 2], W[1, 0]])


def test_the_orbit_frame_points_z_to_nadir_and_x_along_the_velocity():
    """Circular orbit, the inertial frame = LVLH at t = 0: position direction
    r(t) = -cos(n t) e_z + sin(n t) e_x, velocity direction its derivative / n."""
    _, reference = _reference("reference.kind='lvlh'")
    for t in (0.0, 250.0, 700.0, 2600.0, 3999.0):
        R, rate = _attitude(reference, t)
        r = -np.cos(N * t) * np.array([0, 0, 1.0]) + np.sin(N * t) * np.array([1.0, 0, 0])
        v = np.sin(N * t) * np.array([0, 0, 1.0]) + np.cos(N * t) * np.array([1.0, 0, 0])
        np.testing.assert_allclose(R[:, 2], -r, atol=1e-12)  # body z: nadir
        np.testing.assert_allclose(R[:, 0], v, atol=1e-12)  # body x: along the velocity
        np.testing.assert_allclose(rate, [0.0, -N, 0.0], atol=1e-15)
        np.testing.assert_allclose(_rate_by_differences(reference, t), rate, atol=1e-12)


def test_an_offset_turns_the_desired_frame_within_the_orbit_frame():
    offset = [0.3, -0.2, 0.5]
    _, plain = _reference("reference.kind='lvlh'")
    _, turned = _reference("reference.kind='lvlh'", f"reference.lvlh.offset={offset}")
    Q = Rotation.from_rotvec(offset).as_matrix()
    for t in (0.0, 450.0, 3000.0):
        (R, _), (R_turned, rate) = _attitude(plain, t), _attitude(turned, t)
        np.testing.assert_allclose(R_turned, R @ Q, atol=1e-12)
        np.testing.assert_allclose(rate, Q.T @ [0.0, -N, 0.0], atol=1e-15)
        np.testing.assert_allclose(_rate_by_differences(turned, t), rate, atol=1e-12)


def test_an_inertial_reference_holds_its_attitude():
    attitude = [0.1, 0.7, -0.4]
    m, reference = _reference("reference.kind='inertial'", f"reference.inertial.attitude={attitude}")
    for t in (0.0, 520.0, 3000.0):
        R, rate = _attitude(reference, t)
        np.testing.assert_allclose(R, Rotation.from_rotvec(attitude).as_matrix(), atol=1e-14)
        assert not rate.any()
    assert m.describe()["reference"] == {"kind": "inertial", "inertial": {"attitude": attitude}}


def test_the_paper_kind_is_the_default_and_leaves_the_mission_as_it_was():
    default, explicit = missions.load(None), missions.load(None, ["reference.kind='paper'"])
    assert default.fingerprint == explicit.fingerprint and "reference" not in default.describe()
    rates = np.asarray(default.scenario("float64").reference.rates)
    n = default.n
    np.testing.assert_allclose(rates, [[n, -10 * n, 2 * n], [n, -10 * n, 2 * n], [0, 0, 0]], rtol=1e-15)


@pytest.mark.parametrize(("override", "message"), [
    ("reference.kind='spin'", "reference.kind"),
    ("reference.lvlh.offset=[1.0, 2.0]", "reference.lvlh.offset"),
    ("reference.inertial.attitude='x'", "reference.inertial.attitude"),
    ("reference.lvlh.unknown=1.0", "unknown"),
])
def test_bad_reference_tables_are_one_line_errors(override, message):
    with pytest.raises(ValueError, match=message):
        missions.load(None, [override])


CONSTANT = "inertia.J=[[1200.0, 0.0, 0.0], [0.0, 1000.0, 0.0], [0.0, 0.0, 800.0]]"
OWN_PHASES = ("phases.names=['a', 'b']", "phases.start=[0.0, 50.0]")


def test_slews_reach_each_target_and_hold_it():
    targets = [[0.3, 0.0, 0.0], [0.3, 0.4, -0.2]]
    m, reference = _reference(CONSTANT, *OWN_PHASES, "reference.kind='slews'", f"reference.slews.attitudes={targets}",
                              "reference.slews.times=[5.0, 70.0]", "reference.slews.max_rate=0.05")
    ends = np.asarray(reference.times) + np.asarray(reference.durations)
    for k, (target, end) in enumerate(zip(targets, ends)):
        t = np.float64(end + 1.0)
        np.testing.assert_allclose(np.asarray(reference.attitude(t, 0)), Rotation.from_rotvec(target).as_matrix(),
                                   atol=1e-12)
        assert not np.asarray(reference.rate(t, 0)).any()
    assert m.describe()["reference"]["slews"]["times"] == [5.0, 70.0]


def test_a_table_from_a_file_passes_through_its_samples(tmp_path):
    """The mission file's table (a CSV beside it) equals the attitudes it was sampled from at its
    samples; given inline, the same reference."""
    times = np.linspace(0.0, 90.0, 10)
    rotvecs = np.outer(np.sin(times / 30.0), [0.2, -0.1, 0.3])
    q = Rotation.from_rotvec(rotvecs).as_quat()[:, [3, 0, 1, 2]]  # [w, x, y, z]
    np.savetxt(tmp_path / "attitude.csv", np.column_stack([times, q]), delimiter=",", header="t,qw,qx,qy,qz",
               comments="")
    (tmp_path / "m.toml").write_text(f"T = 100.0\n{CONSTANT}\n[phases]\nnames = ['a', 'b']\nstart = [0.0, 50.0]\n"
                                     "[reference]\nkind = 'table'\n[reference.table]\nfile = 'attitude.csv'\n")
    reference = missions.load(tmp_path / "m.toml").scenario("float64").reference
    for t, v in zip(times, rotvecs):
        np.testing.assert_allclose(np.asarray(reference.attitude(np.float64(t), 0)),
                                   Rotation.from_rotvec(v).as_matrix(), atol=1e-12)
    inline = _reference(CONSTANT, *OWN_PHASES, "reference.kind='table'", f"reference.table.times={times.tolist()}",
                        f"reference.table.quaternions={q.tolist()}")[1]
    np.testing.assert_allclose(np.asarray(inline.attitude(np.float64(33.3), 0)),
                               np.asarray(reference.attitude(np.float64(33.3), 0)), atol=1e-15)


EVENTS = ("inertia.kind='events'", "inertia.events.initial=[[1200.0, 0.0, 0.0], [0.0, 1000.0, 0.0], [0.0, 0.0, 800.0]]",
          "inertia.events.times=[0.7, 1.5]", "inertia.events.targets=[1.3, 0.9]",
          "inertia.events.time_constants=[0.4, 0.0]")


def test_a_sweep_s_samples_share_a_reference_they_do_not_change():
    """A slew reference and an inertia timeline in a dispersed batch: one for the batch
    (natively batched), each sample's metrics those of its scenario flown alone."""
    import jax
    import jax.numpy as jnp

    from so3jax.missions import batched, build, draw
    from so3jax.sim.rollout import rollout

    m = missions.load(None, ["T=2.0", "control.mode='continuous'", "sensors.gyro=false", "sensors.star_tracker=false",
                             "estimator.kind='truth'", "actuator.kind='ideal'", "controllers=['pd']", *EVENTS,
                             "phases.names=['a']", "phases.start=[0.0]", "reference.kind='slews'",
                             "reference.slews.attitudes=[[0.02, 0.0, 0.0]]", "reference.slews.times=[0.5]"])
    dispersions, leaves = draw.parse({"initial": {"attitude": {"max_angle_deg": 5.0}}}, m)
    inputs = batched.inputs(draw.draw(dispersions, leaves, 0, 3, 20), jnp.float64)
    controller, gains = m.controller("pd")
    run = jax.jit(lambda inputs: batched.sample_metrics(inputs, gains, controller=controller, mission=m))
    batch = run(inputs)  # under jit, as a sweep runs it
    params = type(inputs[0])(*(x[1] for x in inputs[0]))
    alone = rollout(build.scenario(m, params), controller, gains, params.seed).metrics
    np.testing.assert_allclose(batch["rmse"][1], alone.rmse, rtol=1e-12)
    assert len(np.unique(np.asarray(batch["rmse"]))) == 3


@pytest.mark.parametrize(("overrides", "message"), [
    (("reference.kind='slews'", "reference.slews.attitudes=[[0.3, 0.0, 0.0]]"), "give attitudes"),
    (("reference.kind='slews'", "reference.slews.attitudes=[[0.3, 0.0, 0.0]]", "reference.slews.times=[1.0, 2.0]"),
     "1 attitudes and 2 times"),
    (("reference.kind='slews'", "reference.slews.attitudes=[[3.0, 0.0, 0.0], [0.0, 0.0, 0.0]]",
      "reference.slews.times=[1.0, 2.0]"), "slew 0 ends at"),
    (("reference.kind='table'", "reference.table.times=[0.0, 1.0]",
      "reference.table.quaternions=[[1.0, 0.0, 0.0, 0.0], [0.9, 0.0, 0.0, 0.0]]"), r"quaternions\[1\] is not a unit"),
    (("reference.kind='table'", "reference.table.times=[1.0, 0.0]",
      "reference.table.quaternions=[[1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]]"), "strictly increasing"),
    (("reference.kind='table'", "reference.table.file='x.csv'", "reference.table.times=[0.0, 1.0]"), "one of the two"),
    (("phases.names=['a', 'b']", "phases.start=[0.0]"), "one start time per name"),
    (("phases.names=['a', 'b']", "phases.start=[0.0, 50.005]"), "not a whole number of steps"),
    (("phases.names=['a', 'b']", "phases.start=[10.0, 50.0]"), "begin at 0"),
])
def test_bad_reference_and_phase_tables_are_one_line_errors(overrides, message):
    with pytest.raises(ValueError, match=message) as error:
        missions.load(None, ["T=100", CONSTANT, "reference.kind='inertial'", *overrides])
    assert "\n" not in str(error.value)
    with pytest.raises(ValueError, match="paper's phases"):  # its inertia profile and reference switch there
        missions.load(None, ["T=100", *OWN_PHASES])



TABLE_FILES = {  # kind: (CSV columns, .npz arrays) of a three-row table holding still
    "reference": (("t", "qw", "qx", "qy", "qz"), {"q": np.tile([1.0, 0.0, 0.0, 0.0], (3, 1))}),
    "inertia": (("t", "Jxx", "Jyy", "Jzz", "Jxy", "Jxz", "Jyz"),
                {"J": np.tile(np.diag([900.0, 800.0, 600.0]), (3, 1, 1))}),
}


def _table_files(folder, kind: str) -> dict:
    """{case: path} of table files of ``kind`` that are not one (the good .npz's bytes cut or
    overwritten, a text file named .npz, a .npy named .npz, a CSV cut mid-line, one not UTF-8,
    one naming its second column twice), and a spreadsheet's CSV with a UTF-8 byte-order mark."""
    (columns, arrays), times = TABLE_FILES[kind], np.array([0.0, 5.0, 10.0])
    np.savez(folder / "good.npz", t=times, **arrays)
    good = (folder / "good.npz").read_bytes()
    values = {"qw": 1.0, "Jxx": 900.0, "Jyy": 800.0, "Jzz": 600.0}
    line = lambda t, names: ",".join(str(t if name == "t" else values.get(name, 0.0)) for name in names) + "\n"
    rows = ",".join(columns) + "\n" + "".join(line(t, columns) for t in times)
    twice = columns + columns[1:2]
    repeated = ",".join(twice) + "\n" + "".join(line(t, twice) for t in times)
    files = {"truncated npz": ("cut.npz", good[: len(good) // 2]), "text npz": ("text.npz", rows.encode()),
             "corrupt npz": ("bad.npz", good[:200] + b"\0" * 60 + good[260:]),
             "truncated csv": ("cut.csv", rows[:-7].encode()), "binary csv": ("bin.csv", good),
             "duplicate columns": ("dup.csv", repeated.encode()),
             "byte-order mark": ("bom.csv", rows.encode("utf-8-sig"))}
    for name, data in files.values():
        (folder / name).write_bytes(data)
    np.save(folder / "array.npy", times)
    (folder / "array.npy").rename(folder / "npy.npz")
    return {case: folder / name for case, (name, _) in files.items()} | {"npy npz": folder / "npy.npz"}


def _table_mission(kind: str, path) -> list:
    """--set overrides of a mission reading its reference or inertia table from ``path``."""
    if kind == "inertia":
        return [*OWN_PHASES, "reference.kind='inertial'", "inertia.kind='table'", f"inertia.table.file='{path}'"]
    return [*OWN_PHASES, CONSTANT, "reference.kind='table'", f"reference.table.file='{path}'"]


@pytest.mark.parametrize(("case", "message"), [
    ("truncated npz", "truncated or corrupt"), ("corrupt npz", "truncated or corrupt"),
    ("text npz", "not a .npz (zip) archive"), ("npy npz", "a single .npy array"),
    ("truncated csv", "line 4 holds"), ("binary csv", "not a CSV text file"),
    ("duplicate columns", "names the column '{}' 2 times")])
@pytest.mark.parametrize("kind", ["reference", "inertia"])
def test_a_bad_table_file_is_a_one_line_error_before_compiling(in_process, capsys, case, message, kind):
    from so3jax import commands as cli

    path = _table_files(in_process, kind)[case]
    sets = [x for s in _table_mission(kind, path) for x in ("--set", s)]
    assert cli.main(["fly", "--T", "10", "--out", "o", *sets]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"so3jax fly: error: {kind}.table: {path}: ") and "\n" not in err, err
    assert message.format(TABLE_FILES[kind][0][1]) in err, err
    assert not (in_process / "o").exists()


@pytest.mark.parametrize("kind", ["reference", "inertia"])
def test_a_table_file_with_a_byte_order_mark_reads(tmp_path, kind):
    """A CSV a spreadsheet saved as 'UTF-8 with BOM' reads as the same table without it."""
    path = _table_files(tmp_path, kind)["byte-order mark"]
    plain = tmp_path / "plain.csv"
    plain.write_text(path.read_text(encoding="utf-8-sig"))
    marked, unmarked = (missions.load(None, ["T=10", *_table_mission(kind, p)]).describe() for p in (path, plain))
    assert str(marked).replace(str(path), "") == str(unmarked).replace(str(plain), "")
    mission_file = tmp_path / "m.toml"  # the mission file itself, saved with a byte-order mark
    mission_file.write_text("T = 10.0\n" + "\n".join(_table_mission(kind, path.name)).replace("'", '"'),
                            encoding="utf-8-sig")
    assert str(missions.load(mission_file).describe()).replace(str(path), "") == str(marked).replace(str(path), "")
