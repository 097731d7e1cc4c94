"""The attitude profiles of so3jax.dynamics.attitude_profiles: Omega_d, Omega_d' against finite
differences of R_d(t), the slews against quadrature of their acceleration profile and
their limits, the table's interpolation order, finite gradients, one-line refusals.

Cheap: every evaluation goes through one vmapped program per reference shape and dtype,
compiled with XLA's backend optimizations off and fed batches of a fixed length, so that
the tests share their compilations (the tables all have K_TABLE samples).
"""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import quad
from scipy.spatial.transform import Rotation

from so3jax.dynamics import attitude_profiles as refs
from tests._shared_programs import compiled

N_BATCH = 256  # evaluations run in batches of this many times: one program per reference shape
@compiled
def _evaluate(ref, ts):
    return jax.vmap(lambda t: (ref.attitude(t, 0), ref.rate(t, 0), ref.rate_dot(t, 0)))(ts)


def evaluate(ref, ts):
    """(R_d (N, 3, 3), Omega_d (N, 3), Omega_d' (N, 3)) at times ts (N,), as numpy."""
    ts = np.asarray(ts, np.float64)
    n = len(ts)
    padded = np.concatenate([ts, np.full(-n % N_BATCH, ts[0])])
    batches = [_evaluate(ref, jnp.asarray(batch)) for batch in padded.reshape(-1, N_BATCH)]
    return tuple(np.concatenate([np.asarray(b[i]) for b in batches])[:n] for i in range(3))


def vee(m):
    """(skew part)^vee of (N, 3, 3) matrices."""
    return 0.5 * np.stack([m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], axis=-1)


def rotvec(a, b):
    """log(a^T b)^vee of (N, 3, 3) rotations, by scipy."""
    return Rotation.from_matrix(np.einsum("nji,njk->nik", a, b)).as_rotvec()


# --- the references under test --------------------------------------------------------------

W, A = 0.05, 0.01  # max_rate [rad/s], max_acceleration [rad/s^2]: 2 W^2 / A = 0.5 rad
START = Rotation.from_rotvec([0.1, -0.2, 0.3])
# slew angles: short (no coast), zero (a hold), long (coast), near a half turn (log's half-turn branch)
SLEW_ANGLES = (0.3, 0.0, 1.2, math.pi - 0.05)
SLEW_AXES = ((1.0, 2.0, -0.5), (0.0, 0.0, 1.0), (-0.3, 0.4, 1.0), (0.7, -0.1, 0.2))
SLEW_TIMES = (2.0, 20.0, 25.0, 62.0)


def _attitudes():
    out, current = [], START
    for angle, axis in zip(SLEW_ANGLES, SLEW_AXES):
        current = current * Rotation.from_rotvec(angle * np.asarray(axis) / np.linalg.norm(axis))
        out.append(current.as_matrix())
    return np.stack(out)


def timing(angle):
    """(tau, coast, duration) of the minimum-time slew, from the closed form."""
    if angle <= 2 * W**2 / A:
        tau, coast = math.sqrt(2 * angle / A), 0.0
    else:
        tau, coast = 2 * W / A, angle / W - 2 * W / A
    return tau, coast, 2 * tau + coast


@functools.cache
def slews():
    return refs.eigenaxis_slews(START.as_matrix(), _attitudes(), SLEW_TIMES, W, A)


def slew_sample_times():
    """Times before the first slew, inside each pulse, each coast and each hold, and at every boundary."""
    ts = [0.0, 1.0]
    for t0, angle in zip(SLEW_TIMES, SLEW_ANGLES):
        tau, coast, duration = timing(angle)
        ts += [t0 + f * tau for f in (0.0, 0.1, 0.37, 0.5, 0.81, 1.0)]
        ts += [t0 + tau + f * coast for f in (0.3, 0.6)] if coast else []
        ts += [t0 + duration - f * tau for f in (0.9, 0.5, 0.23, 0.0)] + [t0 + duration + 1.5]
    return np.array(ts + [150.0])


BETA, OMEGA, SIGMA = 0.4, 0.3, 0.5  # coning: R(t) = Rz(OMEGA t) Rx(BETA) Rz(SIGMA t)


