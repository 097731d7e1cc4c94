"""Flexible appendages and propellant slosh on a free hub (docs/flexible.md).

A rigid hub carries N hinged rigid panels (one hinge angle theta_i each, Basilisk's
hingedRigidBodyStateEffector) and M spring-mass-damper particles (one displacement rho_j
each, Basilisk's linearSpringMassDamper). The hub is free to translate and rotate, with no
external force and an external torque L on the hub. The state is (omega (3, *b), theta
(N, *b), theta_dot (N, *b), rho (M, *b), rho_dot (M, *b)); :func:`accelerations` solves the
system's mass matrix (F.10) for (a_B, omega_dot, theta_ddot, rho_ddot), the hub's
translational acceleration a_B solved but not integrated: nothing here depends on the
hub's position or velocity. Nonlinear in theta and rho.

Arrays follow :mod:`so3jax.core.so3`: components first, batch axes last. Parameters are
shared by the batch and cast to the state's dtype. Vectors are in the body frame B, from
the hub's reference point B.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.core import _trig, checks, integrate, so3
from so3jax.core._fusion import materialize
from so3jax.core.pytree import pytree_dataclass, static_field

_UNIT_TOLERANCE = 1e-9  # a unit vector's or a rotation's rows' departure allowed by check()


@pytree_dataclass
class Hub:
    """The rigid hub: mass [kg], inertia (3, 3) about its own centre of mass Bc in the body
    frame [kg m^2] (Basilisk's IHubPntBc_B), r_BcB (3,) its centre of mass from B [m]."""

    mass: jax.Array
    inertia: jax.Array
    r_BcB: jax.Array


@pytree_dataclass
class HingedPanel:
    """A rigid panel on a torsional hinge, Basilisk's hingedRigidBodyStateEffector conventions.

    mass m [kg]; inertia I_S (3, 3) about the panel's centre of mass S in the panel frame
    (s1, s2, s3) [kg m^2]; d: the centre of mass lies at r_HB - d s1 [m]; k [N m/rad], c
    [N m s/rad]: the hinge's spring and damper about theta = 0; r_HB (3,): the hinge point
    from B [m]; dcm_HB (3, 3): rows h1, h2, h3 of the hinge frame in body components, the
    hinge axis h2 (F.1). locked: the hinge held at its angle (its rate taken as 0, theta_ddot =
    0: a rigid part of the hub).
    """

    mass: jax.Array
    inertia: jax.Array
    d: jax.Array
    k: jax.Array
    c: jax.Array
    r_HB: jax.Array
    dcm_HB: jax.Array
    locked: bool = static_field(default=False)


@pytree_dataclass
class SloshParticle:
    """A point mass on a linear spring and damper, Basilisk's linearSpringMassDamper
    conventions: mass [kg], r_PB (3,) its equilibrium location from B [m] (Basilisk's
    r_PB_B), p_hat (3,) the unit direction it moves along, the particle at r_PB + rho p_hat
    (F.3); k [N/m], c [N s/m]."""

    mass: jax.Array
    r_PB: jax.Array
    p_hat: jax.Array
    k: jax.Array
    c: jax.Array


@pytree_dataclass
class FlexibleBody:
    """The hub with its panels and slosh particles (tuples, possibly empty). phases: 0, or P
    where every panel's and particle's k and c carry a leading axis of one value per mission
    phase (P, *b) (docs/model.md §8.9): :func:`at_phase` picks a phase's body, which the
    functions below take."""

    hub: Hub
    panels: tuple = ()
    slosh: tuple = ()
    phases: int = static_field(default=0)


def at_phase(body: FlexibleBody, phase) -> FlexibleBody:
    """The body of phase ``phase`` (an index, possibly traced): each panel's and particle's
    k and c that phase's value where they are given per phase (``body.phases``); the body
    itself otherwise."""
    if not body.phases:
        return body
    pick = lambda part: dataclasses.replace(part, k=jnp.asarray(part.k)[phase], c=jnp.asarray(part.c)[phase])
    return FlexibleBody(body.hub, tuple(map(pick, body.panels)), tuple(map(pick, body.slosh)))


class FlexState(NamedTuple):
    """omega (3, *b) [rad/s] the hub's body rate; theta, theta_dot (N, *b) [rad, rad/s]; rho,
    rho_dot (M, *b) [m, m/s]. Its rate (:func:`derivative`) has the same structure."""

    omega: jax.Array
    theta: jax.Array
    theta_dot: jax.Array
    rho: jax.Array
    rho_dot: jax.Array


class Modal(NamedTuple):
    """The flexible coordinates a closed loop carries beside the hub's rate
    (:func:`so3jax.dynamics.plant.flexible_derivative`): theta, theta_dot (N, *b) [rad, rad/s];
    rho, rho_dot (M, *b) [m, m/s]. Its rate has the same structure."""

    theta: jax.Array
    theta_dot: jax.Array
    rho: jax.Array
    rho_dot: jax.Array


def initial_modal(body: FlexibleBody, batch_shape=(), dtype=None, theta=None, rho=None) -> Modal:
    """The :class:`Modal` coordinates at rest, every leaf (n, *batch_shape): theta (N,) [rad]
    and rho (M,) [m] where given (shared by the batch), their rates 0."""
    dtype = jnp.result_type(float) if dtype is None else dtype
    zeros = lambda n: jnp.zeros((n, *batch_shape), dtype)
    shared = lambda x, n: jnp.asarray(x, dtype).reshape((n,) + (1,) * len(batch_shape))
    given = lambda x, n: zeros(n) if x is None else shared(x, n) + zeros(n)
    n, m = len(body.panels), len(body.slosh)
    return Modal(given(theta, n), zeros(n), given(rho, m), zeros(m))


class Accelerations(NamedTuple):
    """The solution of (F.10): omega_dot (3, *b) [rad/s^2], theta_ddot (N, *b) [rad/s^2],
    rho_ddot (M, *b) [m/s^2], hub_acceleration a_B (3, *b) [m/s^2], the inertial
    acceleration of B in body components."""

    omega_dot: jax.Array
    theta_ddot: jax.Array
    rho_ddot: jax.Array
    hub_acceleration: jax.Array


def initial_state(body: FlexibleBody, omega, theta=None, theta_dot=None, rho=None, rho_dot=None) -> FlexState:
    """A :class:`FlexState` of ``omega`` (3,) with zeros for the coordinates not given."""
    omega = jnp.asarray(omega)
    zeros = lambda n: jnp.zeros((n,) + omega.shape[1:], omega.dtype)
    given = lambda x, n: zeros(n) if x is None else jnp.asarray(x).astype(omega.dtype)
    n, m = len(body.panels), len(body.slosh)
    return FlexState(omega, given(theta, n), given(theta_dot, n), given(rho, m), given(rho_dot, m))


def _check(name: str, x, shape, positive=False, nonnegative=False):
    """:func:`so3jax.core.checks.values`: x's values where concrete, a one-line ValueError
    unless finite (positive / non-negative) of ``shape``."""
    return checks.values(name, x, shape, positive, nonnegative)


def _check_inertia(name: str, x):
    v = _check(name, x, (3, 3))
    if v is not None and (not np.allclose(v, v.T, rtol=1e-12, atol=0) or np.linalg.eigvalsh(v).min() <= 0):
        raise ValueError(f"{name} must be symmetric positive definite, got {v.tolist()}")


def check(body: FlexibleBody) -> None:
    """One-line ValueErrors for bad parameters, where they are concrete: masses and
    inertias positive (symmetric positive definite), d, k, c non-negative, dcm_HB a
    rotation (orthonormal rows, right-handed), p_hat a unit vector, every value finite; k and
    c (P,) of one value per phase where ``body.phases`` is P."""
    modal = (body.phases,) if body.phases else ()
    _check("hub mass [kg]", body.hub.mass, (), positive=True)
    _check_inertia("hub inertia [kg m^2]", body.hub.inertia)
    _check("hub r_BcB [m]", body.hub.r_BcB, (3,))
    for i, panel in enumerate(body.panels):
        name = f"panel {i + 1}"
        _check(f"{name} mass [kg]", panel.mass, (), positive=True)
        _check_inertia(f"{name} inertia [kg m^2]", panel.inertia)
        for field, unit in (("d", "m"), ("k", "N m/rad"), ("c", "N m s/rad")):
            _check(f"{name} {field} [{unit}]", getattr(panel, field), () if field == "d" else modal,
                   nonnegative=True)
        _check(f"{name} r_HB [m]", panel.r_HB, (3,))
        H = _check(f"{name} dcm_HB", panel.dcm_HB, (3, 3))
        if H is not None and (np.abs(H @ H.T - np.eye(3)).max() > _UNIT_TOLERANCE
                              or np.linalg.det(H) <= 0):
            raise ValueError(f"{name} dcm_HB must be a rotation (orthonormal rows h1, h2, h3, h3 = h1 x h2), "
                             f"got {H.tolist()}")
    for j, particle in enumerate(body.slosh):
        name = f"slosh particle {j + 1}"
        _check(f"{name} mass [kg]", particle.mass, (), positive=True)
        for field, unit in (("k", "N/m"), ("c", "N s/m")):
            _check(f"{name} {field} [{unit}]", getattr(particle, field), modal, nonnegative=True)
        _check(f"{name} r_PB [m]", particle.r_PB, (3,))
        p = _check(f"{name} p_hat", particle.p_hat, (3,))
        if p is not None and abs(np.linalg.norm(p) - 1.0) > _UNIT_TOLERANCE:
            raise ValueError(f"{name} p_hat must be a unit vector, got {p.tolist()} (norm {np.linalg.norm(p)})")


# --- geometry ----------------------------------------------------------------------------


def _cast(x, like, core_ndim):
    """A parameter in the dtype of ``like`` (3, *b), with unit axes to broadcast against it."""
    return so3.batch_like(jnp.asarray(x).astype(like.dtype), core_ndim, like)


def _opaque(state):
    """A traced scalar, never NaN (0 or 1), for :func:`so3jax.core._fusion.materialize`:
    a batch's diverged sample does not reach the others through it."""
    return jnp.isnan(state.omega.reshape(-1)[0]).astype(state.omega.dtype)


def _scalar(x, like):
    """A scalar parameter in the dtype of ``like``."""
    return jnp.asarray(x).astype(like.dtype)


def panel_axes(panel: HingedPanel, theta, like):
    """(s1, s2, s3) (3, *b): the panel frame at hinge angle theta, s = M2(theta) h (F.1)."""
    H = _cast(panel.dcm_HB, like, 2)
    h1, h2, h3 = H[0], H[1], H[2]
    ct, st = jnp.cos(theta), jnp.sin(theta)
    s1 = ct * h1 - st * h3
    return s1, jnp.broadcast_to(h2, s1.shape), st * h1 + ct * h3


def _in_body(inertia, axes, like):
    """A matrix given in the frame of ``axes`` (rows s_a) in body components,
    sum_ab I_ab s_a s_b^T (3, 3, *b) (F.4)."""
    S = jnp.stack(axes)  # (a, i, *b): the frame's rows
    return so3.matmul_compact(so3.transpose(S), so3.matmul_compact(_cast(inertia, like, 2), S))


class _Part(NamedTuple):
    """One rigid part at a state: mass [kg], r (3, *b) its centre of mass from B, r_dot its
    rate relative to B, r_ddot its relative acceleration at zero generalized accelerations,
    inertia (3, 3, *b) about its centre of mass, omega_rel (3, *b) its rate relative to B,
    alpha_rel its relative angular acceleration at zero generalized accelerations, all in
    body components (None: a particle, or the hub's zero rates)."""

    mass: jax.Array
    r: jax.Array
    r_dot: jax.Array
    r_ddot: jax.Array
    inertia: jax.Array | None
    omega_rel: jax.Array | None
    alpha_rel: jax.Array | None


def _parts(body: FlexibleBody, state: FlexState):
    """The hub, each panel and each particle as a :class:`_Part`, with each panel's and
    particle's partial velocity e (3, *b) and partial angular velocity w (3, *b) or None of
    its coordinate, its spring and damper force [N m or N] (F.2)-(F.5)."""
    omega = state.omega
    zero = jnp.zeros_like(omega)
    hub = body.hub
    r_c = _cast(hub.r_BcB, omega, 1) + zero
    parts = [(_Part(_scalar(hub.mass, omega), r_c, zero, zero, _cast(hub.inertia, omega, 2), None, None), None)]
    for i, panel in enumerate(body.panels):
        theta = state.theta[i]
        theta_dot = jnp.zeros_like(theta) if panel.locked else state.theta_dot[i]
        s1, s2, s3 = panel_axes(panel, theta, omega)
        d = _scalar(panel.d, omega)
        r = _cast(panel.r_HB, omega, 1) - d * s1
        r_dot = d * theta_dot * s3
        r_ddot = d * theta_dot**2 * s1
        w_rel = theta_dot * s2
        alpha_rel = theta_dot * so3.cross(omega, s2)
        spring = -_scalar(panel.k, omega) * theta - _scalar(panel.c, omega) * theta_dot
        part = _Part(_scalar(panel.mass, omega), r, r_dot, r_ddot,
                     _in_body(panel.inertia, (s1, s2, s3), omega), w_rel, alpha_rel)
        parts.append((part, (d * s3, s2, spring, panel.locked)))
    for j, particle in enumerate(body.slosh):
        rho, rho_dot = state.rho[j], state.rho_dot[j]
        p = _cast(particle.p_hat, omega, 1) + zero
        r = _cast(particle.r_PB, omega, 1) + rho * p
        spring = -_scalar(particle.k, omega) * rho - _scalar(particle.c, omega) * rho_dot
        part = _Part(_scalar(particle.mass, omega), r, rho_dot * p, zero, None, None, None)
        parts.append((part, (p, None, spring, False)))
    return parts


def _remainders(part: _Part, omega):
    """(a_rem, g): the part's inertial acceleration at zero generalized accelerations,
    omega x (omega x r) + 2 omega x r' + r'' (F.6), and its inertia torque about its centre of
    mass, I alpha_rel + omega_p x I omega_p with omega_p = omega + omega_rel (F.7), or None."""
    a_rem = so3.cross(omega, so3.cross(omega, part.r)) + 2.0 * so3.cross(omega, part.r_dot) + part.r_ddot
    if part.inertia is None:
        return a_rem, None
    omega_p = omega if part.omega_rel is None else omega + part.omega_rel
    g = so3.cross(omega_p, so3.matvec(part.inertia, omega_p))
    if part.alpha_rel is not None:
        g = g + so3.matvec(part.inertia, part.alpha_rel)
    return a_rem, g


# --- the equations of motion ---------------------------------------------------------------


class _System(NamedTuple):
    """The blocks of (F.10): A, B, D (3, 3, *b), f_v, f_w (3, *b), and per flexible
    coordinate (cv, cw (3, *b), m_f, f (*b), locked)."""

    A: jax.Array
    B: jax.Array
    D: jax.Array
    f_v: jax.Array
    f_w: jax.Array
    columns: list


def _system(body: FlexibleBody, state: FlexState, torque=None) -> _System:
    """The mass matrix's blocks and the right-hand side (F.8)-(F.10) at a state; torque:
    L (3, *b) [N m] on the hub, None for none."""
    omega = state.omega
    eye = so3.eye_like(omega)
    A = B = D = None
    f_v = jnp.zeros_like(omega)
    f_w = jnp.zeros_like(omega) if torque is None else jnp.asarray(torque).astype(omega.dtype) + 0 * omega
    columns = []
    for part, coordinate in _parts(body, state):
        m = part.mass
        r_hat = so3.hat(part.r)
        I_B = m * so3.rmatmul(r_hat, r_hat)  # m r~^T r~
        if part.inertia is not None:
            I_B = I_B + part.inertia
        A = m * eye if A is None else A + m * eye
        B = -m * r_hat if B is None else B - m * r_hat
        D = I_B if D is None else D + I_B
        a_rem, g = _remainders(part, omega)
        f_v = f_v - m * a_rem
        moment = m * so3.cross(part.r, a_rem) + (0.0 if g is None else g)
        f_w = f_w - moment
        if coordinate is not None:
            e, w, spring, locked = coordinate
            cv = m * e
            cw = m * so3.cross(part.r, e)
            m_f = m * so3.dot(e, e)
            f = spring - m * so3.dot(e, a_rem)
            if w is not None:
                Iw = so3.matvec(part.inertia, w)
                cw = cw + Iw
                m_f = m_f + so3.dot(w, Iw)
                f = f - so3.dot(w, g)
            columns.append((cv, cw, m_f, f, locked))
    return _System(A, B, D, f_v, f_w, columns)


# Per-component arithmetic: a vector is a tuple of 3 batch arrays (*b), a matrix a tuple of
# 3 rows. :func:`accelerations` works on these rather than on (3, *b) and (3, 3, *b) arrays:
# XLA:CPU fuses each 3x3 product built of stacks and slices into every consumer of each of
# its elements (recomputing sines, cross products and products of products), which made the
# flexible plant ~100x the rigid one per step in a batch; on components every value is one
# elementwise operation on the batch, computed once.


def _vec(x, like):
    """(3,) or (3, *b) parameter -> 3 components broadcasting against like's batch."""
    x = _cast(x, like, 1)
    return (x[0], x[1], x[2])


def _mat(x, like):
    x = _cast(x, like, 2)
    return tuple((x[i, 0], x[i, 1], x[i, 2]) for i in range(3))


def _v_add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def _v_sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _v_scale(s, a):
    return (s * a[0], s * a[1], s * a[2])


def _v_cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _v_dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _m_vec(m, v):
    """M v."""
    return tuple(m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2] for i in range(3))


