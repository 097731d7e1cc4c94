"""One fourth-order Runge-Kutta step that keeps rotations on SO(3) (docs/model.md §5).

Rotations are advanced in local coordinates, R = R_k exp(hat(psi)) with
psi' = J_r^{-1}(psi) w and psi(0) = 0 (Munthe-Kaas RK4), and the result is formed as
R_k + R_k (exp(hat(psi)) - I), which drifts less from SO(3) in round-off than
R_k exp(hat(psi)). Vector-space states are advanced by classical RK4 alongside.
"""

from __future__ import annotations

from typing import NamedTuple

import jax

from so3jax.core import so3
from so3jax.core._fusion import materialize

_tree_map = jax.tree_util.tree_map


def _axpy(a, x, y):
    """y + a x over pytrees."""
    return _tree_map(lambda xi, yi: yi + a * xi, x, y)


def lie_rk4_step(field, t, dt, rotations, vectors):
    """Advance (rotations, vectors) from t to t + dt.

    field(t, rotations, vectors) -> (body_rates, vectors_dot, aux), with body_rates a
    tuple of (3,) arrays, one per rotation (R' = R hat(w)), called four times, in stage
    order, at t, t + dt/2, t + dt/2, t + dt (:data:`so3jax.dynamics.stepped.STAGE_OF_CALL`). Returns
    (rotations, vectors, aux of the first stage).
    """

    def stage(c, psis, vecs):
        # the stage's inputs (x_k + c dt k_prev) computed once, not in each of their consumers
        psis, vecs = materialize((psis, vecs), t)
        moved = materialize(tuple(R + so3.matmul(R, so3.expm1(p)) for R, p in zip(rotations, psis)), t)
        rates, vdot, _ = field(t + c * dt, moved, vecs)
        rates, vdot = materialize((rates, vdot), t)
        return tuple(so3.jr_inv_apply(p, w) for p, w in zip(psis, rates)), vdot

    rates1, v1, aux = field(t, rotations, vectors)
    rates1, v1 = materialize((rates1, v1), t)
    k1 = (rates1, v1)
    zero = _tree_map(lambda w: 0.0 * w, rates1)
    k2 = stage(0.5, _axpy(0.5 * dt, k1[0], zero), _axpy(0.5 * dt, k1[1], vectors))
    k3 = stage(0.5, _axpy(0.5 * dt, k2[0], zero), _axpy(0.5 * dt, k2[1], vectors))
    k4 = stage(1.0, _axpy(dt, k3[0], zero), _axpy(dt, k3[1], vectors))
    increment = _tree_map(lambda a, b, c, d: (dt / 6.0) * (a + 2.0 * (b + c) + d), k1, k2, k3, k4)
    increment = materialize(increment, t)
    new_rotations = tuple(R + so3.matmul(R, so3.expm1(p)) for R, p in zip(rotations, increment[0]))
    new_vectors = _tree_map(lambda x, dx: x + dx, vectors, increment[1])
    return new_rotations, new_vectors, aux


class OnSO3(NamedTuple):
    """Marks a rotation in a state pytree: :func:`rk4_step` steps it on SO(3). In a
    derivative of the state, the same node holds the body rate w (R' = R hat(w))."""

    R: jax.Array


def _is_rotation(node) -> bool:
    return isinstance(node, OnSO3)


def rk4_step(field, t, dt, state):
    """Advance a state pytree from t to t + dt: :class:`OnSO3` leaves on SO(3), every
    other leaf additively (:func:`lie_rk4_step`).

    field(t, state) -> (derivative, aux): the derivative has the state's structure, with
    body rates in its OnSO3 nodes. Returns (state, aux of the first stage).
    """
    leaves, treedef = jax.tree_util.tree_flatten(state, is_leaf=_is_rotation)
    marked = [_is_rotation(leaf) for leaf in leaves]

    def join(rotations, vectors):
        rotations, vectors = iter(rotations), iter(vectors)
        return treedef.unflatten([OnSO3(next(rotations)) if m else next(vectors) for m in marked])

    def split(tree):
        parts = treedef.flatten_up_to(tree)
        return (tuple(p.R for p, m in zip(parts, marked) if m), [p for p, m in zip(parts, marked) if not m])

    def flat_field(t, rotations, vectors):
        derivative, aux = field(t, join(rotations, vectors))
        rates, vector_rates = split(derivative)
        return rates, vector_rates, aux

    rotations, vectors = split(state)
    rotations, vectors, aux = lie_rk4_step(flat_field, t, dt, rotations, vectors)
    return join(rotations, vectors), aux
