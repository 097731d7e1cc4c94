"""Stability margins of the sampled closed loop, broken at the actuator input (docs/model.md §8.1).

Over one control period Delta_c = m dt [s] the sampled loop of :mod:`so3jax.sim.loop` is a map

    x_{j+1} = Phi(x_j, w_j),    y_j = tau_c,j(x_j)                                    (M.1)

with the loop broken where the controller's command enters the actuator: w_j (3,) [N m]
is the actuator's input at tick j (``loop.actuator.command(state, w_j, Omega_hat_j)`` in
place of the command), y_j (3,) [N m] the command the controller computed at tick j, and
Phi the tick (sensors, estimator, controller and its state update, actuator) followed by
the m plant steps under the held input, with zero disturbance. The loop closes with
w = y. About a nominal point (x, w = y(x)), forward-mode AD gives

    dx_{j+1} = A dx_j + B dw_j,    dy_j = C dx_j                                      (M.2)

(y does not depend on w: no feedthrough), and the loop transfer in the negative-feedback
convention, broken at all three axes,

    L(z) = -C (zI - A)^{-1} B,    z = exp(i omega Delta_c),  0 < omega <= pi / Delta_c [rad/s]   (M.3)

(w = y is positive feedback of H = C (zI - A)^{-1} B, so L = -H). Margins of (M.3):
:func:`loop_at_a_time` (classical gain, phase and delay margins per axis, the other two
closed) and :func:`disk_margin` (Seiler, Packard and Gahinet 2020, balanced disks).

The state's coordinates are local (:class:`Linearization`): each rotation by its
body-frame error delta [rad], R = R_nominal exp(hat(delta)), the other float leaves as
they are. The margins are taken about a state of the noise-free, disturbance-free flight
(:func:`nominal_state`), the one-period map treated as time-invariant there: exact at a
relative equilibrium (a constant-rate reference tracked steadily at constant inertia,
the filter converged: the map in these coordinates is then the same every period);
elsewhere the map changes as the nominal state does (a tracking transient, the filter's
covariance converging, the inertia of a deployment), by O(that change over one period)
per period. (In the 9 entries of each R instead, a reference rotating at Omega_d would
make the map change by O(|Omega_d| Delta_c) per period even at a relative equilibrium.)

:func:`linearize_traced` and :func:`disk_alpha` are the same linearization and the multi-loop
disk margin (on a fixed grid) as traceable JAX functions of the gains, the nominal state held
fixed: the tuning constraint of :mod:`so3jax.jobs.tune.constraints` (docs/model.md §19.3).

The closed loop w = y is stable when every mode of A + BC that the loop moves lies inside
the unit circle, to NEUTRAL_GROWTH (:class:`Modes`); the modes it cannot move (a constant
gyro bias, the total angular momentum, a wheel's null-space speed: |z| = 1) are reported
apart. The margins of an unstable closed loop are not computed.

A mission with hinged panels or slosh particles (``Scenario.flexible``) carries their
coordinates in the State's ``flexible`` leaf, so they are coordinates of x like any other
(labels '.flexible.theta[i]', '.flexible.theta_dot[i]', '.flexible.rho[j]', ...): with the
command disconnected (B w = 0), the modes of A are the free hub's structural modes,
z = exp(s Delta_c) with s = -zeta omega +- i omega sqrt(1 - zeta^2) of
:func:`so3jax.dynamics.flexible.modes` (to the plant's RK4 step: (omega dt)^4 / 120 relative;
tests/test_flexible_margins.py). :func:`structural_modes` names them at a time (the hub's
inertia J(t)), and :func:`resolving_omegas` adds their resonances to a frequency grid.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.components.sensors import Sensors
from so3jax.controllers.base import Controller
from so3jax.dynamics import flexible
from so3jax.dynamics.scenario import Scenario
from so3jax.sim import loop as loops
from so3jax.sim.loop import Loop, State, initial_state, step, tick

NOISE_PARAMETERS = ("arw", "rrw", "sigma")  # a sensor's noise levels (gyro sigma_v, sigma_u; star tracker sigma)
FIXED_MODE_RESIDUE = 1e-6  # a closed-loop mode whose residue in C (zI - A - BC)^-1 B is below this share of
# the largest mode's is fixed (a conserved quantity: total momentum, seen from a turning body, is a pair on |z| = 1)
MODAL_CONDITION = 1e10  # the moved modes' eigenvectors worse conditioned than this: G by its resolvent, not modes
NEUTRAL_GROWTH = 1e-8  # a mode with |z| < 1 + this is not unstable: at most 1e-8 per period, a conserved
# quantity to round-off (the total momentum seen from a turning body: a pair on |z| = 1)
_ROTATION_TOLERANCE = 1e-8  # |R^T R - I|, |det R - 1| of a leaf taken as a rotation


# --- the one-period map ------------------------------------------------------------------


def noise_free(loop: Loop) -> Loop:
    """The loop with its sensors' noise levels zero: every field of a sensor named in
    ``NOISE_PARAMETERS`` (a gyro's angle and rate random walks sigma_v, sigma_u, a star
    tracker's sigma) replaced by zeros (``dataclasses.replace``). A gyro's initial bias b_0
    stays (a constant, not a noise), and so does the estimator: its assumed noise levels,
    hence its gain, are the flight's. ValueError for a sensor with none of those fields
    (its noise unknown here)."""

    def quiet(sensor):
        if sensor is None:
            return None
        names = [f.name for f in dataclasses.fields(sensor) if f.name in NOISE_PARAMETERS]
        if not names:
            raise ValueError(f"margins: sensor {type(sensor).__name__} has no noise level named "
                             f"{', '.join(NOISE_PARAMETERS)}: cannot fly it noise-free")
        return dataclasses.replace(sensor, **{n: jnp.zeros_like(jnp.asarray(getattr(sensor, n))) for n in names})

    return dataclasses.replace(loop, sensors=Sensors(quiet(loop.sensors.rate), quiet(loop.sensors.attitude)))


class _BrokenAt:
    """The loop's actuator with its command replaced by w (3,) [N m]: the loop broken at
    the actuator input. Everything else is the actuator's own."""

    def __init__(self, actuator, w):
        self.actuator, self.w = actuator, w

    def command(self, state, tau_c, Omega_hat):
        return self.actuator.command(state, self.w, Omega_hat)

    def __getattr__(self, name):
        return getattr(self.actuator, name)


def advance_tick(scenario: Scenario, loop: Loop, controller: Controller, gains, key, state: State, j, w=None):
    """(x_{j+1}, the tick's :class:`~so3jax.sim.loop.Tick`): tick j, its actuator fed w
    (None: the controller's command, the loop closed), then m plant steps with d = 0."""
    ticked = loop if w is None else dataclasses.replace(loop, actuator=_BrokenAt(loop.actuator, w))
    new, out = tick(scenario, ticked, controller, gains, key, state, j)
    d = jnp.zeros_like(state.Omega)
    m = loop.period_steps
    ks = j * m + jnp.arange(m, dtype=jnp.int32)
    new = jax.lax.scan(lambda s, k: (step(scenario, controller, gains, d, s, k, loop)[0], None), new, ks)[0]
    return new, out


def _check_sampled(loop: Loop) -> None:
    if not isinstance(loop, Loop) or loop.continuous:
        raise ValueError("margins need a sampled loop (a control period: control.mode = 'sampled')")


def first_formed_tick(loop: Loop) -> int:
    """The first tick at which every sensor of the loop has a reading (a rate-integrating gyro's
    first angle increment: tick 1); before it the feedback lacks a measurement (tick 0 of such
    a gyro: no rate feedback, the loop a bare double integrator)."""
    return max((s.first_reading for s in (loop.sensors.rate, loop.sensors.attitude) if s is not None), default=0)


def tick_index(scenario: Scenario, loop: Loop, t: float) -> int:
    """j = t / Delta_c, the tick at time t [s]; ValueError unless t >= 0 is a whole number of periods."""
    _check_sampled(loop)
    period = loop.period_steps * scenario.dt
    j = round(t / period)
    if not (math.isfinite(t) and t >= 0 and abs(t - j * period) <= 1e-9 * max(period, abs(t))):
        raise ValueError(f"t = {t} s is not a whole number of control periods ({period:g} s)")
    return int(j)


@functools.partial(jax.jit, static_argnames=("controller",))
def _fly(scenario, loop, controller, gains, key, n_ticks):
    """The state before tick n_ticks (traced: one program for every t)."""
    state = initial_state(scenario, controller, gains, (), loop)
    one = lambda j, state: advance_tick(scenario, loop, controller, gains, key, state, j)[0]
    return jax.lax.fori_loop(jnp.zeros((), jnp.int32), n_ticks, one, state)


def _as_dtype(tree, dtype):
    return jax.tree.map(lambda x: jnp.asarray(x, dtype), tree)


def nominal_state(scenario: Scenario, loop: Loop, controller: Controller, gains, t: float) -> State:
    """The loop's state at t [s] (a whole number of control periods: tick j = t / Delta_c,
    before that tick) flown from the scenario's initial state without sensor noise
    (:func:`noise_free`) and without disturbance (d = 0): a loop over the ticks (``fori_loop``
    with a traced count: one compiled program for every t), each tick followed by a scan
    over its m plant steps, as in a sampled rollout."""
    n = tick_index(scenario, loop, t)
    dtype = scenario.R0.dtype
    return _fly(scenario, noise_free(loop), controller, _as_dtype(gains, dtype), jax.random.key(0),
                jnp.asarray(n, jnp.int32))


# --- local coordinates of the state ------------------------------------------------------


def _is_rotation(x) -> bool:
    """A (3, 3) float leaf that is a rotation matrix (at the nominal point)."""
    x = np.asarray(x)
    if x.shape != (3, 3) or not np.issubdtype(x.dtype, np.floating):
        return False
    tolerance = max(_ROTATION_TOLERANCE, 100 * float(np.finfo(x.dtype).eps))
    return bool(np.abs(x.T @ x - np.eye(3)).max() < tolerance and abs(np.linalg.det(x) - 1.0) < tolerance)


def _kinds(state) -> tuple:
    """Per leaf of the state: 'rotation', 'vector' (another float leaf) or 'fixed' (held fixed)."""

    def kind(x):
        if not jnp.issubdtype(jnp.result_type(x), jnp.floating):
            return "fixed"
        return "rotation" if _is_rotation(x) else "vector"

    return tuple(kind(x) for x in jax.tree.leaves(state))


def _hat(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _exp(v) -> np.ndarray:
    """exp(hat(v)) (3, 3), Rodrigues' formula with its series below 1e-4 rad (NumPy float64)."""
    v = np.asarray(v, float)
    t2 = float(v @ v)
    a, b = (1 - t2 / 6, 0.5 - t2 / 24) if t2 < 1e-8 else (math.sin(math.sqrt(t2)) / math.sqrt(t2),
                                                           (1 - math.cos(math.sqrt(t2))) / t2)
    K = _hat(v)
    return np.eye(3) + a * K + b * (K @ K)


def _log(R) -> np.ndarray:
    """log(R)^vee (3,) [rad] of a rotation within a half turn (NumPy float64)."""
    s = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])  # sin(theta) axis
    c = 0.5 * (np.trace(R) - 1.0)
    sin = float(np.linalg.norm(s))
    return s * (math.atan2(sin, c) / sin if sin > 0 else 1.0)


