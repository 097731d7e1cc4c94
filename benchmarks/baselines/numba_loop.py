"""Numba baseline of the paper's closed loop (docs/model.md §1-§6): scalar code, prange over the batch.

Each trajectory advances with explicit component arithmetic on local scalars (3x3
matrices are row-major 9-tuples), so a step allocates nothing; the batch is split
into one group per thread with ``numba.prange``. What depends only on time (R_d(t),
J(t) and its inverse at the three stage times, the sinusoidal disturbance) is
tabulated once per chunk of CHUNK steps and shared by the trajectories of a group.
The integrator is RK4 in local coordinates (docs/model.md §5): R = R_k exp(hat psi),
psi' = J_r^{-1}(psi) Omega, with Omega and Theta_hat integrated alongside and the
controller evaluated at every stage. Units: SI (s, rad, rad/s, N m, kg m^2). float64
only; compiled with FMA contraction allowed (no other fast-math).

The disturbance noise eta_k is either passed in precomputed (B, n_steps, 3) or, with
``noise="draw"``, drawn inside the kernel from the trajectory's seed, CHUNK steps at a
time before they are advanced, bit for bit as JAX draws it (:mod:`numba_noise`), so a
timing includes the PRNG as so3jax's does.

The scenario data and argument handling come from :mod:`numpy_loop`; the dynamics
and control arithmetic here are written independently of it.
"""

from __future__ import annotations

from collections.abc import Sequence
from math import asin, atan2, cos, exp, sin, sqrt, tan

import numpy as np

try:
    import numba
except ImportError as exc:  # numba is an optional dependency
    raise ImportError(
        "benchmarks.baselines.numba_loop needs numba (pip install numba); "
        "the NumPy baseline benchmarks.baselines.numpy_loop does not"
    ) from exc

from benchmarks.baselines.numba_noise import fill_eta, key_array
from benchmarks.baselines.numpy_loop import (
    DIST_AMPLITUDE,
    DIST_FREQUENCY,
    J0,
    J1,
    J2,
    NOISE_STD,
    OMEGA_D0,
    SMALL_ANGLE,
    T_DOCK,
    T_GROW,
    TAU_J,
    finalize,
    prepare,
)

SMALL2 = SMALL_ANGLE**2
CHUNK = 256  # steps per time table: (CHUNK, 3, N_TT) float64 stays in L2
N_TT = 24  # per stage time: R_d (9), R_d Omega_d (3), J (6), J^{-1} (6)
N_SUMS = 16  # per trajectory: we2[3], tau2[3], ang2[3], tau_max[3], ang_max[3], wu2

_jit = numba.njit(cache=True, error_model="numpy", fastmath={"contract"})


@_jit
def _exp_coeffs(t2):
    """(a, b) = (sin t / t, (1 - cos t) / t^2) for t^2 = t2, series below SMALL_ANGLE."""
    if t2 < SMALL2:
        return (
            1.0 - t2 / 6.0 * (1.0 - t2 / 20.0 * (1.0 - t2 / 42.0)),
            0.5 - t2 / 24.0 * (1.0 - t2 / 30.0 * (1.0 - t2 / 56.0)),
        )
    half = 0.5 * sqrt(t2)
    sh = sin(half)
    return sh * cos(half) / half, 0.5 * (sh / half) ** 2


@_jit
def _exp_minus_identity(p0, p1, p2):
    """exp(hat p) - I = a hat(p) + b (p p^T - |p|^2 I) as a row-major 9-tuple."""
    t2 = p0 * p0 + p1 * p1 + p2 * p2
    a, b = _exp_coeffs(t2)
    return (
        b * (p0 * p0 - t2), -a * p2 + b * p0 * p1, a * p1 + b * p0 * p2,
        a * p2 + b * p1 * p0, b * (p1 * p1 - t2), -a * p0 + b * p1 * p2,
        -a * p1 + b * p2 * p0, a * p0 + b * p2 * p1, b * (p2 * p2 - t2),
    )  # fmt: skip


