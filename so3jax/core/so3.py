"""SO(3) and 3-vector math, written as elementwise arithmetic on components.

Convention: the component axes come FIRST and any batch axes last -- a vector is
(3, *batch), a matrix (3, 3, *batch) -- so that ``v[0]``, ``m[0, 1]`` are whole
batch-shaped arrays ("structure of arrays"). A single vector is simply (3,). Nothing
here calls a matmul or a solver: on CPU a 3x3 ``dot`` is a kernel call of its own,
whereas component arithmetic over batch-shaped arrays fuses into a few SIMD loops.
All operands of one call must have the same batch shape (or none).

Near the singular points (zero rotation for exp / log / J_r^{-1}, a half turn for
log) the functions switch to Taylor series or to another formula with the
"double where" trick, so that values *and* gradients stay finite.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from so3jax.core.inline import inline

# Below these squared angles the Taylor series used are exact to float64 round-off
# (first omitted term < 1e-17 relative).
_SMALL_ANGLE2 = 1e-3
# theta / sin(theta) = arcsin(x) / x (x = sin theta, theta < pi / 2) by its Maclaurin
# series, sum_n C(2n, n) / (4^n (2n + 1)) x^(2n): ten terms are exact to float64 round-off
# (remainder < 6e-18 relative) for x^2 < _SERIES_SIN2, i.e. theta < 10 degrees.
_SERIES_SIN2 = 0.03
_ASIN_RATIO_COEFFICIENTS = tuple(math.comb(2 * n, n) / (4**n * (2 * n + 1)) for n in range(10))
_JR_SERIES_ANGLE2 = 0.05
# log(R) takes the axis from the symmetric part of R when cos(theta) is below this.
_NEAR_PI_COS = -0.99


# --- vectors and matrices -----------------------------------------------------


@inline
def cross(a, b):
    """a x b for (3, ...) arrays."""
    return jnp.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


@inline
def dot(a, b):
    """a . b for (3, ...) arrays."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@inline
def matvec(m, v):
    """M v for M (3, 3, ...), v (3, ...)."""
    return m[:, 0] * v[0] + m[:, 1] * v[1] + m[:, 2] * v[2]


@inline
def rmatvec(m, v):
    """M^T v for M (3, 3, ...), v (3, ...)."""
    return m[0] * v[0] + m[1] * v[1] + m[2] * v[2]


@inline
def matmul(a, b):
    """A B for (3, 3, ...) arrays."""
    return jnp.stack([matvec(a, b[:, j]) for j in range(3)], axis=1)


@inline
def rmatmul(a, b):
    """A^T B for (3, 3, ...) arrays."""
    return jnp.stack([rmatvec(a, b[:, j]) for j in range(3)], axis=1)


@inline
def matmul_compact(a, b):
    """a b for (3, 3, ...) arrays as one broadcast product and one sum over the shared
    axis: the values of :func:`matmul` in a few operations where it writes 27 products out,
    so that a chain of products differentiates into a small program (the MEKF's covariance
    algebra: XLA:CPU compiles the flight loop's reverse pass ~1.5x sooner)."""
    return jnp.sum(a[:, :, None] * b[None], axis=1)


def sum_leading(x, n: int = 1):
    """Sum over the leading n (component) axes, written out as adds: on CPU a reduce
    over leading axes is a strided kernel of its own, a chain of adds fuses with its operands."""
    flat = x.reshape((-1,) + x.shape[n:])
    total = flat[0]
    for row in flat[1:]:
        total = total + row
    return total


@inline
def transpose(m):
    return jnp.swapaxes(m, 0, 1)


@inline
def eye_like(v):
    """Identity (3, 3, ...) with the batch shape and dtype of a (3, ...) array."""
    eye = jnp.eye(3, dtype=v.dtype).reshape((3, 3) + (1,) * (v.ndim - 1))
    return jnp.broadcast_to(eye, (3, 3) + v.shape[1:])