def _skew_vee(M) -> np.ndarray:
    """(M - M^T)^vee / 2 over the last two axes."""
    return 0.5 * np.stack([M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0], M[..., 1, 0] - M[..., 0, 1]], -1)


class _Chart:
    """Local coordinates of the loop's state about a point: a rotation leaf R by delta [rad],
    R = R_point exp(hat(delta)); another float leaf by its values; integer leaves fixed."""

    def __init__(self, point, kinds):
        self.leaves, self.treedef = jax.tree.flatten(point)
        self.kinds = kinds

    def coordinates(self, state) -> np.ndarray:
        """x (n,) of a state (numpy)."""
        parts = [_log(np.asarray(c).T @ np.asarray(x)) if k == "rotation" else np.ravel(np.asarray(x))
                 for x, c, k in zip(jax.tree.leaves(state), self.leaves, self.kinds) if k != "fixed"]
        return np.concatenate(parts)

    def tangent_coordinates(self, tangents) -> np.ndarray:
        """(N, n) coordinates of N tangent vectors at the point (the float leaves, each with a
        leading axis N): delta = (R_point^T dR)^vee, dR = R_point hat(delta)."""
        floats = iter(tangents)
        parts = []
        for c, k in zip(self.leaves, self.kinds):
            if k == "fixed":
                continue
            d = np.asarray(next(floats))
            parts.append(_skew_vee(np.asarray(c).T @ d) if k == "rotation" else d.reshape(d.shape[0], -1))
        return np.concatenate(parts, axis=1)

    def state(self, v, dtype):
        """The state of coordinates v (n,)."""
        v = np.asarray(v, float)
        out, at = [], 0
        for c, k in zip(self.leaves, self.kinds):
            if k == "fixed":
                out.append(c)
                continue
            size = 3 if k == "rotation" else int(np.size(c))
            part = v[at:at + size]
            at += size
            out.append(jnp.asarray(np.asarray(c) @ _exp(part) if k == "rotation" else part.reshape(np.shape(c)), dtype))
        return self.treedef.unflatten(out)

    def basis(self, dtype):
        """The tangents along each coordinate, per float leaf with a leading axis n:
        R_point hat(e_c) for a rotation's delta_c, a unit entry for another leaf's."""
        sizes = [3 if k == "rotation" else int(np.size(c)) for c, k in zip(self.leaves, self.kinds) if k != "fixed"]
        n, at, out = sum(sizes), 0, []
        for c, k in ((c, k) for c, k in zip(self.leaves, self.kinds) if k != "fixed"):
            size = 3 if k == "rotation" else int(np.size(c))
            d = np.zeros((n,) + np.shape(c))
            for i in range(size):
                if k == "rotation":
                    d[at + i] = np.asarray(c) @ _hat(np.eye(3)[i])
                else:
                    d[(at + i,) + np.unravel_index(i, np.shape(c))] = 1.0
            at += size
            out.append(jnp.asarray(d, dtype))
        return out

    def labels(self, point) -> tuple:
        """What each coordinate is: its leaf's path and index ('.R:delta[0]', '.Omega[2]', ...)."""
        out = []
        for (path, x), k in zip(jax.tree_util.tree_flatten_with_path(point)[0], self.kinds):
            name = jax.tree_util.keystr(path)
            if k == "rotation":
                out += [f"{name}:delta[{i}]" for i in range(3)]
            elif k == "vector":
                shape = np.shape(x)
                out += [name + (str(list(i)) if shape else "") for i in np.ndindex(*shape)]
        return tuple(out)


