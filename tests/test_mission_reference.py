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
