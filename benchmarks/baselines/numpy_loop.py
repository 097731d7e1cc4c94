"""Plain NumPy baseline of the paper's closed loop (docs/model.md §1-§6).

A Python loop over time steps; every operation inside a step is vectorized over a
batch axis B (R: (B, 3, 3), Omega: (B, 3), Theta_hat: (B, 9, 3)). The integrator is
RK4 in local coordinates (docs/model.md §5): R = R_k exp(hat psi), psi' = J_r^{-1}(psi) Omega,
with Omega and Theta_hat integrated alongside and the controller evaluated at every
stage. Units: SI (s, rad, rad/s, N m, kg m^2).

This module also holds the paper's scenario data and the argument handling that the
Numba baseline shares (:func:`prepare`, :func:`finalize`); the dynamics and control
arithmetic of the two baselines are written independently.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from benchmarks.baselines.noise import paper_noise_batch

# --- The paper's scenario (docs/model.md §4) -------------------------------------------------

MU_EARTH = 3.986004418e14  # m^3 / s^2
ORBIT_RADIUS = 6378137.0 + 500000.0  # m
ORBITAL_RATE = float(np.sqrt(MU_EARTH / ORBIT_RADIUS**3))  # n, rad/s
OMEGA_D0 = ORBITAL_RATE * np.array([1.0, -10.0, 2.0])  # rad/s, for t < T_DOCK
J0 = np.array([[625.0, 5.5, 3.0], [5.5, 350.0, 4.0], [3.0, 4.0, 1000.0]])  # kg m^2
J1 = 2.0 * J0
J2 = np.array([[3945.4, 66.7, 12.8], [66.7, 3663.5, 160.0], [12.8, 160.0, 2011.8]])
T_GROW = 500.0  # s, start of the inertia growth J0 -> J1
T_DOCK = 2600.0  # s, docking: J = J2, Omega_d = 0
TAU_J = 300.0  # s, time constant of the growth
DIST_AMPLITUDE = 0.1  # N m, sinusoid 0.1 sin(0.001 t) on each axis
DIST_FREQUENCY = 0.001  # rad/s
NOISE_STD = 0.025  # N m

PAPER_GAINS = {
    "pd": {"k_R": 0.5714, "k_Omega": 25.0},  # N m/rad, N m s/rad
    "adaptive": {"K_r": 0.005, "K_w": 75.0, "Gamma": 1e8},  # 1/s, N m s/rad, Gamma
}

SMALL_ANGLE = 1e-2  # rad: below it exp/log/J_r^{-1} coefficients use their series


class Setup(NamedTuple):
    """Validated arguments of :func:`simulate`, in the simulation dtype."""

    adaptive: bool
    n_steps: int
    dt: float
    k1: int  # first step of phase 1 (inertia growth)
    k2: int  # first step of phase 2 (after docking)
    gains: dict  # floats; "Gamma" a (9,) diagonal
    scale: np.ndarray  # (B,) inertia scale
    noise: np.ndarray  # (B, n_steps, 3) eta; (B, 1, 3) zeros if the kernel draws it (noise="draw")


def prepare(controller, n_steps, seeds, dt, gains, inertia_scale, dtype, noise, allow_draw=False) -> Setup:
    """Check the arguments of ``simulate`` and fill in defaults (docs/model.md §4). allow_draw: the
    caller draws eta itself when noise == "draw" (numba_loop)."""
    if controller not in PAPER_GAINS:
        raise ValueError(f"controller must be 'pd' or 'adaptive', got {controller!r}")
    dtype = np.dtype(dtype)
    if dtype not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ValueError(f"dtype must be float32 or float64, got {dtype}")
    n_steps = int(n_steps)
    if n_steps < 1:
        raise ValueError(f"n_steps must be >= 1, got {n_steps}")
    dt = float(dt)
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be positive and finite, got {dt}")
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ValueError("seeds must not be empty")
    batch = len(seeds)

    merged = dict(PAPER_GAINS[controller])
    unknown = set(gains or {}) - set(merged)
    if unknown:
        raise ValueError(f"unknown gains for {controller!r}: {sorted(unknown)}")
    merged.update(gains or {})
    for name, value in merged.items():
        arr = np.asarray(value, dtype=np.float64)
        shape_ok = arr.ndim == 0 or (name == "Gamma" and arr.shape == (9,))
        if not shape_ok or not np.all(np.isfinite(arr)) or not np.all(arr > 0):
            raise ValueError(f"gain {name} must be positive and finite (Gamma: scalar or (9,)), got {value!r}")
        merged[name] = np.broadcast_to(arr, (9,)).copy() if name == "Gamma" else float(arr)

    scale = np.ones(batch) if inertia_scale is None else np.asarray(inertia_scale, np.float64)
    if scale.shape != (batch,) or not np.all(np.isfinite(scale)) or not np.all(scale > 0):
        raise ValueError(f"inertia_scale must be a positive finite array of shape ({batch},)")

    draw = isinstance(noise, str)
    if draw and not (allow_draw and noise == "draw"):
        raise ValueError(f"noise must be None or an array (numba_loop also takes 'draw'), got {noise!r}")
    if noise is None:
        noise = paper_noise_batch(seeds, n_steps, dtype)
    noise = np.zeros((batch, 1, 3), dtype) if draw else np.ascontiguousarray(noise, dtype=dtype)
    if not draw and noise.shape != (batch, n_steps, 3):
        raise ValueError(f"noise must have shape ({batch}, {n_steps}, 3), got {noise.shape}")

    k1, k2 = round(T_GROW / dt), round(T_DOCK / dt)
    return Setup(controller == "adaptive", n_steps, dt, k1, k2, merged, scale.astype(dtype), noise)


def phase_of(k: int, k1: int, k2: int) -> int:
    """Phase of step k: 0 before the growth, 1 during it, 2 after docking (docs/model.md §5)."""
    return 0 if k < k1 else (1 if k < k2 else 2)


def finalize(setup: Setup, sums: dict, R, Omega, Theta) -> dict:
    """Metrics of docs/model.md §6 from per-phase sums over the step starts k = 0..N-1.

    ``sums`` holds (B, 3) arrays per phase: ``we2`` = sum |Omega_e|^2, ``tau2`` = sum
    |tau|^2, ``ang2`` = sum theta^2, ``tau_max``, ``ang_max``; and (B,) ``wu2`` = sum
    |Omega - Omega_d|^2. Phases with no steps get NaN RMS values and 0 sums.
    """
    n = setup.n_steps
    counts = np.array([min(n, setup.k1), max(0, min(n, setup.k2) - setup.k1), max(0, n - setup.k2)], R.dtype)

    def per_step(total):
        return np.where(counts > 0, total / np.maximum(counts, 1), np.nan)

    finite = np.all(np.isfinite(R), axis=(1, 2)) & np.all(np.isfinite(Omega), axis=1)
    if Theta is not None:
        finite &= np.all(np.isfinite(Theta), axis=(1, 2))
    return {
        "rmse": np.sqrt(sums["we2"].sum(axis=1) / n),  # rad/s
        "rmse_unrotated": np.sqrt(sums["wu2"] / n),  # rad/s
        "effort": sums["tau2"].sum(axis=1) * setup.dt,  # N^2 m^2 s
        "rmse_phase": np.sqrt(per_step(sums["we2"])),
        "effort_phase": sums["tau2"] * setup.dt,
        "max_torque": sums["tau_max"].max(axis=1),  # N m
        "max_torque_phase": np.where(counts > 0, sums["tau_max"], np.nan),
        "angle_rms_phase": np.sqrt(per_step(sums["ang2"])),  # rad
        "angle_max_phase": np.where(counts > 0, sums["ang_max"], np.nan),  # rad
        "R": R,
        "Omega": Omega,
        "Theta": Theta,
        "diverged": ~finite,
    }


# --- SO(3) helpers, batched over leading axes ---------------------------------------


def hat(v):
    """(..., 3) -> (..., 3, 3) skew matrix, hat(a) b = a x b."""
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    o = np.zeros_like(x)
    return np.stack([np.stack([o, -z, y], -1), np.stack([z, o, -x], -1), np.stack([-y, x, o], -1)], -2)


def cross(a, b):
    """a x b over the last axis (3); faster than np.cross on small arrays."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], -1)


