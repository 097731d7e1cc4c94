"""The goals' normalized values g and their Jacobians dg/dp over a batch of dispersed
missions, for N sets of tuned parameters at once (the starts: a vmap), docs/model.md §16.6.

The parameters are flat vectors p (P,) (:func:`jax.flatten_util.ravel_pytree` of the
log-gains, :func:`so3jax.jobs.tune.gains.to_params`). Requirement and budget goals are
traced through the batch's rollouts (:func:`so3jax.missions.batched.sample_metrics`,
the attitude errors recorded on the mission's ``record_every`` grid, the one ``fly`` and
``sweep`` check requirements on) and differentiated in forward mode, one JVP per parameter.
Margin goals linearize each sample's loop at each time about its noise-free flight at the
current gains (:mod:`so3jax.jobs.sweep.margins`), the state held fixed, and differentiate
the grid's disk margins, all axes at once and of each axis (:func:`so3jax.sim.margins.disk_alpha`);
a point whose closed loop is unstable has g = :data:`UNSTABLE` rho, rho the spectral radius of the modes the loop
moves, and its derivative (an eigenvalue's, from the closed loop's).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.jobs.sweep import margins as sweep_margins
from so3jax.jobs.tune.gains import to_gains
from so3jax.jobs.tune.goals import budget_value, normalized
from so3jax.missions import batched
from so3jax.sim import margins, pointing, requirement_values
from so3jax.sim.rollout import block_steps

OMEGAS = 256  # a margin goal's frequency grid: log-spaced over 6 decades up to the Nyquist frequency
UNSTABLE = 100.0  # g of a margin point whose closed loop is unstable, times its spectral radius


class GoalValues:
    """g (N, G) and dg/dp (N, G, P) of the goals at N parameter vectors over a batch.

    ``unravel``: flat parameters (P,) -> the log-gains tree; ``controller``: the
    Controller flown; ``mission``: the campaign's (its record grid and phases)."""

    def __init__(self, goals, mission, controller, unravel):
        self.goals, self.mission, self.controller, self.unravel = goals, mission, controller, unravel
        self.traced = [i for i, g in enumerate(goals) if g.kind != "margin"]
        self.margins = [i for i, g in enumerate(goals) if g.kind == "margin"]
        scenario = self.scenario = mission.scenario()
        self.loop = mission.loop()  # the margin points' ticks
        self.block = block_steps(scenario.n_steps, mission.record_every, mission.period_steps)
        self.bounds = pointing.phase_bounds_of(scenario)
        self.plans = None  # on the first batch: the record grid's length is the rollout's
        self._jacobian = jax.jit(jax.vmap(jax.jacfwd(self._traced, has_aux=True), in_axes=(0, None)))
        self._alphas = jax.jit(jax.jacfwd(self._margin_alphas, has_aux=True), static_argnames=("kinds",))
        period = float(mission.period) if mission.period_steps is not None else 1.0
        self.period = period
        self.omegas = margins.default_omegas(period, OMEGAS)

    # --- requirement and budget goals: traced ---------------------------------------------

    def _results(self, p, inputs) -> dict:
        return batched.sample_metrics(inputs, to_gains(self.unravel(p)), controller=self.controller,
                                      mission=self.mission, record_every=self.mission.record_every, pointing=True)

    def _plan(self, p, inputs) -> None:
        """The requirements' plans on the record grid t_m = m b dt of the batch's rollouts."""
        if self.plans is not None:
            return
        shape = jax.eval_shape(self._results, p, inputs)["pointing_performance"].shape
        self.t = np.arange(shape[-2]) * (self.block * self.mission.dt)
        self.plans = {i: requirement_values.plan(self.goals[i].requirement, self.t, self.bounds)
                      for i in self.traced if self.goals[i].kind == "requirement"}

    def _traced(self, p, inputs):
        """(g of the traced goals (T,), (g, their values in their units (T,)))."""
        results = self._results(p, inputs)
        values = []
        for i in self.traced:
            goal = self.goals[i]
            if goal.kind == "requirement":
                e = results["pointing_performance" if goal.requirement.signal == "performance"
                            else "pointing_knowledge"]
                values.append(requirement_values.value(self.plans[i], e))
            else:
                values.append(budget_value(goal, results))
        values = jnp.stack(values) if values else jnp.zeros((0,), p.dtype)
        g = jnp.stack([normalized(self.goals[i], v) for i, v in zip(self.traced, values)]) if self.traced else values
        return g, (g, values)

    # --- margin goals: linearized about each sample's noise-free flight -------------------------

    def _margin_alphas(self, p, inputs, states, j, kinds):
        """((alpha (S, 4), the closed loop A + BC (S, n, n)), (alpha, A, B, C)) of each sample's
        loop at tick j: its disk margins all axes at once and of each axis (x, y, z)."""
        A, B, C, _ = sweep_margins.linearize(inputs, to_gains(self.unravel(p)), states, j,
                                             controller=self.controller, mission=self.mission, kinds=kinds)
        omegas = jnp.asarray(self.omegas, A.dtype)

        def alphas(abc):
            multi, axes = margins.disk_alpha(*abc, self.period, omegas)
            return jnp.concatenate([multi[None], axes])

        # one sample after another: XLA:CPU hangs on the forward derivative of a vmapped batch of eigvalsh
        alpha = jax.lax.map(alphas, (A, B, C))
        return (alpha, A + B @ C), (alpha, A, B, C)

    def _unstable_point(self, lin, d_closed):
        """(rho, d rho / dp (P,)) of an unstable point: the spectral radius of the modes the loop
        moves, d|z| = Re(conj(z) u^H dM v / (u^H v)) / |z| for its mode z (u, v: left and right
        eigenvectors of M = A + BC), d_closed: dM/dp (n, n, P)."""
        modes = margins.closed_loop_modes(lin)
        from scipy import linalg  # SciPy where it is used: the command line starts without it

        z, left, right = linalg.eig(lin.A + lin.B @ lin.C, left=True, right=True)
        k = int(np.argmax(np.where(modes.moved, np.abs(z), -np.inf)))
        u, v = left[:, k], right[:, k]
        dz = np.einsum("i,ijp,j->p", u.conj(), d_closed, v) / (u.conj() @ v)
        return float(np.abs(z[k])), np.real(np.conj(z[k]) * dz) / np.abs(z[k])

    def _margin_points(self, p, inputs, times, states=None):
        """(alpha (S, K, 4), g (S, K, 4), dg/dp (S, K, 4, P), the points' states) at one parameter
        vector: each sample's disk margins (all axes at once, x, y, z) at each time, its loop
        linearized about its noise-free flight (``states``: that flight's states, by default
        flown at p). g is 1 / alpha where the closed loop is stable, else UNSTABLE rho (rho > 1
        its spectral radius, whose derivative leads back to a stable loop)."""
        ticks = np.array([margins.tick_index(self.scenario, self.loop, t) for t in times], np.int32)
        order = np.argsort(ticks, kind="stable")
        if states is None:
            states = sweep_margins.fly(inputs, to_gains(self.unravel(p)), jnp.asarray(ticks[order]),
                                       controller=self.controller, mission=self.mission)
        S, K, n_p = len(np.asarray(inputs[0].J0)), len(times), p.shape[0]
        alpha = np.zeros((S, K, 4))
        g, d_g = np.full((S, K, 4), np.inf), np.zeros((S, K, 4, n_p))
        for at, k in enumerate(order):
            here = jax.tree.map(lambda x: x[:, at], states)
            kinds = sweep_margins.shared_kinds(jax.tree.map(np.asarray, here), S, times[k])
            (da, d_closed), (a, A, B, C) = self._alphas(p, inputs, here, jnp.asarray(ticks[k], jnp.int32),
                                                        kinds=kinds)
            A, B, C, a, da, d_closed = (np.asarray(x, np.float64) for x in (A, B, C, a, da, d_closed))
            alpha[:, k] = a
            for i in range(S):
                if not all(np.isfinite(x).all() for x in (A[i], B[i], C[i], d_closed[i])):
                    continue  # a flight gone non-finite: g infinite
                lin = margins.Linearization(A[i], B[i], C[i], self.period)
                if margins.closed_loop_modes(lin).stable:
                    g[i, k], d_g[i, k] = 1.0 / a[i], -da[i] / a[i, :, None] ** 2
                else:
                    rho, d_rho = self._unstable_point(lin, d_closed[i])
                    g[i, k], d_g[i, k] = UNSTABLE * rho, UNSTABLE * d_rho
        return alpha, g, d_g, states

    @staticmethod
    def _margin_goal(goal, alpha, g, d_g):
        """(g, dg/dp (P,), the worst margin in the goal's unit, None where a point is unstable)
        of one margin goal from its points (:meth:`_margin_points`): the worst point's of the
        goal's disk margins."""
        cols = list(goal.columns)
        g, d_g, alpha = g[:, :, cols], d_g[:, :, cols], alpha[:, :, cols]
        worst = np.unravel_index(np.argmax(g), g.shape)
        value = goal.margin_value(float(alpha[worst])) if (g < UNSTABLE).all() else None
        return goal.alpha_required * float(g[worst]), goal.alpha_required * d_g[worst], value

    # --- all goals -----------------------------------------------------------------------------

    def __call__(self, P, inputs):
        """(g (N, G), dg/dp (N, G, P), values (N, G) in the goals' units) at the N parameter
        vectors P (N, P) over the batch ``inputs`` (sample_metrics' inputs)."""
        N, G = P.shape[0], len(self.goals)
        g, values = np.zeros((N, G)), np.full((N, G), np.nan)
        jac = np.zeros((N, G, P.shape[1]))
        if self.traced:
            self._plan(P[0], inputs)
            d_g, (g_t, v_t) = self._jacobian(P, inputs)
            jac[:, self.traced] = np.asarray(d_g)
            g[:, self.traced], values[:, self.traced] = np.asarray(g_t), np.asarray(v_t)
        for n in range(N):
            points = {}  # the margin points of each distinct set of times, shared by their goals
            for i in self.margins:
                goal = self.goals[i]
                if goal.at not in points:
                    points[goal.at] = self._margin_points(P[n], inputs, goal.at)[:3]
                g[n, i], grad, value = self._margin_goal(goal, *points[goal.at])
                values[n, i] = np.nan if value is None else value
                jac[n, i] = grad
        return g, jac, values
