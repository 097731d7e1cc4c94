"""The equation-error method in its momentum-integral form.

The spacecraft's angular momentum in the inertial frame, H = R (J Omega + h), h = G_s J_s
Omega_w the wheels' momentum relative to the body, changes only by the external torque
(the motor torques are internal). Over an interval [t_a, t_b] between star-tracker samples,
with the gyro's rate omega_m = Omega + b and a disturbance torque d(t) fixed in the body and
polynomial in time:

    R_b (J (omega_b - b) + h_b) - R_a (J (omega_a - b) + h_a) = sum_p (int_a^b R(t) s(t)^p dt) d_p

with s = (t - t_0) / (t_N - t_0). Linear in the inertia's entries theta, in c = J b and in
the d_p, so no rate is differentiated from noisy gyro data. Its regressors hold measured
rates and attitudes, whose noise also enters the residual: least squares would be biased
toward zero (errors in variables). The instruments are the same regressors built from the
samples one tick later: their noise is independent of the endpoints' (white gyro and
star-tracker noise), while the state they read is within a tick of the endpoints', so
they stay strongly correlated with the regressors. Instrumental variables rather than
total least squares, because TLS assumes equal independent noise in every column, and here
the columns mix rates, attitudes, times and exact wheel speeds.

A rate-integrating gyro's reading m_k, its increment over the interval Delta_k ending at
t_k divided by Delta_k, is the rate at the interval's midpoint to O(Delta_k^2): the equation
then reads each sample at t_k - Delta_k / 2, with the attitude carried back by the reading,
R_k exp(-hat(m_k) Delta_k / 2) (the bias's share, Delta_k b / 2, is left out: ~1e-5 rad) and
the wheels' momentum interpolated (:func:`at_midpoints`).

The instrumental-variable estimate is computed as two-stage least squares, then refined
over the log-Cholesky parameters of J (:mod:`so3jax.jobs.identify.inertia`), so that the
estimate is physical by construction; where the unconstrained one is physical, both agree.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.core import so3
from so3jax.jobs.identify import fit, inertia


def blocks(t, valid, interval: float) -> list[np.ndarray]:
    """The star-tracker samples in consecutive blocks of ``interval`` [s] (a partial last
    block dropped), each block's indices in time order."""
    idx = np.nonzero(valid)[0]
    label = np.floor((t[idx] - t[idx[0]]) / interval + 1e-9).astype(int)
    groups = [idx[label == g] for g in range(label.max() + 1)]
    if len(groups) > 1 and t[groups[-1][-1]] - t[groups[-1][0]] < 0.5 * interval:
        groups = groups[:-1]
    return [g for g in groups if len(g) >= 2]


def normalized_time(t):
    """s = (t - t_0) / (t_N - t_0), the disturbance polynomial's variable."""
    return (t - t[0]) / (t[-1] - t[0])


def at_midpoints(tm):
    """Telemetry of a rate-integrating gyro read at its intervals' midpoints (the module's
    docstring); the first row, with no wheel momentum before it, is left out."""
    if tm.gyro_output != "increment":
        return tm
    half = 0.5 * tm.gyro_interval[1:]
    back = np.asarray(so3.exp(jnp.asarray(-(tm.gyro[1:] * half[:, None]).T)))  # (3, 3, N - 1)
    R = np.einsum("nij,jkn->nik", tm.R[1:], back)
    frac = (half / np.diff(tm.t))[:, None]
    h = tm.wheel_momentum[1:] - frac * np.diff(tm.wheel_momentum, axis=0)
    return tm._replace(t=tm.t[1:] - half, gyro=tm.gyro[1:], R=R, valid=tm.valid[1:], wheel_momentum=h,
                       gyro_output="rate", gyro_interval=None)


def _per_sample(tm, degree: int) -> dict:
    """What the momentum equation averages, at every sample: R M(omega_m) (the regressor
    of theta), R, R h, and int_{t_0}^{t} R s^p dt (trapezoid over the star-tracker
    samples; rows without a sample are never read)."""
    valid = np.nonzero(tm.valid)[0]
    tv, Rv, sv = tm.t[valid], tm.R[valid], normalized_time(tm.t)[valid]
    cum = []
    for p in range(degree + 1):
        f = Rv * (sv ** p)[:, None, None]
        seg = 0.5 * (f[1:] + f[:-1]) * np.diff(tv)[:, None, None]
        at_valid = np.concatenate([np.zeros((1, 3, 3)), np.cumsum(seg, 0)])
        full = np.zeros((len(tm.t), 3, 3))
        full[valid] = at_valid
        cum.append(full)
    return {"RM": np.einsum("nij,njk->nik", tm.R, np.asarray(inertia.rate_matrix(tm.gyro))), "R": tm.R,
            "Rh": np.einsum("nij,nj->ni", tm.R, tm.wheel_momentum), "cum": cum}


