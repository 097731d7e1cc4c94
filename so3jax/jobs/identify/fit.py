"""Levenberg-Marquardt for the identification's least-squares problems, the Gauss-Newton
covariance, and the result both methods report (:func:`estimate`).

A problem is ``evaluate(p) -> (cost, H, g)`` with cost = |r(p)|^2 / 2, H = A^T A and
g = A^T r for the Jacobian A = dr/dp (H may be assembled from blocks without forming A),
and ``cost(p)``. The step solves (H + mu diag(H)) dp = -g (Marquardt's scaling) and is
taken only where it lowers the cost. The covariance of p is s^2 H^{-1} at the solution,
s^2 = |r|^2 / (n - k) (the normal matrix scaled by the residuals).

How well the data determine J (:func:`spread`): the 1 sigma of the least-determined
combination of its entries against the smallest principal moment of J less the wheels'
spin inertia (the rest of the spacecraft, which the wheels' motors must push on). The
momentum equation is homogeneous in J, J b and the disturbance: only the momentum the
wheels exchange with the body fixes J's scale, and without it the data are fitted as well
by a vanishing J, or by the wheels' own spin inertia alone. Above ``UNDETERMINED`` the
interval of +-2 sigma reaches zero: the data cannot tell the spacecraft from nothing, and
the identification is refused; above ``POORLY_DETERMINED`` it is reported with a warning.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.jobs.identify import inertia


class Solution(NamedTuple):
    p: np.ndarray  # (k,) the parameters at the minimum
    cost: float  # |r|^2 / 2 there
    H: np.ndarray  # (k, k) the Gauss-Newton normal matrix A^T A there
    iterations: int
    converged: bool


def levenberg_marquardt(evaluate, cost, p0, max_iterations: int = 100, tol: float = 1e-12) -> Solution:
    """Minimize cost from p0; converged when a step lowers the cost by less than ``tol``
    relative, or the gradient vanishes."""
    p = np.asarray(p0, float)
    c, H, g = (np.asarray(x, float) for x in evaluate(p))
    mu = 1e-3
    for it in range(1, max_iterations + 1):
        d = np.maximum(np.diag(H), 1e-300)
        if np.sqrt(np.sum(g * g / d)) <= tol * max(np.sqrt(2.0 * c), 1e-300):
            return Solution(p, float(c), H, it - 1, True)
        while True:
            try:
                step = np.linalg.solve(H + mu * np.diag(d), -g)
            except np.linalg.LinAlgError:
                step = None
            trial = None if step is None else float(cost(p + step))
            if trial is not None and np.isfinite(trial) and trial <= c:
                break
            mu *= 10.0
            if mu > 1e16:
                return Solution(p, float(c), H, it, False)
        p = p + step
        drop = (c - trial) / max(c, 1e-300)
        c, H, g = (np.asarray(x, float) for x in evaluate(p))
        mu = max(mu / 10.0, 1e-12)
        if drop <= tol:
            return Solution(p, float(c), H, it, True)
    return Solution(p, float(c), H, max_iterations, False)


def covariance(solution: Solution, n_residuals: int) -> np.ndarray:
    """s^2 H^{-1}, s^2 = 2 cost / (n - k): the parameters' covariance (k, k)."""
    k = len(solution.p)
    s2 = 2.0 * solution.cost / max(n_residuals - k, 1)
    return s2 * np.linalg.pinv(solution.H, hermitian=True)


UNDETERMINED = 0.5  # spread above which the identification is refused
POORLY_DETERMINED = 0.1  # spread above which it is reported with a warning


def spread(J, std: float, wheel_inertia) -> float:
    """std [kg m^2], the 1 sigma of J's least-determined combination of entries, over the
    smallest principal moment [kg m^2] of J less the wheels' spin inertia (3, 3); inf where
    that moment is not positive."""
    moment = float(np.linalg.eigvalsh(np.asarray(J, float) - wheel_inertia)[0])
    return std / moment if moment > 0 else math.inf


def worst_std(theta_cov) -> float:
    """The 1 sigma [kg m^2] of J's least-determined combination of entries (unit norm):
    the square root of the largest eigenvalue of their covariance (6, 6)."""
    return math.sqrt(max(float(np.linalg.eigvalsh(theta_cov)[-1]), 0.0))


def add_warning(out: dict, text: str) -> None:
    """Add ``text`` to the result's "warning" (one line, "; " between warnings)."""
    out["warning"] = f"{out['warning']}; {text}" if "warning" in out else text


def estimate(p, cov_p, bias: bool, degree: int, solution: Solution, wheel_inertia, **extra) -> dict:
    """The identification's result from p = (log-Cholesky parameters of J, [gyro bias b],
    disturbance coefficients d) and its covariance: J, its entries' covariance (6, 6),
    b and d with theirs, the solver's outcome, and a "warning" where J is poorly
    determined (:func:`spread`, with the wheels' spin inertia (3, 3) [kg m^2]); ``extra``
    is added as it is."""
    T = np.asarray(jax.jacfwd(lambda q: inertia.entries(inertia.from_params(q)))(jnp.asarray(p[:6])))
    n_b = 3 if bias else 0
    cov = cov_p.copy()
    cov[:6, :] = T @ cov[:6, :]
    cov[:, :6] = cov[:, :6] @ T.T
    out = {"J": np.asarray(inertia.from_params(jnp.asarray(p[:6]))), "theta_cov": cov[:6, :6],
           "bias": p[6:6 + n_b] if bias else None, "bias_cov": cov[6:6 + n_b, 6:6 + n_b] if bias else None,
           "disturbance": p[6 + n_b:].reshape(degree + 1, 3) if degree >= 0 else None,
           "disturbance_cov": cov[6 + n_b:, 6 + n_b:] if degree >= 0 else None,
           "iterations": solution.iterations, "converged": solution.converged}
    out.update(extra)
    relative = spread(out["J"], worst_std(out["theta_cov"]), wheel_inertia)
    if relative > POORLY_DETERMINED:
        add_warning(out, f"J is poorly determined: the 1 sigma of its least-determined combination of entries is "
                         f"{relative:.0%} of its smallest principal moment (beyond the wheels' spin inertia); "
                         f"a longer manoeuvre, or wheels exchanging more momentum about every axis")
    return out
