"""Attitude profiles as references (docs/model.md §2): rest-to-rest eigenaxis slews through
a list of attitudes, and an attitude table interpolated through its samples (the constant
rates, the paper's, a fixed attitude and the orbit frame, are
:class:`~so3jax.dynamics.reference.PiecewiseConstantRate`: :mod:`so3jax.components.references`).

Body-frame convention: R_d maps desired-body to inertial, R_d' = R_d hat(Omega_d), so
Omega_d = vee(R_d^T R_d') [rad/s] and Omega_d' [rad/s^2] its time derivative. Every method
is JAX-traceable in t [s] (jit, vmap, grad), computes in the dtype of the reference's
arrays (the builders keep their inputs' dtype) and ignores ``phase``. The builders check
their inputs (one-line ValueErrors): :func:`tabulated` reads the values, so it takes concrete
arrays; :func:`eigenaxis_slews` checks concrete values and builds traced ones unchecked (a
sweep's samples, vmapped). A reference whose leaves carry a trailing batch axis of several
trajectories (each sample's own slews, in a natively batched rollout) is evaluated lane by
lane."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.core import so3, tables
from so3jax.core.pytree import pytree_dataclass
from so3jax.dynamics.reference import Reference

_ROTATION_TOLERANCE = 1e-6  # |R^T R - I| (largest entry), |det R - 1|, ||q| - 1|


def _float_dtype(x):
    """x's dtype where it is floating, else JAX's default float (float64 with x64)."""
    dtype = jnp.asarray(x).dtype
    return dtype if jnp.issubdtype(dtype, jnp.floating) else jnp.asarray(0.0).dtype


def _time(t, like):
    """t [s] as a scalar of ``like``'s dtype (an explicit cast: no promotion)."""
    return jnp.asarray(t, dtype=like.dtype)


def _shared(reference, core_ndims: dict):
    """The reference with a trailing unit axis dropped from every leaf that has one beyond its
    core ndim: a reference shared by a natively batched rollout
    (:func:`so3jax.sim.rollout.rollout_batch`) gets one."""
    changes = {name: getattr(reference, name)[..., 0] for name, ndim in core_ndims.items()
               if jnp.ndim(getattr(reference, name)) > ndim}
    return dataclasses.replace(reference, **changes) if changes else reference


def _lanes(reference, core_ndims: dict) -> dict:
    """{leaf: whether it carries a trailing batch axis of several trajectories} (a sweep's
    samples' own references)."""
    return {name: jnp.ndim(getattr(reference, name)) > ndim and jnp.shape(getattr(reference, name))[-1] > 1
            for name, ndim in core_ndims.items()}


def _per_lane(reference, core_ndims: dict, method, t, phase):
    """``method(reference, t, phase)`` of a reference shared by a batch (:func:`_shared`), or,
    where its leaves carry a trailing batch axis of several trajectories (:func:`_lanes`),
    lane by lane: the outputs' batch axis last."""
    lanes = _lanes(reference, core_ndims)
    if not any(lanes.values()):
        return method(_shared(reference, core_ndims), t, phase)
    axes = dataclasses.replace(reference, **{name: -1 if lane else None for name, lane in lanes.items()})
    return jax.vmap(lambda r: method(r, t, phase), in_axes=(axes,), out_axes=-1)(reference)


def _check_rotations(name: str, r) -> None:
    """One-line ValueError unless r (K, 3, 3) holds rotations (orthonormal, det +1, to 1e-6)."""
    r = np.asarray(r, np.float64)
    gram = np.einsum("kji,kjl->kil", r, r) - np.eye(3)
    error = np.where(np.isfinite(gram).all(axis=(1, 2)), np.abs(gram).max(axis=(1, 2)), np.inf)
    det = np.linalg.det(np.where(np.isfinite(r), r, 0.0))
    bad = np.flatnonzero((error > _ROTATION_TOLERANCE) | (np.abs(det - 1.0) > _ROTATION_TOLERANCE))
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"{name}[{i}] is not a rotation: max |R^T R - I| = {error[i]:.3g}, det R = {det[i]:.9g} "
                         f"(tolerance {_ROTATION_TOLERANCE:g})")