def skew_vee(M):
    """(M - M^T)^vee / 2 for (..., 3, 3) M."""
    return 0.5 * np.stack([M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0], M[..., 1, 0] - M[..., 0, 1]], -1)


def exp_minus_identity(w):
    """exp(hat w) - I = a hat(w) + b hat(w)^2, a = sin t / t, b = (1 - cos t) / t^2, t = |w|."""
    t2 = np.sum(w * w, axis=-1)
    small = t2 < SMALL_ANGLE**2
    t = np.sqrt(np.where(small, 1.0, t2))
    a = np.where(small, 1.0 - t2 / 6.0 * (1.0 - t2 / 20.0 * (1.0 - t2 / 42.0)), np.sin(t) / t)
    half = np.sin(0.5 * t) / (0.5 * t)
    b = np.where(small, 0.5 - t2 / 24.0 * (1.0 - t2 / 30.0 * (1.0 - t2 / 56.0)), 0.5 * half * half)
    W = hat(w)
    return a[..., None, None] * W + b[..., None, None] * (W @ W)


def log_vee(R):
    """e = log(R)^vee (..., 3) and theta = |e|, from v = (R - R^T)^vee / 2 and tr R.

    theta = atan2(|v|, (tr R - 1) / 2); e = (theta / |v|) v, with the series of
    asin(s)/s for |v| = s < SMALL_ANGLE (valid while cos theta > 0). Loses accuracy
    only within ~1e-8 rad of theta = pi, which the paper's scenario never approaches.
    """
    v = skew_vee(R)
    s2 = np.sum(v * v, axis=-1)
    s = np.sqrt(s2)
    c = 0.5 * (R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2] - 1.0)
    theta = np.arctan2(s, c)
    series = (s < SMALL_ANGLE) & (c > 0)
    f = np.where(
        series,
        1.0 + s2 / 6.0 + 3.0 * s2 * s2 / 40.0 + 5.0 * s2 * s2 * s2 / 112.0,
        theta / np.where(series, 1.0, s),
    )
    return f[..., None] * v, theta


