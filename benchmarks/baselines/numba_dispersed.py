"""Numba baseline of the dispersed Monte Carlo sweep (``so3jax sweep``): every trajectory flies its own scenario.

The closed loop is :mod:`numba_loop`'s (docs/model.md §3-§6: the paper's PD or adaptive law with
J_hat = I, RK4 in local coordinates on SO(3), the law evaluated in every stage), and its
stage arithmetic is imported from there (``_stage``, ``_exp_minus_identity``, ``_mul_add``);
the noise eta_k is drawn inside the kernel from each trajectory's seed, CHUNK steps at a
time, bit for bit as JAX draws it (:func:`numba_noise.fill_eta`). What differs from
numba_loop is the scenario: each trajectory b has its own parameters, those of a sample of
``so3jax.missions.draw`` (the fields of ``so3jax.missions.draw.RolloutParams``):

* inertias J0, J1, J2 (3, 3) [kg m^2] and the deployment time constant tau_J [s]:
  J(t) = J0 in phase 0, J1 - (J1 - J0) exp(-(t - T_GROW)/tau_J) in phase 1, J2 in phase 2;
* orbital rate n [rad/s]: the reference rate is Omega_d = n (1, -10, 2) in phases 0 and
  1, zero after docking; in phase p, from t_p in (0, T_GROW, T_DOCK), with w_p its Omega_d,
  R_d(t) = S_p + S_p (exp(hat(w_p) (t - t_p)) - I), S_p = R_d(t_p) (S_0 = I);
* disturbance d_k = amplitude sin(frequency t_k) (1, 1, 1) + noise_std eta_k [N m];
* initial state R0 (3, 3), Omega0 (3,) [rad/s]; the noise seed (in [0, 2**31)).

Phases switch at steps round(T_GROW/dt), round(T_DOCK/dt) (500 s, 2600 s). So where
numba_loop tabulates the time terms once per chunk of steps for a whole group of
trajectories, here each trajectory evaluates its own once per step, as a sweep of so3jax
does per sample (``so3jax.dynamics.stepped``), from constants computed before its time loop:

* reference: the step rotations exp(hat(w_p) dt/2), exp(hat(w_p) dt) of each phase; per
  step, R_d(t_k) in closed form, then R_d(t_k + c dt) = R_d(t_k) exp(hat(w_p) c dt), and
  R_d Omega_d at each of the three RK4 stage times t_k, t_k + dt/2, t_k + dt;
* inertia: J0^{-1} and J2^{-1} (by the adjugate) and the decay factors exp(-dt/(2 tau_J)),
  exp(-dt/tau_J); phases 0 and 2 use J0, J2 and those inverses; in phase 1, per step,
  w_k = exp(-(t_k - T_GROW)/tau_J), w at the later stage times w_k times a decay factor,
  J = J1 - (J1 - J0) w and J^{-1} by the adjugate at each of the three times;
* disturbance: at t_k.

Scalar code: the trajectories are split into one group per thread (``numba.prange``),
each trajectory advanced on local scalars, allocating nothing per step. Units: SI (s, rad,
rad/s, N m, kg m^2). float64 only; FMA contraction allowed (no other fast-math).

The result holds the metrics ``so3jax.missions.batched.sample_metrics`` returns for the paper's
mission, under its names and shapes ((B,) or (B, 3) per phase; a phase the horizon never
reaches has 0, as there); ``diverged`` flags a trajectory whose state was non-finite after
any step.

Numba's cache does not follow imports: after editing numba_loop or numba_noise, clear this
module's cache too (``benchmarks/baselines/__pycache__/numba_dispersed.*``).
"""

from __future__ import annotations

from collections.abc import Mapping
from math import exp, isfinite, sin, sqrt

import numpy as np

try:
    import numba
except ImportError as exc:  # numba is an optional dependency
    raise ImportError("benchmarks.baselines.numba_dispersed needs numba (pip install numba)") from exc