def _check_shape(name: str, x, shape) -> None:
    """One-line ValueError unless x has ``shape`` (None: any length)."""
    ok = x.ndim == len(shape) and all(n is None or n == m for n, m in zip(shape, x.shape))
    if not ok:
        want = "(" + ", ".join("K" if n is None else str(n) for n in shape) + ("," if len(shape) == 1 else "") + ")"
        raise ValueError(f"{name} must have shape {want}, not {tuple(x.shape)}")


def _slew_timing(angle, max_rate, max_acceleration):
    """(pulse duration tau, coast duration) [s] of the minimum-time slew through ``angle`` [rad].

    One raised-sine pulse of peak A turns the rate by A tau / 2 and, from rest, the attitude by
    A tau^2 / 4; two pulses (no coast) turn A tau^2 / 2, so tau = sqrt(2 angle / A) while the
    peak rate sqrt(A angle / 2) stays within W, i.e. angle <= 2 W^2 / A; beyond, tau = 2 W / A
    and the rate coasts at W for (angle - 2 W^2 / A) / W.
    """
    coasting = angle > 2.0 * max_rate**2 / max_acceleration
    pulse = jnp.where(coasting, 2.0 * max_rate / max_acceleration, jnp.sqrt(2.0 * angle / max_acceleration))
    coast = jnp.where(coasting, angle / max_rate - 2.0 * max_rate / max_acceleration, 0.0)
    return pulse, coast


def slew_duration(angle, max_rate, max_acceleration):
    """Duration [s] of the minimum-time rest-to-rest slew through ``angle`` [rad] with raised-sine
    acceleration pulses of peak max_acceleration [rad/s^2] and rate <= max_rate [rad/s]:
    2 sqrt(2 angle / A) for angle <= 2 W^2 / A, else angle / W + 2 W / A."""
    pulse, coast = _slew_timing(angle, max_rate, max_acceleration)
    return 2.0 * pulse + coast


def _pulse(u):
    """The rising pulse per unit peak, u = s / tau in [0, 1]: (theta / (A tau^2), theta' / (A tau),
    theta'' / A) = (u^2/4 - sin^2(pi u) / (4 pi^2), u/2 - sin(2 pi u) / (4 pi), sin^2(pi u))."""
    sin = jnp.sin(math.pi * u)
    position = 0.25 * u * u - sin * sin / (4.0 * math.pi**2)
    return position, 0.5 * u - jnp.sin(2.0 * math.pi * u) / (4.0 * math.pi), sin * sin


def _slew_profile(s, angle, pulse, coast, duration, max_acceleration):
    """theta, theta', theta'' [rad, rad/s, rad/s^2] at s [s] after the slew's start: 0 before,
    the accelerating pulse on [0, tau), the coast at A tau / 2, the mirrored decelerating
    pulse (of the time left, duration - s) up to the duration, the angle after (rates 0)."""
    s = jnp.where(s < 0.0, 0.0, jnp.where(s > duration, duration, s))
    A = max_acceleration
    accelerating = s < pulse
    decelerating = s > pulse + coast
    safe_pulse = jnp.where(pulse > 0.0, pulse, 1.0)  # a zero-angle slew: no pulse, no division by 0
    position, speed, acceleration = _pulse(jnp.where(decelerating, duration - s, s) / safe_pulse)
    peak = 0.5 * A * pulse
    rising = A * pulse**2 * position
    coasting = 0.25 * A * pulse**2 + peak * (s - pulse)
    theta = jnp.where(accelerating, rising, jnp.where(decelerating, angle - rising, coasting))
    rate = jnp.where(accelerating | decelerating, A * pulse * speed, peak)
    acceleration = jnp.where(accelerating, A * acceleration, jnp.where(decelerating, -A * acceleration, 0.0))
    return theta, rate, acceleration