def _once(tree, one, like):
    """tree (of batch arrays broadcasting against ``like`` (*b)) unchanged in value, computed
    once: its leaves stacked into one array behind one fusion boundary
    (:func:`so3jax.core._fusion.materialize`), so that XLA:CPU computes them in one kernel
    and each consumer reads them rather than recomputing them."""
    leaves, treedef = jax.tree.flatten(tree)
    if not leaves:
        return tree
    stacked = materialize(jnp.stack([jnp.broadcast_to(x, like.shape) for x in leaves]), one)
    return jax.tree.unflatten(treedef, list(stacked))


def _sym_inverse(m):
    """The adjugate of a symmetric M (rows as tuples) as rows, and 1 / det M (:func:`so3jax.core.so3.adjugate`)."""
    (c00, c01, c02, c11, c12, c22), inv_det = so3.adjugate(m)
    return ((c00, c01, c02), (c01, c11, c12), (c02, c12, c22)), inv_det


class _Geometry(NamedTuple):
    """One panel or particle per component at a state: mass [kg], r (its centre of mass from
    B), r_dot (its rate relative to B), r_ddot (its relative acceleration at zero generalized
    accelerations), e (its coordinate's partial velocity); a panel's frame (s1, s2, s3), its
    rates in that frame omega_S = (omega . s_a) + theta_dot e2 and inertia I_S; spring [N m or
    N] (F.9); m_f its diagonal entry of (F.10); locked; a panel's cos and sin theta (trig), hinge
    frame (h1, h2, h3), hinge point's components along it (r_HB . h_a) [m] and d [m] (F.1)."""

    mass: jax.Array
    r: tuple
    r_dot: tuple
    r_ddot: tuple | None
    e: tuple
    frame: tuple | None
    omega_S: tuple | None
    theta_dot: jax.Array | None
    inertia: tuple | None
    spring: jax.Array
    m_f: jax.Array
    locked: bool
    trig: tuple | None = None
    hinge: tuple | None = None
    hinge_point: tuple | None = None
    d: jax.Array | None = None


