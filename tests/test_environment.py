"""The space environment of so3jax.dynamics.environment against independent numpy: the circular
orbit's geometry (N from r, v at t = 0), the gravity gradient against hand-derived closed forms
and finite differences of its potential on SO(3), the dipole field's magnitude, direction, sign,
divergence and curl (and ppigrf's IGRF where installed), Vallado's exponential atmosphere, the
sun and the Earth's shadow, the drag, solar and magnetic torques, finite gradients, batches and
dtypes. Values are computed eagerly (no compilation) except where a test is about jit / vmap / grad.
"""

import importlib.util
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.linalg import expm

from so3jax.dynamics import environment as env
from so3jax.dynamics.orbit import EARTH_RADIUS, MAX_MEAN_MOTION, MIN_ALTITUDE, MU_EARTH, orbital_rate

N_500 = orbital_rate(500e3)
ORBITS = [  # (n, inclination, raan, argument_of_latitude, earth_angle)
    (N_500, 0.0, 0.0, 0.0, 0.0),
    (N_500, math.radians(97.4), math.radians(40.0), math.radians(-70.0), 1.1),
    (orbital_rate(800e3), math.radians(51.6), math.radians(200.0), math.radians(135.0), 4.0),
]
J_FULL = np.array([[120.0, 3.0, -2.0], [3.0, 100.0, 4.0], [-2.0, 4.0, 80.0]])
B0_NT = math.sqrt(29404.8**2 + 1450.9**2 + 4652.5**2)
M_HAT = np.array([-1450.9, 4652.5, -29404.8]) / B0_NT  # (g11, h11, g10) / |g|
A_REF = 6371.2e3
# Vallado (2013) Table 8-4: base altitude [km], nominal density [kg/m^3], scale height [km], 100 km up
VALLADO = [(100, 5.297e-7, 5.877), (110, 9.661e-8, 7.263), (120, 2.438e-8, 9.473), (130, 8.484e-9, 12.636),
           (140, 3.845e-9, 16.149), (150, 2.070e-9, 22.523), (180, 5.464e-10, 29.740), (200, 2.789e-10, 37.105),
           (250, 7.248e-11, 45.546), (300, 2.418e-11, 53.628), (350, 9.518e-12, 53.298), (400, 3.725e-12, 58.515),
           (450, 1.585e-12, 60.828), (500, 6.967e-13, 63.822), (600, 1.454e-13, 71.835), (700, 3.614e-14, 88.667),
           (800, 1.170e-14, 124.64), (900, 5.245e-15, 181.05), (1000, 3.019e-15, 268.00)]