@pytree_dataclass
class EigenaxisSlews(Reference):
    """Rest-to-rest eigenaxis slews: slew k, from starts[k] to starts[k + 1], starts at times[k].

    R_d(t) = starts[k] exp(hat(axes[k]) theta_k(t - times[k])) for the last slew k started,
    starts[0] before the first; Omega_d = axes[k] theta_k', Omega_d' = axes[k] theta_k''.
    theta_k: a raised-sine acceleration pulse theta'' = A sin^2(pi s / tau) (s in [0, tau]),
    a coast at the rate limit, the mirrored pulse, then held at angles[k]. Build with
    :func:`eigenaxis_slews`.
    """

    times: jax.Array  # (K,) slew start times [s]
    starts: jax.Array  # (K + 1, 3, 3): R_d before slew 0, after slew 0, ..., after slew K - 1
    axes: jax.Array  # (K, 3) unit eigenaxes (0 for a zero-angle slew)
    angles: jax.Array  # (K,) [rad]
    pulses: jax.Array  # (K,) tau [s], each acceleration pulse's duration
    coasts: jax.Array  # (K,) [s] at max_rate
    durations: jax.Array  # (K,) [s] = 2 tau + coast
    max_rate: jax.Array  # () [rad/s]
    max_acceleration: jax.Array  # () A [rad/s^2]
    _CORE = {"times": 1, "starts": 3, "axes": 2, "angles": 1, "pulses": 1, "coasts": 1, "durations": 1,
             "max_rate": 0, "max_acceleration": 0}

    def _profile(self, t):
        """(k, s = t - times[k], theta, theta', theta'') of the last slew k started (k = 0 before
        the first), of a reference whose leaves have their core ndim."""
        k, s = self._slew_at(t)
        profile = _slew_profile(s, self.angles[k], self.pulses[k], self.coasts[k], self.durations[k],
                                self.max_acceleration)
        return (k, s) + profile

    def rate(self, t, phase):
        """Omega_d = axis_k theta_k' [rad/s]."""
        return self.terms(t, phase)[1]

    def rate_dot(self, t, phase):
        """Omega_d' = axis_k theta_k'' [rad/s^2]."""
        return self.terms(t, phase)[2]

    def attitude(self, t, phase):
        """R_d = starts[k] exp(hat(axis_k) theta_k); the target starts[k + 1] itself once slew k ends."""
        return self.terms(t, phase)[0]

    def terms(self, t, phase):
        """(R_d, Omega_d, Omega_d') from one evaluation of the profile. A batch of plans (its
        leaves with a trailing batch axis) evaluates the profile only while a lane slews: held,
        every lane's attitude is a start of its plan and its rates are 0, the same values."""
        if not any(_lanes(self, self._CORE).values()):  # shared by the batch: one evaluation
            return _per_lane(self, self._CORE, EigenaxisSlews._terms, t, phase)
        held, slewing = _per_lane(self, self._CORE, EigenaxisSlews._held, t, phase)
        zeros = jnp.zeros(held.shape[1:], held.dtype)
        return jax.lax.cond(jnp.any(slewing), lambda: _per_lane(self, self._CORE, EigenaxisSlews._terms, t, phase),
                            lambda: (held, zeros, zeros))

    def _held(self, t, phase):
        """(R_d where no slew is under way: starts[k], or starts[k + 1] once slew k ends;
        whether slew k is under way, 0 < t - times[k] < durations[k])."""
        k, s = self._slew_at(t)
        return jnp.where(s >= self.durations[k], self.starts[k + 1], self.starts[k]), (s > 0) & (s < self.durations[k])

    def _slew_at(self, t):
        """(k, t - times[k]) of the last slew k started (k = 0 before the first)."""
        t = _time(t, self.times)
        k = jnp.maximum(jnp.searchsorted(self.times, t, side="right", method="compare_all") - 1, 0)
        return k, t - self.times[k]

    def _terms(self, t, phase):
        k, s, theta, rate, acceleration = self._profile(t)
        turning = so3.matmul(self.starts[k], so3.exp(self.axes[k] * theta, select=True))
        return jnp.where(s >= self.durations[k], self.starts[k + 1], turning), self.axes[k] * rate, \
            self.axes[k] * acceleration