@functools.partial(jax.jit, static_argnames=("controller", "kinds"))
def _period(scenario, loop, controller, gains, key, j, state, w, tangents, kinds):
    """(x_{j+1}, y_j, whether an actuator limit binds) of (M.1) from (state, w), and the
    derivatives of x_{j+1}'s float leaves and y_j along N directions: ``tangents`` (the
    state's float leaves, each with a leading axis N, then w's (N, 3)), one JVP each."""
    leaves, treedef = jax.tree.flatten(state)
    floats = [x for x, k in zip(leaves, kinds) if k != "fixed"]

    def f(floats, w):
        it = iter(floats)
        x = treedef.unflatten([x if k == "fixed" else next(it) for x, k in zip(leaves, kinds)])
        new, out = advance_tick(scenario, loop, controller, gains, key, x, j, w)
        new_floats = [x for x, k in zip(jax.tree.leaves(new), kinds) if k != "fixed"]
        return (new_floats, out.tau_cmd), (new, out.tau_cmd, loop.actuator.limits(x.actuator, new.held, w))

    jvp = lambda d_floats, d_w: jax.jvp(f, (floats, w), (d_floats, d_w), has_aux=True)[1:]
    (d_new, dy), (new, y, limits) = jax.vmap(jvp, out_axes=(0, None))(tangents[:-1], tangents[-1])
    return new, y, jnp.any(jnp.stack(limits)), d_new, dy


class _Map:
    """The one-period map (M.1) about a state: its compiled program and the chart of its
    input (about the state) and of its output (about the nominal x_{j+1})."""

    def __init__(self, scenario, loop, controller, gains, state, j, key):
        _check_sampled(loop)
        self.dtype = scenario.R0.dtype
        loop, gains = noise_free(loop), _as_dtype(gains, self.dtype)
        key = jax.random.key(0) if key is None else key
        kinds = _kinds(state)
        self.chart = _Chart(state, kinds)
        basis = self.chart.basis(self.dtype)
        n = basis[0].shape[0] if basis else 0
        eye = np.eye(n + 3)
        tangents = [jnp.concatenate([b, jnp.zeros((3,) + b.shape[1:], self.dtype)]) for b in basis]
        tangents.append(jnp.asarray(eye[:, n:], self.dtype))  # the directions of w (3,)
        self.run = lambda state, w: _period(scenario, loop, controller, gains, key, jnp.asarray(j, jnp.int32), state,
                                            jnp.asarray(w, self.dtype), tangents, kinds)
        self.n = n
        self.w = np.asarray(self.run(state, jnp.zeros(3, self.dtype))[1])  # y_j: no feedthrough from w
        self.nominal = self.run(state, self.w)
        next_kinds = _kinds(self.nominal[0])
        if next_kinds != kinds:
            raise ValueError("margins: the state's rotations are not rotations one period later")
        self.next_chart = _Chart(self.nominal[0], kinds)

    def __call__(self, v, w):
        new, y = self.run(self.chart.state(v, self.dtype), w)[:2]
        return self.next_chart.coordinates(new), np.asarray(y)


def one_period_map(scenario: Scenario, loop: Loop, controller: Controller, gains, state: State, j: int, key=None):
    """(phi, v, w): the one-period map (M.1) in the coordinates of :class:`Linearization`,
    phi(v, w) -> (x_{j+1} (n,), y_j (3,)) as NumPy arrays, and its nominal point (v (n,)
    the coordinates of ``state``: zeros for rotations; w = y_j of ``state``). The loop's
    sensors are made noise-free (:func:`noise_free`); key: the sensors' noise key (no
    effect without noise; default key(0)). It runs :func:`linearize`'s compiled program."""
    phi = _Map(scenario, loop, controller, gains, state, j, key)
    return phi, phi.chart.coordinates(state), phi.w.copy()


