"""SO(3) math against scipy's Rotation, finite differences and closed forms."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from so3jax.core import so3

RNG = np.random.default_rng(0)


def last(x):
    """Batch-first numpy array (N, ...) -> so3's batch-last layout (..., N)."""
    return np.moveaxis(np.asarray(x), 0, -1)


def first(x):
    """so3's batch-last output (..., N) -> batch-first (N, ...)."""
    return np.moveaxis(np.asarray(x), -1, 0)


def random_rotvecs(n, max_angle=np.pi):
    axes = RNG.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return axes * RNG.uniform(0, max_angle, size=(n, 1))


ANGLES = [0.0, 1e-12, 1e-8, 1e-5, 1e-3, 0.03, 0.1, 1.0, 2.5, 3.0, np.pi - 0.1, np.pi - 1e-3, np.pi - 1e-6]


def rotvecs_at(angles):
    axes = RNG.normal(size=(len(angles), 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return axes * np.asarray(angles)[:, None]


def test_hat_vee_cross():
    a, b = RNG.normal(size=(2, 5, 3))
    np.testing.assert_allclose(first(so3.hat(last(a))) @ b[..., None], np.cross(a, b)[..., None], atol=1e-15)
    np.testing.assert_allclose(first(so3.cross(last(a), last(b))), np.cross(a, b), atol=1e-15)
    np.testing.assert_array_equal(so3.vee(so3.hat(last(a))), last(a))
    m = RNG.normal(size=(5, 3, 3))
    np.testing.assert_allclose(first(so3.matmul(last(m), last(m))), m @ m, atol=1e-14)
    np.testing.assert_allclose(first(so3.rmatmul(last(m), last(m))), np.swapaxes(m, -1, -2) @ m, atol=1e-14)
    np.testing.assert_allclose(first(so3.matvec(last(m), last(a))), (m @ a[..., None])[..., 0], atol=1e-14)
    np.testing.assert_allclose(first(so3.rmatvec(last(m), last(a))), (np.swapaxes(m, -1, -2) @ a[..., None])[..., 0],
                               atol=1e-14)
    # a single vector / matrix needs no batch axis, and a shared one broadcasts with batch_like
    np.testing.assert_allclose(so3.matvec(m[0], a[0]), m[0] @ a[0], atol=1e-14)
    np.testing.assert_allclose(first(so3.matvec(so3.batch_like(m[0], 2, last(a)), last(a))), a @ m[0].T, atol=1e-14)


def test_solve_spd_matches_numpy():
    a = RNG.normal(size=(6, 3, 3))
    spd = a @ np.swapaxes(a, -1, -2) + 0.5 * np.eye(3)
    b = RNG.normal(size=(6, 3))
    np.testing.assert_allclose(first(so3.solve_spd(last(spd), last(b))), np.linalg.solve(spd, b[..., None])[..., 0],
                               rtol=1e-11)


@pytest.mark.parametrize("max_angle", [1e-6, 0.04, np.pi])
def test_exp_matches_scipy(max_angle):
    v = np.concatenate([random_rotvecs(200, max_angle), rotvecs_at(ANGLES)])
    np.testing.assert_allclose(first(so3.exp(last(v))), Rotation.from_rotvec(v).as_matrix(), atol=1e-12, rtol=0)


@pytest.mark.parametrize("angle", [1e-10, 1e-6, 1e-4, 1e-2, 0.3])
def test_expm1_accurate_for_small_angles(angle):
    """exp(hat v) - I against its power series sum_{k>=1} hat(v)^k / k!, no cancellation."""
    v = rotvecs_at([angle])[0]
    h = np.asarray(so3.hat(v))
    term, series = np.eye(3), np.zeros((3, 3))
    for k in range(1, 25):
        term = term @ h / k
        series += term
    np.testing.assert_allclose(so3.expm1(v), series, rtol=0, atol=1e-15 * angle)


def test_log_matches_scipy():
    v = np.concatenate([random_rotvecs(300), rotvecs_at(ANGLES)])
    R = Rotation.from_rotvec(v).as_matrix()
    ours = np.array(first(so3.log(last(R))))
    theirs = Rotation.from_matrix(R).as_rotvec()
    # near a half turn log is defined up to sign: compare the rotations and the angles
    np.testing.assert_allclose(np.linalg.norm(ours, axis=1), np.linalg.norm(theirs, axis=1), atol=1e-12)
    np.testing.assert_allclose(Rotation.from_rotvec(ours).as_matrix(), R, atol=1e-12)
    away = np.linalg.norm(theirs, axis=1) < np.pi - 1e-3
    np.testing.assert_allclose(ours[away], theirs[away], atol=1e-12)


def test_log_and_angle_across_the_series_threshold():
    """Below 10 degrees theta / sin(theta) comes from its series (no arctangent): against
    scipy to round-off on both sides of the switch (so continuous across it), for a
    batch all below it (the series alone) and a mixed one."""
    theta_switch = np.arcsin(np.sqrt(so3._SERIES_SIN2))
    angles = np.concatenate([[0.0, 1e-9, 1e-3, 0.05, 0.1], theta_switch * (1 + np.array([-1e-9, -1e-15, 1e-15, 1e-9]))])
    v = rotvecs_at(angles)
    R = Rotation.from_rotvec(v).as_matrix()
    theirs = Rotation.from_matrix(R).as_rotvec()
    for batch in (slice(0, 6), slice(None)):  # all in the series' range; both ranges
        ours = first(so3.log(last(R[batch])))
        np.testing.assert_allclose(ours, theirs[batch], rtol=2e-15, atol=1e-300)
        np.testing.assert_allclose(so3.angle(last(R[batch])), np.linalg.norm(theirs[batch], axis=1), rtol=2e-15)


def test_log_exp_roundtrip_and_skew_vee():
    v = random_rotvecs(100, np.pi - 1e-3)
    np.testing.assert_allclose(first(so3.log(so3.exp(last(v)))), v, atol=1e-12)
    R = last(Rotation.from_rotvec(v).as_matrix())
    np.testing.assert_allclose(so3.skew_vee(R), so3.vee((R - np.swapaxes(R, 0, 1)) / 2), atol=1e-15)


def jr_fd(e, h=1e-6):
    """Right Jacobian J_r(e) by central differences: exp(e + d) ~ exp(e) exp(J_r(e) d)."""
    R = Rotation.from_rotvec(e)
    cols = []
    for i in range(3):
        d = np.zeros(3)
        d[i] = h
        plus = (R.inv() * Rotation.from_rotvec(e + d)).as_rotvec()
        minus = (R.inv() * Rotation.from_rotvec(e - d)).as_rotvec()
        cols.append((plus - minus) / (2 * h))
    return np.stack(cols, axis=1)


@pytest.mark.parametrize("angle", [0.0, 1e-4, 0.5, 2.0, 3.0])
def test_jr_inv_inverts_the_right_jacobian(angle):
    e = rotvecs_at([angle])[0]
    np.testing.assert_allclose(np.asarray(so3.jr_inv(e)) @ jr_fd(e), np.eye(3), atol=1e-8)
    w = RNG.normal(size=3)
    np.testing.assert_allclose(so3.jr_inv_apply(e, w), np.asarray(so3.jr_inv(e)) @ w, atol=1e-14)


def test_jr_inv_coefficient_continuous_across_branch():
    t2 = np.array([0.05 * (1 - 1e-12), 0.05 * (1 + 1e-12)])
    g = np.asarray(so3.jr_inv_coefficient(t2))
    assert abs(g[0] - g[1]) < 1e-15
    # closed form at pi: 1/pi^2 - cot(pi/2)/(2 pi) = 1/pi^2
    assert abs(float(so3.jr_inv_coefficient(np.pi**2)) - 1 / np.pi**2) < 1e-15


@functools.lru_cache(maxsize=None)
def _compiled(f):
    """f, jacfwd(f) and jacrev(f) in its first argument, jitted once: every point and
    every angle's case runs the same three compiled programs."""
    return jax.jit(f), jax.jit(jax.jacfwd(f)), jax.jit(jax.jacrev(f))


def _check_derivatives(f, x, *args, h=1e-6, rtol=1e-6, atol=1e-7):
    """jacfwd == jacrev, finite, and both match central differences (in x; args held)."""
    value, jacfwd, jacrev = _compiled(f)
    fwd = np.asarray(jacfwd(x, *args))
    rev = np.asarray(jacrev(x, *args))
    assert np.all(np.isfinite(fwd)) and np.all(np.isfinite(rev))
    np.testing.assert_allclose(fwd, rev, rtol=1e-10, atol=1e-12)
    x = np.asarray(x)
    fd = []
    for i in range(x.size):
        d = np.zeros_like(x)
        d.flat[i] = h
        fd.append((np.asarray(value(x + d, *args)) - np.asarray(value(x - d, *args))) / (2 * h))
    fd = np.moveaxis(np.stack(fd, -1), -1, -1).reshape(fwd.shape)
    np.testing.assert_allclose(fwd, fd, rtol=rtol, atol=atol)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-3, 1.0, np.pi - 1e-2])