@jax.jit
def _slew_plan(start, attitudes, max_rate, max_acceleration):
    """(starts, axes, angles, pulses, coasts, durations) of eigenaxis slews through ``attitudes``."""
    starts = jnp.concatenate([start[None], attitudes])
    rotvecs = jax.vmap(lambda a, b: so3.log(so3.rmatmul(a, b), select=True))(starts[:-1], starts[1:])
    angles = so3.safe_norm(rotvecs.T)
    axes = rotvecs / jnp.where(angles > 0.0, angles, 1.0)[:, None]
    pulses, coasts = _slew_timing(angles, max_rate, max_acceleration)
    return starts, axes, angles, pulses, coasts, 2.0 * pulses + coasts


def overlapping(start, attitudes, times, max_rate, max_acceleration) -> np.ndarray:
    """Whether each plan of a batch is impossible: its times (..., K) [s] not finite, not
    ascending or below 0, or a slew ending after the next one starts (:func:`eigenaxis_slews`'
    checks; start (..., 3, 3), attitudes (..., K, 3, 3), max_rate and max_acceleration (...),
    each possibly shared by the batch), in float64."""
    times = np.asarray(times, np.float64)
    batch = times.shape[:-1]

    def flat(x, core: int):  # broadcast to the batch, one batch axis
        x = np.asarray(x, np.float64)
        x = np.broadcast_to(x, batch + x.shape[x.ndim - core:])
        return x.reshape((-1,) + x.shape[len(batch):])

    plan = jax.vmap(_slew_plan)(flat(start, 2), flat(attitudes, 3), flat(max_rate, 0), flat(max_acceleration, 0))
    ends = times + np.asarray(plan[-1], np.float64).reshape(times.shape)
    bad = ~np.all(np.isfinite(times), axis=-1) | (times[..., 0] < 0.0) | np.any(np.diff(times, axis=-1) < 0.0, axis=-1)
    return bad | np.any(_late(times, ends, np.finfo(np.float64).eps), axis=-1)


def _late(times, ends, eps):
    """(..., K - 1) whether slew k ends after slew k + 1 starts (beyond 16 eps of round-off)."""
    return ends[..., :-1] > times[..., 1:] + 16.0 * eps * np.maximum(1.0, np.abs(ends[..., :-1]))


