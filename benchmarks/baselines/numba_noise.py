"""The paper scenario's disturbance noise drawn inside Numba code, bit for bit as JAX draws it.

    eta_k = jax.random.normal(jax.random.fold_in(jax.random.key(seed), k), (3,), float64)

(docs/model.md §4; :mod:`benchmarks.baselines.noise` draws it with JAX before a run) written out
in Numba functions, so a compiled loop can draw eta_k itself, as so3jax does inside its
timed loop: :func:`paper_eta` for one step, :func:`fill_eta` for a run of steps (what
numba_loop uses; vectorized where the arithmetic allows). The recipe, read off JAX 0.10
(``jax._src.random``) with ``jax_threefry_partitionable=True`` (the default):

* key data of ``key(seed)``: (0, seed) for seed in [0, 2**31) (:func:`key_words`);
* ``fold_in(key, k)``: Threefry-2x32 of the counter pair (0, k) under the key;
* the (3,) float64 draw: element i hashes the counter pair (0, i) under the folded key
  into (w1, w2); the 64-bit word (w1 << 32) | w2 keeps its top 52 bits as the mantissa
  of a float f in [0, 1); u = max(lo, 2 f + lo) with lo = nextafter(-1, 0); the normal
  is sqrt(2) erfinv(u).

:func:`erfinv` is XLA's float64 ``erf_inv`` as JAX compiles it for an x86-64 CPU with
FMA (the CHLO expansion of M. Giles, "Approximating the erfinv function", GPU Computing
Gems Jade, 2011: w = -log1p(-x^2), polynomials in w - 3.125, sqrt(w) - 3.25 or
sqrt(w) - 5, times x; +-1 -> +-inf). XLA's CPU backend contracts each multiply-add of
those polynomials, and of its log1p (a Cephes rational below |z| = sqrt(2) - 1, libm's
log(1 + z) above), into a fused multiply-add; here the same FMAs are spelled out
(``_fma``) and the rest is compiled without contraction, so the result is the same
double. XLA on another backend (GPU) or a CPU without FMA rounds differently (by an ulp
or so). Checked against ``jax.lax.erf_inv`` and ``jax.random`` in
tests/test_numba_noise.py.

Numba's cache does not follow imports: after editing this file, clear the cache of the
modules that compile it in (``benchmarks/baselines/__pycache__/numba_loop.*``).
"""

from __future__ import annotations

import operator
from math import log, sqrt

import numpy as np

from so3jax.core import _erfinv

try:
    import numba
    from numba.core import types
    from numba.extending import intrinsic
except ImportError as exc:  # numba is an optional dependency
    raise ImportError("benchmarks.baselines.numba_noise needs numba (pip install numba)") from exc

_jit = numba.njit(cache=True, error_model="numpy", fastmath={"contract"})
_exact = numba.njit(cache=True, error_model="numpy")  # no contraction: the FMAs are explicit
_inline = numba.njit(cache=True, error_model="numpy", fastmath={"contract"}, inline="always")  # into the caller's IR

u32 = np.uint32
PARITY = 0x1BD11BDA  # Threefry key-schedule parity constant (Salmon et al. 2011)
LO = float(np.nextafter(-1.0, 0.0))  # lower end of the uniform jax.random.normal maps
SQRT2 = float(np.sqrt(2.0))
TWO_M52 = 2.0**-52
TINY = float(np.finfo(np.float64).tiny)  # smallest normal float64

# XLA's log1p rational and Giles' erfinv coefficients (highest degree first), as so3jax's
# own float64 draw uses them
LOG1P_P, LOG1P_Q = np.array(_erfinv.LOG1P_P), np.array(_erfinv.LOG1P_Q)
ERFINV_W625, ERFINV_W16, ERFINV_WBIG = (
    np.array(c) for c in (_erfinv.ERFINV_W625, _erfinv.ERFINV_W16, _erfinv.ERFINV_WBIG)
)
LOG1P_SMALL = _erfinv.LOG1P_SMALL  # the rational holds for |z| < sqrt(2) - 1

N_LOG1P_P, N_LOG1P_Q = len(LOG1P_P), len(LOG1P_Q)
N_ERFINV_W625, N_ERFINV_W16, N_ERFINV_WBIG = len(ERFINV_W625), len(ERFINV_W16), len(ERFINV_WBIG)


