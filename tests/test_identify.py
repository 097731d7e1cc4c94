"""Mass-property identification (``so3jax.jobs.identify``): the log-Cholesky map and the
principal axes with their 1-sigma, the quaternion conversion of the telemetry file, the
file's checks, the telemetry of a simulated flight, and both fits (regression and
simulation) on the identification manoeuvre (``missions/identify.toml``): exact on
noise-free telemetry, calibrated 3-sigma intervals on noisy telemetry.

Compile time dominates: both flights are one horizon and one seed batch (one compiled
simulation), and every fit of a method sees telemetry of one length (one compiled fit).
The statistical tests use fixed seeds, so they are deterministic; their margins were
measured on disjoint seed sets (see test_regression_intervals_cover_the_truth).
"""

import functools
import warnings
from pathlib import Path

import jax
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import so3jax as sj
from so3jax.dynamics.paper import PAPER_J0, PAPER_J2
from so3jax.jobs.identify import inertia, regression, simulation, telemetry
from so3jax.missions import mission as missions

MISSION = Path(__file__).resolve().parents[1] / "missions" / "identify.toml"
T = 120.0  # s: the square waves switch several times, the rate sweeps several directions
SEEDS = np.arange(12)  # one batch for both flights (one compiled program)
J_TRUE = np.asarray(PAPER_J2)  # the mission's [inertia] J
BARE = {"bias": False, "degree": -1}  # what the noise-free truth has: no gyro bias, no disturbance
DEFAULTS = {}  # bias and a linear disturbance fitted


def one_line(err: pytest.ExceptionInfo) -> str:
    message = str(err.value)
    assert "\n" not in message, message
    return message


# --- the log-Cholesky parameters ----------------------------------------------------

from_params_batch = jax.jit(jax.vmap(inertia.from_params))


def assert_physical_by_eigenvalues(J):
    """J (n, 3, 3): symmetric, positive principal moments, strict triangle inequality."""
    np.testing.assert_allclose(J, np.swapaxes(J, 1, 2), rtol=0, atol=1e-15 * np.abs(J).max())
    lam = np.linalg.eigvalsh(J)  # ascending
    assert np.all(lam[:, 0] > 0), lam[:, 0].min()
    margin = lam[:, 0] + lam[:, 1] - lam[:, 2]  # the tightest of J_i + J_j > J_k
    assert np.all(margin > 0), (margin / lam[:, 2]).min()


def shifted(p, c):
    """p with J scaled by exp(2 c): log-diagonal + c, off-diagonal * exp(c)."""
    return np.concatenate([p[:, :3] + c, p[:, 3:] * np.exp(c)], axis=1)


def test_from_params_gives_only_physical_inertias():
    rng = np.random.default_rng(1)
    p = 1.5 * rng.normal(size=(2000, 6))  # principal moments spread over ~5 decades
    for batch in (p, shifted(p, 20.0), shifted(p, -20.0)):  # |J| up to ~1e22 and down to ~1e-13
        J = np.asarray(from_params_batch(batch))
        assert np.all(np.isfinite(J))
        assert_physical_by_eigenvalues(J)
    # the map's own formula: J = tr(S) I - S with S = L L^T
    L = np.tril(np.diag(np.exp(p[0, :3])))
    L[1, 0], L[2, 0], L[2, 1] = p[0, 3:]
    S = L @ L.T
    np.testing.assert_allclose(np.asarray(inertia.from_params(p[0])), np.trace(S) * np.eye(3) - S, rtol=1e-14)


def test_to_params_inverts_from_params():
    rng = np.random.default_rng(2)
    p = 0.5 * rng.normal(size=(500, 6))
    for c in (0.0, 15.0, -15.0):
        batch = shifted(p, c)
        J = np.asarray(from_params_batch(batch))
        back = np.array([inertia.to_params(j) for j in J])
        scale = np.array([1.0, 1.0, 1.0, np.exp(c), np.exp(c), np.exp(c)])  # l entries relative to exp(c)
        np.testing.assert_allclose((back - batch) / scale, 0.0, rtol=0, atol=1e-12)


def random_physical(n, rng):
    """n physical inertias [kg m^2]: principal moments s_j + s_k (every triangle inequality
    strict) about random principal axes."""
    s = 1000.0 * np.exp(rng.normal(size=(n, 3)))
    moments = s.sum(1, keepdims=True) - s
    Q = Rotation.random(n, random_state=rng).as_matrix()
    return np.einsum("nij,nj,nkj->nik", Q, moments, Q)