def eigenaxis_slews(start, attitudes, times, max_rate, max_acceleration) -> EigenaxisSlews:
    """Rest-to-rest eigenaxis slews from ``start`` (3, 3) = R_d(0) through ``attitudes`` (K, 3, 3),
    slew k starting at times[k] [s] (ascending, times[0] >= 0), each in minimum time under
    |Omega_d| <= max_rate [rad/s] and raised-sine acceleration pulses of peak max_acceleration
    [rad/s^2] (:func:`slew_duration`); the attitude is held between slews. Slew k turns about the
    fixed axis of log(R_{k-1}^T R_k) (R_{-1} = start). ValueError where a slew would end after the
    next one starts (``durations`` gives each slew's duration). Traceable: traced values are
    not checked (a sweep checks each sample's where it draws them).
    """
    dtype = _float_dtype(attitudes)
    attitudes = jnp.asarray(attitudes, dtype=dtype)
    start, times = jnp.asarray(start, dtype=dtype), jnp.asarray(times, dtype=dtype)
    max_rate, max_acceleration = jnp.asarray(max_rate, dtype=dtype), jnp.asarray(max_acceleration, dtype=dtype)
    _check_shape("eigenaxis_slews start", start, (3, 3))
    _check_shape("eigenaxis_slews attitudes", attitudes, (None, 3, 3))
    K = attitudes.shape[0]
    _check_shape("eigenaxis_slews times", times, (K,))
    if K == 0:
        raise ValueError("eigenaxis_slews: no attitudes (attitudes must have shape (K, 3, 3) with K >= 1)")
    if any(isinstance(x, jax.core.Tracer) for x in (start, attitudes, times, max_rate, max_acceleration)):
        return EigenaxisSlews(times, *_slew_plan(start, attitudes, max_rate, max_acceleration), max_rate,
                              max_acceleration)  # traced (a sweep's samples): checked where they are drawn
    for name, value in (("max_rate", max_rate), ("max_acceleration", max_acceleration)):
        if value.shape != () or not float(value) > 0.0 or not np.isfinite(float(value)):
            raise ValueError(f"eigenaxis_slews: {name} must be a positive finite scalar, not {np.asarray(value)}")
    t = np.asarray(times, np.float64)
    if not np.isfinite(t).all() or t[0] < 0.0:
        raise ValueError(f"eigenaxis_slews: times must be finite and times[0] >= 0, not {t.tolist()}")
    if np.any(np.diff(t) < 0.0):
        k = int(np.flatnonzero(np.diff(t) < 0.0)[0])
        raise ValueError(f"eigenaxis_slews: times must be ascending: times[{k + 1}] = {t[k + 1]:g} s "
                         f"< times[{k}] = {t[k]:g} s")
    _check_rotations("eigenaxis_slews start", start[None])
    _check_rotations("eigenaxis_slews attitudes", attitudes)
    plan = _slew_plan(start, attitudes, max_rate, max_acceleration)
    ends = t + np.asarray(plan[-1], np.float64)
    late = np.flatnonzero(_late(t, ends, float(jnp.finfo(dtype).eps)))
    if late.size:
        k = int(late[0])
        raise ValueError(f"eigenaxis_slews: slew {k} ends at {ends[k]:.9g} s (duration {ends[k] - t[k]:.9g} s), "
                         f"after slew {k + 1} starts at {t[k + 1]:.9g} s")
    return EigenaxisSlews(times, *plan, max_rate, max_acceleration)


# --- a tabulated attitude history ---------------------------------------------------------------