from benchmarks.baselines.numba_loop import CHUNK, _exp_minus_identity, _jit, _mul_add, _stage
from benchmarks.baselines.numba_noise import fill_eta, key_array
from benchmarks.baselines.numpy_loop import T_DOCK, T_GROW, prepare

FIELDS = ("J0", "J1", "J2", "tau_J", "n", "amplitude", "frequency", "noise_std", "R0", "Omega0", "seed")
N_SUMS = 17  # per trajectory: we2[3], tau2[3], ang2[3], tau_max[3], ang_max[3], wu2, finite (1 or 0)
IDENTITY = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)


@_jit
def _matmul(x, y):
    """x y for row-major 9-tuples."""
    return (
        x[0] * y[0] + x[1] * y[3] + x[2] * y[6], x[0] * y[1] + x[1] * y[4] + x[2] * y[7],
        x[0] * y[2] + x[1] * y[5] + x[2] * y[8], x[3] * y[0] + x[4] * y[3] + x[5] * y[6],
        x[3] * y[1] + x[4] * y[4] + x[5] * y[7], x[3] * y[2] + x[4] * y[5] + x[5] * y[8],
        x[6] * y[0] + x[7] * y[3] + x[8] * y[6], x[6] * y[1] + x[7] * y[4] + x[8] * y[7],
        x[6] * y[2] + x[7] * y[5] + x[8] * y[8],
    )  # fmt: skip


@_jit
def _plus_identity(e):
    """I + e for a row-major 9-tuple."""
    return (1.0 + e[0], e[1], e[2], e[3], 1.0 + e[4], e[5], e[6], e[7], 1.0 + e[8])


@_jit
def _start_attitudes(w0, w1, w2):
    """R_d at the starts of phases 1 and 2 for the rate w = Omega_d (phases 0 and 1):
    S_1 = exp(hat(w) T_GROW), S_2 = S_1 exp(hat(w) (T_DOCK - T_GROW))."""
    s1 = _plus_identity(_exp_minus_identity(w0 * T_GROW, w1 * T_GROW, w2 * T_GROW))
    c = T_DOCK - T_GROW
    return s1, _matmul(s1, _plus_identity(_exp_minus_identity(w0 * c, w1 * c, w2 * c)))


@_jit
def _step_rotations(v0, v1, v2, h):
    """exp(hat(v) h/2), exp(hat(v) h): a phase's step rotations for its rate v."""
    c = 0.5 * h
    return (
        _plus_identity(_exp_minus_identity(v0 * c, v1 * c, v2 * c)),
        _plus_identity(_exp_minus_identity(v0 * h, v1 * h, v2 * h)),
    )


@_jit
def _sym(J):
    """(xx, yy, zz, xy, xz, yz) of a symmetric (3, 3) array."""
    return J[0, 0], J[1, 1], J[2, 2], J[0, 1], J[0, 2], J[1, 2]


@_jit
def _inverse(j):
    """J^{-1} of a symmetric J by its adjugate, both as (xx, yy, zz, xy, xz, yz)."""
    jxx, jyy, jzz, jxy, jxz, jyz = j
    cxx, cyy, czz = jyy * jzz - jyz * jyz, jxx * jzz - jxz * jxz, jxx * jyy - jxy * jxy
    cxy, cxz, cyz = jxz * jyz - jxy * jzz, jxy * jyz - jxz * jyy, jxy * jxz - jxx * jyz
    inv_det = 1.0 / (jxx * cxx + jxy * cxy + jxz * cxz)
    return cxx * inv_det, cyy * inv_det, czz * inv_det, cxy * inv_det, cxz * inv_det, cyz * inv_det