_MONOMIALS = ("c", "s", "cc", "cs", "ss")  # of a panel's cos(theta), sin(theta), beside 1


def _poly_mul(p, q):
    """The product of two linear forms in (1, cos theta, sin theta), coefficients (a0, ac, as)
    (None: 0), as {monomial: coefficient} over 1 and _MONOMIALS."""
    out = {}
    for (i, a), (j, b) in ((x, y) for x in enumerate(p) for y in enumerate(q)):
        if a is not None and b is not None:
            key = ("1", "c", "s")[i] if j == 0 else ("1", "c", "s")[j] if i == 0 else \
                {(1, 1): "cc", (1, 2): "cs", (2, 1): "cs", (2, 2): "ss"}[(i, j)]
            out[key] = a * b if key not in out else out[key] + a * b
    return out


def _poly_add(p, q, scale=1.0):
    """p + scale q of two {monomial: coefficient}."""
    out = dict(p)
    for k, v in q.items():
        out[k] = scale * v if k not in out else out[k] + scale * v
    return out


def _panel_inertia(panel: HingedPanel, like):
    """A panel's inertia about B, m (|r|^2 1 - r r^T) + S^T I_S S (F.4), as its upper
    triangle's entries {monomial: coefficient}, quadratic in (cos theta, sin theta):
    r = r_HB - d s1, s1 = c h1 - s h3, s2 = h2, s3 = s h1 + c h3 (F.1)."""
    h1, h2, h3 = _mat(panel.dcm_HB, like)
    m, d = _scalar(panel.mass, like), _scalar(panel.d, like)
    I_S = _mat(panel.inertia, like)
    r_HB = _vec(panel.r_HB, like)
    r = [(r_HB[i], -d * h1[i], d * h3[i]) for i in range(3)]
    frame = [[(None, h1[i], -h3[i]) for i in range(3)], [(h2[i], None, None) for i in range(3)],
             [(None, h3[i], h1[i]) for i in range(3)]]
    r2 = functools.reduce(_poly_add, [_poly_mul(r[k], r[k]) for k in range(3)])
    out = {}
    for i in range(3):
        for j in range(i, 3):
            entry = _poly_add(r2, _poly_mul(r[i], r[j]), -1.0) if i == j else _poly_add({}, _poly_mul(r[i], r[j]), -1.0)
            entry = {k: m * v for k, v in entry.items()}
            for a in range(3):
                for b in range(3):
                    entry = _poly_add(entry, {k: I_S[a][b] * v for k, v in _poly_mul(frame[a][i], frame[b][j]).items()})
            out[(i, j)] = entry
    return out