class Linearization(NamedTuple):
    """(M.2) about a nominal point, NumPy float64.

    Coordinates of x: every float leaf of the loop's :class:`~so3jax.sim.loop.State`, in
    tree order (``labels`` names them), a rotation (R, the estimate R_hat, a gyro's
    R_{j-1}, an integrated R_d) by its body-frame error delta [rad], R = R_nominal
    exp(hat(delta)), about the nominal state at the start of the period and about the
    nominal next state at its end. Not the 9 entries of R: the nominal state is in general
    not a fixed point of Phi (a rotating reference, a transient), so dPhi maps the tangent
    space at R_j into that at R_{j+1}, not into itself, and A iterated as a time-invariant
    map would leak into the directions normal to SO(3) (modes at |z| = 1 that the loop
    reaches). In local coordinates nothing leaves SO(3), and the map is exactly
    time-invariant at a relative equilibrium."""

    A: np.ndarray  # (n, n) dx_{j+1} / dx_j
    B: np.ndarray  # (n, 3) dx_{j+1} / dw_j, per N m
    C: np.ndarray  # (3, n) dy_j / dx_j [N m per unit of x]
    period: float  # Delta_c [s]
    labels: tuple = ()  # (n,) each coordinate's leaf ('.R:delta[0]', '.Omega[1]', ...)
    at_limit: bool = False  # an actuator limit binds at the point: the loop's gain through it is zero there


def linearize(scenario: Scenario, loop: Loop, controller: Controller, gains, state: State, j: int,
              key=None) -> Linearization:
    """A, B, C of (M.2) for the map (M.1) at tick j from ``state`` (the state before tick j,
    e.g. :func:`nominal_state`: one trajectory, no batch axes), w = the command of that
    state, by forward-mode AD: one JVP of the map per coordinate of :class:`Linearization`
    (``jax.jvp`` vmapped over the tangents R hat(e_c) of a rotation's delta_c and the unit
    vectors of the other float leaves and of w: ``jax.jacfwd`` in local coordinates),
    integer leaves held fixed; the tangents at the end of the period read as delta =
    (R^T dR)^vee, exact for dR tangent to SO(3), which every R the map produces stays on.
    The sensors' noise levels are zero here (:func:`noise_free`), so no noise enters the
    nominal point; the estimator keeps its assumed noise levels, hence the flight's gain."""
    phi = _Map(scenario, loop, controller, gains, state, j, key)
    new, _, at_limit, d_new, dy = phi.nominal
    d_x = phi.next_chart.tangent_coordinates(d_new)  # (n + 3, n)
    dy = np.asarray(dy, np.float64)
    n = phi.n
    if np.any(dy[n:]):
        raise AssertionError("the controller's command depends on the actuator's input")
    return Linearization(np.asarray(d_x[:n].T, np.float64), np.asarray(d_x[n:].T, np.float64), dy[:n].T.copy(),
                         float(loop.period_steps * scenario.dt), phi.chart.labels(state), bool(at_limit))


# --- a traceable linearization and disk margin (the tuning constraint, docs/model.md §19.3) --


def state_kinds(state) -> tuple:
    """Per leaf of a concrete state: 'rotation' (a rotation matrix there), 'vector' (another
    float leaf) or 'fixed' (an integer leaf): :func:`linearize_traced`'s ``kinds``."""
    return _kinds(state)


def _skew_vee_last(M):
    """(M - M^T)^vee / 2 over the last two axes (jnp)."""
    return 0.5 * jnp.stack([M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0], M[..., 1, 0] - M[..., 0, 1]], -1)


def _traced_basis(leaves, kinds, dtype):
    """:meth:`_Chart.basis` of traced leaves: per float leaf, its tangents along each
    coordinate (leading axis n), R hat(e_c) for a rotation's delta_c, a unit entry else."""
    floats = [(c, k) for c, k in zip(leaves, kinds) if k != "fixed"]
    sizes = [3 if k == "rotation" else int(np.size(c)) for c, k in floats]
    n, at, out = sum(sizes), 0, []
    hats = jnp.asarray(np.stack([_hat(e) for e in np.eye(3)]), dtype)  # hat(e_c), (3, 3, 3)
    for (c, k), size in zip(floats, sizes):
        block = c @ hats if k == "rotation" else jnp.eye(size, dtype=dtype).reshape((size,) + np.shape(c))
        out.append(jnp.zeros((n,) + np.shape(c), dtype).at[at:at + size].set(block))
        at += size
    return out


def linearize_traced(scenario: Scenario, loop: Loop, controller: Controller, gains, state: State, j, kinds=None,
                     key=None):
    """(A, B, C) of (M.2) as jnp arrays, a traceable function of ``gains`` (and of the
    scenario and loop): the same map, point and local coordinates as :func:`linearize`
    (one JVP per coordinate, a rotation's tangent at the end of the period read as
    (R^T dR)^vee about the nominal next state R), in jnp operations only, so that
    ``jax.jacfwd`` (or ``jax.grad``) of a function of (A, B, C) differentiates through it.

    The nominal ``state`` is held fixed (``jax.lax.stop_gradient``): a derivative with
    respect to the gains is that of the linearization about this state, its own dependence
    on the gains (the flight that reached it) left out; what follows from the state within
    the period does follow the gains: the nominal input w = y_j(state) (the command the
    gains compute there), the nominal next state the output's chart is centred on, and
    the map's derivatives. ``kinds``: :func:`state_kinds` of the state (required where the
    state is traced, e.g. an argument of a jitted function; the next state's leaves are
    taken to be of the same kinds, as :func:`linearize` checks). j: the tick (an int or a
    traced int32). No check of an actuator limit at the point (:func:`linearize`'s
    ``at_limit``)."""
    _check_sampled(loop)
    state = jax.lax.stop_gradient(state)
    kinds = _kinds(state) if kinds is None else tuple(kinds)
    dtype = scenario.R0.dtype
    loop, gains = noise_free(loop), _as_dtype(gains, dtype)
    key = jax.random.key(0) if key is None else key
    j = jnp.asarray(j, jnp.int32)
    basis = _traced_basis(jax.tree.leaves(state), kinds, dtype)
    n = basis[0].shape[0]
    tangents = [jnp.concatenate([b, jnp.zeros((3,) + b.shape[1:], dtype)]) for b in basis]
    tangents.append(jnp.eye(n + 3, dtype=dtype)[:, n:])  # the directions of w (3,)
    w = tick(scenario, loop, controller, gains, key, state, j)[1].tau_cmd  # y_j: no feedthrough from w
    new, _, _, d_new, dy = _period(scenario, loop, controller, gains, key, j, state, w, tangents, kinds)
    floats = [(c, k) for c, k in zip(jax.tree.leaves(new), kinds) if k != "fixed"]
    d_x = jnp.concatenate([_skew_vee_last(jnp.swapaxes(c, -1, -2) @ d) if k == "rotation" else d.reshape(d.shape[0], -1)
                           for (c, k), d in zip(floats, d_new)], axis=1)  # (n + 3, n)
    return d_x[:n].T, d_x[n:].T, dy[:n].T