def jr_inv_apply(e, w):
    """J_r^{-1}(e) w = w + e x w / 2 + g(theta) e x (e x w), g = 1/theta^2 - cot(theta/2)/(2 theta)
    (docs/model.md §3.2)."""
    t2 = np.sum(e * e, axis=-1)
    small = t2 < SMALL_ANGLE**2
    t = np.sqrt(np.where(small, 1.0, t2))
    g = np.where(small, 1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0, 1.0 / (t * t) - 0.5 / (t * np.tan(0.5 * t)))
    exw = cross(e, w)
    return w + 0.5 * exw + g[..., None] * cross(e, exw)


# --- The scenario's time laws (docs/model.md §2, §4) -----------------------------------------


def desired_attitude(t: float) -> np.ndarray:
    """R_d(t) = exp(hat(Omega_d0) min(t, T_DOCK)) (3, 3)."""
    return np.eye(3) + exp_minus_identity(OMEGA_D0 * min(t, T_DOCK))


def inertia(t: float, phase: int) -> np.ndarray:
    """True inertia J(t) (3, 3) [kg m^2] under the law of ``phase`` (docs/model.md §4)."""
    if phase == 0:
        return J0
    if phase == 1:
        return J1 - (J1 - J0) * np.exp(-(t - T_GROW) / TAU_J)
    return J2


# --- The closed loop ------------------------------------------------------------------


def _stage(setup, R_k, psi, Omega, Theta, t, phase, d):
    """Derivatives (psi', Omega', Theta_hat') at one RK4 stage, and the signals metrics need.

    The controller sees R = R_k exp(hat psi) and the stage time t; the plant uses
    J(t) (docs/model.md §1) through a 3x3 solve. Returns (dpsi, dOmega, dTheta, tau, Omega_e, theta_e).
    """
    dtype = Omega.dtype
    g = setup.gains
    R = R_k + R_k @ exp_minus_identity(psi)
    R_d = desired_attitude(t).astype(dtype)
    Omega_d = (OMEGA_D0 if phase < 2 else np.zeros(3)).astype(dtype)
    R_e = R_d.T @ R  # (B, 3, 3)
    Omega_r = np.einsum("bji,j->bi", R, R_d @ Omega_d)  # R^T R_d Omega_d
    Omega_e = Omega - Omega_r
    Omega_x_Omega_r = cross(Omega, Omega_r)
    if setup.adaptive:  # docs/model.md §3.2 with J_hat = I and Omega_d' = 0
        e, theta_e = log_vee(R_e)
        z = Omega - (-g["K_r"] * e + Omega_r)
        beta_dot = -g["K_r"] * jr_inv_apply(e, Omega_e) - Omega_x_Omega_r
        x, y, w = Omega[:, 0], Omega[:, 1], Omega[:, 2]
        Phi = np.concatenate([np.stack([y * w, w * x, x * y, x * x, y * y, w * w], -1), beta_dot], -1)
        tau = -g["K_r"] * e - g["K_w"] * z + np.einsum("bij,bi->bj", Theta, Phi)
        dTheta = -(g["Gamma"].astype(dtype) * Phi)[:, :, None] * z[:, None, :]
    else:  # docs/model.md §3.1 with J_hat = I (Omega x J_hat Omega = 0) and Omega_d' = 0
        theta_e = log_vee(R_e)[1]
        tau = -g["k_R"] * skew_vee(R_e) - g["k_Omega"] * Omega_e - Omega_x_Omega_r
        dTheta = None
    J = inertia(t, phase).astype(dtype)
    J_Omega = setup.scale[:, None] * (Omega @ J.T)
    rhs = -cross(Omega, J_Omega) + tau + d
    dOmega = np.linalg.solve(J, rhs.T).T / setup.scale[:, None]
    return jr_inv_apply(psi, Omega), dOmega, dTheta, tau, Omega_e, theta_e