def _geometry(body: FlexibleBody, state: FlexState):
    """Each panel's and particle's :class:`_Geometry` (F.1)-(F.5)."""
    omega = state.omega
    om = (omega[0], omega[1], omega[2])
    zero = jnp.zeros_like(omega[0])
    zv = (zero, zero, zero)
    # the sines by vectorizable arithmetic (so3jax.core._trig): XLA:CPU's are a call per element
    sin, cos = _trig.sincos_near_zero(state.theta) if body.panels else ((), ())
    trig = [(cos[i], sin[i]) for i in range(len(body.panels))]
    out = []
    for i, panel in enumerate(body.panels):
        theta = state.theta[i]
        theta_dot = jnp.zeros_like(theta) if panel.locked else state.theta_dot[i]
        h1, h2, h3 = _mat(panel.dcm_HB, omega)
        ct, st = trig[i]
        s1 = _v_sub(_v_scale(ct, h1), _v_scale(st, h3))
        s2 = _v_add(h2, zv)
        s3 = _v_add(_v_scale(st, h1), _v_scale(ct, h3))
        m, d = _scalar(panel.mass, omega), _scalar(panel.d, omega)
        I_S = _mat(panel.inertia, omega)
        r_HB = _vec(panel.r_HB, omega)
        r = _v_sub(r_HB, _v_scale(d, s1))
        # omega in the panel frame from its components along h1, h3 (s = M2(theta) h)
        a1, a3 = _v_dot(om, h1), _v_dot(om, h3)
        omega_S = (ct * a1 - st * a3, _v_dot(om, h2) + theta_dot, st * a1 + ct * a3)
        spring = -_scalar(panel.k, omega) * theta - _scalar(panel.c, omega) * theta_dot
        out.append(_Geometry(m, r, _v_scale(d * theta_dot, s3), _v_scale(d * theta_dot**2, s1), _v_scale(d, s3),
                             (s1, s2, s3), omega_S, theta_dot, I_S, spring, m * d * d + I_S[1][1], panel.locked,
                             (ct, st), (h1, h2, h3), (_v_dot(r_HB, h1), _v_dot(r_HB, h2), _v_dot(r_HB, h3)), d))
    for j, particle in enumerate(body.slosh):
        rho, rho_dot = state.rho[j], state.rho_dot[j]
        m = _scalar(particle.mass, omega)
        p = _v_add(_vec(particle.p_hat, omega), zv)
        r = _v_add(_vec(particle.r_PB, omega), _v_scale(rho, p))
        spring = -_scalar(particle.k, omega) * rho - _scalar(particle.c, omega) * rho_dot
        out.append(_Geometry(m, r, _v_scale(rho_dot, p), None, p, None, None, None, None, spring, m + zero, False))
    return out