@pytree_dataclass
class Tabulated(Reference):
    """An attitude history R_k at times t_k [s] (K >= 2), interpolated C1 through every sample.

    On [t_k, t_{k+1}]: R_d(t) = R_k exp(hat(p(t))), p the cubic Hermite with p(t_k) = 0,
    p'(t_k) = w_k, p(t_{k+1}) = log(R_k^T R_{k+1}), p'(t_{k+1}) = J_r^{-1}(p(t_{k+1})) w_{k+1}
    (so the body rate at knot k is w_k [rad/s]). Omega_d = vee(R_d^T R_d') and Omega_d' are the
    interpolant's own derivatives, by forward-mode differentiation in t. Outside [t_0, t_{K-1}]
    the end attitude is held, Omega_d = Omega_d' = 0. Build with :func:`tabulated`.
    """

    times: jax.Array  # (K,) [s], strictly increasing
    rotations: jax.Array  # (K, 3, 3)
    rates: jax.Array  # (K, 3) w_k [rad/s], body rates at the knots
    increments: jax.Array  # (K - 1, 3) log(R_k^T R_{k+1})
    end_slopes: jax.Array  # (K - 1, 3) J_r^{-1}(increments[k]) w_{k+1} [rad/s]
    _CORE = {"times": 1, "rotations": 3, "rates": 2, "increments": 2, "end_slopes": 2}

    def _interval(self, t):
        """(k, t held in [t_0, t_{K-1}], dt/dt (1 inside, 0 where held), t' -> exp(hat(p(t'))) on interval k)."""
        times, t = self.times, _time(t, self.times)
        held = jnp.where(t < times[0], times[0], jnp.where(t > times[-1], times[-1], t))
        moving = jnp.where(held == t, 1.0, 0.0).astype(t.dtype)
        k = jnp.clip(jnp.searchsorted(times, held, side="right") - 1, 0, times.shape[0] - 2)
        start, h = times[k], times[k + 1] - times[k]
        w0, p1, slope1 = self.rates[k], self.increments[k], self.end_slopes[k]

        def turn(t):
            u = (t - start) / h
            u2 = u * u
            u3 = u2 * u
            p = (h * (u3 - 2.0 * u2 + u)) * w0 + (3.0 * u2 - 2.0 * u3) * p1 + (h * (u3 - u2)) * slope1
            return so3.exp(p, select=True)

        return k, held, moving, turn

    def attitude(self, t, phase):
        """R_d(t) = R_k exp(hat(p(t)))."""
        return _per_lane(self, self._CORE, Tabulated._attitude, t, phase)

    def rate(self, t, phase):
        """Omega_d = vee(R_d^T R_d') = vee(E^T E') [rad/s], E = exp(hat(p(t))) (forward mode)."""
        return _per_lane(self, self._CORE, Tabulated._rate, t, phase)

    def rate_dot(self, t, phase):
        """Omega_d' [rad/s^2] (forward mode over Omega_d)."""
        return _per_lane(self, self._CORE, Tabulated._rate_dot, t, phase)

    def _attitude(self, t, phase):
        k, held, _, turn = self._interval(t)
        return so3.matmul(self.rotations[k], turn(held))

    def _rate(self, t, phase):
        _, held, moving, turn = self._interval(t)
        return _body_rate(turn, held, moving)

    def _rate_dot(self, t, phase):
        _, held, moving, turn = self._interval(t)
        return jax.jvp(lambda t: _body_rate(turn, t, moving), (held,), (moving,))[1]


def _body_rate(turn, t, dt):
    """vee(E^T dE / dt) of E = turn(t) (3, 3), dt: the tangent of t (1, or 0 where held)."""
    E, E_dot = jax.jvp(turn, (t,), (dt,))
    return so3.skew_vee(so3.rmatmul(E, E_dot))


def _neighbours(K: int):
    """Two other knots for each knot's rate: (k - 1, k + 1) inside, (1, 2) and (K - 2, K - 3) at the ends."""
    k = np.arange(K)
    first, second = k - 1, k + 1
    first[0], second[0] = 1, 2
    first[-1], second[-1] = K - 2, K - 3
    return first, second


@jax.jit
def _table_terms(times, rotations, rates):
    """(rates, log(R_k^T R_{k+1}), J_r^{-1}(that) w_{k+1}) for Tabulated; rates None: estimated,
    from xi_j = log(R_k^T R_j) = d_j w_k + d_j^2 / 2 w_k' + O(d^3), d_j = t_j - t_k, at two other
    knots j: w_k = (d_2^2 xi_1 - d_1^2 xi_2) / (d_1 d_2 (d_2 - d_1)), central inside, one-sided at
    the ends (both second order); K = 2: w_0 = w_1 = log(R_0^T R_1) / (t_1 - t_0). One log for all."""
    K = times.shape[0]
    k = np.arange(K - 1)
    a, b = [k], [k + 1]
    if rates is None and K > 2:
        first, second = _neighbours(K)
        a, b = a + [np.arange(K)] * 2, b + [first, second]
    a, b = np.concatenate(a), np.concatenate(b)
    logs = jax.vmap(lambda x, y: so3.log(so3.rmatmul(x, y), select=True))(rotations[a], rotations[b])
    increments = logs[:K - 1]
    if rates is None and K == 2:
        rates = jnp.concatenate([increments, increments]) / (times[1] - times[0])
    elif rates is None:
        xi1, xi2 = logs[K - 1:2 * K - 1], logs[2 * K - 1:]
        d1, d2 = (times[first] - times)[:, None], (times[second] - times)[:, None]
        rates = (d2 * d2 * xi1 - d1 * d1 * xi2) / (d1 * d2 * (d2 - d1))
    return rates, increments, jax.vmap(so3.jr_inv_apply)(increments, rates[1:])