def test_exp_gradients(angle):
    v = rotvecs_at([angle])[0]
    _check_derivatives(so3.exp, jnp.asarray(v))


def _jr_inv_apply(x, w):
    return so3.jr_inv_apply(x, w)


@pytest.mark.parametrize("angle", [0.0, 1e-3, 1.0, np.pi - 0.05])
def test_jr_inv_gradients(angle):
    e = rotvecs_at([angle])[0]
    w = RNG.normal(size=3)
    _check_derivatives(_jr_inv_apply, jnp.asarray(e), jnp.asarray(w))


def _log_local(x, R):
    """log(R exp(hat(x)))."""
    return so3.log(so3.matmul(R, so3.exp(x)))


_exp = jax.jit(so3.exp)
_jr_inv = jax.jit(so3.jr_inv)
_log_sq_grad = jax.jit(jax.grad(lambda m: jnp.sum(so3.log(m) ** 2)))


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-3, 0.1, 1.0, 3.0, np.pi - 1e-2])
def test_log_gradients(angle):
    """d log(exp(v) exp(hat(x))) / dx at x = 0 equals J_r^{-1}(v); FD on R's entries near it."""
    v = jnp.asarray(rotvecs_at([angle])[0])
    R = _exp(v)
    jac = np.asarray(_compiled(_log_local)[1](jnp.zeros(3), R))
    np.testing.assert_allclose(jac, _jr_inv(v), atol=1e-7)
    _check_derivatives(_log_local, jnp.zeros(3), R)
    # through the raw matrix entries, as an optimizer sees them
    grad = _log_sq_grad(R)
    assert np.all(np.isfinite(np.asarray(grad)))