def test_from_params_inverts_to_params():
    J = random_physical(500, np.random.default_rng(3))
    back = np.asarray(from_params_batch(np.array([inertia.to_params(j) for j in J])))
    err = np.linalg.norm(back - J, axis=(1, 2)) / np.linalg.norm(J, axis=(1, 2))
    assert err.max() < 1e-12, err.max()


def test_to_params_refuses_the_paper_J0():
    J0 = np.array([[625.0, 5.5, 3.0], [5.5, 350.0, 4.0], [3.0, 4.0, 1000.0]])
    np.testing.assert_array_equal(J0, np.asarray(PAPER_J0))
    lam = np.linalg.eigvalsh(J0)
    assert lam[0] + lam[1] < lam[2]  # 625 + 350 < 1000: no rigid body has it
    with pytest.raises(ValueError, match="triangle inequality") as err:
        inertia.to_params(J0)
    one_line(err)
    with pytest.raises(ValueError):
        inertia.to_params(J_TRUE + np.triu(np.ones((3, 3)), 1))  # not symmetric


def test_principal_axes_and_their_sigma():
    """Moments and axes as numpy's eigh; the 1-sigma against a Monte Carlo of J drawn from
    the covariance (small against the moments' gaps, where first order holds): sampling
    error ~0.5 % at 20 000 draws, bound 5 %."""
    rng = np.random.default_rng(4)
    A = rng.normal(size=(6, 6))
    cov = 4.0 * (A @ A.T) / 6.0 + np.eye(6)  # ~2 kg m^2 per entry; moment gaps >= 299 kg m^2
    lam, V, moment_std, axis_std = inertia.principal(J_TRUE, cov)
    want_lam, want_V = np.linalg.eigh(J_TRUE)
    np.testing.assert_allclose(lam, want_lam, rtol=1e-14)
    np.testing.assert_allclose(np.abs(np.sum(V * want_V, axis=0)), 1.0, rtol=0, atol=1e-13)  # the same axes
    np.testing.assert_allclose(V.T @ V, np.eye(3), atol=1e-14)
    assert np.linalg.det(V) > 0  # a rotation
    np.testing.assert_allclose(J_TRUE @ V, V * lam, rtol=0, atol=1e-10)

    theta = rng.multivariate_normal(inertia.entries(J_TRUE), cov, size=20_000)
    J = np.asarray(jax.vmap(inertia.from_entries)(theta))
    np.testing.assert_array_equal(inertia.entries(J), theta)  # entries' order is from_entries'
    np.testing.assert_array_equal(J, np.swapaxes(J, 1, 2))
    mc_lam, mc_V = np.linalg.eigh(J)
    np.testing.assert_allclose(mc_lam.std(0), moment_std, rtol=0.05)
    angles = np.stack([inertia.axis_angles(V, v) for v in mc_V])  # (n, 3)
    np.testing.assert_allclose(np.sqrt(np.mean(angles**2, axis=0)), axis_std, rtol=0.05)


# --- quaternions ------------------------------------------------------------------------


def scipy_wxyz(R):
    x, y, z, w = np.moveaxis(Rotation.from_matrix(R).as_quat(), -1, 0)
    return np.stack([w, x, y, z], -1)