def disk_alpha(A, B, C, period: float, omegas):
    """(alpha, alphas): the balanced disk margin (19.4) of all axes at once (the sigma_max
    lower bound of :func:`disk_margin`) and of each axis (q,), as jnp values differentiable
    in A, B, C: 1 / max over the grid ``omegas`` [rad/s] (e.g. :func:`default_omegas` with
    256 points) of sigma_max(S - I/2), S = I + C (zI - A - BC)^{-1} B, z = exp(i omega
    Delta_c), sigma_max^2 the largest eigenvalue of (S - I/2)^H (S - I/2) (``eigvalsh``), and
    of |S_ii - 1/2|. No refinement between the grid's points: each alpha is at least
    :func:`disk_margin`'s, by what the grid misses of the peak. Meaningful only where the
    closed loop A + BC is stable (:func:`closed_loop_modes`: not checked here)."""
    complex_dtype = jnp.complex128 if A.dtype == jnp.float64 else jnp.complex64
    theta = jnp.asarray(omegas, A.dtype) * period
    z = jax.lax.complex(jnp.cos(theta), jnp.sin(theta))  # exp(i omega Delta_c)
    n, q = B.shape
    closed = (A + B @ C).astype(complex_dtype)
    M = z[:, None, None] * jnp.eye(n, dtype=complex_dtype) - closed
    X = jnp.linalg.solve(M, jnp.broadcast_to(B.astype(complex_dtype), (z.shape[0], n, q)))
    D = C.astype(complex_dtype) @ X + 0.5 * jnp.eye(q, dtype=complex_dtype)  # S - I/2, (n_omega, q, q)
    gram = jnp.conj(jnp.swapaxes(D, -1, -2)) @ D
    peak = jnp.sqrt(_grid_max(jnp.linalg.eigvalsh(gram)[:, -1]))
    axes = _grid_max(jnp.abs(jnp.diagonal(D, axis1=1, axis2=2)))
    return 1.0 / peak, 1.0 / axes


def _grid_max(x):
    """The maximum over the grid (axis 0) of x, differentiated at the maximum's frequency alone:
    jnp.max's derivative is every point's tangent times its 0/1 indicator, NaN wherever one is."""
    k = jnp.argmax(jax.lax.stop_gradient(x), axis=0)
    return jnp.take_along_axis(x, k[None], axis=0)[0]


# --- frequency responses -----------------------------------------------------------------


def default_omegas(period: float, count: int = 2000, decades: float = 6.0) -> np.ndarray:
    """``count`` frequencies [rad/s] log-spaced over ``decades`` up to the Nyquist frequency pi / Delta_c."""
    top = math.log10(math.pi / period)
    return np.logspace(top - decades, top, count)


# The points added about each structural mode's frequency omega_r by resolving_omegas: omega_r (1 + u) for
# u = +-zeta_r times these (its half-power band is omega_r (1 +- zeta_r), the peak 1 / (2 zeta_r) there) ...
MODE_BAND = (0.125, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0)
# ... and for u = +- these (the mode as the loop moves it, closed about the other axes; an undamped mode)
MODE_SPREAD = (1e-4, 1e-3, 3e-3, 0.01, 0.02, 0.05, 0.1)


class StructuralMode(NamedTuple):
    """A structural mode of the free hub with its appendages and slosh at rest (docs/flexible.md
    (F.17)-(F.20)): frequency omega_r [rad/s] and damping ratio zeta_r [-]."""

    frequency: float  # omega_r [rad/s]
    damping_ratio: float  # zeta_r [-]

    @property
    def frequency_hz(self) -> float:
        """omega_r / 2 pi [Hz]."""
        return self.frequency / (2.0 * math.pi)

    def to_dict(self) -> dict:
        return _json({"frequency_hz": self.frequency_hz, "frequency": self.frequency,
                      "damping_ratio": self.damping_ratio})


def structural_modes(scenario: Scenario, t: float) -> tuple | None:
    """The :class:`StructuralMode` s of the scenario's flexible body at t [s], by ascending
    frequency (:func:`so3jax.dynamics.flexible.modes`): the free hub of the loop's inertia at
    t, J(t) of the step starting at t (wheels locked: the hub carries them), its panels' and
    particles' k and c those of the phase holding at t (:func:`so3jax.dynamics.flexible.at_phase`).
    None for a scenario without appendages or slosh."""
    body = scenario.flexible
    if body is None:
        return None
    dtype = scenario.R0.dtype
    k = int(round(t / scenario.dt))
    p = loops.phase(scenario, jnp.asarray(k, jnp.int32))
    J = loops.inertia(scenario, jnp.asarray(t, dtype), p)
    body = flexible.at_phase(body, int(p))
    body = dataclasses.replace(body, hub=dataclasses.replace(body.hub, inertia=jnp.asarray(J, dtype)))
    modes = flexible.modes(body, dtype)
    return tuple(StructuralMode(float(w), float(z)) for w, z in zip(np.asarray(modes.frequency, np.float64),
                                                                     np.asarray(modes.damping_ratio, np.float64)))


def resolving_omegas(period: float, modes=(), count: int = 2000, decades: float = 6.0) -> np.ndarray:
    """:func:`default_omegas` with points about each structural mode (:class:`StructuralMode`,
    or (omega_r, zeta_r) pairs) below the Nyquist frequency: omega_r itself and omega_r (1 + u)
    for u = +-zeta_r MODE_BAND (its half-power band omega_r (1 +- zeta_r), where a lightly
    damped mode's peak of height 1 / (2 zeta_r) lies, narrower than the log grid's spacing) and
    u = +-MODE_SPREAD (the resonance as the loop shifts it). Sorted, the log grid's own points
    kept: without modes, :func:`default_omegas`."""
    omegas = default_omegas(period, count, decades)
    if not modes:
        return omegas
    band = np.asarray(MODE_BAND)
    added = []
    for omega, zeta in modes:
        u = np.concatenate([[0.0], zeta * band, -zeta * band, MODE_SPREAD, -np.asarray(MODE_SPREAD)])
        added.append(omega * (1.0 + u))
    added = np.concatenate(added)
    added = added[(added > omegas[0]) & (added < omegas[-1] * (1.0 - 1e-9))]
    return np.unique(np.concatenate([omegas, added]))