def test_safe_norm_gradient_at_zero():
    g = jax.grad(so3.safe_norm)(jnp.zeros(3))
    np.testing.assert_array_equal(g, np.zeros(3))


def test_project_to_so3():
    for R in Rotation.from_rotvec(random_rotvecs(5)).as_matrix():
        noisy = R + 1e-4 * RNG.normal(size=R.shape)
        P = np.asarray(so3.project_to_so3(noisy))
        assert so3.orthogonality_error(P) < 1e-13
        np.testing.assert_allclose(np.linalg.det(P), 1.0, atol=1e-13)
        np.testing.assert_allclose(P, R, atol=1e-3)
    reflection = np.diag([1.0, 1.0, -1.0])
    assert np.linalg.det(so3.project_to_so3(reflection)) > 0


def test_sum_leading_is_a_sum_over_the_component_axes():
    x = jnp.asarray(np.random.default_rng(0).normal(size=(3, 3, 5)))
    np.testing.assert_allclose(so3.sum_leading(x, 2), jnp.sum(x, axis=(0, 1)), rtol=1e-14)
    np.testing.assert_allclose(so3.sum_leading(x), jnp.sum(x, axis=0), rtol=1e-14)


def test_matmul_compact_is_the_matrix_product():
    a, b = RNG.normal(size=(16, 3, 3)), RNG.normal(size=(16, 3, 3))
    np.testing.assert_allclose(first(so3.matmul_compact(last(a), last(b))), a @ b, rtol=1e-14, atol=1e-15)
    np.testing.assert_array_equal(so3.matmul_compact(last(a), last(b)), so3.matmul(last(a), last(b)))


def test_select_computes_the_branches_values_with_finite_gradients():
    """exp and log with ``select=True`` (every branch computed, selected elementwise): the
    values of the branching forms on a batch spanning the series, the closed form and a
    half turn, and finite gradients at zero rotation."""
    v = rotvecs_at(ANGLES)
    R = np.asarray(Rotation.from_rotvec(v).as_matrix())
    np.testing.assert_allclose(so3.exp(last(v), select=True), so3.exp(last(v)), rtol=0, atol=1e-15)
    np.testing.assert_allclose(so3.log(last(R), select=True), so3.log(last(R)), rtol=0, atol=1e-15)
    grads = jax.grad(lambda x: jnp.sum(so3.log(so3.exp(x, select=True), select=True) ** 2))(jnp.zeros(3))
    assert np.all(np.isfinite(np.asarray(grads)))