@_jit
def _jr_inv_apply(e0, e1, e2, w0, w1, w2):
    """J_r^{-1}(e) w = w + e x w / 2 + g e x (e x w), g = 1/t^2 - cot(t/2)/(2t), t = |e| (docs/model.md §3.2)."""
    t2 = e0 * e0 + e1 * e1 + e2 * e2
    if t2 < SMALL2:
        g = 1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0
    else:
        t = sqrt(t2)
        g = 1.0 / t2 - 0.5 / (t * tan(0.5 * t))
    c0, c1, c2 = e1 * w2 - e2 * w1, e2 * w0 - e0 * w2, e0 * w1 - e1 * w0
    cc0, cc1, cc2 = e1 * c2 - e2 * c1, e2 * c0 - e0 * c2, e0 * c1 - e1 * c0
    return w0 + 0.5 * c0 + g * cc0, w1 + 0.5 * c1 + g * cc1, w2 + 0.5 * c2 + g * cc2


@_jit
def _mul_add(x, y):
    """x + (x y) for row-major 9-tuples: R_k + R_k (exp(hat psi) - I), the small term summed
    first (docs/model.md §5)."""
    return (
        x[0] + (x[0] * y[0] + x[1] * y[3] + x[2] * y[6]),
        x[1] + (x[0] * y[1] + x[1] * y[4] + x[2] * y[7]),
        x[2] + (x[0] * y[2] + x[1] * y[5] + x[2] * y[8]),
        x[3] + (x[3] * y[0] + x[4] * y[3] + x[5] * y[6]),
        x[4] + (x[3] * y[1] + x[4] * y[4] + x[5] * y[7]),
        x[5] + (x[3] * y[2] + x[4] * y[5] + x[5] * y[8]),
        x[6] + (x[6] * y[0] + x[7] * y[3] + x[8] * y[6]),
        x[7] + (x[6] * y[1] + x[7] * y[4] + x[8] * y[7]),
        x[8] + (x[6] * y[2] + x[7] * y[5] + x[8] * y[8]),
    )


@_jit
def _time_terms(t, phase, wd0, wd1, wd2, Ja, Jb):
    """What depends only on time: R_d(t) (9), q = R_d Omega_d (3), J(t) (6) and its inverse (6).

    R_d(t) = exp(hat(Omega_d0) min(t, T_DOCK)); Omega_d = Omega_d0 before docking, 0 after.
    J(t) = Jb - (Jb - Ja) exp(-(t - T_GROW)/TAU_J) in phase 1 (Ja = J0, Jb = J1), else
    Jb (= J0 or J2). Symmetric matrices as (xx, yy, zz, xy, xz, yz).
    """
    tc = min(t, T_DOCK)
    r = _exp_minus_identity(wd0 * tc, wd1 * tc, wd2 * tc)
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = (
        1.0 + r[0], r[1], r[2], r[3], 1.0 + r[4], r[5], r[6], r[7], 1.0 + r[8],
    )  # fmt: skip
    if phase == 2:
        q0 = q1 = q2 = 0.0
    else:
        q0 = r00 * wd0 + r01 * wd1 + r02 * wd2
        q1 = r10 * wd0 + r11 * wd1 + r12 * wd2
        q2 = r20 * wd0 + r21 * wd1 + r22 * wd2
    f = exp(-(t - T_GROW) / TAU_J) if phase == 1 else 0.0
    jxx = Jb[0, 0] - (Jb[0, 0] - Ja[0, 0]) * f
    jyy = Jb[1, 1] - (Jb[1, 1] - Ja[1, 1]) * f
    jzz = Jb[2, 2] - (Jb[2, 2] - Ja[2, 2]) * f
    jxy = Jb[0, 1] - (Jb[0, 1] - Ja[0, 1]) * f
    jxz = Jb[0, 2] - (Jb[0, 2] - Ja[0, 2]) * f
    jyz = Jb[1, 2] - (Jb[1, 2] - Ja[1, 2]) * f
    cxx, cyy, czz = jyy * jzz - jyz * jyz, jxx * jzz - jxz * jxz, jxx * jyy - jxy * jxy
    cxy, cxz, cyz = jxz * jyz - jxy * jzz, jxy * jyz - jxz * jyy, jxy * jxz - jxx * jyz
    inv_det = 1.0 / (jxx * cxx + jxy * cxy + jxz * cxz)
    return (
        r00, r01, r02, r10, r11, r12, r20, r21, r22, q0, q1, q2,
        jxx, jyy, jzz, jxy, jxz, jyz,
        cxx * inv_det, cyy * inv_det, czz * inv_det, cxy * inv_det, cxz * inv_det, cyz * inv_det,
    )  # fmt: skip