def test_quaternion_conversion_against_scipy():
    rng = np.random.default_rng(5)
    axes = Rotation.random(200, random_state=rng).apply([1.0, 0.0, 0.0])  # random unit axes
    eps = np.array([0.0, 1e-12, 1e-9, 1e-6, 1e-3, 0.1])
    near_half = (axes[:, None, :] * (np.pi - eps)[None, :, None]).reshape(-1, 3)  # half turns, just below
    exact = np.pi * np.concatenate([np.eye(3), -np.eye(3)])
    random = Rotation.random(1000, random_state=rng).as_rotvec()
    rotations = np.concatenate([random, near_half, exact, np.zeros((1, 3))])
    R = Rotation.from_rotvec(rotations).as_matrix()

    q = telemetry.matrix_to_quaternion(R)
    want = scipy_wxyz(R)
    assert np.all(q[:, 0] >= 0)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, rtol=0, atol=1e-15)
    same_sign = np.where(np.sum(q * want, axis=1, keepdims=True) < 0, -want, want)  # q and -q: one rotation
    np.testing.assert_allclose(q, same_sign, rtol=0, atol=1e-14)
    # a half turn's w is its only small component: still exact well below it
    small = np.abs(want[:, 0]) < 1e-3
    assert small.sum() > 600
    np.testing.assert_allclose(q[small, 0], np.abs(want[small, 0]), rtol=1e-8, atol=1e-16)

    np.testing.assert_allclose(telemetry.quaternion_to_matrix(want), R, rtol=0, atol=1e-14)
    np.testing.assert_allclose(telemetry.quaternion_to_matrix(q), R, rtol=0, atol=1e-14)
    # batch axes in front
    q2 = telemetry.matrix_to_quaternion(R[:1000].reshape(10, 100, 3, 3))
    np.testing.assert_array_equal(q2, q[:1000].reshape(10, 100, 4))
    R2 = telemetry.quaternion_to_matrix(q2)
    np.testing.assert_array_equal(R2, telemetry.quaternion_to_matrix(q[:1000]).reshape(10, 100, 3, 3))


# --- flights ------------------------------------------------------------------------------


@functools.cache
def manoeuvre():
    """The mission's (one) controller, open loop, and its gains: one object, so both flights
    share one compiled program (the controller is a static argument)."""
    mission = missions.load(MISSION)
    (name,) = mission.controllers
    return mission.controller(name)


def fly(mission):
    """The history of the manoeuvre for every seed (batch axis first)."""
    controller, gains = manoeuvre()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sj.InertiaWarning)
        result = sj.simulate(mission.scenario(), controller, gains, SEEDS, loop=mission.loop(),
                             record_every=mission.record_every)
    return jax.tree.map(np.asarray, result.history)


def run(history, i):
    """Seed i's history."""
    return jax.tree.map(lambda x: x[i], history)


@pytest.fixture(scope="module")
def noisy():
    """The identification manoeuvre with the mission's gyro, star tracker and disturbance:
    (mission, history of every seed)."""
    mission = missions.load(MISSION, [f"T={T!r}"])
    return mission, fly(mission)


@pytest.fixture(scope="module")
def noisy_telemetry(noisy):
    mission, history = noisy
    return [telemetry.from_run(mission, run(history, i), int(s)) for i, s in enumerate(SEEDS)]


@pytest.fixture(scope="module")
def clean():
    """Noise-free telemetry (a dict) of the manoeuvre without disturbance: the true rate and
    attitude as perfect sensors read them, the wheels' speeds and geometry. The excitation
    is open loop, so the mission's sensors and filter (flown, one compiled program with the
    noisy flight) do not touch the true motion."""
    mission = missions.load(MISSION, [f"T={T!r}", "disturbance.amplitude=0.0", "disturbance.noise_std=0.0"])
    return perfect_telemetry(mission, run(fly(mission), 0))


def perfect_telemetry(mission, h):
    """The telemetry dict of one flight's true rate and attitude and its wheels."""
    np.testing.assert_array_equal(h.disturbance, 0.0)
    np.testing.assert_array_equal(mission.J0, J_TRUE)
    wheels = mission.actuator["wheels"]
    axes = np.asarray(wheels["axes"], float).T  # (3, n): the mission lists one axis per wheel
    assert np.ptp(h.actuator) > 10.0  # rad/s: the wheels took the manoeuvre's momentum
    spin = np.broadcast_to(np.asarray(wheels["spin_inertia"], float), (axes.shape[1],)).copy()
    return {"t": h.t, "gyro": h.Omega, "attitude": telemetry.matrix_to_quaternion(h.R), "wheel_speed": h.actuator,
            "wheel_axes": axes, "spin_inertia": spin}


def as_increments(data, period):
    """A rate-integrating gyro's noise-free telemetry from a sampled-rate gyro's (rows at
    consecutive ticks): row k's reading log(R_{k-1}^T R_k)^v / period (scipy), tick 0 left out."""
    R = Rotation.from_quat(np.asarray(data["attitude"])[:, [1, 2, 3, 0]])
    increments = (R[:-1].inv() * R[1:]).as_rotvec() / period
    rows = {k: np.asarray(v)[1:] for k, v in data.items() if k in ("t", "attitude", "wheel_speed")}
    return {**data, **rows, "gyro": increments, "gyro_output": np.asarray("increment")}