def _panel_torque(part: _Geometry):
    """A panel's inertia torque about its centre of mass at zero generalized accelerations
    (F.7) in its own frame, g_S = Omega x I_S Omega + theta_dot I_S (S (omega x s2)) with
    Omega = omega' + theta_dot e2, omega' = S omega and S (omega x s2) = (-omega'_3, 0,
    omega'_1): (its s2 component, g_S - omega' x I_S omega' = theta_dot (e2 x I_S omega'
    + omega' x I_S e2 + I_S S (omega x s2)) + theta_dot^2 e2 x I_S e2, the part that the
    panel's own rate makes)."""
    W, I_S, rate = part.omega_S, part.inertia, part.theta_dot
    rigid = (W[0], W[1] - rate, W[2])
    spin = _v_add(_v_scale(-W[2], (I_S[0][0], I_S[1][0], I_S[2][0])), _v_scale(W[0], (I_S[0][2], I_S[1][2], I_S[2][2])))
    I_e2 = (I_S[0][1], I_S[1][1], I_S[2][1])
    IW = [sum((I_S[i][j] * W[j] for j in range(1, 3)), I_S[i][0] * W[0]) for i in (0, 2)]
    along = W[2] * IW[0] - W[0] * IW[1] + rate * spin[1]  # (Omega x I_S Omega)_2 + theta_dot spin_2
    Iw = [sum((I_S[i][j] * rigid[j] for j in range(1, 3)), I_S[i][0] * rigid[0]) for i in (0, 2)]
    turn = _v_add(_v_add((Iw[1], 0.0, -Iw[0]), _v_cross(rigid, I_e2)), spin)
    return along, _v_add(_v_scale(rate, turn), _v_scale(rate * rate, (I_e2[2], 0.0, -I_e2[0])))


def _columns(part: _Geometry):
    """(c_v, c_omega) of a flexible coordinate (F.10): m e and m r x e (+ I_S^B s2 for a panel).
    A panel's (e = d s3, r = r_HB - d s1): m d ((r_HB . s2) s1 + (d - r_HB . s1) s2) + I_S s2 in
    its frame, turned onto the hinge frame's constant axes (s = M2(theta) h, F.1)."""
    cv = _v_scale(part.mass, part.e)
    if part.hinge is None:
        return cv, _v_scale(part.mass, _v_cross(part.r, part.e))
    (h1, h2, h3), (q1, q2, q3) = part.hinge, part.hinge_point
    I_S, ct, st = part.inertia, *part.trig
    md = part.mass * part.d
    k1 = md * q2 + I_S[0][1]
    k2 = md * (part.d - (ct * q1 - st * q3)) + I_S[1][1]
    k3 = I_S[2][1]
    u1, u3 = ct * k1 + st * k3, ct * k3 - st * k1
    return cv, tuple(u1 * h1[i] + k2 * h2[i] + u3 * h3[i] for i in range(3))