def rot(axis, angle):
    """The rotation by ``angle`` about x, y or z (0, 1, 2) as a numpy (3, 3)."""
    c, s = math.cos(angle), math.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m = np.eye(3)
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def hat(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def random_rotation(seed):
    return expm(hat(np.random.default_rng(seed).normal(size=3)))


def orbit_of(params):
    return env.circular_orbit(*params)


def np_position_eci(params, t):
    """r_ECI from the module docstring's formula, numpy."""
    n, i, raan, u0, _ = params
    a = (MU_EARTH / n**2) ** (1 / 3)
    u = u0 + n * t
    return a * np.array([math.cos(raan) * math.cos(u) - math.sin(raan) * math.sin(u) * math.cos(i),
                         math.sin(raan) * math.cos(u) + math.cos(raan) * math.sin(u) * math.cos(i),
                         math.sin(u) * math.sin(i)])


def np_eci_from_n(params):
    """N's axes in ECI from r, v at t = 0 (v by central differences): x = v^, z = -r^, y = z x x."""
    r = np_position_eci(params, 0.0)
    v = (np_position_eci(params, 1e-3) - np_position_eci(params, -1e-3)) / 2e-3
    x, z = v / np.linalg.norm(v), -r / np.linalg.norm(r)
    return np.stack([x, np.cross(z, x), z], axis=1)


def np_dipole(r, g=(-29404.8, -1450.9, 4652.5)):
    """B [T] of the degree-1 potential V = a^3 (gv . r) / |r|^3, gv = (g11, h11, g10) [nT], by numpy."""
    gv = np.array([g[1], g[2], g[0]]) * 1e-9
    rn = np.linalg.norm(r)
    return A_REF**3 * (3.0 * (gv @ r) * r / rn**5 - gv / rn**3)


# --- the orbit ------------------------------------------------------------------------------


@pytest.mark.parametrize("params", ORBITS)
def test_orbit_geometry(params):
    orbit = orbit_of(params)
    n = params[0]
    a = (MU_EARTH / n**2) ** (1 / 3)
    assert float(orbit.radius()) == pytest.approx(a, rel=1e-14)
    C = np.asarray(orbit.eci_from_n())
    np.testing.assert_allclose(C, np_eci_from_n(params), atol=1e-9)
    np.testing.assert_allclose(C.T @ C, np.eye(3), atol=1e-14)
    assert np.linalg.det(C) == pytest.approx(1.0, abs=1e-14)
    normal = np.cross(np_position_eci(params, 0.0), np_position_eci(params, 10.0))
    np.testing.assert_allclose(C[:, 1], -normal / np.linalg.norm(normal), atol=1e-12)  # y = -orbit normal
    for t in (0.0, 123.4, 1500.0, 4321.0, 2 * math.pi / n):
        r_eci, v_eci = np.asarray(orbit.position_eci(t)), np.asarray(orbit.velocity_eci(t))
        r_n, v_n = np.asarray(orbit.position_n(t)), np.asarray(orbit.velocity_n(t))
        np.testing.assert_allclose(r_eci, np_position_eci(params, t), rtol=0, atol=1e-6)
        np.testing.assert_allclose(r_n, C.T @ r_eci, rtol=0, atol=1e-6)
        np.testing.assert_allclose(v_n, C.T @ v_eci, rtol=0, atol=1e-9)
        np.testing.assert_allclose(r_n, a * np.array([math.sin(n * t), 0.0, -math.cos(n * t)]), rtol=0, atol=1e-6)
        assert np.linalg.norm(r_eci) == pytest.approx(a, rel=1e-14)
        assert np.linalg.norm(v_eci) == pytest.approx(n * a, rel=1e-14)
        assert abs(r_eci @ v_eci) < 1e-12 * a * n * a
    np.testing.assert_allclose(orbit.position_eci(2 * math.pi / n), orbit.position_eci(0.0), rtol=0, atol=1e-6)
    np.testing.assert_allclose(orbit.position_n(0.0), [0.0, 0.0, -a], rtol=0, atol=1e-9)  # r^_N(0) = -z
    # v = dr/dt, by forward-mode differentiation
    np.testing.assert_allclose(jax.jacfwd(orbit.position_eci)(700.0), orbit.velocity_eci(700.0), rtol=1e-12)


def test_circular_orbit_builder():
    orbit = env.circular_orbit(np.float32(N_500), 0.5)
    assert all(leaf.dtype == jnp.float32 for leaf in jax.tree.leaves(orbit))
    assert env.circular_orbit(N_500).n.dtype == jnp.float64
    assert env.circular_orbit(N_500, dtype=jnp.float32).raan.dtype == jnp.float32
    with pytest.raises(ValueError, match="positive"):
        env.circular_orbit(-1e-3)
    assert float(env.circular_orbit(orbital_rate(500e3)).altitude()) == pytest.approx(500e3, abs=1e-6)


def test_an_orbit_below_the_least_altitude_is_refused():
    """The least altitude: MIN_ALTITUDE (100 km) above the equatorial radius, n <= MAX_MEAN_MOTION."""
    assert MAX_MEAN_MOTION == pytest.approx(orbital_rate(MIN_ALTITUDE)) and MIN_ALTITUDE == 100e3
    assert float(env.circular_orbit(MAX_MEAN_MOTION).altitude()) == pytest.approx(100e3, abs=1e-3)
    with pytest.raises(ValueError, match=r"^the mean motion n = 0.002 rad/s is a circular orbit of radius 4636 km, "
                                         r"altitude -1742 km: below the least altitude, 100 km above"):
        env.circular_orbit(0.002)
    with pytest.raises(ValueError, match="below the least altitude"):
        env.circular_orbit(np.array([N_500, 0.002]))


@pytest.mark.parametrize("overrides,message", [
    (["orbit.n=0.002"], "orbit.n = 0.002 rad/s is a circular orbit of radius 4636 km, altitude -1742 km: below the "
                        "least altitude, 100 km above the Earth's equatorial radius 6378.137 km "
                        "(orbit.n <= 0.00121086 rad/s)"),
    (["orbit.n=0.0", "environment.gravity_gradient={}"],
     "orbit.n = 0 rad/s is no orbit, but environment.gravity_gradient fly on one: give orbit.n > 0 "
     "(at most 0.00121086 rad/s, an orbit 100 km high)"),
    (["orbit.n=0.0", 'momentum.kind="magnetorquers"'], "orbit.n = 0 rad/s is no orbit, but momentum.kind = "
                                                       "'magnetorquers' fly on one"),
])
def test_a_mission_s_orbit_below_the_least_altitude_or_missing_is_refused_when_parsed(overrides, message):
    from so3jax.missions import mission

    with pytest.raises(ValueError) as err:
        mission.load(None, ["T=1.0", *overrides])
    assert str(err.value).startswith(message) and "\n" not in str(err.value)
    mission.load(None, ["T=1.0", f"orbit.n={MAX_MEAN_MOTION!r}", "environment.gravity_gradient={}"])
    mission.load(None, ["T=1.0", "orbit.n=0.0"])  # no orbital motion, nothing on the orbit


def test_fly_refuses_an_orbit_below_the_surface_with_exit_2(in_process, capsys):
    from so3jax import commands as cli

    leo = str(Path(__file__).parents[1] / "missions" / "leo.toml")
    assert cli.main(["fly", leo, "--set", "orbit.n=0.002", "--T", "20"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("so3jax fly: error: orbit.n = 0.002 rad/s is a circular orbit of radius 4636 km")
    assert err.count("\n") == 1 and "Traceback" not in err


# --- the gravity gradient ---------------------------------------------------------------------


def np_gravity_gradient(n, r_hat_n, R, J):
    r_b = R.T @ r_hat_n
    return 3 * n**2 * np.cross(r_b, J @ r_b)


def test_gravity_gradient_closed_forms():
    orbit = env.circular_orbit(N_500)
    n = N_500
    J = np.diag([120.0, 100.0, 80.0])
    Jxx, Jyy, Jzz = np.diag(J)
    r_hat = np.array([0.0, 0.0, -1.0])  # r^_N(0)
    gg = lambda t, R, J: np.asarray(env.gravity_gradient_torque(orbit, t, jnp.asarray(R), jnp.asarray(J)))
    np.testing.assert_allclose(gg(0.0, np.eye(3), J), 0.0, atol=1e-20)  # principal axes along LVLH
    for t in (0.0, 800.0, 2500.0):  # the body held in the orbit frame: columns x = v^, y, z = -r^
        c, s = math.cos(n * t), math.sin(n * t)
        lvlh = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
        np.testing.assert_allclose(gg(t, lvlh, J), 0.0, atol=1e-20)
    for theta in (0.1, -0.4, 1.0, 2.5):
        # pitch R = Ry(theta): r_b = [sin, 0, -cos], J r_b = [Jxx sin, 0, -Jzz cos],
        # r_b x J r_b = [0, sin cos (Jzz - Jxx), 0]: restoring (< 0 for theta > 0) where Jzz < Jxx
        R = rot(1, theta)
        expected = np.array([0.0, 3 * n**2 * (Jzz - Jxx) * math.sin(theta) * math.cos(theta), 0.0])
        np.testing.assert_allclose(np_gravity_gradient(n, r_hat, R, J), expected, atol=1e-20)
        np.testing.assert_allclose(gg(0.0, R, J), expected, rtol=1e-12, atol=1e-20)
        # roll R = Rx(phi): r_b = [0, -sin, -cos], r_b x J r_b = [sin cos (Jzz - Jyy), 0, 0]
        R = rot(0, theta)
        expected = np.array([3 * n**2 * (Jzz - Jyy) * math.sin(theta) * math.cos(theta), 0.0, 0.0])
        np.testing.assert_allclose(np_gravity_gradient(n, r_hat, R, J), expected, atol=1e-20)
        np.testing.assert_allclose(gg(0.0, R, J), expected, rtol=1e-12, atol=1e-20)
    assert gg(0.0, rot(1, 0.2), J)[1] < 0.0  # pitch: the minimum-inertia axis (z) pulled back to nadir


@pytest.mark.parametrize("params", ORBITS[1:])
def test_gravity_gradient_is_minus_the_potential_gradient(params):
    orbit = orbit_of(params)
    n = params[0]
    for seed, t in ((0, 0.0), (1, 1234.5), (2, 4000.0)):
        R = random_rotation(seed)
        r_hat = np.asarray(orbit.position_n(t)) / float(orbit.radius())
        U = lambda R: 1.5 * n**2 * (R.T @ r_hat) @ J_FULL @ (R.T @ r_hat)
        eps = 1e-5
        minus_grad = np.array([-(U(R @ expm(hat(eps * e))) - U(R @ expm(hat(-eps * e)))) / (2 * eps)
                               for e in np.eye(3)])
        tau = np.asarray(env.gravity_gradient_torque(orbit, t, jnp.asarray(R), jnp.asarray(J_FULL)))
        scale = 3 * n**2 * np.abs(J_FULL).max()
        np.testing.assert_allclose(tau, minus_grad, rtol=0, atol=1e-8 * scale)
        np.testing.assert_allclose(tau, np_gravity_gradient(n, r_hat, R, J_FULL), rtol=0, atol=1e-12 * scale)
        assert np.linalg.norm(tau) > 1e-3 * scale


# --- the geomagnetic field ---------------------------------------------------------------------


def test_dipole_equator_and_poles():
    for r in (6878e3, 7178e3):
        strength = B0_NT * 1e-9 * (A_REF / r) ** 3
        pole = np.asarray(env.dipole_field_ecef(jnp.asarray(r * M_HAT)))
        np.testing.assert_allclose(pole, 2 * strength * M_HAT, rtol=1e-12)
        np.testing.assert_allclose(np.asarray(env.dipole_field_ecef(jnp.asarray(-r * M_HAT))), 2 * strength * M_HAT,
                                   rtol=1e-12)
        e1 = np.cross(M_HAT, [1.0, 0.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(M_HAT, e1)
        for angle in (0.0, 1.0, 2.5, 4.0):
            at = r * (math.cos(angle) * e1 + math.sin(angle) * e2)  # on the magnetic equator
            np.testing.assert_allclose(np.asarray(env.dipole_field_ecef(jnp.asarray(at))), -strength * M_HAT,
                                       rtol=1e-12, atol=1e-12 * strength)
        generic = r * np.array([0.3, -0.5, 0.81]) / np.linalg.norm([0.3, -0.5, 0.81])
        np.testing.assert_allclose(np.asarray(env.dipole_field_ecef(jnp.asarray(generic))), np_dipole(generic),
                                   rtol=1e-12)


def test_dipole_points_down_in_the_north():
    north, south = np.array([0.0, 0.0, 6878e3]), np.array([0.0, 0.0, -6878e3])
    axial = np.asarray(env.dipole_field_ecef(jnp.asarray(north), coefficients=(-30000.0, 0.0, 0.0)))
    np.testing.assert_allclose(axial[:2], 0.0, atol=1e-20)
    assert axial[2] < 0.0  # toward -r^: down at the geographic north pole
    assert axial[2] == pytest.approx(-2 * 30000e-9 * (A_REF / 6878e3) ** 3, rel=1e-12)
    assert float(env.dipole_field_ecef(jnp.asarray(north))[2]) < 0.0  # the tilted one too
    assert float(env.dipole_field_ecef(jnp.asarray(south))[2]) < 0.0  # up (toward +r^ = -z) in the south


def test_dipole_divergence_and_curl_free():
    f = lambda r: np.asarray(env.dipole_field_ecef(jnp.asarray(r)))
    h = 100.0  # m
    for point in ([6878e3, 0.0, 0.0], [3000e3, -4000e3, 4500e3], [-1000e3, 2000e3, -6500e3]):
        point = np.asarray(point)
        jac = np.stack([(f(point + h * e) - f(point - h * e)) / (2 * h) for e in np.eye(3)], axis=1)  # dB_i/dx_j
        scale = np.linalg.norm(f(point)) / np.linalg.norm(point)
        assert np.abs(jac).max() > 0.5 * scale
        assert abs(np.trace(jac)) < 1e-7 * scale
        np.testing.assert_allclose(jac - jac.T, 0.0, atol=1e-7 * scale)  # curl: the antisymmetric part


@pytest.mark.parametrize("params", ORBITS)
def test_magnetic_field_n_is_the_rotating_dipole(params):
    orbit = orbit_of(params)
    C = np_eci_from_n(params)
    for t in (0.0, 900.0, 3000.0, 20000.0):
        theta = params[4] + env.OMEGA_EARTH * t
        r_eci = np_position_eci(params, t)
        b_eci = rot(2, theta) @ np_dipole(rot(2, -theta) @ r_eci)
        b_n = np.asarray(env.magnetic_field_n(orbit, t))
        np.testing.assert_allclose(b_n, C.T @ b_eci, rtol=0, atol=1e-9 * np.linalg.norm(b_eci))
        assert 1.5e-5 < np.linalg.norm(b_n) < 6e-5  # T, a low orbit's range


_PPIGRF = """import datetime, json, sys
import numpy as np, ppigrf
a = json.loads(sys.stdin.read())
b = ppigrf.igrf_gc(a["r"], np.asarray(a["th"]), np.asarray(a["ph"]), datetime.datetime(2020, 1, 1), max_degree=a["n"])
print(json.dumps([np.asarray(x).reshape(-1).tolist() for x in b]))
"""


def _igrf_ecef(r_km, colatitude, longitude, max_degree):
    """ppigrf's IGRF (2020-01-01) [T] in ECEF axes (N, 3) and the points [m] (N, 3), at colatitudes
    and longitudes [deg] (N,)."""
    if importlib.util.find_spec("ppigrf") is None:
        pytest.skip("ppigrf is not installed")
    th, ph = np.radians(colatitude), np.radians(longitude)
    # ppigrf imports pandas: evaluated in a child process, kept out of the test workers
    given = {"r": r_km, "th": np.asarray(colatitude, float).tolist(), "ph": np.asarray(longitude, float).tolist(),
             "n": max_degree}
    child = subprocess.run([sys.executable, "-c", _PPIGRF], input=json.dumps(given), capture_output=True, text=True,
                           check=True, timeout=120)
    br, bth, bph = (np.asarray(b) * 1e-9 for b in json.loads(child.stdout))
    r_hat = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)
    th_hat = np.stack([np.cos(th) * np.cos(ph), np.cos(th) * np.sin(ph), -np.sin(th)], axis=-1)
    ph_hat = np.stack([-np.sin(ph), np.cos(ph), 0.0 * ph], axis=-1)
    return br[:, None] * r_hat + bth[:, None] * th_hat + bph[:, None] * ph_hat, r_km * 1e3 * r_hat


def _against_igrf(colatitude, longitude):
    """(the dipole's field (N, 3), ppigrf's degree-1 field, ppigrf's full IGRF) at 500 km [T]."""
    r_km = (EARTH_RADIUS + 500e3) / 1e3
    b_dipole, r = _igrf_ecef(r_km, colatitude, longitude, max_degree=1)
    b_igrf, _ = _igrf_ecef(r_km, colatitude, longitude, max_degree=13)
    ours = np.asarray(env.dipole_field_ecef(jnp.asarray(r.T))).T
    return ours, b_dipole, b_igrf


def _ratio_and_angle(ours, theirs):
    """|ours| / |theirs| and the angle between them [deg], per row."""
    norms = np.linalg.norm(ours, axis=1) * np.linalg.norm(theirs, axis=1)
    angle = np.degrees(np.arccos(np.clip(np.sum(ours * theirs, axis=1) / norms, -1.0, 1.0)))
    return np.linalg.norm(ours, axis=1) / np.linalg.norm(theirs, axis=1), angle


def test_dipole_against_ppigrf():
    """Degree 1: the same field to the coefficients' revision (ppigrf's IGRF-14 2020 DGRF, < 0.1 %).
    All degrees at 500 km, at points away from the South Atlantic Anomaly (where a dipole is 60 %
    too strong) and the equatorial Atlantic (where the nearly horizontal field turns 30 deg):
    within 25 % in magnitude and 20 deg in direction; over a 10 x 8 grid of the whole sphere,
    the median within 15 % and 12 deg."""
    colatitude = np.array([10.0, 30.0, 50.0, 70.0, 90.0, 90.0, 110.0, 130.0, 170.0])
    longitude = np.array([0.0, 45.0, 180.0, 225.0, 180.0, 225.0, 180.0, 135.0, 90.0])
    ours, b_dipole, b_igrf = _against_igrf(colatitude, longitude)
    np.testing.assert_allclose(ours, b_dipole, rtol=0, atol=1e-3 * np.linalg.norm(b_dipole, axis=1).min())
    ratio, angle = _ratio_and_angle(ours, b_igrf)
    assert np.all(np.abs(ratio - 1.0) < 0.25), ratio
    assert np.all(angle < 20.0), angle
    grid_colatitude, grid_longitude = (x.ravel() for x in np.meshgrid(np.linspace(9.0, 171.0, 10),
                                                                         np.arange(0.0, 360.0, 45.0)))
    ours, b_dipole, b_igrf = _against_igrf(grid_colatitude, grid_longitude)
    np.testing.assert_allclose(ours, b_dipole, rtol=0, atol=1e-3 * np.linalg.norm(b_dipole, axis=1).min())
    ratio, angle = _ratio_and_angle(ours, b_igrf)
    assert np.median(np.abs(ratio - 1.0)) < 0.15 and np.median(angle) < 12.0, (np.median(ratio), np.median(angle))


def test_magnetic_torque_is_the_cross_product():
    rng = np.random.default_rng(3)
    m, b = rng.normal(size=3), rng.normal(size=3) * 3e-5
    np.testing.assert_allclose(np.asarray(env.magnetic_torque(jnp.asarray(m), jnp.asarray(b))), np.cross(m, b),
                               rtol=1e-14)


# --- the atmosphere ----------------------------------------------------------------------------


def test_atmosphere_table_values_and_continuity():
    bases = np.array([row[0] for row in VALLADO]) * 1e3
    rho = np.asarray(env.atmosphere_density(jnp.asarray(bases)))
    np.testing.assert_allclose(rho, [row[1] for row in VALLADO], rtol=1e-12)
    for h0, rho0, H in VALLADO[:-1]:  # inside a band: rho0 exp(-(h - h0) / H)
        h = (h0 + 0.37 * (VALLADO[[r[0] for r in VALLADO].index(h0) + 1][0] - h0)) * 1e3
        assert float(env.atmosphere_density(h)) == pytest.approx(rho0 * math.exp(-(h / 1e3 - h0) / H), rel=1e-12)
    all_bases = env.ATMOSPHERE_BASE_ALTITUDE
    below = np.asarray(env.atmosphere_density(jnp.asarray(all_bases[1:] - 1e-3)))
    np.testing.assert_allclose(below, env.ATMOSPHERE_DENSITY[1:], rtol=1e-2)  # continuous to 1 % (0.14 % at 25 km)
    grid = np.linspace(0.0, 1200e3, 4801)
    assert np.all(np.diff(np.asarray(env.atmosphere_density(jnp.asarray(grid)))) < 0.0)
    assert float(env.atmosphere_density(1200e3)) == pytest.approx(3.019e-15 * math.exp(-200 / 268.0), rel=1e-12)
    assert float(env.atmosphere_density(0)) == pytest.approx(1.225)  # an integer altitude: float


def test_aerodynamic_torque():
    orbit = env.circular_orbit(orbital_rate(520e3))
    a, n = float(orbit.radius()), float(orbit.n)
    area, cd, d = 2.0, 2.2, 0.3
    rho = 6.967e-13 * math.exp(-20.0 / 63.822)
    drag = 0.5 * rho * cd * area * (n * a) ** 2
    aero = lambda t, R, cp: np.asarray(env.aerodynamic_torque(orbit, t, jnp.asarray(R), area, cd, jnp.asarray(cp)))
    # R = I at t = 0: v along x, F = [-drag, 0, 0]; c_p = [0, d, 0]: tau = c_p x F = [0, 0, d drag]
    np.testing.assert_allclose(aero(0.0, np.eye(3), [0.0, d, 0.0]), [0.0, 0.0, d * drag], rtol=1e-6, atol=1e-22)
    np.testing.assert_allclose(aero(0.0, np.eye(3), [d, 0.0, 0.0]), 0.0, atol=1e-22)  # c_p along the flow
    for seed, t in ((4, 0.0), (5, 2000.0)):
        R = random_rotation(seed)
        np.testing.assert_allclose(aero(t, R, [0.0, 0.0, 0.0]), 0.0, atol=0.0)
        cp = np.array([0.1, -0.2, 0.05])
        v_b = R.T @ np.asarray(orbit.velocity_n(t))
        expected = np.cross(cp, -0.5 * rho * cd * area * np.linalg.norm(v_b) * v_b)
        np.testing.assert_allclose(aero(t, R, cp), expected, rtol=1e-6)


# --- the sun, the shadow, solar pressure -----------------------------------------------------------


def test_sun_direction():
    eps = math.radians(23.4393)
    year = 365.25636 * 86400.0
    for longitude in (0.0, 1.0, 3.5):
        for t in (0.0, 1e6, 2e7):
            s = np.asarray(env.sun_direction_eci(t, longitude))
            assert np.linalg.norm(s) == pytest.approx(1.0, abs=1e-15)
            np.testing.assert_allclose(np.asarray(env.sun_direction_eci(t + year, longitude)), s, atol=1e-12)
    np.testing.assert_allclose(np.asarray(env.sun_direction_eci(0.0, 0.0)), [1.0, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(np.asarray(env.sun_direction_eci(year / 4, 0.0)), [0.0, math.cos(eps), math.sin(eps)],
                               atol=1e-12)  # the June solstice: declination +eps
    s = np.asarray(env.sun_direction_eci(year / 2, 0.0))
    np.testing.assert_allclose(s, [-1.0, 0.0, 0.0], atol=1e-12)


def test_sunlit():
    s = np.asarray(env.sun_direction_eci(1e6, 0.7))
    r = EARTH_RADIUS + 500e3
    side = np.cross(s, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    lit = lambda x: float(env.sunlit(jnp.asarray(x), jnp.asarray(s)))
    assert lit(-r * s) == 0.0  # directly behind the Earth
    assert lit(r * s) == 1.0  # in front
    assert lit(r * side) == 1.0  # over the terminator
    assert lit(-r * s + 0.99 * EARTH_RADIUS * side) == 0.0  # inside the shadow cylinder
    assert lit(-r * s + 1.01 * EARTH_RADIUS * side) == 1.0  # just outside it
    assert env.sunlit(jnp.asarray(r * s, jnp.float32), jnp.asarray(s, jnp.float32)).dtype == jnp.float32


def test_solar_pressure_torque():
    area, reflectivity, d = 2.0, 0.3, 0.2
    force = env.P_SUN * area * (1 + reflectivity)

    def solar(u0, R, cp, t=0.0):
        orbit = env.circular_orbit(N_500, 0.0, 0.0, u0)
        return np.asarray(env.solar_pressure_torque(orbit, t, jnp.asarray(R), area, reflectivity, jnp.asarray(cp), 0.0))

    # equatorial orbit, sun along ECI x (longitude 0 at t = 0), the spacecraft at u0 = 0 under the sun:
    # N: x = [0, 1, 0], y = [0, 0, -1], z = [-1, 0, 0] in ECI, s^_N = [0, 0, -1] (zenith);
    # F = P A (1 + rho) [0, 0, 1] (pushed toward nadir), c_p = [d, 0, 0]: tau = [0, -d F, 0]
    np.testing.assert_allclose(solar(0.0, np.eye(3), [d, 0.0, 0.0]), [0.0, -d * force, 0.0], rtol=1e-12, atol=1e-22)
    np.testing.assert_allclose(solar(math.pi, np.eye(3), [d, 0.0, 0.0]), 0.0, atol=0.0)  # midnight: eclipse
    R = random_rotation(6)
    cp = np.array([0.1, 0.2, -0.3])
    np.testing.assert_allclose(solar(math.pi, R, cp), 0.0, atol=0.0)
    np.testing.assert_allclose(solar(math.pi, R, cp, t=300.0), 0.0, atol=0.0)  # still in the shadow
    assert np.linalg.norm(solar(math.pi, R, cp, t=0.25 * 2 * math.pi / N_500)) > 0.0  # dawn: over the terminator


def test_solar_pressure_lit_generic():
    params = ORBITS[1]
    orbit = orbit_of(params)
    area, reflectivity, longitude = 1.5, 0.6, 1.0
    R = random_rotation(7)
    cp = np.array([0.1, 0.2, -0.3])
    C = np_eci_from_n(params)
    seen = set()
    for t in np.linspace(0.0, 2 * math.pi / params[0], 36):
        lam = longitude + 2 * math.pi * t / (365.25636 * 86400.0)
        eps = math.radians(23.4393)
        s = np.array([math.cos(lam), math.cos(eps) * math.sin(lam), math.sin(eps) * math.sin(lam)])
        r = np_position_eci(params, t)
        shadow = r @ s < 0 and np.linalg.norm(r - (r @ s) * s) < EARTH_RADIUS
        seen.add(shadow)
        expected = 0.0 if shadow else np.cross(cp, -env.P_SUN * area * (1 + reflectivity) * (R.T @ C.T @ s))
        tau = env.solar_pressure_torque(orbit, t, jnp.asarray(R), area, reflectivity, jnp.asarray(cp), longitude)
        np.testing.assert_allclose(np.asarray(tau), expected, rtol=1e-9, atol=1e-20)
    assert seen == {True, False}  # the orbit crosses the shadow


# --- gradients, batches, dtypes ----------------------------------------------------------------


def _torques(orbit, t, R, J):
    """The four torques' sum of entries (one scalar each), at attitude R, inertia J."""
    cp = jnp.asarray([0.05, 0.02, -0.1])
    b_body = env.magnetic_field_n(orbit, t) @ R  # R^T B_N
    return jnp.stack([
        jnp.sum(env.gravity_gradient_torque(orbit, t, R, J)),
        jnp.sum(env.magnetic_torque(jnp.asarray([0.1, 0.2, 0.3]), b_body)),
        jnp.sum(env.aerodynamic_torque(orbit, t, R, 2.0, 2.2, cp)),
        jnp.sum(env.solar_pressure_torque(orbit, t, R, 2.0, 0.3, cp, 0.5)),
    ])


@pytest.mark.parametrize("R", [np.eye(3), random_rotation(8)], ids=["identity", "generic"])
def test_gradients_finite(R):
    orbit = orbit_of(ORBITS[1])
    args = (orbit, jnp.asarray(1000.0), jnp.asarray(R), jnp.asarray(J_FULL))
    jac = jax.jit(jax.jacrev(_torques, argnums=(0, 1, 2, 3)))(*args)
    for leaf in jax.tree.leaves(jac):
        assert np.all(np.isfinite(np.asarray(leaf)))
    d_t, d_R, d_J = (np.asarray(x) for x in jac[1:])
    assert np.abs(d_R[0]).max() > 0 and np.abs(d_J[0]).max() > 0 and abs(d_t[0]) > 0  # gravity gradient
    assert np.abs(d_R).max(axis=(1, 2)).min() > 0  # each torque depends on the attitude
    # d/dt of the gravity gradient against a central difference
    f = lambda t: float(_torques(orbit, t, args[2], args[3])[0])
    assert d_t[0] == pytest.approx((f(1000.5) - f(999.5)) / 1.0, rel=1e-5)


def test_batched_orbit_and_vmap():
    stacked = jax.tree.map(lambda *x: jnp.stack(x), *(orbit_of(p) for p in ORBITS))  # fields (3,)
    ts = jnp.asarray([10.0, 500.0, 3000.0])
    R = jnp.asarray(np.stack([random_rotation(s) for s in range(3)], axis=-1))  # (3, 3, B): batch last
    J = jnp.asarray(J_FULL)[..., None]
    for name in ("position_eci", "velocity_eci", "position_n", "velocity_n"):
        batched = np.asarray(getattr(stacked, name)(ts))
        assert batched.shape == (3, 3)
        for k, p in enumerate(ORBITS):
            np.testing.assert_allclose(batched[:, k], getattr(orbit_of(p), name)(ts[k]), rtol=1e-13, atol=1e-9)
    assert stacked.eci_from_n().shape == (3, 3, 3)
    tau = np.asarray(env.gravity_gradient_torque(stacked, ts, R, J))
    b_n = np.asarray(env.magnetic_field_n(stacked, ts))
    solar = np.asarray(env.solar_pressure_torque(stacked, ts, R, 2.0, 0.3, jnp.asarray([0.1, 0.0, 0.0]), 0.5))
    aero = np.asarray(env.aerodynamic_torque(stacked, ts, R, 2.0, 2.2, jnp.asarray([0.1, 0.0, 0.0])))
    mapped = jax.jit(jax.vmap(lambda o, t, R: (env.gravity_gradient_torque(o, t, R, jnp.asarray(J_FULL)),
                                               env.magnetic_field_n(o, t),
                                               env.solar_pressure_torque(o, t, R, 2.0, 0.3,
                                                                         jnp.asarray([0.1, 0.0, 0.0]), 0.5),
                                               env.aerodynamic_torque(o, t, R, 2.0, 2.2, jnp.asarray([0.1, 0.0, 0.0]))),
                              in_axes=(0, 0, -1), out_axes=-1))(stacked, ts, R)
    for ours, theirs in zip((tau, b_n, solar, aero), mapped):
        np.testing.assert_allclose(ours, np.asarray(theirs), rtol=1e-12, atol=1e-25)


def test_float32():
    orbit = env.circular_orbit(N_500, 0.9, 0.2, 0.1, dtype=jnp.float32)
    R = jnp.asarray(random_rotation(9), jnp.float32)
    J = jnp.asarray(J_FULL, jnp.float32)
    cp = jnp.asarray([0.1, 0.2, 0.3], jnp.float32)
    one = jnp.asarray(1.0, jnp.float32)
    outs = [orbit.position_eci(10.0), orbit.position_n(10.0), orbit.eci_from_n(), env.magnetic_field_n(orbit, 10.0),
            env.gravity_gradient_torque(orbit, 10.0, R, J), env.aerodynamic_torque(orbit, 10.0, R, one, one, cp),
            env.solar_pressure_torque(orbit, 10.0, R, one, one, cp, 0.5),
            env.atmosphere_density(jnp.asarray(5e5, jnp.float32))]
    assert [x.dtype for x in outs] == [jnp.float32] * len(outs)


def test_the_models_constants_are_the_ones_docs_model_md_states():
    """docs/model.md §4 writes the environment's constants: its atmosphere table, dipole
    coefficients and reference radius and solar pressure are the code's, digit for digit."""
    text = (Path(__file__).resolve().parents[1] / "docs" / "model.md").read_text()
    section = text[text.index("The environment's constants"):]
    rows = []
    for line in section.splitlines()[2:]:
        if line.startswith("| ") and re.match(r"\| \d", line):
            cells = [c.strip() for c in line.strip("|").split("|")]
            rows += [tuple(float(x) for x in cells[i:i + 3]) for i in (0, 3) if cells[i]]
        elif rows:
            break
    documented = sorted(rows)
    np.testing.assert_array_equal(np.array(documented)[:, 0] * 1e3, env.ATMOSPHERE_BASE_ALTITUDE)
    np.testing.assert_array_equal(np.array(documented)[:, 1], env.ATMOSPHERE_DENSITY)
    np.testing.assert_allclose(np.array(documented)[:, 2] * 1e3, env.ATMOSPHERE_SCALE_HEIGHT, rtol=1e-15)
    g10, g11, h11 = env.IGRF_2020_DIPOLE
    assert f"$g_1^0 = {g10}$" in section and f"$g_1^1 = {g11}$" in section and f"$h_1^1 = {h11}$" in section
    assert f"$a = {env.IGRF_REFERENCE_RADIUS / 1e3:g}$ km" in section
    assert f"$S$ = {env.SOLAR_IRRADIANCE:g} W/m²" in section and 1361.0 <= env.SOLAR_IRRADIANCE <= 1368.0
    assert env.P_SUN == env.SOLAR_IRRADIANCE / env.SPEED_OF_LIGHT and f"{env.P_SUN:.3e}".startswith("4.540")