@_jit
def _stage(adaptive, first, g0, g1, gam, Rk, p0, p1, p2, w0, w1, w2, th, tt, s, d0, d1, d2):
    """One RK4 stage: controller at R = R_k exp(hat p), Omega = w, Theta_hat = th; plant at tt.

    first: the stage at the step start, where p = 0 (so R = R_k, psi' = Omega) and where
    the metrics sample. g0, g1 = (K_r, K_w) for the adaptive law (docs/model.md §3.2), (k_R, k_Omega)
    for PD (§3.1), both with J_hat = I and Omega_d' = 0; tt: a row of the time table;
    s: inertia scale. Returns psi' (3), Omega' (3), tau (3), Omega_e (3), the attitude-error
    angle (computed only when first or when the adaptive law needs it, else 0), and
    Gamma Phi (9), z (3) (zeros for PD): Theta_hat' = -(Gamma Phi) z^T.
    """
    R = Rk if first else _mul_add(Rk, _exp_minus_identity(p0, p1, p2))  # psi = 0 at stage 1
    # R_e = R_d^T R, only what the laws use: v = (R_e - R_e^T)^vee / 2 and tr R_e
    e00 = tt[0] * R[0] + tt[3] * R[3] + tt[6] * R[6]
    e11 = tt[1] * R[1] + tt[4] * R[4] + tt[7] * R[7]
    e22 = tt[2] * R[2] + tt[5] * R[5] + tt[8] * R[8]
    e01 = tt[0] * R[1] + tt[3] * R[4] + tt[6] * R[7]
    e10 = tt[1] * R[0] + tt[4] * R[3] + tt[7] * R[6]
    e02 = tt[0] * R[2] + tt[3] * R[5] + tt[6] * R[8]
    e20 = tt[2] * R[0] + tt[5] * R[3] + tt[8] * R[6]
    e12 = tt[1] * R[2] + tt[4] * R[5] + tt[7] * R[8]
    e21 = tt[2] * R[1] + tt[5] * R[4] + tt[8] * R[7]
    v0, v1, v2 = 0.5 * (e21 - e12), 0.5 * (e02 - e20), 0.5 * (e10 - e01)
    sn2 = v0 * v0 + v1 * v1 + v2 * v2  # sin^2 of the error angle
    sn = sqrt(sn2)
    cs = 0.5 * (e00 + e11 + e22 - 1.0)  # its cosine
    # angle theta and f = theta / sin(theta): asin(sn)/sn's series near 0, asin below pi/4,
    # atan2 beyond (log(R_e)^vee = f v); PD needs them only for the metrics
    theta = 0.0
    f = 1.0
    if adaptive or first:
        if sn < SMALL_ANGLE and cs > 0.0:
            f = 1.0 + sn2 / 6.0 + 3.0 * sn2 * sn2 / 40.0 + 5.0 * sn2 * sn2 * sn2 / 112.0
            theta = f * sn
        else:
            theta = asin(sn) if cs >= sn else atan2(sn, cs)
            f = theta / sn
    # Omega_r = R^T R_d Omega_d, Omega_e = Omega - Omega_r
    q0, q1, q2 = tt[9], tt[10], tt[11]
    or0 = R[0] * q0 + R[3] * q1 + R[6] * q2
    or1 = R[1] * q0 + R[4] * q1 + R[7] * q2
    or2 = R[2] * q0 + R[5] * q1 + R[8] * q2
    we0, we1, we2 = w0 - or0, w1 - or1, w2 - or2
    x0, x1, x2 = w1 * or2 - w2 * or1, w2 * or0 - w0 * or2, w0 * or1 - w1 * or0  # Omega x Omega_r
    ph0 = ph1 = ph2 = ph3 = ph4 = ph5 = ph6 = ph7 = ph8 = 0.0
    z0 = z1 = z2 = 0.0
    if adaptive:
        l0, l1, l2 = f * v0, f * v1, f * v2  # e = log(R_e)^vee
        z0, z1, z2 = w0 - (or0 - g0 * l0), w1 - (or1 - g0 * l1), w2 - (or2 - g0 * l2)
        ed0, ed1, ed2 = _jr_inv_apply(l0, l1, l2, we0, we1, we2)
        ph0, ph1, ph2, ph3, ph4, ph5 = w1 * w2, w2 * w0, w0 * w1, w0 * w0, w1 * w1, w2 * w2
        ph6, ph7, ph8 = -g0 * ed0 - x0, -g0 * ed1 - x1, -g0 * ed2 - x2  # beta'
        ff0 = ff1 = ff2 = 0.0
        for i, ph in enumerate((ph0, ph1, ph2, ph3, ph4, ph5, ph6, ph7, ph8)):
            ff0 += th[i, 0] * ph
            ff1 += th[i, 1] * ph
            ff2 += th[i, 2] * ph
        tau0 = -g0 * l0 - g1 * z0 + ff0
        tau1 = -g0 * l1 - g1 * z1 + ff1
        tau2 = -g0 * l2 - g1 * z2 + ff2
    else:
        tau0 = -g0 * v0 - g1 * we0 - x0
        tau1 = -g0 * v1 - g1 * we1 - x1
        tau2 = -g0 * v2 - g1 * we2 - x2
    # plant: Omega' = (s J)^{-1} (-Omega x s J Omega + tau + d)
    h0 = s * (tt[12] * w0 + tt[15] * w1 + tt[16] * w2)
    h1 = s * (tt[15] * w0 + tt[13] * w1 + tt[17] * w2)
    h2 = s * (tt[16] * w0 + tt[17] * w1 + tt[14] * w2)
    b0 = -(w1 * h2 - w2 * h1) + tau0 + d0
    b1 = -(w2 * h0 - w0 * h2) + tau1 + d1
    b2 = -(w0 * h1 - w1 * h0) + tau2 + d2
    dw0 = (tt[18] * b0 + tt[21] * b1 + tt[22] * b2) / s
    dw1 = (tt[21] * b0 + tt[19] * b1 + tt[23] * b2) / s
    dw2 = (tt[22] * b0 + tt[23] * b1 + tt[20] * b2) / s
    dp0, dp1, dp2 = (w0, w1, w2) if first else _jr_inv_apply(p0, p1, p2, w0, w1, w2)
    return (
        dp0, dp1, dp2, dw0, dw1, dw2, tau0, tau1, tau2, we0, we1, we2, theta,
        gam[0] * ph0, gam[1] * ph1, gam[2] * ph2, gam[3] * ph3, gam[4] * ph4,
        gam[5] * ph5, gam[6] * ph6, gam[7] * ph7, gam[8] * ph8, z0, z1, z2,
    )  # fmt: skip