def broadcast(x, core_ndim, batch_shape):
    """x (core, [batch or unit axes]) -> (core, *batch_shape)."""
    x = jnp.asarray(x)
    x = x.reshape(x.shape + (1,) * (core_ndim + len(batch_shape) - x.ndim))
    return jnp.broadcast_to(x, x.shape[:core_ndim] + tuple(batch_shape))


def batch_like(x, core_ndim, like):
    """x (core shape, no batch) with trailing unit axes to broadcast against ``like``,
    a (3, *batch) array: for shared quantities (a nominal inertia, a common reference)."""
    x = jnp.asarray(x)
    return x.reshape(x.shape + (1,) * (like.ndim - 1 - (x.ndim - core_ndim)))


@inline
def outer(a, b):
    """a b^T for (3, ...) arrays."""
    return a[:, None] * b[None, :]


@inline
def adjugate(m):
    """The adjugate's entries (c00, c01, c02, c11, c12, c22) of a symmetric M (3, 3, ...), or
    of its rows as nested tuples, and 1 / det M."""
    at = (lambda i, j: m[i][j]) if isinstance(m, tuple) else (lambda i, j: m[i, j])
    a, d, e = at(0, 0), at(0, 1), at(0, 2)
    bb, f, c = at(1, 1), at(1, 2), at(2, 2)
    c00 = bb * c - f * f
    c01 = e * f - d * c
    c02 = d * f - e * bb
    c11 = a * c - e * e
    c12 = d * e - a * f
    c22 = a * bb - d * d
    return (c00, c01, c02, c11, c12, c22), 1.0 / (a * c00 + d * c01 + e * c02)


@inline
def solve_spd(m, b):
    """M^{-1} b for a symmetric positive definite M (3, 3, ...) by its adjugate."""
    (c00, c01, c02, c11, c12, c22), inv_det = adjugate(m)
    x, y, z = b[0], b[1], b[2]
    return jnp.stack([c00 * x + c01 * y + c02 * z, c01 * x + c11 * y + c12 * z, c02 * x + c12 * y + c22 * z]) * inv_det


@inline
def inv_spd(m):
    """M^{-1} (3, 3, ...) of a symmetric positive definite M by its adjugate."""
    (c00, c01, c02, c11, c12, c22), inv_det = adjugate(m)
    return jnp.stack([jnp.stack([c00, c01, c02]), jnp.stack([c01, c11, c12]), jnp.stack([c02, c12, c22])]) * inv_det


def safe_sqrt(x):
    """sqrt(x) for x >= 0 with a zero (not infinite) derivative at x = 0."""
    pos = x > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1.0)), 0.0)


@inline
def safe_norm(v):
    """|v| with a zero (not NaN) gradient at v = 0."""
    return safe_sqrt(dot(v, v))


# --- the Lie algebra ------------------------------------------------------------


@inline
def hat(v):
    """Skew matrix of v: hat(a) b = a x b. (3, ...) -> (3, 3, ...)."""
    x, y, z = v[0], v[1], v[2]
    o = jnp.zeros_like(x)
    return jnp.stack([jnp.stack([o, -z, y]), jnp.stack([z, o, -x]), jnp.stack([-y, x, o])])


@inline
def vee(m):
    """Inverse of hat on skew matrices. (3, 3, ...) -> (3, ...)."""
    return jnp.stack([m[2, 1], m[0, 2], m[1, 0]])


@inline
def skew_vee(m):
    """vee of the skew part, (M - M^T)^vee / 2 (docs/model.md §3.1: e_R for M = R_e)."""
    return 0.5 * jnp.stack([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]])


@inline
def trace(m):
    return m[0, 0] + m[1, 1] + m[2, 2]


# --- exp, log, right Jacobian ------------------------------------------------------


