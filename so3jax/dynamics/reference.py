"""Reference trajectories R_d(t), Omega_d(t), Omega_d'(t) (docs/model.md §2).

A reference is a pytree with ``rate(t, phase)`` [rad/s], ``rate_dot(t, phase)``
[rad/s^2] and ``attitude(t, phase)`` -> R_d (3, 3), or ``None`` when R_d has no closed
form: the rollout then integrates R_d' = R_d hat(Omega_d) with the plant's SO(3)
integrator, from R_d(0) = I.
"""

from __future__ import annotations

import abc
from collections.abc import Callable

import jax
import jax.numpy as jnp

from so3jax.core import so3
from so3jax.core.pytree import pytree_dataclass, static_field


class Reference(abc.ABC):
    """The shape of a reference (docs/model.md §2): Omega_d(t) [rad/s] (3,), its derivative
    [rad/s^2] (3,), and R_d(t) (3, 3), or None where the rollout integrates
    R_d' = R_d hat(Omega_d) from R_d(0) = I. ``phase``: the mission phase holding at the
    step's start (a reference may switch on it or ignore it). A subclass is a pytree."""

    @abc.abstractmethod
    def rate(self, t, phase): ...

    @abc.abstractmethod
    def rate_dot(self, t, phase): ...

    @abc.abstractmethod
    def attitude(self, t, phase): ...

    def terms(self, t, phase):
        """(R_d, Omega_d, Omega_d') at t: what the loop reads at every stage (a reference that
        computes them from shared terms overrides it)."""
        return self.attitude(t, phase), self.rate(t, phase), self.rate_dot(t, phase)


@pytree_dataclass
class PiecewiseConstantRate(Reference):
    """Omega_d = rates[p] during phase p (starting at phase_times[p]), Omega_d' = 0.

    R_d(t) = start_attitudes[p] exp(hat(rates[p]) (t - phase_times[p])): closed form.
    Build with :func:`piecewise_constant_rate`.
    """

    rates: jax.Array  # (P, 3)
    phase_times: jax.Array  # (P,), phase_times[0] = 0
    start_attitudes: jax.Array  # (P, 3, 3), R_d at each phase start

    def rate(self, t, phase):
        return self.rates[phase]

    def rate_dot(self, t, phase):
        return jnp.zeros_like(self.rates[0])

    def attitude(self, t, phase, sin=jnp.sin):
        """R_d(t); sin: the sine of so3.expm1."""
        rate = self.rates[phase]
        start = self.start_attitudes[phase]
        return start + so3.matmul(start, so3.expm1(rate * (t - self.phase_times[phase]), sin))


def piecewise_constant_rate(rates, phase_times) -> PiecewiseConstantRate:
    """Reference that holds rates[p] from phase_times[p] (phase_times[0] must be 0)."""
    rates = jnp.asarray(rates)
    phase_times = jnp.asarray(phase_times, dtype=rates.dtype)
    return PiecewiseConstantRate(rates, phase_times, _start_attitudes(rates, phase_times))


@jax.jit
def _start_attitudes(rates, phase_times):
    """R_d at each phase start (P, 3, 3); jitted: one compilation instead of one per eager op."""
    starts = [jnp.eye(3, dtype=rates.dtype)]
    for p in range(1, rates.shape[0]):
        starts.append(so3.matmul(starts[-1], so3.exp(rates[p - 1] * (phase_times[p] - phase_times[p - 1]))))
    return jnp.stack(starts)


@pytree_dataclass
class RateFunction(Reference):
    """A user rate profile Omega_d(t) (JAX-traceable function of time [s] -> (3,)).

    ``rate_dot_fn`` defaults to the forward-mode derivative of ``rate_fn``; R_d is
    integrated by the rollout.
    """

    rate_fn: Callable = static_field()
    rate_dot_fn: Callable | None = static_field(default=None)

    def rate(self, t, phase):
        return self.rate_fn(t)

    def rate_dot(self, t, phase):
        if self.rate_dot_fn is not None:
            return self.rate_dot_fn(t)
        return jax.jvp(self.rate_fn, (t,), (jnp.ones_like(t),))[1]

    def attitude(self, t, phase):
        return None