@_jit
def _fill_table(k0, nk, h, k1, k2, wd, table, dist):
    """table[i, c] = time terms at t_k + (0, h/2, h)[c] and dist[i] = 0.1 sin(0.001 t_k) [N m],
    for k = k0 + i (docs/model.md §4)."""
    for i in range(nk):
        k = k0 + i
        phase = 0 if k < k1 else (1 if k < k2 else 2)
        Ja = J2 if phase == 2 else J0
        Jb = J0 if phase == 0 else (J1 if phase == 1 else J2)
        t = k * h
        for c in range(3):
            tt = _time_terms(t + 0.5 * c * h, phase, wd[0], wd[1], wd[2], Ja, Jb)
            for m in range(N_TT):
                table[i, c, m] = tt[m]
        dist[i] = DIST_AMPLITUDE * sin(DIST_FREQUENCY * t)


@_jit
def _advance(adaptive, draw, key, k0, nk, h, k1, k2, g0, g1, gam, wd, s, noise, etab, ubuf, table, dist, Rio, wio,
             th, ths, acc, sums):  # fmt: skip
    """Advance one trajectory (state Rio (3, 3), wio (3), th (9, 3), updated in place) over
    steps k0 .. k0+nk-1 with RK4 (docs/model.md §5), adding its metrics to sums (§6).
    eta_k: noise[k] or, if draw, drawn here for the chunk from the key words key (2,) of
    its seed into etab (CHUNK, 3) (ubuf (3 CHUNK): scratch). ths, acc: (9, 3) scratch for
    the stage value and the RK4 sum of Theta_hat'."""
    if draw:
        fill_eta(key[0], key[1], k0, nk, etab, ubuf)
        eta, base = etab, 0
    else:
        eta, base = noise, k0
    R = (Rio[0, 0], Rio[0, 1], Rio[0, 2], Rio[1, 0], Rio[1, 1], Rio[1, 2], Rio[2, 0], Rio[2, 1], Rio[2, 2])
    w0, w1, w2 = wio[0], wio[1], wio[2]
    c = 0.5 * h
    c6 = h / 6.0
    for i in range(nk):
        k = k0 + i
        phase = 0 if k < k1 else (1 if k < k2 else 2)
        d0 = dist[i] + NOISE_STD * eta[base + i, 0]
        d1 = dist[i] + NOISE_STD * eta[base + i, 1]
        d2 = dist[i] + NOISE_STD * eta[base + i, 2]
        o1 = _stage(adaptive, True, g0, g1, gam, R, 0.0, 0.0, 0.0, w0, w1, w2, th,
                    table[i, 0], s, d0, d1, d2)  # fmt: skip
        if adaptive:
            for a in range(9):
                for b in range(3):
                    acc[a, b] = -o1[13 + a] * o1[22 + b]
                    ths[a, b] = th[a, b] + c * acc[a, b]
        o2 = _stage(adaptive, False, g0, g1, gam, R, c * o1[0], c * o1[1], c * o1[2],
                    w0 + c * o1[3], w1 + c * o1[4], w2 + c * o1[5], ths, table[i, 1], s, d0, d1, d2)  # fmt: skip
        if adaptive:
            for a in range(9):
                for b in range(3):
                    dth = -o2[13 + a] * o2[22 + b]
                    acc[a, b] = acc[a, b] + 2.0 * dth
                    ths[a, b] = th[a, b] + c * dth
        o3 = _stage(adaptive, False, g0, g1, gam, R, c * o2[0], c * o2[1], c * o2[2],
                    w0 + c * o2[3], w1 + c * o2[4], w2 + c * o2[5], ths, table[i, 1], s, d0, d1, d2)  # fmt: skip
        if adaptive:
            for a in range(9):
                for b in range(3):
                    dth = -o3[13 + a] * o3[22 + b]
                    acc[a, b] = acc[a, b] + 2.0 * dth
                    ths[a, b] = th[a, b] + h * dth
        o4 = _stage(adaptive, False, g0, g1, gam, R, h * o3[0], h * o3[1], h * o3[2],
                    w0 + h * o3[3], w1 + h * o3[4], w2 + h * o3[5], ths, table[i, 2], s, d0, d1, d2)  # fmt: skip

        # metrics at the step start (stage 1), docs/model.md §6
        tau_sq = o1[6] * o1[6] + o1[7] * o1[7] + o1[8] * o1[8]
        we_sq = o1[9] * o1[9] + o1[10] * o1[10] + o1[11] * o1[11]
        if phase < 2:
            u0, u1, u2 = w0 - wd[0], w1 - wd[1], w2 - wd[2]
        else:
            u0, u1, u2 = w0, w1, w2
        sums[phase] += we_sq
        sums[3 + phase] += tau_sq
        sums[6 + phase] += o1[12] * o1[12]
        sums[9 + phase] = max(sums[9 + phase], sqrt(tau_sq))
        sums[12 + phase] = max(sums[12 + phase], o1[12])
        sums[15] += u0 * u0 + u1 * u1 + u2 * u2

        p0 = c6 * (o1[0] + 2.0 * o2[0] + 2.0 * o3[0] + o4[0])
        p1 = c6 * (o1[1] + 2.0 * o2[1] + 2.0 * o3[1] + o4[1])
        p2 = c6 * (o1[2] + 2.0 * o2[2] + 2.0 * o3[2] + o4[2])
        R = _mul_add(R, _exp_minus_identity(p0, p1, p2))
        w0 = w0 + c6 * (o1[3] + 2.0 * o2[3] + 2.0 * o3[3] + o4[3])
        w1 = w1 + c6 * (o1[4] + 2.0 * o2[4] + 2.0 * o3[4] + o4[4])
        w2 = w2 + c6 * (o1[5] + 2.0 * o2[5] + 2.0 * o3[5] + o4[5])
        if adaptive:
            for a in range(9):
                for b in range(3):
                    th[a, b] = th[a, b] + c6 * (acc[a, b] - o4[13 + a] * o4[22 + b])
    for m in range(9):
        Rio[m // 3, m % 3] = R[m]
    wio[0], wio[1], wio[2] = w0, w1, w2


@numba.njit(cache=True, parallel=True)
def _batch(n_groups, adaptive, draw, keys, n_steps, h, k1, k2, g0, g1, gam, wd, scale, noise, R, Omega, Theta, sums):
    """Split the batch into n_groups groups (prange, one per thread); each goes through the
    steps in chunks of CHUNK: tabulate the time terms, then advance its trajectories.
    draw: eta drawn in _advance from keys (B, 2) (noise is then a (B, 1, 3) placeholder)."""
    B = scale.shape[0]
    for g in numba.prange(n_groups):
        table = np.empty((CHUNK, 3, N_TT))
        dist = np.empty(CHUNK)
        etab = np.empty((CHUNK if draw else 1, 3))
        ubuf = np.empty(3 * CHUNK if draw else 1)
        ths = np.empty((9, 3))
        acc = np.empty((9, 3))
        for k0 in range(0, n_steps, CHUNK):
            nk = min(CHUNK, n_steps - k0)
            _fill_table(k0, nk, h, k1, k2, wd, table, dist)
            for b in range(g * B // n_groups, (g + 1) * B // n_groups):
                _advance(adaptive, draw, keys[b], k0, nk, h, k1, k2, g0, g1, gam, wd, scale[b], noise[b], etab,
                         ubuf, table, dist, R[b], Omega[b], Theta[b], ths, acc, sums[b])  # fmt: skip


def simulate(
    controller: str,
    n_steps: int,
    seeds: Sequence[int],
    *,
    dt: float = 0.01,
    gains: dict | None = None,
    inertia_scale: np.ndarray | None = None,
    dtype=np.float64,
    noise: np.ndarray | str | None = None,
) -> dict:
    """Run the paper's scenario (docs/model.md §4) for a batch of len(seeds) trajectories.

    Same signature and result as :func:`benchmarks.baselines.numpy_loop.simulate`
    (see there); dtype must be float64. One more choice for noise: "draw" draws eta_k
    inside the compiled loop from each seed (in [0, 2**31)), so a timing includes it;
    the same values as noise=None, which draws them with JAX before the loop.
    """
    if np.dtype(dtype) != np.float64:
        raise ValueError(f"the Numba baseline computes in float64 only, got dtype={dtype}")
    setup = prepare(controller, n_steps, seeds, dt, gains, inertia_scale, dtype, noise, allow_draw=True)
    B = setup.noise.shape[0]
    draw = isinstance(noise, str)
    if draw and setup.n_steps > 2**32:
        raise ValueError(f"noise='draw' folds the step k in as a uint32: n_steps must be <= 2**32, got {n_steps}")
    keys = key_array([int(s) for s in seeds]) if draw else np.zeros((B, 2), np.uint32)  # as prepare reads seeds
    g = setup.gains
    if setup.adaptive:
        g0, g1, gam = g["K_r"], g["K_w"], g["Gamma"]
    else:
        g0, g1, gam = g["k_R"], g["k_Omega"], np.zeros(9)
    R = np.zeros((B, 3, 3))
    R[:] = np.eye(3)
    Omega = np.zeros((B, 3))
    Theta = np.zeros((B, 9, 3))
    Theta[:, 6:, :] = np.eye(3)  # Theta(J_hat = I)
    sums = np.zeros((B, N_SUMS))
    n_groups = min(B, numba.get_num_threads())
    _batch(n_groups, setup.adaptive, draw, keys, setup.n_steps, setup.dt, setup.k1, setup.k2, g0, g1, gam,
           OMEGA_D0, setup.scale, setup.noise, R, Omega, Theta, sums)  # fmt: skip
    named = {
        "we2": sums[:, 0:3], "tau2": sums[:, 3:6], "ang2": sums[:, 6:9],
        "tau_max": sums[:, 9:12], "ang_max": sums[:, 12:15], "wu2": sums[:, 15],
    }  # fmt: skip
    return finalize(setup, named, R, Omega, Theta if setup.adaptive else None)