def accelerations(body: FlexibleBody, state: FlexState, torque=None) -> Accelerations:
    """Solve (F.10) for (omega_dot, theta_ddot, rho_ddot, a_B): its blocks at the state, then
    the translation eliminated, the flexible coordinates, omega_dot and back-substitution
    (:func:`_solve`: (F.11)-(F.13)'s solution, the translation eliminated first). torque: L
    (3, *b) [N m] on the hub (a couple), None for none."""
    omega = state.omega
    om = (omega[0], omega[1], omega[2])
    one = _opaque(state)
    zero = jnp.zeros_like(omega[0])
    zv = (zero, zero, zero)
    hub = body.hub
    m_h, r_h, J = _scalar(hub.mass, omega), _v_add(_vec(hub.r_BcB, omega), zv), _mat(hub.inertia, omega)
    parts = _geometry(body, state)
    w2 = _v_dot(om, om)
    # the mass moment c = sum m r and its rate (B = -c~, F.10)
    c_m = functools.reduce(_v_add, [_v_scale(p.mass, p.r) for p in parts], _v_scale(m_h, r_h))
    c_dot = functools.reduce(_v_add, [_v_scale(p.mass, p.r_dot) for p in parts], zv)
    # D = J + sum m (|r|^2 1 - r r^T) + I_S^B, upper triangle
    D = [[J[i][j] + m_h * ((_v_dot(r_h, r_h) if i == j else zero) - r_h[i] * r_h[j]) for j in range(i, 3)]
         for i in range(3)]
    slosh = zip(body.slosh, state.rho)
    for p, panel in itertools.zip_longest(parts, body.panels):
        if panel is not None:  # a polynomial in (cos theta, sin theta) of constant coefficients
            ct, st = p.trig
            phi = {"c": ct, "s": st, "cc": ct * ct, "cs": ct * st, "ss": st * st}
            for (i, j), entry in _panel_inertia(panel, omega).items():
                terms = [entry[k] * phi[k] for k in _MONOMIALS if k in entry]
                D[i][j - i] = functools.reduce(jnp.add, terms, D[i][j - i] + entry.get("1", 0.0))
            continue
        particle, rho = next(slosh)
        # a particle's m (|r|^2 1 - r r^T) with r = r_PB + rho p_hat (F.3): a quadratic in rho
        a, b = _vec(particle.r_PB, omega), _vec(particle.p_hat, omega)
        for i in range(3):
            for j in range(i, 3):
                eye = 1.0 if i == j else 0.0
                c0 = p.mass * (eye * _v_dot(a, a) - a[i] * a[j])
                c1 = p.mass * (eye * 2.0 * _v_dot(a, b) - a[i] * b[j] - b[i] * a[j])
                c2 = p.mass * (eye * _v_dot(b, b) - b[i] * b[j])
                D[i][j - i] = D[i][j - i] + c0 + rho * (c1 + rho * c2)
    # f_v = -sum m a_r with a_r = omega (omega . r) - |omega|^2 r + 2 omega x r' + r'' (F.6)
    f_v = _v_add(_v_sub(_v_scale(_v_dot(om, c_m), om), _v_scale(w2, c_m)), _v_scale(2.0, _v_cross(om, c_dot)))
    for p in parts:
        if p.r_ddot is not None:
            f_v = _v_add(f_v, _v_scale(p.mass, p.r_ddot))
    f_v = _v_scale(-1.0, f_v)
    # each coordinate's force (F.10): Q - m e . a_r (- s2 . g_S for a panel), e . (omega x r') = e . r'' = 0;
    # and the moments of f_omega below as sigma omega + sum (scalar) (axis): a particle's
    # m [2 ((r . r') omega - (r . omega) r')] along omega and p_hat, with r' = rho_dot p_hat; a
    # panel's, with r' = d theta_dot s3, r'' = d theta_dot^2 s1, r x r'' = d theta_dot^2 (rho_3 s2
    # - rho_2 s3) where rho_a = r_HB . s_a, plus S^T (g_S - omega_S x I_S omega_S),
    # along omega and s1, s2, s3
    forces, sigma, turned, axes = [], zero, [], []
    rho_dot = iter(state.rho_dot)
    for p in parts:
        w_r = _v_dot(om, p.r)
        if p.hinge is not None:  # a panel, e = d s3: e . omega = d omega_S3, e . r = d rho_3
            (ct, st), (q1, q2, q3), d = p.trig, p.hinge_point, p.d
            rho3 = st * q1 + ct * q3
            along, g = _panel_torque(p)
            f = p.spring - p.mass * d * (p.omega_S[2] * w_r - w2 * rho3) - along
            md_rate = p.mass * d * p.theta_dot
            sigma = sigma + 2.0 * md_rate * rho3
            k2 = g[1] + md_rate * p.theta_dot * rho3
            k3 = g[2] - md_rate * (2.0 * w_r + p.theta_dot * q2)
            turned += [g[0], k2, k3]
            axes += list(p.frame)
        else:
            f = p.spring - p.mass * (_v_dot(p.e, om) * w_r - w2 * _v_dot(p.e, p.r))
            twice = 2.0 * p.mass * next(rho_dot)
            sigma = sigma + twice * _v_dot(p.r, p.e)
            turned.append(-twice * w_r)
            axes.append(p.e)
        forces.append(f)
    # computed once, each in its own kernel, not within each of their consumers (XLA:CPU would,
    # recomputing products of products in every element; so too the hub block below)
    D, f_v, forces, sigma, turned = _once((D, f_v, forces, sigma, turned), one, zero)
    # f_omega = L - sum (m r x a_r + g) (F.10) = L - omega x D omega - sum m [2 ((r . r') omega
    # - (r . omega) r') + r x r''] - sum S^T (g_S - omega_S x I_S omega_S): the terms in
    # omega omega of the particles (m (omega . r) r x omega), the hub and the panels
    # (omega x I omega) make up omega x D omega
    D = tuple(tuple(D[min(i, j)][abs(j - i)] for j in range(3)) for i in range(3))  # the whole symmetric D
    f_w = zv if torque is None else tuple(jnp.asarray(torque).astype(omega.dtype)[i] + zero for i in range(3))
    f_w = _v_sub(f_w, _v_cross(om, _m_vec(D, om)))
    f_w = _v_sub(f_w, _v_scale(sigma, om))
    for k, axis in zip(turned, axes):
        f_w = _v_sub(f_w, _v_scale(k, axis))
    return _solve(body, state, parts, m_h, c_m, D, f_v, f_w, forces, one, zero)