def small_angle_branch(small, series, general, x, select=False):
    """series(x) where ``small``, general(x) elsewhere (general must be finite, with finite
    gradients, everywhere). On CPU, when every element is small -- the common case inside
    an RK4 step, for one trajectory or a natively batched step -- only the series is
    computed (under vmap, and on GPUs, where a branch costs more than it saves, both are
    computed and selected elementwise). ``select``: both computed and selected on every
    device, for code that runs once per control tick: there the branch saves little, and
    without it the loop's reverse pass is a smaller program (no branch residuals)."""
    mixed = lambda x: jax.tree.map(lambda a, b: jnp.where(small, a, b), series(x), general(x))
    if select:
        return mixed(x)
    on_cpu = lambda x: jax.lax.cond(jnp.all(small), series, mixed, x)
    return jax.lax.platform_dependent(x, cpu=on_cpu, default=mixed)


def _exp_series(s):
    """(sin t / t, (1 - cos t) / t^2) for t^2 = s < _SMALL_ANGLE2, exact to round-off."""
    return 1.0 - s / 6.0 * (1.0 - s / 20.0 * (1.0 - s / 42.0)), 0.5 - s / 24.0 * (1.0 - s / 30.0 * (1.0 - s / 56.0))


def _exp_coefficients(theta2, sin=jnp.sin, select=False):
    """(sin t / t, (1 - cos t) / t^2) for t^2 = theta2, finite with gradients at 0."""
    small = theta2 < _SMALL_ANGLE2

    def trigonometric(theta2):
        half = 0.5 * jnp.sqrt(jnp.where(small, 1.0, theta2))  # keeps the unselected branch finite
        sinc_half = sin(half) / half
        return sin(2.0 * half) / (2.0 * half), 0.5 * sinc_half * sinc_half

    return small_angle_branch(small, _exp_series, trigonometric, theta2, select)


@inline(static_argnames=("sin", "select"))
def expm1(v, sin=jnp.sin, select=False):
    """exp(hat(v)) - I = a hat(v) + b (v v^T - theta^2 I), accurate for small |v| (docs/model.md (9.1)).
    sin: the sine used beyond the series (``so3jax.core._trig.sin``: vectorized in float64);
    select: see :func:`small_angle_branch`."""
    theta2 = dot(v, v)
    a, b = _exp_coefficients(theta2, sin, select)
    return a * hat(v) + b * (outer(v, v) - theta2 * eye_like(v))


@inline(static_argnames=("select",))
def exp(v, select=False):
    """Rotation matrix exp(hat(v)) of a rotation vector v [rad]. select: see :func:`small_angle_branch`."""
    return eye_like(v) + expm1(v, select=select)


def _asin_ratio_series(s2):
    """theta / sin(theta) for sin(theta)^2 = s2 < _SERIES_SIN2 and cos(theta) > 0 (Horner)."""
    ratio = _ASIN_RATIO_COEFFICIENTS[-1]
    for coefficient in _ASIN_RATIO_COEFFICIENTS[-2::-1]:
        ratio = coefficient + s2 * ratio
    return ratio


def _axis_terms(r):
    """s = (R - R^T)^vee / 2 = sin(theta) axis, c = (tr R - 1) / 2 = cos(theta), |s|^2, and
    where the series for theta / sin(theta) holds."""
    s = skew_vee(r)
    c = 0.5 * (trace(r) - 1.0)
    s2 = dot(s, s)
    return s, c, s2, (s2 < _SERIES_SIN2) & (c > 0)


def _arctan_angle(s, c, atan2=jnp.arctan2):
    """theta = atan2(|s|, c) in [0, pi], for s, c of _axis_terms."""
    return atan2(safe_norm(s), c)


@inline(static_argnames=("atan2",))
def angle(r, atan2=jnp.arctan2):
    """Rotation angle |log(R)^vee| in [0, pi] [rad]: atan2(|s|, c), or |s| times the
    series for theta / sin(theta) below 10 degrees (no arctangent when all are small).
    atan2: the arctangent (``so3jax.core._trig.atan2``: vectorized in float64)."""
    s, c, s2, small = _axis_terms(r)
    return small_angle_branch(small, lambda _: safe_norm(s) * _asin_ratio_series(s2),
                              lambda _: _arctan_angle(s, c, atan2), r)