def _resolvent(A, B, C, omegas, period):
    """C (zI - A)^{-1} B at z = exp(i omega Delta_c), (n_omega, p, q) complex."""
    z = np.exp(1j * np.asarray(omegas, float) * period)
    M = z[:, None, None] * np.eye(A.shape[0]) - A
    return C @ np.linalg.solve(M, np.broadcast_to(B.astype(complex), (len(z),) + B.shape))


def frequency_response(lin: Linearization, omegas) -> np.ndarray:
    """L(exp(i omega Delta_c)) = -C (zI - A)^{-1} B (M.3), (n_omega, 3, 3) complex [-]
    (N m per N m), all three axes broken; omegas [rad/s]."""
    return -_resolvent(lin.A, lin.B, lin.C, omegas, lin.period)


def axis_response(lin: Linearization, omegas) -> np.ndarray:
    """L_i(exp(i omega Delta_c)) of each axis's loop with the other axes closed
    (:func:`loop_at_a_time`), (n_omega, 3) complex [-]; omegas [rad/s]."""
    G = _Modal(lin).response(np.asarray(omegas, float))
    return _loop(np.diagonal(G, axis1=1, axis2=2))


def _closed_loop(lin: Linearization):
    return lin.A + lin.B @ lin.C


class Modes(NamedTuple):
    """The closed loop's eigenvalues z_k of A + BC and their residues |res_k| =
    |C v_k| |u_k^H B| / |u_k^H v_k| in C (zI - A - BC)^{-1} B (v_k, u_k: right and left
    eigenvectors): a mode with |res_k| < FIXED_MODE_RESIDUE max_k |res_k| is fixed, no
    feedback through the broken loop moves it (uncontrollable from w or unobservable in y:
    a constant gyro bias, the total angular momentum, a wheel's null-space speed), up to
    round-off and the nominal state's own change over a period."""

    eigenvalues: np.ndarray  # (n,) complex
    residues: np.ndarray  # (n,) [-]

    @property
    def moved(self) -> np.ndarray:
        finite = self.residues[np.isfinite(self.residues)]
        return self.residues >= FIXED_MODE_RESIDUE * finite.max(initial=0.0)

    @property
    def spectral_radius(self) -> float:
        """max |z_k| over the modes the loop moves (0 for none)."""
        return float(np.abs(self.eigenvalues[self.moved]).max(initial=0.0))

    @property
    def stable(self) -> bool:
        """Every mode the loop moves inside the unit circle, to NEUTRAL_GROWTH."""
        return self.spectral_radius < 1.0 + NEUTRAL_GROWTH

    @property
    def fixed_spectral_radius(self) -> float:
        """max |z_k| over the fixed modes (0 for none); 1 for a conserved quantity."""
        return float(np.abs(self.eigenvalues[~self.moved]).max(initial=0.0))