def _rows(q: dict, sets, bias: bool):
    """(X (3 n, k), y (3 n,)): the momentum equation between consecutive blocks, each
    block's terms (:func:`_per_sample`) averaged over its samples ``sets``."""
    mean = lambda x: np.stack([x[i].mean(0) for i in sets])
    diff = lambda x: x[1:] - x[:-1]
    parts = [diff(mean(q["RM"]))]
    if bias:
        parts.append(-diff(mean(q["R"])))
    parts += [-diff(mean(c)) for c in q["cum"]]
    X = np.concatenate(parts, axis=2)
    return X.reshape(-1, X.shape[2]), -diff(mean(q["Rh"])).reshape(-1)


def identify(tm, *, bias: bool = True, degree: int = 1, interval: float = 5.0, instruments: bool = True) -> dict:
    """The fit: {"J", "theta_cov", "bias", "bias_cov", "disturbance", "disturbance_cov",
    "residual_rms", "residuals" ({"t": s, name: (n, 3)}), "intervals", "iterations",
    "converged"}; degree: the disturbance polynomial's (-1: no disturbance torque). Each
    block's even-numbered samples form the equation, its odd-numbered ones the
    instruments (``instruments=False``: every sample in the equation, ordinary least
    squares)."""
    tm = at_midpoints(tm)
    groups = blocks(tm.t, tm.valid, interval)
    k = 6 + (3 if bias else 0) + 3 * (degree + 1)
    if len(groups) - 1 < k // 3 + 1:
        raise ValueError(f"the telemetry gives {max(len(groups) - 1, 0)} intervals of {interval:g} s; "
                         f"at least {k // 3 + 1} are needed for {k} unknowns: a longer record or a shorter --interval")
    q = _per_sample(tm, degree)
    if instruments:
        X, y = _rows(q, [g[0::2] for g in groups], bias)
        Z = _rows(q, [g[1::2] for g in groups], bias)[0]
    else:
        X, y = _rows(q, groups, bias)
        Z = X
    # two-stage least squares: the regressors projected on the instruments' span
    Q, _ = np.linalg.qr(Z)
    Xh = Q @ (Q.T @ X)
    beta = np.linalg.lstsq(Xh, y, rcond=None)[0]
    J0 = np.asarray(inertia.from_entries(beta[:6]))
    start = J0 if inertia.is_physical(J0) else inertia.nearest_physical(J0)
    b0 = np.linalg.solve(start, beta[6:9]) if bias else np.zeros(0)
    p0 = np.concatenate([inertia.to_params(start), b0, beta[6 + len(b0):]])

    solution = fit.levenberg_marquardt(lambda p: _evaluate(p, Xh, y, bias), lambda p: _cost(p, Xh, y, bias), p0)
    # the residual's scale from the structural equation (the measured regressors), not the projected one
    structural = X @ np.asarray(_coefficients(jnp.asarray(solution.p), bias)) - y
    scaled = solution._replace(cost=0.5 * float(structural @ structural))
    ends = np.array([tm.t[g[-1]] for g in groups[1:]])
    return fit.estimate(solution.p, fit.covariance(scaled, len(y)), bias, degree, solution,
                        residual_rms=float(np.sqrt(np.mean(structural ** 2))), intervals=len(groups) - 1,
                        residuals={"t": ends, "momentum equation [N m s]": structural.reshape(-1, 3)})


def _coefficients(p, bias: bool):
    """(theta, [c = J b], d) of p = (log-Cholesky, [b], d)."""
    J = inertia.from_params(p[:6])
    parts = [inertia.entries(J)]
    if bias:
        parts.append(J @ p[6:9])
    parts.append(p[6 + (3 if bias else 0):])
    return jnp.concatenate(parts)


@partial(jax.jit, static_argnames="bias")
def _cost(p, Xh, y, bias):
    r = Xh @ _coefficients(p, bias) - y
    return 0.5 * r @ r


@partial(jax.jit, static_argnames="bias")
def _evaluate(p, Xh, y, bias):
    """(cost, A^T A, A^T r) of the projected equation's residual r = Xh beta(p) - y."""
    residual = lambda q: Xh @ _coefficients(q, bias) - y
    r, A = residual(p), jax.jacfwd(residual)(p)
    return 0.5 * r @ r, A.T @ A, A.T @ r
