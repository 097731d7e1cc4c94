"""float64 sine and cosine written so XLA:CPU vectorizes them.

XLA:CPU computes a float64 ``sin`` or ``cos`` by a scalar call per element (~9 ns on the
2-core Intel Xeon of benchmarks/results/, against ~1 ns for a vectorized ``exp``). Here
they are elementwise arithmetic: the argument reduced by multiples of pi/2 (Cody and
Waite, pi/2 in three 33-bit parts, exact products for |n| < 2^20), then fdlibm's kernels
(``__kernel_sin``, ``__kernel_cos``: degree-13 and degree-14 polynomials on
[-pi/4, pi/4], error < 1 ulp) and the quadrant selected per element. Against NumPy's:
within 2 ulp of the larger of |value| and 2^-52 (tests/test_trig.py).

Used where a batch evaluates a sine per trajectory and step (a sweep's per-sample
reference and disturbance). Other dtypes, and arguments beyond 2^19 pi/2 (where the
reduction would lose bits), take ``jnp.sin`` / ``jnp.cos``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

_TWO_OVER_PI = 6.36619772367581382433e-01
# pi/2 = sum of these: three parts of 33 bits and the rest
_PIO2 = (1.57079632673412561417e00, 6.07710050630396597660e-11, 2.02226624871116645580e-21, 8.47842766036889956997e-32)
_LIMIT = 8.2e5  # < 2^19 pi/2: n < 2^19, every n * _PIO2[i] exact
_S = (-1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04,
      2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10)  # fmt: skip
_C = (4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05,
      -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11)  # fmt: skip


def _horner(coefficients, z):
    acc = coefficients[-1]
    for c in coefficients[-2::-1]:
        acc = c + z * acc
    return acc


def _kernels(r):
    """(sin r, cos r) for |r| <= pi/4 (fdlibm's kernels, no tail term)."""
    z = r * r
    s = r + (z * r) * _horner(_S, z)
    hz = 0.5 * z
    w = 1.0 - hz
    c = w + (((1.0 - w) - hz) + z * (z * _horner(_C, z)))
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


def sincos(x):
    """(sin x, cos x) elementwise [x in rad]; vectorizable arithmetic in float64."""
    x = jnp.asarray(x)
    if x.dtype != jnp.float64:
        return jnp.sin(x), jnp.cos(x)
    in_range = jnp.abs(x) < _LIMIT

    def mixed(x):  # out of range, or not finite: the library's
        s, c = _reduced(jnp.where(in_range, x, 0.0))
        return jnp.where(in_range, s, jnp.sin(x)), jnp.where(in_range, c, jnp.cos(x))

    return jax.lax.cond(jnp.all(in_range), _reduced, mixed, x)


def sin(x):
    """sin x elementwise [x in rad] (see :func:`sincos`)."""
    return sincos(x)[0]
