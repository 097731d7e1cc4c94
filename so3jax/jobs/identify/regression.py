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
Before the refinement, the unconstrained estimate must determine J
(:func:`so3jax.jobs.identify.fit.spread` below ``fit.UNDETERMINED``): otherwise the
constraint would hold a confident-looking estimate at the edge of the physical set (near
zero, or near the wheels' own spin inertia) and the identification is refused
(:func:`check`, which the command calls before it writes anything).
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.core import so3
from so3jax.jobs.identify import fit, inertia


def check_interval(t, valid, interval: float) -> None:
    """ValueError unless ``interval`` [s] spans at least two star-tracker samples at their
    median spacing: a block needs one sample for the equation and one for the instruments.
    So there are at most half as many blocks as samples, and the work grows with the record
    only."""
    if np.count_nonzero(valid) < 2:
        raise ValueError("the telemetry has fewer than two star-tracker samples")
    spacing = float(np.median(np.diff(t[valid])))
    if not interval >= 2.0 * spacing * (1 - 1e-9):  # (the midpoints' spacing is rounded)
        raise ValueError(f"--interval {interval:g} s is shorter than two star-tracker samples (their median spacing "
                         f"is {spacing:g} s); a block needs two, one for the equation and one for the instruments")


def blocks(t, valid, interval: float) -> list[np.ndarray]:
    """The star-tracker samples in consecutive blocks of ``interval`` [s] (a partial last
    block dropped), each block's indices in time order; blocks with fewer than two samples
    are left out."""
    idx = np.nonzero(valid)[0]
    label = np.floor((t[idx] - t[idx[0]]) / interval + 1e-9)
    starts = np.flatnonzero(np.diff(label, prepend=-1.0))  # labels ascend: each block is one run
    groups = np.split(idx, starts[1:])
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


def unknowns(bias: bool, degree: int) -> int:
    """k: J's 6 entries, [c = J b], and 3 per disturbance coefficient."""
    return 6 + (3 if bias else 0) + 3 * (degree + 1)


def equation(tm, bias: bool, degree: int, interval: float, instruments: bool = True):
    """(X, Z, y, ends): the momentum equation's rows (:func:`_rows`) between blocks of
    ``interval`` [s] of telemetry read at its rates' instants (:func:`at_midpoints`), three
    per block pair; Z the instruments' rows (``instruments=False``: Z = X), and the time [s]
    each row's later block ends."""
    tm = at_midpoints(tm)
    check_interval(tm.t, tm.valid, interval)
    groups = blocks(tm.t, tm.valid, interval)
    k = unknowns(bias, degree)
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
    return X, Z, y, np.array([tm.t[g[-1]] for g in groups[1:]])


def projected(X, Z):
    """Two-stage least squares' regressors: X projected on the span of the instruments Z."""
    Q, _ = np.linalg.qr(Z)
    return Q @ (Q.T @ X)


def system(tm, bias: bool, degree: int, interval: float, instruments: bool = True):
    """(X, Xh, y, ends): :func:`equation`'s rows with Xh the regressors X projected on the
    instruments' span (``instruments=False``: Xh = X)."""
    X, Z, y, ends = equation(tm, bias, degree, interval, instruments)
    return X, projected(X, Z), y, ends


SIGNIFICANCE = 1e-3  # the constant-inertia test's: the chance it warns on a constant inertia


def constancy(tm, *, bias: bool = True, degree: int = 1, interval: float = 5.0,
              significance: float = SIGNIFICANCE) -> dict:
    """The test of the constant-inertia hypothesis (docs/model.md §17.7), the same for both
    methods (on the momentum equation's linear instrumental-variable form, fast): the score
    (Lagrange multiplier) test of a change of J between the record's two halves. The
    equation's rows get 6 more unknowns, the change of J's entries from the second half's
    first block pair on (their regressors J's columns there, their instruments likewise),
    and W = u^T Xa (Xa^T Xa)^-1 Xa^T u / s^2, with Xa the augmented regressors projected on
    the instruments, u the structural residual of the constant-J fit and s^2 that of the
    changing-J fit per degree of freedom, is chi-square with 6 degrees of freedom where J is
    constant. {"tested": True, "statistic", "dof", "p_value", "significance", "rejected"
    (p_value < significance), "split_s" (the second half's first time [s])}; {"tested":
    False, "reason"} where a half has too few block pairs."""
    from scipy import stats  # here: only an identification needs it

    X, Z, y, ends = equation(tm, bias, degree, interval)
    pairs, k = len(ends), unknowns(bias, degree)
    first = pairs // 2
    if first < k // 3 + 1 or pairs - first < 6 // 3 + 1:
        return {"tested": False, "reason": f"the record gives {pairs} intervals of {interval:g} s; two halves need "
                                           f"{2 * (k // 3 + 1)} for {k} unknowns"}
    second = np.repeat(np.arange(pairs) >= first, 3)[:, None]  # the rows of the second half's block pairs
    Xa, Za = np.concatenate([X, X[:, :6] * second], 1), np.concatenate([Z, Z[:, :6] * second], 1)
    Q, _ = np.linalg.qr(Za)
    Xh, Xah = Q @ (Q.T @ X), Q @ (Q.T @ Xa)
    u = y - X @ np.linalg.lstsq(Xh, y, rcond=None)[0]  # constant J
    ua = y - Xa @ np.linalg.lstsq(Xah, y, rcond=None)[0]  # J changing between the halves
    dof = int(np.linalg.matrix_rank(Xah) - np.linalg.matrix_rank(Xh))
    s2 = ua @ ua / max(len(y) - Xa.shape[1], 1)
    g = Xah.T @ u
    W = float(g @ np.linalg.pinv(Xah.T @ Xah, hermitian=True) @ g / s2)
    p = float(stats.chi2.sf(W, dof))
    return {"tested": True, "statistic": W, "dof": dof, "p_value": p, "significance": significance,
            "rejected": p < significance, "split_s": float(ends[first - 1])}


def add_constancy(out: dict, tm, *, bias: bool, degree: int, interval: float) -> dict:
    """The fit ``out`` with its "constancy" (:func:`constancy`) and, where the test rejects
    a constant inertia, a warning."""
    test = out["constancy"] = constancy(tm, bias=bias, degree=degree, interval=interval)
    if test["tested"] and test["rejected"]:
        fit.add_warning(out, f"the telemetry does not fit one constant inertia: a change of J between the record's "
                             f"halves fits it beyond its noise (score statistic {test['statistic']:.4g}, {test['dof']} "
                             f"degrees of freedom, p = {test['p_value']:.2g} < {test['significance']:g}): the inertia "
                             "changes over the record, or the record breaks the model otherwise (a torque it leaves "
                             "out, thruster pulses, a disturbance torque fed back into the wheels by a closed loop), "
                             "and J is no one inertia's estimate")
    return out


def determined(X, Xh, y, wheel_inertia) -> np.ndarray:
    """The unconstrained instrumental-variable estimate beta of the system (:func:`system`),
    checked: ValueError where it does not determine J (its spread, :func:`so3jax.jobs.identify.fit.spread`,
    above ``fit.UNDETERMINED``). The 1 sigma of J's least-determined combination of entries
    is s / sigma_min, s^2 = |X beta - y|^2 / (n - k) and sigma_min the smallest singular
    value of J's columns of Xh with the other unknowns' (bias, disturbance) projected out."""
    if not np.any(y):
        raise ValueError("the telemetry records no momentum exchanged with wheels (no wheel_speed, or no change "
                         "in the wheels' momentum seen from the inertial frame): the data then fix J only up to a "
                         "common factor; a manoeuvre that drives the wheels determines it")
    beta = np.linalg.lstsq(Xh, y, rcond=None)[0]
    r = X @ beta - y
    s = np.sqrt(r @ r / max(len(y) - X.shape[1], 1))
    J_cols, other = Xh[:, :6], Xh[:, 6:]
    if other.shape[1]:
        J_cols = J_cols - other @ np.linalg.lstsq(other, J_cols, rcond=None)[0]
    sigma_min = np.linalg.svd(J_cols, compute_uv=False)[-1]
    std = s / sigma_min if sigma_min > 0 else np.inf
    J = np.asarray(inertia.from_entries(beta[:6]))
    relative = fit.spread(J, std, wheel_inertia)
    if not relative <= fit.UNDETERMINED:
        moment = np.linalg.eigvalsh(J - wheel_inertia)[0]
        raise ValueError(f"the telemetry does not determine the inertia: J less the wheels' spin inertia has the "
                         f"smallest principal moment {moment:.3g} kg m^2, and its least-determined combination of "
                         f"entries a 1 sigma of {std:.3g} kg m^2 (at most {fit.UNDETERMINED:.0%} of that moment); "
                         f"a manoeuvre whose wheels exchange momentum with the body about every axis")
    return beta


def check(tm, *, bias: bool = True, degree: int = 1, interval: float = 5.0) -> None:
    """ValueError where :func:`identify` would refuse the telemetry or options, before its fit."""
    determined(*system(tm, bias, degree, interval)[:3], tm.wheel_inertia)


def identify(tm, *, bias: bool = True, degree: int = 1, interval: float = 5.0, instruments: bool = True) -> dict:
    """The fit: {"J", "theta_cov", "bias", "bias_cov", "disturbance", "disturbance_cov",
    "residual_rms", "residuals" ({"t": s, name: (n, 3)}), "intervals", "iterations",
    "converged", "constancy" (:func:`constancy`), and "warning" where J is poorly determined
    or does not fit one constant inertia}; degree: the disturbance
    polynomial's (-1: no disturbance torque). Each block's even-numbered samples form the
    equation, its odd-numbered ones the instruments (``instruments=False``: every sample
    in the equation, ordinary least squares). ValueError where the telemetry does not
    determine J (:func:`determined`)."""
    X, Xh, y, ends = system(tm, bias, degree, interval, instruments)
    beta = determined(X, Xh, y, tm.wheel_inertia)
    J0 = np.asarray(inertia.from_entries(beta[:6]))
    start = J0 if inertia.is_physical(J0) else inertia.nearest_physical(J0)
    b0 = np.linalg.solve(start, beta[6:9]) if bias else np.zeros(0)
    p0 = np.concatenate([inertia.to_params(start), b0, beta[6 + len(b0):]])

    solution = fit.levenberg_marquardt(lambda p: _evaluate(p, Xh, y, bias), lambda p: _cost(p, Xh, y, bias), p0)
    # the residual's scale from the structural equation (the measured regressors), not the projected one
    structural = X @ np.asarray(_coefficients(jnp.asarray(solution.p), bias)) - y
    scaled = solution._replace(cost=0.5 * float(structural @ structural))
    out = fit.estimate(solution.p, fit.covariance(scaled, len(y)), bias, degree, solution, tm.wheel_inertia,
                       residual_rms=float(np.sqrt(np.mean(structural ** 2))), intervals=len(ends),
                       residuals={"t": ends, "momentum equation [N m s]": structural.reshape(-1, 3)})
    return add_constancy(out, tm, bias=bias, degree=degree, interval=interval)


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