def _e_dot(pa: _Geometry, pb: _Geometry, same: bool):
    """m_a m_b e_a . e_b of two flexible coordinates (F.10) (same: one coordinate twice): a
    panel's e = d s3 = d (sin theta h1 + cos theta h3) of unit s3 (F.1), a particle's e = p_hat
    (F.3), constant."""
    if pa.hinge is not None and pb.hinge is None:
        pa, pb = pb, pa
    if pb.hinge is None:  # two particles: constant
        return pa.mass * pb.mass * _v_dot(pa.e, pb.e)
    md = pb.mass * pb.d
    if same:
        return md * md
    if pa.hinge is None:  # a particle and a panel
        (h1, _, h3), (ct, st) = pb.hinge, pb.trig
        return pa.mass * md * (st * _v_dot(h1, pa.e) + ct * _v_dot(h3, pa.e))
    return pa.mass * pb.mass * _v_dot(pa.e, pb.e)


def _solve(body, state, parts, m_h, c_m, D, f_v, f_w, forces, one, zero) -> Accelerations:
    """(F.10) from its blocks: the translation eliminated first (A = m 1, B = -c~ with c the
    mass moment: the hub block D - (|c|^2 1 - c c^T) / m about the centre of mass, the
    columns c_omega - c x c_v / m), then each flexible coordinate in turn (the symmetric
    system's Gaussian elimination onto the 3x3 hub block), omega_dot by the adjugate, and
    back-substitution for q_ddot and a_B = (f_v + c x omega_dot - sum c_v q_ddot) / m."""
    m_tot = functools.reduce(lambda a, p: a + p.mass, parts, m_h)
    inv_m = 1.0 / m_tot
    c2 = _v_dot(c_m, c_m)
    S = [[D[i][j] - ((c2 if i == j else zero) - c_m[i] * c_m[j]) * inv_m for j in range(3)] for i in range(3)]
    rhs = _v_sub(f_w, _v_scale(inv_m, _v_cross(c_m, f_v)))
    coords = []  # per coordinate: c_v, its column and force about the centre of mass, m_f
    for p, f in zip(parts, forces):
        if p.locked:
            coords.append(None)
            continue
        cv, cw = _columns(p)
        coords.append([cv, _v_sub(cw, _v_scale(inv_m, _v_cross(c_m, cv))), f - _v_dot(cv, f_v) * inv_m, p.m_f])
    free = [k for k, c in enumerate(coords) if c is not None]
    M = {(a, b): (coords[a][3] if a == b else 0.0) - _e_dot(parts[a], parts[b], a == b) * inv_m
         for a in free for b in free}
    C = {a: coords[a][1] for a in free}
    F = {a: coords[a][2] for a in free}
    pivots = []  # per eliminated coordinate: 1 / pivot, column, force, its row's remaining entries
    for n_, k in enumerate(free):
        p_k = M[(k, k)]
        inv_p = 1.0 / p_k
        rest = free[n_ + 1:]
        pivots.append((k, inv_p, C[k], F[k], {j: M[(k, j)] for j in rest}))
        S = [[S[i][j] - C[k][i] * C[k][j] * inv_p for j in range(3)] for i in range(3)]
        rhs = _v_sub(rhs, _v_scale(F[k] * inv_p, C[k]))
        for j in rest:
            l_j = M[(j, k)] * inv_p
            C[j] = _v_sub(C[j], _v_scale(l_j, C[k]))
            F[j] = F[j] - l_j * F[k]
            for i in rest:
                M[(j, i)] = M[(j, i)] - l_j * M[(k, i)]
    # the hub block and its right-hand side computed once, then omega_dot once
    U, rhs = _once(([[S[i][j] for j in range(i, 3)] for i in range(3)], rhs), one, zero)
    S = [[U[min(i, j)][abs(j - i)] for j in range(3)] for i in range(3)]
    adj, inv_det = _sym_inverse(tuple(tuple(row) for row in S))
    omega_dot = _once(tuple(v * inv_det for v in _m_vec(adj, rhs)), one, zero)
    q = {}
    for k, inv_p, C_k, F_k, row in reversed(pivots):
        q[k] = (F_k - _v_dot(C_k, omega_dot) - sum((row[j] * q[j] for j in row), zero)) * inv_p
    q_ddot = [q.get(k, jnp.zeros_like(zero)) for k in range(len(parts))]
    moved = functools.reduce(_v_add, [_v_scale(q_ddot[k], coords[k][0]) for k in free], (zero, zero, zero))
    a_B = _v_scale(inv_m, _v_add(_v_sub(f_v, moved), _v_cross(c_m, omega_dot)))
    n = len(body.panels)
    stack = lambda xs, like: jnp.stack(xs) if xs else jnp.zeros((0,) + like.shape[1:], like.dtype)
    return Accelerations(jnp.stack(omega_dot), stack(q_ddot[:n], state.theta), stack(q_ddot[n:], state.rho),
                         jnp.stack(a_B))


def derivative(body: FlexibleBody, state: FlexState, torque=None) -> FlexState:
    """The state's rate (omega_dot, theta_dot, theta_ddot, rho_dot, rho_ddot) (F.10)."""
    acc = accelerations(body, state, torque)
    theta_rate = [jnp.zeros_like(state.theta[i]) if panel.locked else state.theta_dot[i]
                  for i, panel in enumerate(body.panels)]
    theta_rate = jnp.stack(theta_rate) if theta_rate else state.theta_dot
    return FlexState(acc.omega_dot, theta_rate, acc.theta_ddot, state.rho_dot, acc.rho_ddot)