def _step(setup, k, R, Omega, Theta, sums):
    """One RK4 step from t_k = k dt (docs/model.md §5), adding the step-start metrics to sums (§6).

    Returns (R, Omega, Theta) at t_{k+1}; Theta is None for PD.
    """
    h = setup.dt
    phase = phase_of(k, setup.k1, setup.k2)
    t = k * h
    d = DIST_AMPLITUDE * float(np.sin(DIST_FREQUENCY * t)) + NOISE_STD * setup.noise[:, k, :]

    def advanced(X, dX, c):
        return None if X is None else X + c * h * dX

    zero = np.zeros_like(Omega)
    dp1, dw1, dT1, tau, Omega_e, theta_e = _stage(setup, R, zero, Omega, Theta, t, phase, d)
    Om2, Th2 = advanced(Omega, dw1, 0.5), advanced(Theta, dT1, 0.5)
    dp2, dw2, dT2 = _stage(setup, R, 0.5 * h * dp1, Om2, Th2, t + 0.5 * h, phase, d)[:3]
    Om3, Th3 = advanced(Omega, dw2, 0.5), advanced(Theta, dT2, 0.5)
    dp3, dw3, dT3 = _stage(setup, R, 0.5 * h * dp2, Om3, Th3, t + 0.5 * h, phase, d)[:3]
    Om4, Th4 = advanced(Omega, dw3, 1.0), advanced(Theta, dT3, 1.0)
    dp4, dw4, dT4 = _stage(setup, R, h * dp3, Om4, Th4, t + 1.0 * h, phase, d)[:3]

    Omega_d = (OMEGA_D0 if phase < 2 else np.zeros(3)).astype(Omega.dtype)
    tau2 = np.sum(tau * tau, axis=1)
    sums["we2"][:, phase] += np.sum(Omega_e * Omega_e, axis=1)
    sums["wu2"] += np.sum((Omega - Omega_d) ** 2, axis=1)
    sums["tau2"][:, phase] += tau2
    sums["ang2"][:, phase] += theta_e * theta_e
    sums["tau_max"][:, phase] = np.maximum(sums["tau_max"][:, phase], np.sqrt(tau2))
    sums["ang_max"][:, phase] = np.maximum(sums["ang_max"][:, phase], theta_e)

    psi = h / 6.0 * (dp1 + 2.0 * dp2 + 2.0 * dp3 + dp4)
    R = R + R @ exp_minus_identity(psi)
    Omega = Omega + h / 6.0 * (dw1 + 2.0 * dw2 + 2.0 * dw3 + dw4)
    if Theta is not None:
        Theta = Theta + h / 6.0 * (dT1 + 2.0 * dT2 + 2.0 * dT3 + dT4)
    return R, Omega, Theta


def simulate(
    controller: str,
    n_steps: int,
    seeds: Sequence[int],
    *,
    dt: float = 0.01,
    gains: dict | None = None,
    inertia_scale: np.ndarray | None = None,
    dtype=np.float64,
    noise: np.ndarray | None = None,
) -> dict:
    """Run the paper's scenario (docs/model.md §4) for a batch of len(seeds) trajectories.

    controller: "pd" (gains k_R, k_Omega) or "adaptive" (K_r, K_w, Gamma scalar or
    (9,) diagonal); missing gains take the paper's values. dt [s]; n_steps steps from
    t = 0. inertia_scale (B,) multiplies J0, J1, J2 per trajectory. noise (B, n_steps, 3)
    replaces the eta_k drawn from the seeds (pass it to keep the draw out of timings).

    Returns numpy arrays: rmse, rmse_unrotated [rad/s], effort [N^2 m^2 s],
    max_torque [N m] (B,); rmse_phase, effort_phase, max_torque_phase,
    angle_rms_phase, angle_max_phase [rad] (B, 3); final R (B, 3, 3), Omega (B, 3),
    Theta (B, 9, 3) or None for "pd"; diverged (B,) bool (non-finite final state).
    """
    setup = prepare(controller, n_steps, seeds, dt, gains, inertia_scale, dtype, noise)
    dtype = setup.noise.dtype
    B = setup.noise.shape[0]
    R = np.broadcast_to(np.eye(3, dtype=dtype), (B, 3, 3)).copy()
    Omega = np.zeros((B, 3), dtype)
    Theta = None
    if setup.adaptive:  # Theta(J_hat = I): zeros for the monomials, then I
        Theta = np.zeros((B, 9, 3), dtype)
        Theta[:, 6:, :] = np.eye(3, dtype=dtype)
    sums = {key: np.zeros((B, 3), dtype) for key in ("we2", "tau2", "ang2", "tau_max", "ang_max")}
    sums["wu2"] = np.zeros(B, dtype)
    with np.errstate(all="ignore"):  # a diverging run is flagged, not warned about
        for k in range(setup.n_steps):
            R, Omega, Theta = _step(setup, k, R, Omega, Theta, sums)
    return finalize(setup, sums, R, Omega, Theta)