def relative_error(J):
    return np.linalg.norm(J - J_TRUE) / np.linalg.norm(J_TRUE)


# --- noise-free telemetry: both methods exact --------------------------------------------


@pytest.mark.parametrize("options", [BARE, DEFAULTS], ids=["bare", "defaults"])
def test_regression_is_exact_on_noise_free_telemetry(clean, options):
    tm = telemetry.check(clean)
    result = regression.identify(tm, **options)
    assert result["converged"]
    assert relative_error(result["J"]) < 1e-8, relative_error(result["J"])
    if options is DEFAULTS:
        np.testing.assert_allclose(result["bias"], 0.0, atol=1e-10)  # rad/s (the rates: ~1e-2)
        np.testing.assert_allclose(result["disturbance"], 0.0, atol=1e-7)  # N m (the torque: ~0.35)


@pytest.mark.parametrize("start", ["regression", pytest.param("3000 I", marks=pytest.mark.slow)])  # a far start
@pytest.mark.parametrize("options", [pytest.param(BARE, id="bare", marks=pytest.mark.slow),  # its own compile (~18 s)
                                     pytest.param(DEFAULTS, id="defaults")])
def test_simulation_is_exact_on_noise_free_telemetry(clean, options, start):
    initial = None if start == "regression" else 3000.0 * np.eye(3)
    result = simulation.identify(telemetry.check(clean), initial=initial, **options)
    assert result["converged"]
    assert relative_error(result["J"]) < 1e-8, relative_error(result["J"])


def test_regression_reads_a_rate_integrating_gyro_at_its_midpoints(clean):
    """A rate-integrating gyro's reading is the rate at its interval's midpoint to O(Delta^2):
    read there, the noise-free fit is within 1e-5 of the truth (measured: 2.1e-7); read as
    the rate at the tick, it is off by far more (measured: 5.7e-4)."""
    period = missions.load(MISSION).period
    data = as_increments(clean, period)
    error = relative_error(regression.identify(telemetry.check(data), **BARE)["J"])
    assert error < 1e-5, error
    as_rate = relative_error(regression.identify(telemetry.check({**data, "gyro_output": np.asarray("rate")}),
                                                 **BARE)["J"])
    assert as_rate > 1e-4, as_rate


def test_simulation_is_exact_on_noise_free_increments(clean):
    """The output error compares the reading with the model's own increment, log(R_k^T R_k+1)^v / Delta."""
    data = as_increments(clean, missions.load(MISSION).period)
    result = simulation.identify(telemetry.check(data))
    assert result["converged"]
    assert relative_error(result["J"]) < 1e-8, relative_error(result["J"])


def test_simulation_is_exact_on_noise_free_telemetry_without_momentum():
    """At rest before the manoeuvre, the body's and the wheels' momenta cancel: the rate is
    exactly piecewise linear in time and noise-free readings have no second differences."""
    mission = missions.load(MISSION, [f"T={T!r}", "disturbance.amplitude=0.0", "disturbance.noise_std=0.0",
                                      "initial.rate=[0.0, 0.0, 0.0]"])
    data = perfect_telemetry(mission, run(fly(mission), 0))
    result = simulation.identify(telemetry.check(data))
    assert relative_error(result["J"]) < 1e-8, relative_error(result["J"])


# --- noisy telemetry: calibrated intervals -----------------------------------------------


def standardized_errors(identify, telemetries):
    """(flights, 6): each fit's error in the inertia's entries over its 1-sigma (sqrt of
    theta_cov's diagonal)."""
    z = []
    for data in telemetries:
        result = identify(telemetry.check(data))
        assert result["converged"]
        z.append((inertia.entries(result["J"]) - inertia.entries(J_TRUE)) / np.sqrt(np.diag(result["theta_cov"])))
    return np.array(z)


def assert_calibrated(z):
    """The 3-sigma intervals cover the truth (>= 90 % of flights x entries), and the
    standardized errors' RMS is near 1 (within [0.4, 2.5]: neither over- nor under-confident)."""
    coverage, rms = np.mean(np.abs(z) <= 3.0), np.sqrt(np.mean(z**2))
    assert coverage >= 0.9, (coverage, rms)
    assert 0.4 <= rms <= 2.5, (coverage, rms)