def rk4_step(body: FlexibleBody, state: FlexState, dt, torque=None) -> FlexState:
    """One classical RK4 step of dt [s], the torque held over it."""
    field = lambda t, x: (derivative(body, x, torque), None)
    return integrate.rk4_step(field, jnp.zeros((), state.omega.dtype), dt, state)[0]


def mass_matrix(body: FlexibleBody, state: FlexState):
    """The symmetric mass matrix of (F.10), (6 + N + M, 6 + N + M) for an unbatched state,
    in the order (a_B, omega_dot, theta_ddot, rho_ddot)."""
    A, B, D, _, _, columns = _system(body, state)
    top = jnp.concatenate([jnp.concatenate([A, B], axis=1), jnp.concatenate([B.T, D], axis=1)], axis=0)
    if not columns:
        return top
    C = jnp.stack([jnp.concatenate([cv, cw]) for cv, cw, _, _, _ in columns], axis=1)
    diag = jnp.diag(jnp.stack([m_f for _, _, m_f, _, _ in columns]))
    return jnp.concatenate([jnp.concatenate([top, C], axis=1), jnp.concatenate([C.T, diag], axis=1)], axis=0)


# --- energy and momentum -------------------------------------------------------------------


def _about_centre(body: FlexibleBody, state: FlexState):
    """The parts with the system's centre of mass c and its rate c' relative to B (F.14)."""
    parts = [part for part, _ in _parts(body, state)]
    total = sum(part.mass for part in parts)
    c = sum(part.mass * part.r for part in parts) / total
    c_dot = sum(part.mass * part.r_dot for part in parts) / total
    return parts, c, c_dot


def angular_momentum(body: FlexibleBody, state: FlexState):
    """H_C (3, *b) [N m s]: the total angular momentum about the system's centre of mass,
    body components (F.15); conserved in inertial space without external torque."""
    omega = state.omega
    parts, c, c_dot = _about_centre(body, state)
    H = jnp.zeros_like(omega)
    for part in parts:
        rel = part.r - c
        H = H + part.mass * so3.cross(rel, so3.cross(omega, rel) + part.r_dot - c_dot)
        if part.inertia is not None:
            omega_p = omega if part.omega_rel is None else omega + part.omega_rel
            H = H + so3.matvec(part.inertia, omega_p)
    return H


def energy(body: FlexibleBody, state: FlexState):
    """E (*b) [J]: kinetic energy relative to the system's centre of mass plus the springs'
    energy (F.16) (Basilisk's rotational energy); constant without torque and damping."""
    omega = state.omega
    parts, c, c_dot = _about_centre(body, state)
    E = jnp.zeros_like(omega[0])
    for part in parts:
        v = so3.cross(omega, part.r - c) + part.r_dot - c_dot
        E = E + 0.5 * part.mass * so3.dot(v, v)
        if part.inertia is not None:
            omega_p = omega if part.omega_rel is None else omega + part.omega_rel
            E = E + 0.5 * so3.dot(omega_p, so3.matvec(part.inertia, omega_p))
    for i, panel in enumerate(body.panels):
        E = E + 0.5 * _scalar(panel.k, omega) * state.theta[i] ** 2
    for j, particle in enumerate(body.slosh):
        E = E + 0.5 * _scalar(particle.k, omega) * state.rho[j] ** 2
    return E


# --- the linearization about rest ----------------------------------------------------------


class Modes(NamedTuple):
    """The flexible modes on a free hub, by ascending frequency: frequency (K,) [rad/s],
    damping ratio (K,) [1], shape (K, K) M_eff-normalized columns over the free coordinates
    (the unlocked panels' theta, then the particles' rho)."""

    frequency: jax.Array
    damping_ratio: jax.Array
    shape: jax.Array


def modes(body: FlexibleBody, dtype=None) -> Modes:
    """The linearization about rest (omega = 0, theta = 0, rho = 0): K phi = w^2 M_eff phi with
    the rigid-body modes condensed out of the mass matrix (F.17)-(F.19); damping ratios
    zeta_r = phi_r^T C phi_r / (2 w_r) (F.20). A body with per-phase springs: each phase's,
    ``modes(at_phase(body, p))``."""
    if body.phases:
        raise ValueError(f"modes: the body's springs are given per phase ({body.phases}): pass at_phase(body, p)")
    if dtype is None:
        dtype = jnp.asarray(body.hub.inertia).dtype
        dtype = dtype if jnp.issubdtype(dtype, jnp.floating) else jnp.zeros(()).dtype
    state = initial_state(body, jnp.zeros(3, dtype))
    M = mass_matrix(body, state)
    free = [6 + i for i, p in enumerate(body.panels) if not p.locked]
    free += [6 + len(body.panels) + j for j in range(len(body.slosh))]
    rigid = list(range(6))
    M_rr, M_rf, M_ff = M[np.ix_(rigid, rigid)], M[np.ix_(rigid, free)], M[np.ix_(free, free)]
    M_eff = M_ff - M_rf.T @ jnp.linalg.solve(M_rr, M_rf)
    springs = [p for p in body.panels if not p.locked] + list(body.slosh)
    if not springs:
        return Modes(jnp.zeros(0, dtype), jnp.zeros(0, dtype), jnp.zeros((0, 0), dtype))
    k = jnp.stack([jnp.asarray(p.k).astype(dtype) for p in springs])
    c = jnp.stack([jnp.asarray(p.c).astype(dtype) for p in springs])
    L = jnp.linalg.cholesky(M_eff)
    Linv = jax.scipy.linalg.solve_triangular(L, jnp.eye(len(free), dtype=dtype), lower=True)
    lam, Y = jnp.linalg.eigh(Linv @ (k[:, None] * Linv.T))
    phi = Linv.T @ Y
    frequency = jnp.sqrt(lam)
    return Modes(frequency, jnp.einsum("ir,i,ir->r", phi, c, phi) / (2.0 * frequency), phi)