@intrinsic
def _fma(typingctx, a, b, c):
    """a * b + c rounded once (llvm.fma.f64: one instruction where the CPU has FMA)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        return builder.fma(*args)

    return sig, codegen


@_exact
def _horner(coeffs, n, w):
    """sum coeffs[i] w^(n-1-i), i < n, with one FMA per degree, as XLA's CPU backend evaluates
    it. coeffs: a global array, n: its length as a global int (a constant the compiler sees
    before it vectorizes, so the loop unrolls and a loop around it vectorizes)."""
    p = coeffs[0]
    for i in range(1, n):
        p = _fma(p, w, coeffs[i])
    return p


@_exact
def _log1p_small(z):
    """log(1 + z) for |z| < sqrt(2) - 1 as XLA's CPU backend computes it: z - z^2/2 + z^3 P(z)/Q(z)."""
    z2 = z * z
    return z + _fma(z2, -0.5, (z * z2) * (_horner(LOG1P_P, N_LOG1P_P, z) / _horner(LOG1P_Q, N_LOG1P_Q, z)))


@_exact
def _log1p(z):
    """log(1 + z) as XLA's CPU backend computes float64 log-plus-one (z >= -1 here)."""
    return _log1p_small(z) if abs(z) < LOG1P_SMALL else log(z + 1.0)


@_exact
def erfinv(x):
    """Inverse error function in float64, equal to ``jax.lax.erf_inv`` on the CPU (x = +-1 -> +-inf).

    XLA's CPU runtime flushes subnormals to zero (FTZ, DAZ), so a subnormal x, or a
    subnormal result (|x| < 2.5e-308), gives +-0 here too."""
    if abs(x) < TINY:
        return 0.0 * x
    if abs(x) == 1.0:
        return x * np.inf
    w = -_log1p(x * -x)
    if w < 6.25:
        p = _horner(ERFINV_W625, N_ERFINV_W625, w - 3.125)
    elif w < 16.0:
        p = _horner(ERFINV_W16, N_ERFINV_W16, sqrt(w) - 3.25)
    else:
        p = _horner(ERFINV_WBIG, N_ERFINV_WBIG, sqrt(w) - 5.0)
    r = p * x
    return r if abs(r) >= TINY else 0.0 * r


@_jit
def _rounds(x0, x1, r0, r1, r2, r3):
    """Four Threefry mix rounds with rotations r0 .. r3 (uint32 in, uint32 out: every sum is
    cut back to 32 bits, since Numba computes on uint32 in 64 bits)."""
    for r in (r0, r1, r2, r3):
        x0 = u32(x0 + x1)
        x1 = u32(u32((x1 << u32(r)) | (x1 >> u32(32 - r))) ^ x0)
    return x0, x1


@_jit
def _threefry(k0, k1, x0, x1):
    """Threefry-2x32: 20 rounds, the key injected every 4, on uint32 values; unrolled like
    JAX's lowering (jax._src.random.threefry2x32). uint32 throughout lets the compiler
    vectorize a loop of hashes (32-bit lanes and rotates)."""
    k2 = u32(k0 ^ k1 ^ u32(PARITY))
    x0, x1 = _rounds(u32(x0 + k0), u32(x1 + k1), 13, 15, 26, 6)
    x0, x1 = _rounds(u32(x0 + k1), u32(x1 + k2 + u32(1)), 17, 29, 16, 24)
    x0, x1 = _rounds(u32(x0 + k2), u32(x1 + k0 + u32(2)), 13, 15, 26, 6)
    x0, x1 = _rounds(u32(x0 + k0), u32(x1 + k1 + u32(3)), 17, 29, 16, 24)
    x0, x1 = _rounds(u32(x0 + k1), u32(x1 + k2 + u32(4)), 13, 15, 26, 6)
    return u32(x0 + k2), u32(x1 + k0 + u32(5))


@_jit
def threefry2x32(k0, k1, x0, x1):
    """Threefry-2x32 of the counter pair (x0, x1) under the key (k0, k1) -> (y0, y1).

    Arguments are taken modulo 2**32; the results are uint32 (Python ints when called
    from Python)."""
    return _threefry(u32(k0), u32(k1), u32(x0), u32(x1))