def coning(ts):
    """R(t) (N, 3, 3) and its body rate Omega = Rz(-SIGMA t) Rx(-BETA) OMEGA e_z + SIGMA e_z (N, 3)."""
    ts = np.asarray(ts, np.float64)
    z = np.outer(ts, [0.0, 0.0, 1.0])
    tilt = Rotation.from_rotvec([BETA, 0.0, 0.0])
    R = (Rotation.from_rotvec(OMEGA * z) * tilt * Rotation.from_rotvec(SIGMA * z)).as_matrix()
    rate = (Rotation.from_rotvec(-SIGMA * z) * tilt.inv()).apply([0.0, 0.0, OMEGA]) + [0.0, 0.0, SIGMA]
    return R, rate


CONING_T = 5.0
K_TABLE = 21  # every table has this many samples: one compiled program serves them all


def knots(span=CONING_T):
    return np.linspace(0.0, span, K_TABLE)


@functools.cache
def coning_table(span=CONING_T, exact_rates=False):
    """The coning motion sampled at K_TABLE knots over [0, span] [s], with its exact rates or estimated ones."""
    ts = knots(span)
    R, rate = coning(ts)
    return refs.tabulated(ts, R, rate if exact_rates else None)


def between_knots(span=CONING_T, end=CONING_T):
    """Times inside every interval of coning_table(span) that ends by ``end`` (away from the knots)."""
    ts = knots(span)
    ts = ts[ts <= end]
    return np.concatenate([ts[:-1] + f * (ts[1] - ts[0]) for f in (0.13, 0.5, 0.77)])


# kind: (reference, sample times [s], finite-difference step [s], atol Omega [rad/s], atol Omega' [rad/s^2])
CASES = {
    "slews": (slews, slew_sample_times, 1e-4, 1e-10, 1e-9),
    "tabulated": (coning_table, lambda: np.concatenate([[-1.0, 6.0], between_knots()]), 1e-5, 1e-9, 1e-8),
}