class _Modal:
    """The closed loop A + BC of one :class:`Linearization`, decomposed once (``linalg.eig``,
    left and right eigenvectors) for every frequency a search evaluates: its :class:`Modes`
    and G = C (zI - A - BC)^{-1} B (:meth:`response`)."""

    def __init__(self, lin: Linearization):
        self.lin = lin
        self.closed = _closed_loop(lin)
        from scipy import linalg  # SciPy where it is used: the command line starts without it

        z, left, right = linalg.eig(self.closed, left=True, right=True)
        uv = np.sum(left.conj() * right, axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            uB = (left.conj().T @ lin.B) / uv[:, None]  # u_k^H B / u_k^H v_k (n, 3)
        Cv = lin.C @ right  # C v_k (3, n)
        residues = np.linalg.norm(Cv, axis=0) * np.linalg.norm(uB, axis=1)
        self.modes = Modes(z, np.where(np.isfinite(residues), residues, np.inf))
        self._eig = z, right, Cv, uB

    @functools.cached_property
    def _modal_form(self):
        """(z_k (k,), C v_k (3, k), u_k^H B / u_k^H v_k (k, 3)) over the moved modes, or None
        where G is taken by its resolvent (:meth:`response`)."""
        z_k, V, Cv, uB = self._eig
        moved = self.modes.moved
        if moved.all() or not np.all(np.isfinite(uB[moved])) or np.linalg.cond(V[:, moved]) > MODAL_CONDITION:
            return None
        return z_k[moved], Cv[:, moved], uB[moved]

    def response(self, omegas) -> np.ndarray:
        """G = C (zI - A - BC)^{-1} B (n_omega, 3, 3), the closed loop's (S = I + G), omegas
        [rad/s], in modal form over the modes the loop moves, G(z) = sum_k (C v_k)(u_k^H B) /
        (u_k^H v_k) / (z - z_k): the fixed modes add nothing to G but round-off, which the
        resolvent would blow up wherever z meets them on the unit circle (a conserved momentum
        seen from the turning body). The full resolvent where the moved modes' eigenvectors
        are ill-conditioned (a defective closed loop), and for a closed loop without fixed modes."""
        form = self._modal_form
        if form is None:
            return _resolvent(self.closed, self.lin.B, self.lin.C, omegas, self.lin.period)
        z_k, Cv, uB = form
        z = np.exp(1j * np.asarray(omegas, float) * self.lin.period)
        weights = 1.0 / (z[:, None] - z_k[None, :])  # (n_omega, k)
        return np.einsum("wk,ik,kj->wij", weights, Cv, uB)


def closed_loop_modes(lin: Linearization) -> Modes:
    """The :class:`Modes` of the closed loop w = y, A + BC."""
    return _Modal(lin).modes


# --- classical margins, loop at a time ---------------------------------------------------


# The units of the margins' JSON keys (so3jax.results.units).
UNITS = {"t": "s", "spectral_radius": "-", "fixed_spectral_radius": "-", "alpha": "-", "frequency": "rad/s",
         "gain_margin_lower_db": "dB", "gain_margin_upper_db": "dB", "phase_crossover_lower": "rad/s",
         "phase_crossover_upper": "rad/s", "phase_margin_deg": "deg", "gain_crossover": "rad/s",
         "delay_margin_s": "s", "delay_margin_periods": "-"}


@dataclasses.dataclass(frozen=True)
class AxisMargins:
    """Margins of axis i's loop, the other axes closed (:func:`loop_at_a_time`)."""

    axis: int
    gain_margin_lower_db: float  # 20 log10 k_lower < 0: the loop goes unstable at gain factor k_lower (-inf: none)
    gain_margin_upper_db: float  # 20 log10 k_upper > 0 (inf: none)
    phase_crossover_lower: float  # omega [rad/s] of k_lower (nan: none)
    phase_crossover_upper: float  # omega [rad/s] of k_upper (nan: none)
    phase_margin_deg: float  # 180 + arg L_i(omega_gc) [deg] (inf: |L_i| never crosses 1)
    gain_crossover: float  # omega_gc [rad/s] (nan: none)
    delay_margin_s: float  # the smallest added delay [s] that destabilizes the loop (inf: none)
    delay_margin_periods: float  # the same in control periods

    def to_dict(self) -> dict:
        return _json(dataclasses.asdict(self))


@dataclasses.dataclass(frozen=True)
class LoopMargins:
    """:func:`loop_at_a_time`'s answer: ``axes`` None where the closed loop is unstable."""

    stable: bool  # spectral_radius < 1 + NEUTRAL_GROWTH
    spectral_radius: float  # of A + BC over the modes the loop moves (:class:`Modes`)
    fixed_spectral_radius: float  # of the fixed modes (1: a conserved quantity), for information
    axes: tuple | None  # (AxisMargins,) per axis, or None (unstable: no margins)
    at_limit: bool = False  # the linearization's: an actuator limit binds, its channel is open in (M.2)

    def to_dict(self) -> dict:
        """JSON-ready: a non-finite number (an infinite margin, a frequency that does not exist) is None."""
        return _json({"stable": self.stable, "spectral_radius": self.spectral_radius,
                      "fixed_spectral_radius": self.fixed_spectral_radius, "at_limit": self.at_limit,
                      "axes": None if self.axes is None else [a.to_dict() for a in self.axes]})


def _json(d):
    """Floats, with non-finite values as None (JSON's null)."""
    if isinstance(d, dict):
        return {k: _json(v) for k, v in d.items()}
    if isinstance(d, (list, tuple)):
        return [_json(v) for v in d]
    if isinstance(d, (float, np.floating)):
        return float(d) if math.isfinite(d) else None
    if isinstance(d, (np.bool_, np.integer)):
        return d.item()
    return d


class _Axis:
    """Axis i's loop transfer L_i(omega) = -C_i (zI - A_i)^{-1} B_i, A_i = A + B_o C_o (o: the other axes),
    from the closed loop's: S_i = (1 + L_i)^{-1} = 1 + G_ii with G = C (zI - A - BC)^{-1} B, so
    L_i = -G_ii / (1 + G_ii) (the push-through identity; G from the closed loop's :class:`_Modal`)."""

    def __init__(self, modal: _Modal, i: int):
        self.modal, self.i = modal, i

    def closed(self, omegas):
        """G_ii (n_omega,) complex."""
        return self.modal.response(np.atleast_1d(omegas))[:, self.i, self.i]

    def loop(self, omegas):
        return _loop(self.closed(omegas))


def _loop(g):
    """L_i = -G_ii / (1 + G_ii) from G_ii."""
    return -g / (1.0 + g)


def _roots(fn, omegas, values):
    """The zeros of fn(omega) between grid points where ``values`` changes sign (brentq)."""
    from scipy import optimize

    out = []
    for k in np.nonzero(np.sign(values[:-1]) * np.sign(values[1:]) < 0)[0]:
        out.append(optimize.brentq(fn, omegas[k], omegas[k + 1], xtol=1e-15 * omegas[k], rtol=4 * np.finfo(float).eps,
                                   maxiter=200))
    return np.asarray(out)


def _axis_margins(modal: _Modal, i: int, omegas, G_ii) -> AxisMargins:
    """Axis i's margins from G_ii on the grid, its crossings refined."""
    lin, axis = modal.lin, _Axis(modal, i)
    L = _loop(G_ii)
    scalar = lambda fn: (lambda w: fn(axis.loop(w)[0]))
    # phase crossovers: L_i real and negative, the loop then unstable at gain factor k = 1 / |L_i|
    w_pc = _roots(scalar(lambda x: x.imag), omegas, L.imag)
    nyquist = math.pi / lin.period
    if omegas[-1] >= nyquist * (1 - 1e-12):  # z = -1: L_i real there
        w_pc = np.append(w_pc, nyquist)
    L_pc = axis.loop(w_pc) if len(w_pc) else np.zeros(0, complex)
    negative = L_pc.real < 0
    w_pc, k_pc = w_pc[negative], 1.0 / np.abs(L_pc[negative])
    up, down = k_pc > 1, k_pc < 1
    k_up = k_pc[up].min(initial=np.inf)
    k_down = k_pc[down].max(initial=0.0)
    w_up = w_pc[up][np.argmin(k_pc[up])] if up.any() else np.nan
    w_down = w_pc[down][np.argmax(k_pc[down])] if down.any() else np.nan
    # gain crossovers: |L_i| = 1; phase margin 180 + arg L_i, delay margin its phase margin in [0, 2 pi) / omega
    w_gc = _roots(scalar(lambda x: np.log(np.abs(x))), omegas, np.log(np.abs(L)))
    if len(w_gc):
        pm = np.degrees(np.angle(-axis.loop(w_gc)))  # 180 + arg L in (-180, 180]
        worst = int(np.argmin(np.abs(pm)))
        delay = np.radians(np.mod(pm, 360.0)) / w_gc
        phase_margin, w_c, delay_margin = float(pm[worst]), float(w_gc[worst]), float(delay.min())
    else:
        phase_margin, w_c, delay_margin = math.inf, math.nan, math.inf
    with np.errstate(divide="ignore"):
        lower_db, upper_db = 20 * np.log10(k_down), 20 * np.log10(k_up)
    return AxisMargins(i, float(lower_db), float(upper_db), float(w_down), float(w_up), phase_margin, w_c,
                       delay_margin, delay_margin / lin.period)


def loop_at_a_time(lin: Linearization, omegas=None) -> LoopMargins:
    """Classical margins of each axis's loop (M.3) with the other axes closed:
    L_i(z) = -C_i (zI - A_i)^{-1} B_i, A_i = A + B_o C_o (o: the other two axes).

    Gain margins: at a phase crossover omega_pc (L_i real and negative, refined by brentq
    from the grid's sign changes of Im L_i; the Nyquist frequency included) the loop with
    gain factor k = 1 / |L_i(omega_pc)| has a pole on the unit circle; k_upper is the
    smallest such k > 1, k_lower the largest k < 1 (margins 20 log10 k [dB]; +-inf where
    none: a double integrator's loop has no k_lower > 0). Phase margin: 180 + arg L_i
    [deg] at the gain crossover |L_i| = 1 (brentq), the smallest in magnitude where there
    are several; delay margin: min over crossovers of (phase margin in [0, 2 pi)) /
    omega_gc [s], the extra delay exp(-i omega tau) that puts L_i through -1 (and in
    control periods). omegas: the grid [rad/s] (default :func:`default_omegas`); a crossing
    below its lowest frequency, or two between neighbouring points, goes unseen.

    The margins mean something only about a stable closed loop: where A + BC has a mode
    the loop moves with |z| >= 1 (:class:`Modes`), ``stable`` is False and ``axes`` None."""
    omegas = default_omegas(lin.period) if omegas is None else np.asarray(omegas, float)
    modal = _Modal(lin)
    modes = modal.modes
    rho = modes.spectral_radius
    stable = modes.stable
    axes = None
    if stable:
        G = modal.response(omegas)
        axes = tuple(_axis_margins(modal, i, omegas, G[:, i, i]) for i in range(lin.B.shape[1]))
    return LoopMargins(bool(stable), rho, modes.fixed_spectral_radius, axes, bool(lin.at_limit))


# --- disk margins ------------------------------------------------------------------------


def alpha_of_db(db: float) -> float:
    """The balanced disk margin alpha whose gain interval is +-db [dB]: 2 (g - 1) / (g + 1), g = 10^(db/20)."""
    g = 10.0 ** (db / 20.0)
    return 2.0 * (g - 1.0) / (g + 1.0)


def db_of_alpha(alpha: float) -> float:
    """The gain interval +-dB a disk margin alpha covers: 20 log10((1 + alpha/2) / (1 - alpha/2)) (inf from 2 on)."""
    a = alpha / 2.0
    return 20.0 * math.log10((1.0 + a) / (1.0 - a)) if a < 1.0 else math.inf


@dataclasses.dataclass(frozen=True)
class Disk:
    """A balanced disk margin alpha and the gain and phase variations it covers:
    gains in [(1 - alpha/2) / (1 + alpha/2), (1 + alpha/2) / (1 - alpha/2)] (dB; -inf, inf
    from alpha >= 2 on) and phases within +-2 atan(alpha / 2) (deg), each alone or together."""

    alpha: float  # [-]
    frequency: float  # omega [rad/s] where |S - I/2| peaks
    gain_margin_lower_db: float
    gain_margin_upper_db: float
    phase_margin_deg: float

    @classmethod
    def of(cls, alpha: float, frequency: float) -> Disk:
        upper = db_of_alpha(alpha)
        return cls(alpha, frequency, -upper, upper, math.degrees(2 * math.atan(alpha / 2.0)))

    def to_dict(self) -> dict:
        return _json(dataclasses.asdict(self))


@dataclasses.dataclass(frozen=True)
class DiskMargins:
    """:func:`disk_margin`'s answer: ``axes`` and ``multiloop`` None where the closed loop is unstable."""

    stable: bool
    spectral_radius: float
    axes: tuple | None  # (Disk,) per axis, the other axes closed
    multiloop: Disk | None  # all axes at once (a lower bound: sigma_max in place of mu)
    at_limit: bool = False  # the linearization's: an actuator limit binds, its channel is open in (M.2)

    def to_dict(self) -> dict:
        """JSON-ready (non-finite numbers as None)."""
        return _json({"stable": self.stable, "spectral_radius": self.spectral_radius, "at_limit": self.at_limit,
                      "axes": None if self.axes is None else [a.to_dict() for a in self.axes],
                      "multiloop": None if self.multiloop is None else self.multiloop.to_dict()})


def _peak(fn, omegas, values):
    """(max over omega of fn, where): the largest of its ``values`` on the grid refined between its
    neighbours (bounded Brent)."""
    from scipy import optimize

    k = int(np.argmax(values))
    lo, hi = omegas[max(k - 1, 0)], omegas[min(k + 1, len(omegas) - 1)]
    if hi > lo:
        found = optimize.minimize_scalar(lambda w: -fn(np.array([w]))[0], bounds=(lo, hi), method="bounded",
                                         options={"xatol": 1e-12 * hi})
        if -found.fun > values[k]:
            return float(-found.fun), float(found.x)
    return float(values[k]), float(omegas[k])


def disk_margin(lin: Linearization, omegas=None) -> DiskMargins:
    """Balanced (skew sigma = 0) disk margins (Seiler, Packard, Gahinet, "An introduction
    to disk margins", IEEE Control Systems 40(5), 2020):

        alpha = 1 / max_omega ||S - I/2||,    S = (I + L)^{-1} = I + C (zI - A - BC)^{-1} B

    per axis (the SISO loop L_i of :func:`loop_at_a_time`, the other axes closed: S_i =
    1 + G_ii, its largest value on the grid refined by bounded Brent) and multi-loop (all
    three axes varied at once, by the largest singular value of S - I/2 in place of the
    structured singular value mu: sigma_max >= mu, so this alpha is a lower bound on the
    simultaneous disk margin). Each with the gain interval [(1 - alpha/2) / (1 + alpha/2),
    (1 + alpha/2) / (1 - alpha/2)] [dB] and the phase margin 2 atan(alpha/2) [deg] it
    guarantees (:class:`Disk`). omegas [rad/s]: default :func:`default_omegas` (the
    endpoints omega -> 0 and pi / Delta_c included as they are in the grid). None where
    the closed loop is unstable."""
    omegas = default_omegas(lin.period) if omegas is None else np.asarray(omegas, float)
    modal = _Modal(lin)
    modes = modal.modes
    rho = modes.spectral_radius
    if not modes.stable:
        return DiskMargins(False, rho, None, None, bool(lin.at_limit))
    G, eye = modal.response(omegas), np.eye(lin.B.shape[1])
    norm = lambda G: np.linalg.norm(G + 0.5 * eye, ord=2, axis=(1, 2))  # sigma_max(S - I/2)
    axes = []
    for i in range(lin.B.shape[1]):
        axis = _Axis(modal, i)
        peak, where = _peak(lambda w: np.abs(axis.closed(w) + 0.5), omegas, np.abs(G[:, i, i] + 0.5))
        axes.append(Disk.of(1.0 / peak, where))
    peak, where = _peak(lambda w: norm(modal.response(w)), omegas, norm(G))
    return DiskMargins(True, rho, tuple(axes), Disk.of(1.0 / peak, where), bool(lin.at_limit))