def tabulated(times, rotations, rates=None) -> Tabulated:
    """The C1 interpolant of :class:`Tabulated` through rotations (K, 3, 3) at times (K,) [s]
    (strictly increasing, K >= 2), with body rates (K, 3) [rad/s] at the knots where given, else
    estimated by second-order differences of the logs of the relative rotations to the
    neighbouring knots (central inside, one-sided at the ends)."""
    dtype = _float_dtype(rotations)
    rotations, times = jnp.asarray(rotations, dtype=dtype), jnp.asarray(times, dtype=dtype)
    if isinstance(times, jax.core.Tracer) and rates is None:  # a sweep's sample: checked where drawn
        return Tabulated(times, rotations, *_table_terms(times, rotations, None))
    _check_shape("tabulated times", times, (None,))
    K = times.shape[0]
    if K < 2:
        raise ValueError(f"tabulated: at least 2 samples are needed, not {K}")
    _check_shape("tabulated rotations", rotations, (K, 3, 3))
    t = np.asarray(times, np.float64)
    if not np.isfinite(t).all():
        raise ValueError("tabulated: times must be finite")
    steps = np.diff(t)
    if np.any(steps <= 0.0):
        k = int(np.flatnonzero(steps <= 0.0)[0])
        raise ValueError(f"tabulated: times must be strictly increasing: times[{k + 1}] = {t[k + 1]:g} s "
                         f"<= times[{k}] = {t[k]:g} s")
    _check_rotations("tabulated rotations", rotations)
    if rates is not None:
        rates = jnp.asarray(rates, dtype=dtype)
        _check_shape("tabulated rates", rates, (K, 3))
        if not np.isfinite(np.asarray(rates, np.float64)).all():
            raise ValueError("tabulated: rates must be finite")
    return Tabulated(times, rotations, *_table_terms(times, rotations, rates))


def quaternion_to_rotation(q) -> np.ndarray:
    """Rotation matrices (K, 3, 3) of unit quaternions q (K, 4) [w, x, y, z] (Hamilton; the
    matrix maps body to inertial as R_d does)."""
    q = np.asarray(q, np.float64)
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=-2)


_TABLE_COLUMNS = ("t", "qw", "qx", "qy", "qz")


def read_attitude_table(path) -> tuple[np.ndarray, np.ndarray]:
    """(times (K,) [s], rotations (K, 3, 3)), float64, from a CSV file (a header line naming the
    columns t, qw, qx, qy, qz, in any order) or a .npz file (arrays t (K,) and q (K, 4)
    [w, x, y, z]) of unit quaternions (to 1e-6; normalized). For :func:`tabulated`."""
    path = Path(path)
    if path.suffix == ".npz":
        times, q = tables.read_npz_arrays(path, {"t": "(K,)", "q": "(K, 4) [w, x, y, z]"})
        rows = [f"q[{i}]" for i in range(len(q))]
    else:
        columns = tables.read_csv_columns(path, _TABLE_COLUMNS)
        times = columns["t"]
        q = np.stack([columns[name] for name in _TABLE_COLUMNS[1:]], axis=-1)
        rows = [f"line {i + 2}" for i in range(len(q))]
    if times.ndim != 1 or q.shape != (times.shape[0], 4):
        raise ValueError(f"{path}: t must have shape (K,) and q (K, 4), not {times.shape} and {q.shape}")
    norms = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(~(np.abs(norms - 1.0) <= _ROTATION_TOLERANCE))
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"{path}: {rows[i]} (t = {times[i]:g} s): quaternion norm {norms[i]:.9g}, not 1 "
                         f"(tolerance {_ROTATION_TOLERANCE:g})")
    return times, quaternion_to_rotation(q / norms[:, None])