@pytest.mark.parametrize("kind", CASES)
def test_rates_are_the_derivatives_of_the_attitude(kind):
    """Omega_d = vee(R^T (R(t+h) - R(t-h)) / 2h), Omega_d' = (Omega(t+h) - Omega(t-h)) / 2h."""
    make, times, h, atol_rate, atol_dot = CASES[kind]
    ref, ts = make(), times()
    R, rate, rate_dot = evaluate(ref, np.concatenate([ts, ts - h, ts + h]))
    n = len(ts)
    fd_rate = vee(np.einsum("nji,njk->nik", R[:n], R[2 * n:] - R[n:2 * n])) / (2 * h)
    fd_dot = (rate[2 * n:] - rate[n:2 * n]) / (2 * h)
    np.testing.assert_allclose(rate[:n], fd_rate, rtol=0, atol=atol_rate)
    np.testing.assert_allclose(rate_dot[:n], fd_dot, rtol=0, atol=atol_dot)
    np.testing.assert_allclose(np.einsum("nji,njk->nik", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-14)
    if kind != "fixed":
        assert np.abs(rate).max() > 100 * atol_rate  # the comparison sees motion


def _acceleration(sigma, angle):
    """The slew's angular acceleration [rad/s^2] at sigma [s] after its start, piece by piece."""
    tau, coast, duration = timing(angle)
    if sigma < tau:
        return A * math.sin(math.pi * sigma / tau) ** 2
    if sigma < tau + coast:
        return 0.0
    if sigma < duration:
        return -A * math.sin(math.pi * (duration - sigma) / tau) ** 2
    return 0.0


def test_slews_follow_the_quadrature_of_their_acceleration_about_the_eigenaxis():
    """theta' = int a, theta = int (s - sigma) a(sigma) dsigma; R_d = R_{k-1} exp(axis theta) (scipy)."""
    ts = slew_sample_times()
    R, rate, rate_dot = evaluate(slews(), ts)
    before = np.concatenate([[START.as_matrix()], _attitudes()])
    k = np.searchsorted(SLEW_TIMES, ts, side="right")  # slew k - 1 is the last started
    for i, t in enumerate(ts):
        if k[i] == 0:
            np.testing.assert_allclose(R[i], before[0], atol=1e-15)
            assert not rate[i].any() and not rate_dot[i].any()
            continue
        slew = k[i] - 1
        angle, s = SLEW_ANGLES[slew], t - SLEW_TIMES[slew]
        tau, coast, duration = timing(angle)
        points = [p for p in (tau, tau + coast, duration) if 0.0 < p < s]
        speed = quad(_acceleration, 0.0, s, args=(angle,), points=points or None, epsabs=1e-14)[0] if s > 0 else 0.0
        theta = quad(lambda x: (s - x) * _acceleration(x, angle), 0.0, s, points=points or None,
                     epsabs=1e-14)[0] if s > 0 else 0.0
        target = rotvec(before[slew][None], before[slew + 1][None])[0]
        axis = target / max(np.linalg.norm(target), 1e-300)
        if angle == 0.0:
            np.testing.assert_allclose(R[i], before[slew], atol=1e-15)
        else:
            np.testing.assert_allclose(rotvec(before[slew][None], R[i][None])[0], theta * axis, atol=1e-10)
        np.testing.assert_allclose(rate[i], speed * axis, atol=1e-11)
        np.testing.assert_allclose(rate_dot[i], _acceleration(s, angle) * axis, atol=1e-12)
        if s >= duration:  # held at the target itself
            np.testing.assert_allclose(R[i], before[slew + 1], atol=1e-15)


def test_slews_keep_within_the_limits_and_reach_them():
    """|Omega_d| <= max_rate, |Omega_d'| <= max_acceleration on a fine grid, with equality at
    each pulse's middle (acceleration) and in each coast (rate); at rest at each end."""
    ref = slews()
    grid = np.concatenate([np.linspace(0.0, 140.0, 700), slew_sample_times()])
    _, rate, rate_dot = evaluate(ref, grid)
    speed, acceleration = np.linalg.norm(rate, axis=1), np.linalg.norm(rate_dot, axis=1)
    assert speed.max() <= W * (1 + 1e-12) and acceleration.max() <= A * (1 + 1e-12)
    for t0, angle in zip(SLEW_TIMES, SLEW_ANGLES):
        tau, coast, duration = timing(angle)
        _, rate, rate_dot = evaluate(ref, [t0, t0 + tau / 2, t0 + tau + coast / 2, t0 + duration - tau / 2,
                                           t0 + duration])
        speed, acceleration = np.linalg.norm(rate, axis=1), np.linalg.norm(rate_dot, axis=1)
        assert speed[[0, -1]].max() == 0.0 and acceleration[[0, -1]].max() == 0.0
        if angle > 0:
            np.testing.assert_allclose(acceleration[[1, 3]], A, rtol=1e-12)
            np.testing.assert_allclose(speed[2], min(W, math.sqrt(A * angle / 2)), rtol=1e-12)


def test_slew_durations_are_the_closed_form_minimum():
    """2 sqrt(2 theta / A) without coast, theta / W + 2 W / A with one: the shortest raised-sine
    profile whose peak acceleration is A and whose rate stays within W."""
    ref = slews()
    expected = [timing(angle)[2] for angle in SLEW_ANGLES]
    np.testing.assert_allclose(ref.durations, expected, rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(refs.slew_duration(np.array(SLEW_ANGLES), W, A), expected, rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(ref.angles, SLEW_ANGLES, atol=1e-12)
    assert ref.durations[0] == pytest.approx(2 * math.sqrt(0.6 / A)) and ref.coasts[0] == 0.0
    assert ref.durations[2] == pytest.approx(1.2 / W + 2 * W / A) and ref.pulses[2] == pytest.approx(2 * W / A)
    # continuous where the coast begins (theta = 2 W^2 / A); a shorter slew would break a limit
    edge = 2 * W**2 / A
    np.testing.assert_allclose(refs.slew_duration(np.array([edge, edge * (1 + 1e-9)]), W, A), 4 * W / A, rtol=1e-8)


@compiled
def _time_gradients(cases):
    """d/dt sum(weights * R_d(t)) by reverse mode, for each (references, times) with a leading batch axis."""
    weights = jnp.arange(9.0).reshape(3, 3)
    gradient = jax.grad(lambda t, ref: jnp.sum(weights * ref.attitude(t, 0)))
    return [jax.vmap(gradient)(ts, ref) for ref, ts in cases]


def test_zero_rotations_have_finite_gradients():
    """At a zero-angle slew (its start, inside, after), a slew's start (at rest), a table of equal samples,
    LVLH at t = 0 and with n = 0: d R_d / dt finite by reverse mode (zero where nothing moves), and by
    forward mode (Omega_d, Omega_d' of the table)."""
    still = refs.tabulated(knots(), np.stack([np.eye(3)] * K_TABLE))  # log and exp at zero rotations
    zero_slew = SLEW_TIMES[1]
    cases = [  # (reference, times, whether R_d moves there)
        (slews(), [zero_slew, zero_slew + 1.0, SLEW_TIMES[2] - 1.0, SLEW_TIMES[0], 0.0, 3.0], [0, 0, 0, 0, 0, 1]),
        (still, [0.0, 1.0, 1.3, 9.0], [0, 0, 0, 0]),
    ]
    batched = []
    for ref, ts, _ in cases:
        ref = ref if isinstance(ref, list) else [ref] * len(ts)
        batched.append((jax.tree.map(lambda *x: jnp.stack(x), *ref), jnp.asarray(ts)))
    for (ref, _, moves), grad in zip(cases, _time_gradients(batched)):
        grad = np.asarray(grad)
        assert np.isfinite(grad).all(), grad
        np.testing.assert_array_equal(grad != 0.0, np.array(moves, bool), err_msg=str(grad))
    for ref in (slews(), still):
        assert all(np.isfinite(x).all() for x in evaluate(ref, [0.0, zero_slew, zero_slew + 1.0, 1.0]))


def test_table_passes_through_its_samples_and_holds_outside():
    """R_d(t_k) = R_k; Omega_d -> w_k from either side (C1); the end attitudes held outside, at rest."""
    ref = coning_table(exact_rates=True)
    ts = knots()
    R_true, rate_true = coning(ts)
    R, rate, rate_dot = evaluate(ref, np.concatenate([ts, [-2.0, -1e-3, CONING_T + 1e-3, 10.0], ts[1:] - 1e-9]))
    K = K_TABLE
    np.testing.assert_allclose(R[:K], R_true, atol=1e-14)  # at every knot, the last one included
    np.testing.assert_allclose(rate[:K], rate_true, atol=1e-13)  # the given rates, by differentiation
    np.testing.assert_allclose(rate[K + 4:], rate_true[1:], atol=1e-8)  # the same from the left
    np.testing.assert_allclose(R[K:K + 2], np.stack([R_true[0]] * 2), atol=1e-15)
    np.testing.assert_allclose(R[K + 2:K + 4], np.stack([R_true[-1]] * 2), atol=1e-14)
    assert not rate[K:K + 4].any() and not rate_dot[K:K + 4].any()


def _table_error(span, exact_rates):
    """Largest angle [rad] between the table over [0, span] and the coning motion, between knots up to CONING_T."""
    ts = between_knots(span)
    R, _, _ = evaluate(coning_table(span, exact_rates), ts)
    return np.linalg.norm(rotvec(coning(ts)[0], R), axis=1).max()


def test_table_converges_with_the_sample_spacing():
    """Over [0, 5 s], samples every h = 0.5 s and 0.25 s: with estimated rates (second-order differences)
    the error falls like h^3, with the exact rates like h^4, and is smaller."""
    spans = (2 * CONING_T, CONING_T)  # K_TABLE samples each: h = 0.5 s, 0.25 s
    estimated = [_table_error(span, False) for span in spans]
    exact = [_table_error(span, True) for span in spans]
    h = 2 * CONING_T / (K_TABLE - 1)
    assert estimated[0] < 1e-3 * h**3 and estimated[1] < estimated[0] / 6.5, estimated
    assert exact[0] < 1e-4 * h**4 and exact[1] < exact[0] / 13.0, exact
    assert exact[0] < estimated[0] / 3 and exact[1] < estimated[1] / 5, (estimated, exact)


def _quaternions(K):
    times = np.linspace(0.0, 9.0, K)
    rotations = Rotation.from_rotvec(np.outer(times, [0.1, -0.2, 0.05]) + [0.3, 0.0, 0.0])
    xyzw = rotations.as_quat()
    return times, np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1), rotations.as_matrix()


def test_read_attitude_table(tmp_path):
    """CSV (header t, qw, qx, qy, qz; columns in any order) and .npz (t, q [w, x, y, z]): the times and
    scipy's matrices; a quaternion 1e-7 off unit is normalized, one 1e-3 off is refused by its row."""
    times, q, matrices = _quaternions(6)
    q[2] *= 1 + 1e-7
    csv = tmp_path / "table.csv"
    rows = [",".join(f"{x:.17g}" for x in (q[i, 1], t, q[i, 0], q[i, 2], q[i, 3])) for i, t in enumerate(times)]
    csv.write_text("qx, t, qw, qy, qz\n" + "\n".join(rows) + "\n")
    npz = tmp_path / "table.npz"
    np.savez(npz, t=times, q=q)
    for path in (csv, npz):
        t, R = refs.read_attitude_table(path)
        np.testing.assert_array_equal(t, times)
        np.testing.assert_allclose(R, matrices, atol=1e-15)
    q[3] *= 1 + 1e-3
    np.savez(npz, t=times, q=q)
    rows = [",".join(f"{x:.17g}" for x in (t, *q[i])) for i, t in enumerate(times)]
    csv.write_text("t,qw,qx,qy,qz\n" + "\n".join(rows))
    for path, row in ((csv, "line 5"), (npz, "q[3]")):
        with pytest.raises(ValueError, match=r"\(t = 5\.4 s\): quaternion norm 1\.001") as error:
            refs.read_attitude_table(path)
        assert row in str(error.value) and "\n" not in str(error.value)
    csv.write_text("t,qw,qx,qy\n0,1,0,0\n")
    with pytest.raises(ValueError, match="no column 'qz'"):
        refs.read_attitude_table(csv)


@compiled
def _evaluate_all(references, ts):
    return [jax.vmap(lambda t, ref=ref: (ref.attitude(t, 0), ref.rate(t, 0), ref.rate_dot(t, 0)))(ts)
            for ref in references]


def test_single_precision_inputs_give_single_precision_references():
    """float32 inputs: float32 arrays and outputs (t given in float64 is cast), near the float64 values."""
    f32 = np.float32
    R, _ = coning(knots())
    made = [
        refs.eigenaxis_slews(START.as_matrix().astype(f32), _attitudes().astype(f32), np.array(SLEW_TIMES, f32),
                             f32(W), f32(A)),
        refs.tabulated(knots().astype(f32), R.astype(f32)),
    ]
    doubles = [slews(), coning_table()]
    ts = np.array([0.7, 3.1, 4.9, 30.0, 80.0])
    for single, out, double in zip(made, _evaluate_all(made, jnp.asarray(ts)), doubles):
        assert {x.dtype for x in jax.tree.leaves(single)} == {jnp.dtype("float32")}
        assert {x.dtype for x in out} == {jnp.dtype("float32")}
        for x, y in zip(out, evaluate(double, ts)):
            np.testing.assert_allclose(x, y, atol=2e-5)


def _overlap():
    attitudes = _attitudes()[:3]
    refs.eigenaxis_slews(START.as_matrix(), attitudes, [2.0, 17.0, 25.0], W, A)  # slew 0 lasts 15.49 s


BAD_INPUTS = {
    "overlapping slews": (_overlap, r"slew 0 ends at 17\.49\d* s .*after slew 1 starts at 17 s"),
    "unsorted slew times": (lambda: refs.eigenaxis_slews(np.eye(3), _attitudes()[:2], [30.0, 2.0], W, A),
                            r"ascending: times\[1\] = 2 s < times\[0\] = 30 s"),
    "negative slew time": (lambda: refs.eigenaxis_slews(np.eye(3), _attitudes()[:1], [-1.0], W, A),
                           r"times\[0\] >= 0"),
    "zero max_rate": (lambda: refs.eigenaxis_slews(np.eye(3), _attitudes()[:1], [1.0], 0.0, A), "max_rate"),
    "slew target not a rotation": (lambda: refs.eigenaxis_slews(np.eye(3), 1.01 * _attitudes()[:2], [1.0, 40.0], W, A),
                                   r"attitudes\[0\] is not a rotation"),
    "slew times shape": (lambda: refs.eigenaxis_slews(np.eye(3), _attitudes()[:2], [1.0], W, A), r"shape \(2,\)"),
    "unsorted table": (lambda: refs.tabulated([0.0, 2.0, 1.0], np.stack([np.eye(3)] * 3)),
                       r"strictly increasing: times\[2\] = 1 s <= times\[1\] = 2 s"),
    "repeated table time": (lambda: refs.tabulated([0.0, 1.0, 1.0], np.stack([np.eye(3)] * 3)), "strictly increasing"),
    "reflection in the table": (lambda: refs.tabulated([0.0, 1.0], np.stack([np.eye(3), np.diag([1.0, 1.0, -1.0])])),
                                r"rotations\[1\] is not a rotation: .*det R = -1"),
    "table rotations shape": (lambda: refs.tabulated([0.0, 1.0, 2.0], np.stack([np.eye(3)] * 2)), r"shape \(3, 3, 3\)"),
    "table rates shape": (lambda: refs.tabulated([0.0, 1.0], np.stack([np.eye(3)] * 2), np.zeros((2, 2))),
                          r"rates must have shape \(2, 3\)"),
    "one sample": (lambda: refs.tabulated([0.0], np.eye(3)[None]), "at least 2 samples"),
}


@pytest.mark.parametrize("case", BAD_INPUTS)
def test_bad_inputs_are_refused_in_one_line(case):
    build, message = BAD_INPUTS[case]
    with pytest.raises(ValueError, match=message) as error:
        build()
    assert "\n" not in str(error.value)
