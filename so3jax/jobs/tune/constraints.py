"""[tune.constraints]: the sampled loop's multi-loop disk margin held above a floor by a
penalty on the tuning cost (docs/model.md §19.3).

At each iteration, each training scenario's loop is flown noise-free and disturbance-free
with the current gains to each constraint time (:func:`so3jax.sim.margins.nominal_state`),
outside the gradient; there its one-period map is linearized as a traced function of the
log-gains (:func:`~so3jax.sim.margins.linearize_traced`, the state held fixed) and its disk
margin alpha taken on a fixed grid (:func:`~so3jax.sim.margins.disk_alpha`), with its
Jacobian in forward mode (one JVP per log-gain). The cost adds

    weight * mean over points of max(0, alpha_req - alpha)^2 / alpha_req^2,
    alpha_req = 2 (g - 1) / (g + 1),  g = 10^(min_db / 20),

and its gradient, by the chain rule, that of each point's alpha. A point whose closed loop
is unstable (:func:`~so3jax.sim.margins.closed_loop_modes`) has alpha = 0 there (no
margin), a constant: its penalty is the largest and its gradient zero. The scenarios are
the training set's inertia scales: a seed changes only noise and disturbance, neither of
which the nominal flight has.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.jobs.tune.config import TuneConfig, constraint_times
from so3jax.jobs.tune.gains import to_gains, to_params
from so3jax.sim import margins
from so3jax.sim.gradients import scale_inertia
from so3jax.sim.margins import alpha_of_db, db_of_alpha

OMEGAS = 256  # the constraint's frequency grid: log-spaced over 6 decades up to the Nyquist frequency
COLUMNS = ("disk_margin_db", "margin_penalty")  # history.csv's columns of the constraint


@functools.partial(jax.jit, static_argnames=("controller", "kinds"))
def margin_and_jacobian(params, scenario, loop, controller, state, j, omegas, kinds):
    """((alpha, alpha per axis, (A, B, C)), d alpha / d params) of the loop linearized at
    tick j about ``state`` (held fixed) with gains to_gains(params): forward mode, one JVP
    per parameter; one compiled program for every state, tick and gains."""
    period = loop.period_steps * scenario.dt

    def alpha(p):
        A, B, C = margins.linearize_traced(scenario, loop, controller, to_gains(p), state, j, kinds)
        a, axes = margins.disk_alpha(A, B, C, period, omegas)
        return a, (a, axes, (A, B, C))

    jacobian, aux = jax.jacfwd(alpha, has_aux=True)(params)
    return aux, jacobian


def stable(A, B, C, period: float) -> bool:
    """Whether the closed loop A + BC's modes that the loop moves lie inside the unit circle."""
    lin = margins.Linearization(np.asarray(A, np.float64), np.asarray(B, np.float64), np.asarray(C, np.float64),
                                period)
    return margins.closed_loop_modes(lin).stable


def penalty(alphas, jacobians, alpha_required: float, weight: float):
    """(P, dP/dp) of P = weight mean_k max(0, alpha_req - alpha_k)^2 / alpha_req^2 over the
    points' alphas, from their Jacobians d alpha_k / dp (trees like the parameters p):
    dP/dp = -2 weight / (alpha_req^2 K) sum_k max(0, alpha_req - alpha_k) d alpha_k / dp."""
    shortfalls = [max(0.0, alpha_required - float(a)) for a in alphas]
    value = weight * float(np.mean(np.square(shortfalls))) / alpha_required**2
    factors = [-2.0 * weight * s / (alpha_required**2 * len(shortfalls)) for s in shortfalls]
    grad = jax.tree.map(lambda *jac: sum(jnp.asarray(f, jnp.result_type(d)) * d for f, d in zip(factors, jac)),
                        *jacobians)
    return value, grad


class MarginConstraint:
    """The disk-margin constraint of a campaign: its points (inertia scales x times), its
    penalty and gradient at given log-gains, and reports of fixed gains."""

    def __init__(self, config: TuneConfig, problem):
        spec = config.constraints.disk_margin
        self.min_db, self.weight, self.alpha_required = spec.min_db, spec.weight, alpha_of_db(spec.min_db)
        self.times = constraint_times(config)
        self.scenario, self.loop = problem.scenario, problem.loop
        self.controller = config.mission.controller(config.controller)[0]
        self.dtype = self.scenario.R0.dtype
        self.period = float(config.mission.period)
        self.ticks = tuple(margins.tick_index(self.scenario, self.loop, t) for t in self.times)
        self.omegas = jnp.asarray(margins.default_omegas(self.period, OMEGAS), self.dtype)

    def points(self, params, scales) -> list:
        """[(alpha, d alpha / d params, alpha per axis)] at each inertia scale and time
        (scale-major); alpha = 0 (and a zero derivative) where the closed loop is unstable."""
        gains = to_gains(params)
        out = []
        for scale in scales:
            scenario = scale_inertia(self.scenario, jnp.asarray(scale, self.dtype))
            for t, j in zip(self.times, self.ticks):
                state = margins.nominal_state(scenario, self.loop, self.controller, gains, t)
                kinds = margins.state_kinds(state)
                (alpha, axes, abc), jacobian = margin_and_jacobian(params, scenario, self.loop, self.controller,
                                                                   state, jnp.asarray(j, jnp.int32), self.omegas,
                                                                   kinds)
                if stable(*abc, self.period):
                    out.append((float(alpha), jacobian, np.asarray(axes)))
                else:
                    out.append((0.0, jax.tree.map(jnp.zeros_like, jacobian), np.zeros(np.shape(axes))))
        return out

    def evaluate(self, params, scales):
        """(penalty, its gradient (like params), history columns) at log-gains params over the
        inertia scales: weight * mean max(0, alpha_req - alpha)^2 / alpha_req^2."""
        points = self.points(params, scales)
        alphas = [alpha for alpha, _, _ in points]
        value, grad = penalty(alphas, [jacobian for _, jacobian, _ in points], self.alpha_required, self.weight)
        return value, grad, {"disk_margin_db": db_of_alpha(min(alphas)), "margin_penalty": value}

    def report(self, gains, scales) -> dict:
        """The multi-loop disk margin of fixed gains at each inertia scale and time: alpha and
        its gain interval [dB] ([scale][time]; 0 where unstable) and the smallest."""
        alphas = np.reshape([alpha for alpha, _, _ in self.points(to_params(gains), scales)],
                            (len(scales), len(self.times)))
        return {"alpha": alphas.tolist(), "db": [[db_of_alpha(a) for a in row] for row in alphas],
                "smallest_db": db_of_alpha(float(alphas.min()))}


def distinct(scales) -> list:
    """The distinct inertia scales of a batch, in order."""
    return list(dict.fromkeys(float(s) for s in np.asarray(scales).ravel()))


def validation_report(constraint: MarginConstraint, config: TuneConfig, initial, tuned) -> dict:
    """validation.json's ``disk_margin``: the floor, the times, and the initial and tuned
    gains' margins on the validation set's inertia scales."""
    scales = distinct(config.validation.inertia_scales)
    return {"min_db": constraint.min_db, "alpha_required": constraint.alpha_required, "weight": constraint.weight,
            "times": list(constraint.times), "inertia_scales": scales, "grid": OMEGAS,
            "initial": constraint.report(initial, scales), "tuned": constraint.report(tuned, scales)}