@_jit
def _blend(Ja, Jb, w):
    """Jb - (Jb - Ja) w, symmetric matrices as (xx, yy, zz, xy, xz, yz)."""
    return (
        Jb[0] - (Jb[0] - Ja[0]) * w, Jb[1] - (Jb[1] - Ja[1]) * w, Jb[2] - (Jb[2] - Ja[2]) * w,
        Jb[3] - (Jb[3] - Ja[3]) * w, Jb[4] - (Jb[4] - Ja[4]) * w, Jb[5] - (Jb[5] - Ja[5]) * w,
    )  # fmt: skip


@_jit
def _time_terms(r, v0, v1, v2, J, Ji):
    """One stage time's terms in the layout of numba_loop's time table: R_d = r (9),
    q = R_d v (3), J (6) and J^{-1} = Ji (6), symmetric matrices as (xx, yy, zz, xy, xz, yz);
    v: the phase's Omega_d."""
    return (
        r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8],
        r[0] * v0 + r[1] * v1 + r[2] * v2, r[3] * v0 + r[4] * v1 + r[5] * v2, r[6] * v0 + r[7] * v1 + r[8] * v2,
        J[0], J[1], J[2], J[3], J[4], J[5], Ji[0], Ji[1], Ji[2], Ji[3], Ji[4], Ji[5],
    )  # fmt: skip


