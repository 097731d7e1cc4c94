"""float64 sine, cosine and arctangent written so XLA:CPU vectorizes them.

XLA:CPU computes a float64 ``sin``, ``cos`` or ``atan2`` by a scalar call per element
(~8-11 ns on the 2-core Intel Xeon of benchmarks/results/, against ~1 ns for a vectorized
``exp``). Here they are elementwise arithmetic, after fdlibm:

* sin, cos: the argument reduced by multiples of pi/2 (Cody and Waite: pi/2 in three
  33-bit parts and a tail, exact products for |n| < 2^19), ``__kernel_sin`` and
  ``__kernel_cos`` (polynomials of degree 13 and 14 on [-pi/4, pi/4]), the quadrant
  selected per element;
* atan2(y, x) for y >= 0: ``s_atan``'s five argument ranges (atan of 0, 1/2, 1, 3/2, inf
  plus a degree-22 odd polynomial), the half plane x < 0 by pi - atan.

Against NumPy's: within 2 ulp of the larger of |value| and 2^-52 (tests/test_trig.py).
Used where a batch evaluates these per trajectory and step (a sweep's per-sample
reference, disturbance and attitude error). Other dtypes, and sine arguments beyond
2^19 pi/2 (where the reduction would lose bits), take the library's functions.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from so3jax.core._erfinv import horner  # coefficients highest degree first
from so3jax.core.inline import inline
from so3jax.core.so3 import small_angle_branch

_TWO_OVER_PI = 6.36619772367581382433e-01
# pi/2 = sum of these: three parts of 33 bits and the rest
_PIO2 = (1.57079632673412561417e00, 6.07710050630396597660e-11, 2.02226624871116645580e-21, 8.47842766036889956997e-32)
_LIMIT = 8.2e5  # < 2^19 pi/2: n < 2^19, every n * _PIO2[i] exact
# the kernels' polynomials in z = r^2, highest degree first
_S = (1.58969099521155010221e-10, -2.50507602534068634195e-08, 2.75573137070700676789e-06,
      -1.98412698298579493134e-04, 8.33333333332248946124e-03, -1.66666666666666324348e-01)  # fmt: skip
_C = (-1.13596475577881948265e-11, 2.08757232129817482790e-09, -2.75573143513906633035e-07,
      2.48015872894767294178e-05, -1.38888888888741095749e-03, 4.16666666666666019037e-02)  # fmt: skip


def _kernels(r):
    """(sin r, cos r) for |r| <= pi/4 (fdlibm's kernels, no tail term)."""
    z = r * r
    s = r + (z * r) * horner(_S, z)
    hz = 0.5 * z
    w = 1.0 - hz
    c = w + (((1.0 - w) - hz) + z * (z * horner(_C, z)))
    return s, c


def _reduced(x):
    """(sin x, cos x) by reduction to [-pi/4, pi/4], for |x| < _LIMIT."""
    n = jnp.round(x * _TWO_OVER_PI)
    r = (((x - n * _PIO2[0]) - n * _PIO2[1]) - n * _PIO2[2]) - n * _PIO2[3]
    s, c = _kernels(r)
    q = n.astype(jnp.int64) & 3
    sin = jnp.where(q == 0, s, jnp.where(q == 1, c, jnp.where(q == 2, -s, -c)))
    cos = jnp.where(q == 0, c, jnp.where(q == 1, -s, jnp.where(q == 2, -c, s)))
    return sin, cos


@inline
def sincos(x):
    """(sin x, cos x) elementwise [x in rad]; vectorizable arithmetic in float64."""
    x = jnp.asarray(x)
    if x.dtype != jnp.float64:
        return jnp.sin(x), jnp.cos(x)
    in_range = jnp.abs(x) < _LIMIT  # else (or not finite): the library's
    reduced = lambda x: _reduced(jnp.where(in_range, x, 0.0))
    return small_angle_branch(in_range, reduced, lambda x: (jnp.sin(x), jnp.cos(x)), x)


_QUARTER = 0.78  # < pi/4: |x| * 2/pi rounds to n = 0, where the reduction leaves x as it is


@inline
def sincos_near_zero(x):
    """:func:`sincos` for angles that stay within about +-pi/4 (a hinge's deflection): on CPU,
    when every element is within _QUARTER, the kernels alone (no reduction: the same values)."""
    x = jnp.asarray(x)
    if x.dtype != jnp.float64:
        return jnp.sin(x), jnp.cos(x)
    within = lambda x: jax.lax.cond(jnp.all(jnp.abs(x) < _QUARTER), _kernels, sincos, x)
    return jax.lax.platform_dependent(x, cpu=within, default=sincos)


def sin(x):
    """sin x elementwise [x in rad] (see :func:`sincos`)."""
    return sincos(x)[0]


_ATAN_HI = (4.63647609000806093515e-01, 7.85398163397448278999e-01, 9.82793723247329054082e-01,
            1.57079632679489655800e00)
_ATAN_LO = (2.26987774529616870924e-17, 3.06161699786838301793e-17, 1.39033110312309984516e-17,
            6.12323399573676603587e-17)
# atan's odd and even parts in w = x^4, highest degree first
_AT_ODD = (1.62858201153657823623e-02, 4.97687799461593236017e-02, 6.66107313738753120669e-02,
           9.09088713343650656196e-02, 1.42857142725034663711e-01, 3.33333333333329318027e-01)  # fmt: skip
_AT_EVEN = (-3.65315727442169155270e-02, -5.83357013379057348645e-02, -7.69187620504482999495e-02,
            -1.11111104054623557880e-01, -1.99999999998764832476e-01)  # fmt: skip
_PI_LO = 1.2246467991473531772e-16  # pi - fl(pi)


def _atan_nonnegative(a):
    """atan(a) for a >= 0 (a = inf included) [rad]."""
    ranges = (a >= 7.0 / 16.0, a >= 11.0 / 16.0, a >= 19.0 / 16.0, a >= 39.0 / 16.0)
    safe = jnp.where(ranges[3], a, 1.0)  # keeps the unselected -1/a finite at a = 0
    x = jnp.where(ranges[3], -1.0 / safe,
                  jnp.where(ranges[2], (a - 1.5) / (1.0 + 1.5 * a),
                            jnp.where(ranges[1], (a - 1.0) / (a + 1.0),
                                      jnp.where(ranges[0], (2.0 * a - 1.0) / (2.0 + a), a))))  # fmt: skip
    z = x * x
    w = z * z
    tail = x * (z * horner(_AT_ODD, w) + w * horner(_AT_EVEN, w))
    hi = jnp.where(ranges[3], _ATAN_HI[3],
                   jnp.where(ranges[2], _ATAN_HI[2], jnp.where(ranges[1], _ATAN_HI[1], _ATAN_HI[0])))
    lo = jnp.where(ranges[3], _ATAN_LO[3],
                   jnp.where(ranges[2], _ATAN_LO[2], jnp.where(ranges[1], _ATAN_LO[1], _ATAN_LO[0])))
    return jnp.where(ranges[0], hi - ((tail - lo) - x), x - tail)


@inline
def atan2(y, x):
    """atan2(y, x) in [0, pi] for y >= 0 [rad], elementwise; vectorizable arithmetic in float64."""
    y, x = jnp.asarray(y), jnp.asarray(x)
    if jnp.result_type(y, x) != jnp.float64:
        return jnp.arctan2(y, x)
    ax = jnp.abs(x)
    zero = ax == 0.0
    a = _atan_nonnegative(jnp.where(zero, jnp.inf, y / jnp.where(zero, 1.0, ax)))
    angle = jnp.where(x < 0.0, jnp.pi - (a - _PI_LO), a)
    return jnp.where(y == 0.0, jnp.where(x < 0.0, jnp.pi, 0.0), angle)