def test_regression_intervals_cover_the_truth(noisy_telemetry):
    """12 flights x 6 entries (the mission's rate-integrating gyro). Measured on seeds 0-95
    at this horizon (8 disjoint sets of 12): 3-sigma coverage 0.986-1.00 (at most 1 miss of
    72; the bound allows 7), RMS 0.95-1.11."""
    assert_calibrated(standardized_errors(regression.identify, noisy_telemetry))


def test_the_constant_inertia_is_kept_on_every_flight(noisy_telemetry):
    """The test of docs/model.md §17.7 on the 12 flights of the manoeuvre (a constant J):
    kept in each at 0.1 % (statistics 0.9-17.9, the least p 0.0066). Over the same flights
    with J growing linearly by 30 % (inertia.kind = "linear"), it rejects every one
    (statistics 58-67, p <= 1.3e-10); tests/test_identify_refusals.py tests a growing body."""
    tests = [regression.constancy(telemetry.check(data)) for data in noisy_telemetry]
    assert all(t["tested"] and t["dof"] == 6 for t in tests)
    assert not any(t["rejected"] for t in tests), [t["p_value"] for t in tests]


@pytest.mark.slow  # a longer flight and the fit's compile for its length: ~1 min
def test_simulation_intervals_cover_the_truth():
    """12 flights x 6 entries at T = 300 s (29 windows of 10 s), the mission's rate-integrating
    gyro. Measured on seeds 0-23 (2 disjoint sets of 12): 3-sigma coverage 0.958-0.972, RMS
    1.17-1.36 (with the sampled-rate gyro, seeds 0-47: 0.986-1.00, 1.01-1.11). At T = 120 s
    (11 windows, fewer than the 15 global parameters) the windows' sandwich covariance is
    overconfident: RMS 1.4-1.8, coverage 0.89-0.96."""
    mission = missions.load(MISSION, ["T=300.0"])
    history = fly(mission)
    telemetries = [telemetry.from_run(mission, run(history, i), int(s)) for i, s in enumerate(SEEDS)]
    assert_calibrated(standardized_errors(simulation.identify, telemetries))


# --- the telemetry of a flight ------------------------------------------------------------


def test_flight_telemetry_is_what_the_estimator_read(noisy, noisy_telemetry):
    """The gyro readings regenerated by from_run are the filter's: Omega_hat + bias_hat; the
    mission's gyro integrates, so tick 0 (no increment yet) is left out and each reading
    covers one control period."""
    mission, history = noisy
    assert mission.sensors["gyro"]["output"] == "increment"
    for i in (0, len(SEEDS) - 1):
        h, data = jax.tree.map(lambda x: x[1:], run(history, i)), noisy_telemetry[i]
        assert data["gyro_output"] == "increment" and data["gyro_interval"] == mission.period
        np.testing.assert_array_equal(data["t"], h.t)
        np.testing.assert_allclose(data["gyro"], h.Omega_hat + h.bias_hat, rtol=0, atol=1e-15)
        assert np.all(data["attitude_valid"])  # this mission's star tracker samples every tick
        # the readings are noisy: neither the truth nor another seed's
        assert np.abs(data["gyro"] - h.Omega).max() > 1e-5
        assert np.abs(data["gyro"] - noisy_telemetry[1]["gyro"]).max() > 1e-5
        # the star tracker's attitude: within ~1e-4 rad of the truth, not equal to it
        tm = telemetry.check(data)
        err = np.linalg.norm(Rotation.from_matrix(np.einsum("nji,njk->nik", h.R, tm.R)).as_rotvec(), axis=1)
        assert 1e-7 < err.max() < 1e-3, err.max()
        np.testing.assert_array_equal(data["wheel_speed"], h.actuator)