@_jit
def _trajectory(adaptive, key0, key1, n_steps, h, k1, k2, g0, g1, gam, J0, J1, J2, tau_J, n, amp, freq, nstd,
                etab, ubuf, Rio, wio, th, ths, a1, a23, sums):  # fmt: skip
    """Advance one trajectory over steps 0 .. n_steps-1 with RK4 (docs/model.md §5) in its own
    scenario (module docstring), adding its metrics to sums (docs/model.md §6). State: Rio (3, 3),
    wio (3), th (9, 3) (Theta_hat), updated in place. eta_k is drawn CHUNK steps at a time
    from the key words (key0, key1) into etab (CHUNK, 3) (ubuf (3 CHUNK): scratch); ths, a1,
    a23: (9, 3) scratch (a stage's Theta_hat, stage 1's Theta_hat', stages 2 + 3's)."""
    # per-trajectory constants (module docstring)
    wd0, wd1, wd2 = n, -10.0 * n, 2.0 * n
    S1, S2 = _start_attitudes(wd0, wd1, wd2)
    half01, full01 = _step_rotations(wd0, wd1, wd2, h)  # phases 0 and 1 (rate w)
    half2, full2 = _step_rotations(0.0, 0.0, 0.0, h)  # phase 2 (rate 0)
    J0s, J1s, J2s = _sym(J0), _sym(J1), _sym(J2)
    J0_inv, J2_inv = _inverse(J0s), _inverse(J2s)
    e_half, e_full = exp(-0.5 * h / tau_J), exp(-h / tau_J)
    R = (Rio[0, 0], Rio[0, 1], Rio[0, 2], Rio[1, 0], Rio[1, 1], Rio[1, 2], Rio[2, 0], Rio[2, 1], Rio[2, 2])
    w0, w1, w2 = wio[0], wio[1], wio[2]
    finite = True
    c = 0.5 * h
    c6 = h / 6.0
    for k0 in range(0, n_steps, CHUNK):
        nk = min(CHUNK, n_steps - k0)
        fill_eta(key0, key1, k0, nk, etab, ubuf)
        for i in range(nk):
            k = k0 + i
            t = k * h
            if k < k1:
                phase, S, tp, v0, v1, v2, half, full = 0, IDENTITY, 0.0, wd0, wd1, wd2, half01, full01
            elif k < k2:
                phase, S, tp, v0, v1, v2, half, full = 1, S1, T_GROW, wd0, wd1, wd2, half01, full01
            else:
                phase, S, tp, v0, v1, v2, half, full = 2, S2, T_DOCK, 0.0, 0.0, 0.0, half2, full2
            ts = t - tp
            r0 = _mul_add(S, _exp_minus_identity(v0 * ts, v1 * ts, v2 * ts))  # R_d(t_k)
            r_m, r_e = _matmul(r0, half), _matmul(r0, full)  # R_d(t_k + dt/2), R_d(t_k + dt)
            if phase == 1:
                w = exp(-(t - T_GROW) / tau_J)
                Jt0, Jtm, Jte = _blend(J0s, J1s, w), _blend(J0s, J1s, w * e_half), _blend(J0s, J1s, w * e_full)
                tt0 = _time_terms(r0, v0, v1, v2, Jt0, _inverse(Jt0))
                ttm = _time_terms(r_m, v0, v1, v2, Jtm, _inverse(Jtm))
                tte = _time_terms(r_e, v0, v1, v2, Jte, _inverse(Jte))
            elif phase == 0:
                tt0 = _time_terms(r0, v0, v1, v2, J0s, J0_inv)
                ttm = _time_terms(r_m, v0, v1, v2, J0s, J0_inv)
                tte = _time_terms(r_e, v0, v1, v2, J0s, J0_inv)
            else:
                tt0 = _time_terms(r0, v0, v1, v2, J2s, J2_inv)
                ttm = _time_terms(r_m, v0, v1, v2, J2s, J2_inv)
                tte = _time_terms(r_e, v0, v1, v2, J2s, J2_inv)
            sw = amp * sin(freq * t)
            d0 = sw + nstd * etab[i, 0]
            d1 = sw + nstd * etab[i, 1]
            d2 = sw + nstd * etab[i, 2]

            o1 = _stage(adaptive, True, g0, g1, gam, R, 0.0, 0.0, 0.0, w0, w1, w2, th, tt0, 1.0, d0, d1, d2)
            if adaptive:
                for a in range(9):
                    for b in range(3):
                        a1[a, b] = -o1[13 + a] * o1[22 + b]
                        ths[a, b] = th[a, b] + c * a1[a, b]
            o2 = _stage(adaptive, False, g0, g1, gam, R, c * o1[0], c * o1[1], c * o1[2],
                        w0 + c * o1[3], w1 + c * o1[4], w2 + c * o1[5], ths, ttm, 1.0, d0, d1, d2)  # fmt: skip
            if adaptive:
                for a in range(9):
                    for b in range(3):
                        dth = -o2[13 + a] * o2[22 + b]
                        a23[a, b] = dth
                        ths[a, b] = th[a, b] + c * dth
            o3 = _stage(adaptive, False, g0, g1, gam, R, c * o2[0], c * o2[1], c * o2[2],
                        w0 + c * o2[3], w1 + c * o2[4], w2 + c * o2[5], ths, ttm, 1.0, d0, d1, d2)  # fmt: skip
            if adaptive:
                for a in range(9):
                    for b in range(3):
                        dth = -o3[13 + a] * o3[22 + b]
                        a23[a, b] = a23[a, b] + dth
                        ths[a, b] = th[a, b] + h * dth
            o4 = _stage(adaptive, False, g0, g1, gam, R, h * o3[0], h * o3[1], h * o3[2],
                        w0 + h * o3[3], w1 + h * o3[4], w2 + h * o3[5], ths, tte, 1.0, d0, d1, d2)  # fmt: skip

            # metrics at the step start (stage 1), docs/model.md §6; Omega - Omega_d with the phase's Omega_d
            tau_sq = o1[6] * o1[6] + o1[7] * o1[7] + o1[8] * o1[8]
            we_sq = o1[9] * o1[9] + o1[10] * o1[10] + o1[11] * o1[11]
            u0, u1, u2 = w0 - v0, w1 - v1, w2 - v2
            sums[phase] += we_sq
            sums[3 + phase] += tau_sq
            sums[6 + phase] += o1[12] * o1[12]
            sums[9 + phase] = max(sums[9 + phase], sqrt(tau_sq))
            sums[12 + phase] = max(sums[12 + phase], o1[12])
            sums[15] += u0 * u0 + u1 * u1 + u2 * u2

            # x_{k+1} = x_k + dt/6 (k1 + 2 (k2 + k3) + k4)
            p0 = c6 * (o1[0] + 2.0 * (o2[0] + o3[0]) + o4[0])
            p1 = c6 * (o1[1] + 2.0 * (o2[1] + o3[1]) + o4[1])
            p2 = c6 * (o1[2] + 2.0 * (o2[2] + o3[2]) + o4[2])
            R = _mul_add(R, _exp_minus_identity(p0, p1, p2))
            w0 = w0 + c6 * (o1[3] + 2.0 * (o2[3] + o3[3]) + o4[3])
            w1 = w1 + c6 * (o1[4] + 2.0 * (o2[4] + o3[4]) + o4[4])
            w2 = w2 + c6 * (o1[5] + 2.0 * (o2[5] + o3[5]) + o4[5])
            if adaptive:
                for a in range(9):
                    for b in range(3):
                        th[a, b] = th[a, b] + c6 * (a1[a, b] + 2.0 * a23[a, b] - o4[13 + a] * o4[22 + b])
            total = R[0] + R[1] + R[2] + R[3] + R[4] + R[5] + R[6] + R[7] + R[8] + w0 + w1 + w2
            finite = finite and isfinite(total)
    for m in range(9):
        Rio[m // 3, m % 3] = R[m]
    wio[0], wio[1], wio[2] = w0, w1, w2
    sums[16] = 1.0 if finite else 0.0


@numba.njit(cache=True, parallel=True)
def _batch(n_groups, adaptive, keys, n_steps, h, k1, k2, g0, g1, gam, J0, J1, J2, tau_J, n, amp, freq, nstd,
           R, Omega, Theta, sums):  # fmt: skip
    """Split the batch into n_groups groups (prange, one per thread); each advances its
    trajectories one after the other, with its own scratch arrays."""
    B = R.shape[0]
    for g in numba.prange(n_groups):
        etab = np.empty((CHUNK, 3))
        ubuf = np.empty(3 * CHUNK)
        ths = np.empty((9, 3))
        a1 = np.empty((9, 3))
        a23 = np.empty((9, 3))
        for b in range(g * B // n_groups, (g + 1) * B // n_groups):
            _trajectory(adaptive, keys[b, 0], keys[b, 1], n_steps, h, k1, k2, g0, g1, gam, J0[b], J1[b], J2[b],
                        tau_J[b], n[b], amp[b], freq[b], nstd[b], etab, ubuf, R[b], Omega[b], Theta[b], ths, a1, a23,
                        sums[b])  # fmt: skip


def _fields(samples) -> dict:
    """{field: float64 or seed array} of a RolloutParams-like record or mapping, checked for shape."""
    as_dict = samples._asdict() if hasattr(samples, "_asdict") else samples if isinstance(samples, Mapping) else None
    if as_dict is None or not set(FIELDS) <= set(as_dict):
        raise ValueError(f"samples must hold the fields {', '.join(FIELDS)} (a RolloutParams or a mapping)")
    out = {name: np.ascontiguousarray(as_dict[name], np.float64) for name in FIELDS if name != "seed"}
    out["seed"] = np.asarray(as_dict["seed"]).reshape(-1)
    B = out["tau_J"].shape[0] if out["tau_J"].ndim == 1 else -1
    shapes = {"J0": (3, 3), "J1": (3, 3), "J2": (3, 3), "R0": (3, 3), "Omega0": (3,)}
    for name, value in out.items():
        if value.shape != (B, *shapes.get(name, ())):
            raise ValueError(f"samples.{name} must have shape {(B, *shapes.get(name, ()))}, got {value.shape}")
    return out


def simulate_dispersed(controller: str, samples, n_steps: int, *, dt: float = 0.01, gains=None) -> dict:
    """Fly B trajectories, each in its own scenario (module docstring), for n_steps steps of dt [s].

    controller: "pd" (gains k_R, k_Omega) or "adaptive" (K_r, K_w, Gamma scalar or (9,)
    diagonal); gains: a mapping or a NamedTuple (so3jax's PDGains, AdaptiveGains) of
    those names, missing ones the paper's. samples: so3jax's RolloutParams (numpy, leading
    axis B) or a mapping of its fields: J0, J1, J2 (B, 3, 3) [kg m^2], tau_J [s], n [rad/s],
    amplitude [N m], frequency [rad/s], noise_std [N m], seed (B,); R0 (B, 3, 3), Omega0
    (B, 3) [rad/s].

    Returns numpy arrays under ``so3jax.missions.batched.sample_metrics``' names: rmse,
    rmse_unrotated [rad/s], effort [N^2 m^2 s], max_torque [N m], orthogonality_error
    (|R^T R - I|_F at the end), diverged (bool) (B,); rmse_phase, effort_phase,
    max_torque_phase, rms_angle_phase, max_angle_phase [rad] (B, 3).
    """
    p = _fields(samples)
    seeds = [int(s) for s in p["seed"]]
    if hasattr(gains, "_asdict"):
        gains = gains._asdict()
    setup = prepare(controller, n_steps, seeds, dt, gains, None, np.float64, "draw", allow_draw=True)
    if setup.n_steps > 2**32:
        raise ValueError(f"the noise draw folds the step k in as a uint32: n_steps must be <= 2**32, got {n_steps}")
    keys = key_array(seeds)
    B = len(seeds)
    g = setup.gains
    if setup.adaptive:
        g0, g1, gam = g["K_r"], g["K_w"], g["Gamma"]
    else:
        g0, g1, gam = g["k_R"], g["k_Omega"], np.zeros(9)
    R = p["R0"].copy()
    Omega = p["Omega0"].copy()
    Theta = np.zeros((B, 9, 3))
    Theta[:, 6:, :] = np.eye(3)  # Theta(J_hat = I)
    sums = np.zeros((B, N_SUMS))
    n_groups = min(B, numba.get_num_threads())
    _batch(n_groups, setup.adaptive, keys, setup.n_steps, setup.dt, setup.k1, setup.k2, g0, g1, gam, p["J0"],
           p["J1"], p["J2"], p["tau_J"], p["n"], p["amplitude"], p["frequency"], p["noise_std"], R, Omega, Theta,
           sums)  # fmt: skip
    return _metrics(sums, setup, R)


def _metrics(sums, setup, R) -> dict:
    """The metrics of docs/model.md §6 from the per-trajectory sums, as so3jax.sim.metrics.finalize forms them."""
    n = setup.n_steps
    counts = np.array([min(n, setup.k1), max(0, min(n, setup.k2) - setup.k1), max(0, n - setup.k2)], np.float64)
    per_step = np.maximum(counts, 1.0)
    we2, tau2, ang2 = sums[:, 0:3], sums[:, 3:6], sums[:, 6:9]
    G = np.einsum("bki,bkj->bij", R, R) - np.eye(3)
    with np.errstate(invalid="ignore"):
        return {
            "diverged": ~((sums[:, 16] == 1.0) & np.all(np.isfinite(R), axis=(1, 2))),
            "effort": tau2.sum(axis=1) * setup.dt,
            "effort_phase": tau2 * setup.dt,
            "max_angle_phase": sums[:, 12:15].copy(),
            "max_torque": sums[:, 9:12].max(axis=1),
            "max_torque_phase": sums[:, 9:12].copy(),
            "orthogonality_error": np.sqrt(np.sum(G * G, axis=(1, 2))),
            "rms_angle_phase": np.sqrt(ang2 / per_step),
            "rmse": np.sqrt(we2.sum(axis=1) / n),
            "rmse_phase": np.sqrt(we2 / per_step),
            "rmse_unrotated": np.sqrt(sums[:, 15] / n),
        }