@inline(static_argnames=("select",))
def log(r, select=False):
    """Rotation vector log(R)^vee, |log| = theta in [0, pi].

    theta = atan2(|s|, c) with s = (R - R^T)^vee / 2 = sin(theta) axis and
    c = (tr R - 1) / 2; below 10 degrees, the series for theta / sin(theta) instead
    (no arctangent); near a half turn the axis comes from the symmetric part
    R + R^T = 2c I + 2(1 - c) axis axis^T. select: see :func:`small_angle_branch`.
    """
    s, c, s2, small = _axis_terms(r)
    near_pi = c < _NEAR_PI_COS

    def series(r):
        return _asin_ratio_series(s2) * s

    def generic(r):  # theta / sin(theta) for c > _NEAR_PI_COS (selected where not small)
        return (_arctan_angle(s, c) / jnp.where(small | near_pi, 1.0, safe_norm(s))) * s

    def half_turn(r):
        sym = 0.5 * (r + transpose(r)) - c * eye_like(s)
        diag = jnp.stack([sym[0, 0], sym[1, 1], sym[2, 2]])
        pick = _first_max_indicator(diag).astype(r.dtype)
        column = matvec(sym, pick)
        scale2 = jnp.where(near_pi, (1.0 - c) * dot(diag, pick), 1.0)
        axis = column / jnp.sqrt(scale2)
        sign = jnp.where(dot(axis, s) < 0, -1.0, 1.0)
        return (sign * _arctan_angle(s, c)) * axis

    return small_angle_branch(small, series, lambda r: small_angle_branch(~near_pi, generic, half_turn, r, select), r,
                              select)


def _first_max_indicator(v):
    """One-hot (3, ...) of argmax over v's 3 components (first on ties), by comparisons:
    a variadic argmax reduce is a slow kernel of its own on CPU."""
    first = (v[0] >= v[1]) & (v[0] >= v[2])
    second = ~first & (v[1] >= v[2])
    return jnp.stack([first, second, ~(first | second)])


@inline
def jr_inv_coefficient(theta2):
    """gamma(theta) = 1/theta^2 - cot(theta/2) / (2 theta) of J_r^{-1} (docs/model.md §3.2).

    The closed form cancels for small theta; below theta^2 = 0.05 the Bernoulli series
    (truncation < 2e-16) is used instead.
    """
    small = theta2 < _JR_SERIES_ANGLE2

    def series(s):
        return 1.0 / 12.0 + s * (1.0 / 720.0 + s * (1.0 / 30240.0 + s * (1.0 / 1209600.0 + s / 47900160.0)))

    def closed_form(theta2):
        t2 = jnp.where(small, 1.0, theta2)
        half = 0.5 * jnp.sqrt(t2)
        return (1.0 - half * jnp.cos(half) / jnp.sin(half)) / t2

    return small_angle_branch(small, series, closed_form, theta2)


@inline
def jr_inv_apply(e, w):
    """J_r^{-1}(e) w = w + e x w / 2 + gamma(|e|) e x (e x w)  (docs/model.md §3.2)."""
    theta2 = dot(e, e)
    gamma = jr_inv_coefficient(theta2)
    return w + 0.5 * cross(e, w) + gamma * (e * dot(e, w) - theta2 * w)


@inline
def jr_inv(e):
    """J_r^{-1}(e) as a (3, 3, ...) matrix."""
    h = hat(e)
    gamma = jr_inv_coefficient(dot(e, e))
    return eye_like(e) + 0.5 * h + gamma * matmul(h, h)


def project_to_so3(m):
    """Nearest rotation matrix to a single M (3, 3) (Frobenius), by SVD. For inputs, not the hot path."""
    u, _, vt = jnp.linalg.svd(m)
    d = jnp.sign(jnp.linalg.det(u @ vt))
    return u @ jnp.diag(jnp.stack([jnp.ones_like(d), jnp.ones_like(d), d])) @ vt


@inline
def orthogonality_error(r):
    """|R^T R - I|_F."""
    g = rmatmul(r, r) - eye_like(r[0])
    return jnp.sqrt(jnp.sum(g * g, axis=(0, 1)))