@_jit
def _uniform(w1, w2):
    """jax.random.uniform's float64 in [lo, 1) from one element's hash words (w1, w2): the top
    52 bits of the 64-bit word (w1 << 32) | w2 are the mantissa m of 1 + f, so f = m 2^-52
    exactly; u = max(lo, f (1 - lo) + lo), where 1 - lo rounds to 2.0."""
    mantissa = (np.int64(w1) << 20) | (np.int64(w2) >> 12)
    return max(LO, mantissa * TWO_M52 * 2.0 + LO)


@_inline
def _uniforms(seed_key0, seed_key1, k):
    """The three uniforms behind eta_k: fold_in(key, k), then the counters (0, i), i = 0, 1, 2."""
    f0, f1 = _threefry(u32(seed_key0), u32(seed_key1), u32(0), u32(k))
    a0, a1 = _threefry(f0, f1, u32(0), u32(0))
    b0, b1 = _threefry(f0, f1, u32(0), u32(1))
    c0, c1 = _threefry(f0, f1, u32(0), u32(2))
    return _uniform(a0, a1), _uniform(b0, b1), _uniform(c0, c1)


@_jit
def paper_eta(seed_key0, seed_key1, k):
    """eta_k (3 float64) at step k for the key words (seed_key0, seed_key1) of key(seed)
    (:func:`key_words`): docs/model.md §4's normal(fold_in(key(seed), k), (3,), float64), bit for bit."""
    u0, u1, u2 = _uniforms(seed_key0, seed_key1, k)
    return SQRT2 * erfinv(u0), SQRT2 * erfinv(u1), SQRT2 * erfinv(u2)


@_exact
def _sqrt2_erfinv(u, n, out):
    """out[j] = sqrt(2) erfinv(u[j]) for j < n (flat float64 arrays): the values of
    :func:`erfinv`, in passes the compiler vectorizes where they allow it: w = -log1p(-u^2)
    by the rational for every j, then log(1 + z) where |z| >= sqrt(2) - 1 (a call per
    element), then the w < 6.25 polynomial for every j; erfinv itself for the rest
    (|u| > 0.999, about 1 draw in 1000; |u| < 1e-300 or +-1), marked NaN in between."""
    for j in range(n):
        out[j] = -_log1p_small(u[j] * -u[j])
    for j in range(n):
        z = u[j] * -u[j]
        if not abs(z) < LOG1P_SMALL:
            out[j] = -log(z + 1.0)
    for j in range(n):
        w = out[j]
        r = SQRT2 * (_horner(ERFINV_W625, N_ERFINV_W625, w - 3.125) * u[j])
        out[j] = r if w < 6.25 and abs(u[j]) >= 1e-300 else np.nan  # tiny u: erfinv flushes to zero
    for j in range(n):
        if out[j] != out[j]:
            out[j] = SQRT2 * erfinv(u[j])


@_jit
def fill_eta(seed_key0, seed_key1, k0, nk, out, scratch):
    """out[i] = eta_{k0 + i} (:func:`paper_eta`) for i < nk; out: C-contiguous (>= nk, 3)
    float64; scratch: float64 (>= 3 nk), the uniforms. The hashes of all nk steps first
    (a loop the compiler vectorizes), then the inverse error function (_sqrt2_erfinv)."""
    for i in range(nk):
        scratch[3 * i], scratch[3 * i + 1], scratch[3 * i + 2] = _uniforms(seed_key0, seed_key1, k0 + i)
    _sqrt2_erfinv(scratch, 3 * nk, out.reshape(-1))


def key_words(seed) -> tuple[int, int]:
    """The two uint32 words of ``jax.random.key_data(jax.random.key(seed))``, computed without JAX.

    (0, seed) for seed in [0, 2**31), the range where JAX's answer does not depend on
    ``jax_enable_x64`` (a negative seed gives (0, seed mod 2**32) without it, (2**32 - 1,
    seed mod 2**32) with it); other seeds raise ValueError.
    """
    seed = operator.index(seed)
    if not 0 <= seed < 2**31:
        raise ValueError(f"seed must be in [0, 2**31) for key_words, got {seed}")
    return 0, seed


def key_array(seeds) -> np.ndarray:
    """(len(seeds), 2) uint32 key words of each seed (:func:`key_words`)."""
    return np.array([key_words(s) for s in seeds], dtype=np.uint32).reshape(-1, 2)
