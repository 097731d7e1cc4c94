"""Physically consistent inertias by construction: the log-Cholesky map.

A rigid body's inertia is J = tr(S) I - S with S = integral of r r^T dm its second moment
of mass (kg m^2), positive definite for a body that is not flat. With S = L L^T and L lower
triangular with a positive diagonal exp(a_i), every parameter vector

    p = (a_1, a_2, a_3, l_21, l_31, l_32)

gives a physical inertia (positive principal moments that satisfy the triangle inequality
J_i + J_j > J_k strictly), and every physical inertia has exactly one p (Wensing, Kim and
Slotine 2017; Rucker and Wensing 2022). The inverse: S = tr(J)/2 I - J, L = chol(S).

theta = (J_xx, J_yy, J_zz, J_xy, J_xz, J_yz) [kg m^2] are the inertia's six entries, the
order of every covariance here.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

ENTRIES = ("J_xx", "J_yy", "J_zz", "J_xy", "J_xz", "J_yz")
_ROWS = np.array([0, 1, 2, 0, 0, 1])
_COLS = np.array([0, 1, 2, 1, 2, 2])


def from_params(p):
    """J (3, 3) [kg m^2] of log-Cholesky parameters p (6,): physical for every finite p."""
    p = jnp.asarray(p)
    zero = jnp.zeros_like(p[0])
    L = jnp.array([[jnp.exp(p[0]), zero, zero], [p[3], jnp.exp(p[1]), zero], [p[4], p[5], jnp.exp(p[2])]])
    S = L @ L.T
    return jnp.trace(S) * jnp.eye(3, dtype=p.dtype) - S


def second_moment(J):
    """S = tr(J)/2 I - J [kg m^2]: positive definite exactly when J is physical."""
    J = np.asarray(J, float)
    return 0.5 * np.trace(J) * np.eye(3) - J


def is_physical(J) -> bool:
    """Symmetric, and the second moment positive definite (so the principal moments are
    positive and satisfy the strict triangle inequality)."""
    J = np.asarray(J, float)
    return bool(np.allclose(J, J.T, rtol=0, atol=1e-12 * np.abs(J).max())
                and np.linalg.eigvalsh(second_moment(J)).min() > 0)


def to_params(J) -> np.ndarray:
    """The log-Cholesky parameters (6,) of a physical inertia; ValueError otherwise."""
    J = np.asarray(J, float)
    if not np.allclose(J, J.T, rtol=0, atol=1e-12 * np.abs(J).max()):
        raise ValueError("not a physical inertia (not symmetric)")
    if not is_physical(J):
        raise ValueError("not a physical inertia (its principal moments break the triangle inequality)")
    L = np.linalg.cholesky(second_moment(J))
    return np.array([np.log(L[0, 0]), np.log(L[1, 1]), np.log(L[2, 2]), L[1, 0], L[2, 0], L[2, 1]])


def nearest_physical(J, floor: float = 1e-6) -> np.ndarray:
    """J with its second moment's eigenvalues raised to at least ``floor`` times the largest:
    the starting point of a fit whose unconstrained estimate is not physical."""
    S = second_moment(0.5 * (np.asarray(J, float) + np.asarray(J, float).T))
    w, V = np.linalg.eigh(S)
    S = (V * np.maximum(w, floor * max(w.max(), 1e-300))) @ V.T
    return np.trace(S) * np.eye(3) - S


def entries(J):
    """theta (6,) of J (3, 3) (the module's order)."""
    return J[..., _ROWS, _COLS]


def from_entries(theta):
    """J (3, 3) of theta (6,)."""
    theta = jnp.asarray(theta)
    return jnp.array([[theta[0], theta[3], theta[4]], [theta[3], theta[1], theta[5]], [theta[4], theta[5], theta[2]]])


def rate_matrix(w):
    """M(w) (..., 3, 6) with J w = M(w) theta, for rates w (..., 3) [rad/s]."""
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    o = jnp.zeros_like(x)
    return jnp.stack([jnp.stack([x, o, o, y, z, o], -1),
                      jnp.stack([o, y, o, x, o, z], -1),
                      jnp.stack([o, o, z, o, x, y], -1)], -2)


def principal(J, covariance):
    """Principal moments (3,) [kg m^2] in ascending order, principal axes (columns of a
    rotation, 3 x 3), and their 1-sigma: each moment's standard deviation [kg m^2] and each
    axis's rms angle error [rad], by first-order perturbation of the eigenproblem with the
    covariance (6, 6) of theta: d lambda_i = v_i^T dJ v_i,
    d v_i = sum_{k != i} v_k (v_k^T dJ v_i) / (lambda_i - lambda_k); an axis whose moment
    another equals has no direction of its own (its 1-sigma is inf)."""
    J = np.asarray(J, float)
    lam, V = np.linalg.eigh(J)
    if np.linalg.det(V) < 0:
        V[:, 2] = -V[:, 2]
    basis = np.zeros((6, 3, 3))
    for n, (r, c) in enumerate(zip(_ROWS, _COLS)):
        basis[n, r, c] = basis[n, c, r] = 1.0
    dlam = np.einsum("ai,nab,bi->in", V, basis, V)  # (3, 6): d lambda_i / d theta
    moment_std = np.sqrt(np.maximum(np.einsum("in,nm,im->i", dlam, covariance, dlam), 0.0))
    axis_std = np.zeros(3)
    for i in range(3):
        if np.any(np.delete(lam, i) == lam[i]):
            axis_std[i] = np.inf
            continue
        D = np.array([np.einsum("a,nab,b->n", V[:, k], basis, V[:, i]) / (lam[i] - lam[k])
                      for k in range(3) if k != i])  # components of d v_i along the other two axes: small angles
        axis_std[i] = np.sqrt(max(np.trace(D @ covariance @ D.T), 0.0))
    return lam, V, moment_std, axis_std


def axis_angles(V_true, V) -> np.ndarray:
    """Angle [rad] between each column of V and the same column of V_true (sign-free)."""
    c = np.abs(np.sum(np.asarray(V_true) * np.asarray(V), axis=0))
    return np.arccos(np.clip(c, -1.0, 1.0))