def test_flight_telemetry_round_trips_through_files(noisy, noisy_telemetry, tmp_path):
    mission, _ = noisy
    data = noisy_telemetry[0]
    want = telemetry.check(data)
    np.savez(tmp_path / "savez.npz", **data)
    got = telemetry.load(tmp_path / "savez.npz")
    for name, a, b in zip(want._fields, want, got):
        np.testing.assert_array_equal(a, b, err_msg=name)
    # save (the module's writer) then load; the mission's wheels where the file has none
    telemetry.save(tmp_path / "save.npz", want.t, want.gyro, want.R, want.valid, data["wheel_speed"],
                   data["wheel_axes"], data["spin_inertia"])
    got = telemetry.load(tmp_path / "save.npz")
    np.testing.assert_array_equal(got.t, want.t)
    np.testing.assert_array_equal(got.gyro, want.gyro)
    np.testing.assert_array_equal(got.valid, want.valid)
    np.testing.assert_allclose(got.R, want.R, rtol=0, atol=1e-15)
    np.testing.assert_allclose(got.wheel_momentum, want.wheel_momentum, rtol=1e-15, atol=0)
    bare = {k: v for k, v in data.items() if k not in ("wheel_axes", "spin_inertia")}
    np.savez(tmp_path / "bare.npz", **bare)
    wheels = mission.actuator["wheels"]
    got = telemetry.load(tmp_path / "bare.npz", wheels=(np.asarray(wheels["axes"]).T, wheels["spin_inertia"]))
    np.testing.assert_allclose(got.wheel_momentum, want.wheel_momentum, rtol=1e-15, atol=0)


# --- bad telemetry: one-line errors -------------------------------------------------------

N_BAD = 10


def good_telemetry():
    t = 0.1 * np.arange(N_BAD)
    angle = 0.01 * t
    attitude = np.stack([np.cos(angle / 2), np.sin(angle / 2), 0.0 * t, 0.0 * t], -1)
    return {"t": t, "gyro": np.tile([0.01, 0.0, 0.0], (N_BAD, 1)), "attitude": attitude,
            "wheel_speed": np.ones((N_BAD, 4)), "wheel_axes": np.eye(3)[:, [0, 1, 2, 2]],
            "spin_inertia": np.full(4, 0.16)}


def without(name):
    return lambda d: {k: v for k, v in d.items() if k != name}


def changed(name, f):
    return lambda d: {**d, name: f(np.array(d[name]))}


def set_row(a, row, value):
    a[row] = value
    return a


BAD = {
    "missing gyro": (without("gyro"), r"missing gyro"),
    "NaN gyro": (changed("gyro", lambda a: set_row(a, 3, [0.0, np.nan, 0.0])), r"gyro has 1 non-finite sample.*row 3"),
    "t not increasing": (changed("t", lambda a: set_row(a, 5, a[4])), r"t must be strictly increasing; t\[5\]"),
    "gyro (N, 4)": (changed("gyro", lambda a: np.zeros((N_BAD, 4))), r"gyro must have shape \(N, 3\), got \(10, 4\)"),
    "attitude not unit": (changed("attitude", lambda a: set_row(a, 7, 1.01 * a[7])),
                          r"attitude must hold unit quaternions.*row 7"),
    "unknown field": (lambda d: {**d, "gyro_temperature": np.zeros(N_BAD)}, r"unknown field\(s\) gyro_temperature"),
    "wheels without geometry": (lambda d: without("spin_inertia")(without("wheel_axes")(d)),
                                r"wheel_speed needs the wheels' geometry"),
}


def test_good_telemetry_passes():
    tm = telemetry.check(good_telemetry())
    np.testing.assert_allclose(tm.wheel_momentum, np.tile([0.16, 0.16, 0.32], (N_BAD, 1)), rtol=1e-15)
    assert tm.valid.all() and tm.R.shape == (N_BAD, 3, 3)


@pytest.mark.parametrize("case", list(BAD))
def test_bad_telemetry_file_is_a_one_line_error(case, tmp_path):
    change, match = BAD[case]
    path = tmp_path / "telemetry.npz"
    np.savez(path, **change(good_telemetry()))
    with pytest.raises(ValueError, match=match) as err:
        telemetry.load(path)
    assert str(path) in one_line(err)
    if case not in ("missing gyro", "unknown field"):  # a file's fields; check() reads the known ones
        with pytest.raises(ValueError, match=match) as err:
            telemetry.check(change(good_telemetry()))
        one_line(err)


def test_missing_file_and_not_an_npz_are_one_line_errors(tmp_path):
    with pytest.raises(ValueError, match="no such file; expected a telemetry .npz file") as err:
        telemetry.load(tmp_path / "absent.npz")
    assert "absent.npz" in one_line(err)
    text = tmp_path / "notes.npz"
    text.write_text("t, gyro, attitude\n0.0, 0.01, 1.0\n0.1, 0.01, 1.0\n")
    with pytest.raises(ValueError, match="expected a telemetry .npz file") as err:
        telemetry.load(text)
    assert "notes.npz" in one_line(err)
