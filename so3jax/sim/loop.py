"""The closed loop as a wiring of components (docs/model.md §1-§6, §8).

    true state --sensors--> measurements --estimator--> estimate --controller--> command
        ^                                                                          |
        +------ plant (RK4 at dt) <-- applied torque <-- actuator (held over a tick) +

A :class:`Loop` holds the sensors, the estimator, the actuator and the control period;
the plant (inertia), reference and disturbance come from the :class:`~so3jax.dynamics.scenario.Scenario`,
the law from a :class:`~so3jax.controllers.Controller`. Each component owns a field of
:class:`State`. The plant (:func:`so3jax.dynamics.plant.derivative`) integrates the rigid body
and the actuator's state under the actuator's input (with the scenario's ``flexible`` body,
:func:`so3jax.dynamics.plant.flexible_derivative`: the hub, its panels and slosh particles,
their modal coordinates in the state, docs/model.md §8.9); one :func:`step` serves two wirings:

* sampled (``period_steps=m``, docs/model.md §8.1): at every m-th step a :func:`tick` runs
  sensors -> estimator -> controller -> actuator once (the controller's state by its
  ``update``, else forward Euler over the period), and the plant's RK4 steps see the
  actuator's input held over the period;
* continuous (``period_steps=None``, the paper's mode, docs/model.md §5): the same step with the
  law and the actuator's command evaluated in every RK4 stage on the true state, the
  controller's state integrated with the plant (``truth`` and no sensors).

Both take the metrics' torque sample of a step from the actuator's ``delivered`` at the
step start, from its own state.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.components import registry as components
from so3jax.components.actuators import Ideal, Wheels
from so3jax.components.base import Actuator, Estimate, Estimator, Filter, MomentumManager
from so3jax.components.estimators import Truth
from so3jax.components.faults import Faults
from so3jax.components.momentum import Thrusters
from so3jax.components.sensors import Sensors
from so3jax.controllers.base import Controller, Desired, Feedback, tracking_error
from so3jax.core import _trig, so3
from so3jax.core.integrate import OnSO3, rk4_step
from so3jax.core.pytree import pytree_dataclass, static_field
from so3jax.core.so3 import broadcast
from so3jax.dynamics import flexible, plant, stepped
from so3jax.dynamics.inertia import concrete_values
from so3jax.dynamics.plant import inertia_rate, stage_inertia
from so3jax.dynamics.scenario import Scenario
from so3jax.sim import metrics


@pytree_dataclass
class Loop:
    """The components between the true state and the torque on the body.

    period_steps: control period in plant steps (Delta_c = m dt, docs/model.md §8.1); None for
    the continuous-time controller of the paper's mode. The components' parameters have
    no batch axes where a batch of trajectories shares them (``so3.batch_like``), or
    their batch axes last where each trajectory has its own (``rollout_batch``'s loop_axes).
    """

    sensors: Sensors = Sensors()
    estimator: Estimator = Truth()
    actuator: Actuator = Ideal()
    period_steps: int | None = static_field(default=None)
    momentum: MomentumManager | None = None  # beside the actuator (docs/model.md §8.6), or None
    faults: Faults | None = None  # the failures the sampled loop rides through (docs/model.md §8.7), or None
    filter: Filter | None = None  # a structural filter at the tick (docs/model.md §8.8), or None

    @property
    def continuous(self) -> bool:
        return self.period_steps is None


PAPER_LOOP = Loop()


class State(NamedTuple):
    """Closed-loop state, a field per component; batch axes, if any, last."""

    R: jax.Array  # (3, 3) plant attitude, body -> inertial
    Omega: jax.Array  # (3,) plant body rate, rad/s
    controller: Any  # the law's internal state (docs/model.md §3)
    R_d: Any  # (3, 3) reference attitude when it is integrated, else ()
    actuator: Any = ()  # the actuator's state (wheels: speeds (N,) rad/s), or ()
    sensors: Any = ()  # gyro bias (3,) rad/s, or ()
    estimator: Any = ()  # the estimator's state (the prior for the next tick)
    held: Any = ()  # the actuator's input held over the current period (sampled wiring), or ()
    manager: Any = ()  # the momentum manager's state, or ()
    managed: Any = ()  # the momentum manager's input held until its next tick, or ()
    filter: Any = ()  # the structural filter's delays, or ()
    flexible: Any = ()  # the flexible body's so3jax.dynamics.flexible.Modal (theta, theta_dot, rho, rho_dot), or ()


class Tick(NamedTuple):
    """What a control tick computed (docs/model.md §8.1), at t_j."""

    t: jax.Array  # s
    desired: Desired
    estimate: Estimate
    bias: jax.Array  # (3,) true gyro bias b_j, rad/s
    tau_cmd: jax.Array  # (3,) the controller's command, N m
    tau_applied: jax.Array  # (3,) the control torque delivered at t_j (actuator.delivered), N m


def time(scenario: Scenario, k):
    """t_k = k dt [s] in the scenario's dtype."""
    dtype = scenario.R0.dtype
    return k.astype(dtype) * jnp.asarray(scenario.dt, dtype)


def midpoint(scenario: Scenario, t):
    """t + dt/2 [s]: the midpoint of the step starting at t, where the inertia's own steps
    switch (:func:`so3jax.dynamics.plant.stage_inertia`)."""
    return t + 0.5 * jnp.asarray(scenario.dt, scenario.R0.dtype)


def inertia(scenario: Scenario, t, p):
    """J [kg m^2] of the step starting at t [s] in phase p, as its first stage sees it:
    what the records show."""
    return stage_inertia(scenario.inertia, t, p, midpoint(scenario, t))


def phase(scenario: Scenario, k):
    """Index of the phase holding at step k (phase switches on step boundaries)."""
    return sum((k >= K).astype(jnp.int32) for K in scenario.phase_steps) if scenario.phase_steps else 0


def integrates_reference(scenario: Scenario) -> bool:
    """R_d is integrated when the reference has no closed form."""
    return scenario.reference.attitude(0.0, 0) is None


def desired(scenario: Scenario, t, phase, integrated_R_d, like) -> Desired:
    """R_d, Omega_d, Omega_d' at t; a reference shared by a batch is computed once."""
    attitude, rate, rate_dot = scenario.reference.terms(t, phase)
    R_d = integrated_R_d if isinstance(integrated_R_d, jax.Array) else so3.batch_like(attitude, 2, like)
    return Desired(R_d, so3.batch_like(rate, 1, like), so3.batch_like(rate_dot, 1, like))


def initial_state(scenario: Scenario, controller: Controller, gains, batch_shape=(), loop: Loop = PAPER_LOOP) -> State:
    """The state at t = 0, every leaf broadcast to (core, *batch_shape)."""
    dtype = scenario.R0.dtype
    R_d = broadcast(jnp.eye(3, dtype=dtype), 2, batch_shape) if integrates_reference(scenario) else ()
    controller_state = jax.tree.map(lambda x: broadcast(x, x.ndim, batch_shape), controller.init(gains))
    R0, Omega0 = broadcast(scenario.R0, 2, batch_shape), broadcast(scenario.Omega0, 1, batch_shape)
    state = State(R0, Omega0, controller_state, R_d, loop.actuator.init(batch_shape, dtype))
    if scenario.flexible is not None:
        theta0, rho0 = (None, None) if scenario.flexible_initial is None else scenario.flexible_initial
        state = state._replace(flexible=flexible.initial_modal(scenario.flexible, batch_shape, dtype, theta0, rho0))
    if loop.momentum is not None:
        manager, managed = loop.momentum.init(batch_shape, dtype)
        state = state._replace(manager=manager, managed=managed)
    if loop.continuous:
        return state
    zero = jnp.zeros_like(Omega0)
    if loop.filter is not None:
        state = state._replace(filter=loop.filter.init(batch_shape, dtype))
    actuator = loop.actuator if loop.faults is None else loop.faults.actuator(loop.actuator, jnp.zeros((), dtype))
    return state._replace(
        sensors=loop.sensors.init(batch_shape, dtype),
        estimator=loop.estimator.init(R0, batch_shape, dtype),
        held=actuator.command(state.actuator, zero, zero),  # the held input's structure; tick 0 sets it
    )


# --- the plant's step -------------------------------------------------------------------


def _integrated(state: State, with_controller: bool) -> State:
    """The continuous part of the state, rotations marked for the SO(3) integrator."""
    R_d = OnSO3(state.R_d) if isinstance(state.R_d, jax.Array) else ()
    return State(OnSO3(state.R), state.Omega, state.controller if with_controller else (), R_d, state.actuator,
                 flexible=state.flexible)


def _field(scenario: Scenario, loop: Loop, phase, d, law, midpoint, stages=None, managed=()):
    """The vector field of one step (phase and disturbance held; midpoint: t_k + dt/2 [s],
    where the inertia's own steps switch). law(t, x, desired) ->
    (actuator input, controller state rate): the controller in every stage
    (continuous), or the held input (sampled). stages: the step's precomputed time terms
    (:func:`so3jax.dynamics.stepped.stage_terms`), taken in the order RK4 calls the field; None:
    each stage evaluates the reference and the inertia at its time. managed: the momentum
    manager's held input; its torque and the environment's are external torques of the
    stage's attitude (docs/model.md §8.6)."""
    calls = iter(stepped.STAGE_OF_CALL)
    # the flexible body of the step's phase, picked once for the four stages
    body = None if scenario.flexible is None else flexible.at_phase(scenario.flexible, phase)

    def field(t, x: State):
        Omega = x.Omega
        terms = stepped.StageTerms(None, None, None) if stages is None else stages[next(calls)]
        R_d = x.R_d.R if isinstance(x.R_d, OnSO3) else terms.R_d
        wanted = desired(scenario, t, phase, R_d, Omega)
        held, controller_dot = law(t, x, wanted)
        J = terms.J if terms.J is not None else so3.batch_like(stage_inertia(scenario.inertia, t, phase, midpoint),
                                                               2, Omega)
        J_dot = (
            so3.batch_like(inertia_rate(scenario.inertia, t, phase), 2, Omega)
            if scenario.variable_inertia_term
            else None
        )
        external = external_torque(scenario, loop, d, managed, t, x.R.R, J)
        modal_dot = ()
        if scenario.flexible is None:
            Omega_dot, actuator_dot = plant.derivative(loop.actuator, J, Omega, x.actuator, held, external, t, J_dot,
                                                       terms.J_inv)
        else:  # hinged panels and slosh on the hub (docs/model.md §8.9)
            Omega_dot, actuator_dot, modal_dot = plant.flexible_derivative(
                loop.actuator, body, J, Omega, x.flexible, x.actuator, held, external, t, J_dot)
        R_d_rate = OnSO3(wanted.Omega_d) if isinstance(x.R_d, OnSO3) else ()
        return (State(OnSO3(Omega), Omega_dot, controller_dot, R_d_rate, actuator_dot, flexible=modal_dot),
                (held, wanted))

    return field


def manage(scenario: Scenario, loop: Loop, state: State, t, key, j, momentum=None):
    """The momentum manager's tick j at t [s] (every step in the continuous wiring): (its next
    state, the input it holds until its next tick), from the wheels' momentum and the true
    attitude in ``state``. momentum: the manager as the faults leave it (None: the loop's)."""
    h_rel = loop.actuator.stored_momentum(state.actuator)
    momentum = loop.momentum if momentum is None else momentum
    return momentum.command(state.manager, None if h_rel is None else h_rel.relative, scenario.environment, t,
                            state.R, key, j)


def _less_feedforward(loop: Loop, tau_c, managed):
    """The command the actuator gets: tau_c less the momentum manager's feedforward (the
    torque it expects to put on the body, for the wheels to absorb), where it has one."""
    feedforward = None if loop.momentum is None else loop.momentum.feedforward(managed)
    return tau_c if feedforward is None else tau_c - feedforward


def external_torque(scenario: Scenario, loop: Loop, d, managed, t, R, J):
    """d plus the environment's torques and the momentum manager's (3, *b) [N m] at t [s],
    attitude R, inertia J; d itself where the mission has neither (the paper's arithmetic)."""
    env = scenario.environment
    if env is not None and env.torques:
        d = d + env.torque(t, R, J)
    if loop.momentum is not None:
        d = d + loop.momentum.body_torque(managed, env, t, R)
    return d


def sample(state: State, tau, wanted: Desired, atan2=jnp.arctan2) -> metrics.Sample:
    """The docs/model.md §6 metrics' sample of a step start (true state; tau: the control torque delivered)."""
    err = tracking_error(Feedback(state.R, state.Omega), wanted)
    return metrics.Sample(err.Omega_e, state.Omega - wanted.Omega_d, tau, so3.angle(err.R_e, atan2))


def step(scenario: Scenario, controller: Controller, gains, d, state: State, k, loop: Loop = PAPER_LOOP,
         constants=None, key=None):
    """Advance over step k with disturbance d_k held (docs/model.md §5, §8.1): RK4 of the plant and the
    actuator under the actuator's input, the input held since the last tick (sampled
    wiring), or the law and the actuator's command evaluated in every stage on the true
    state, the controller's state integrated too (continuous wiring).
    constants: :func:`so3jax.dynamics.stepped.constants` of a batch of per-trajectory scenarios
    (the time terms then computed once per step), or None. key: the run's key (a momentum
    manager's sensor noise in the continuous wiring).
    Returns (state, phase, metrics sample at t_k), the sample's torque the actuator's
    ``delivered`` at the step start."""
    dtype = scenario.R0.dtype
    t, p = time(scenario, k), phase(scenario, k)
    continuous = loop.continuous
    stages = None
    if constants is not None:
        with_inverse = loop.actuator.stored_momentum(state.actuator) is None and not scenario.variable_inertia_term
        stages = stepped.stage_terms(scenario, constants, t, p, with_inverse)

    manager, managed = state.manager, state.managed
    if continuous and loop.momentum is not None:  # the manager ticks every step
        manager, managed = manage(scenario, loop, state, t, key, k)

    def law(t, x, wanted):
        if not continuous:
            return state.held, ()
        h_w = loop.actuator.uncompensated_momentum(x.actuator, x.Omega)
        tau, controller_dot = controller.torque(gains, x.controller, Feedback(x.R.R, x.Omega, h_w), wanted, t)
        return loop.actuator.command(x.actuator, _less_feedforward(loop, tau, managed), x.Omega), controller_dot
    field = _field(scenario, loop, p, d, law, midpoint(scenario, t), stages, managed)
    x, (held, wanted) = rk4_step(field, t, jnp.asarray(scenario.dt, dtype), _integrated(state, continuous))
    new = state._replace(
        manager=manager,
        managed=managed,
        R=x.R.R,
        Omega=x.Omega,
        controller=x.controller if continuous else state.controller,
        R_d=x.R_d.R if isinstance(x.R_d, OnSO3) else state.R_d,
        actuator=x.actuator,
        flexible=x.flexible,
    )
    atan2 = jnp.arctan2 if constants is None else _trig.atan2  # a batch of per-trajectory scenarios: vectorized
    return new, p, sample(state, loop.actuator.delivered(state.actuator, held, state.Omega), wanted, atan2)


class Observation(NamedTuple):
    """What the continuous wiring records at a step start (no step taken)."""

    t: jax.Array  # s
    tau: jax.Array  # (3, *b) the control torque delivered, N m
    desired: Desired  # broadcast to the batch
    sample: metrics.Sample
    J: jax.Array  # (3, 3, *b) true inertia, kg m^2
    tau_cmd: jax.Array  # (3, *b) the controller's command, N m


def observe(scenario: Scenario, controller: Controller, gains, state: State, k, loop: Loop = PAPER_LOOP):
    """The :class:`Observation` at step start k of the continuous wiring."""
    t, p = time(scenario, k), phase(scenario, k)
    wanted = desired(scenario, t, p, state.R_d, state.Omega)
    h_w = loop.actuator.uncompensated_momentum(state.actuator, state.Omega)
    tau_cmd, _ = controller.torque(gains, state.controller, Feedback(state.R, state.Omega, h_w), wanted, t)
    tau = loop.actuator.delivered(state.actuator, loop.actuator.command(state.actuator, tau_cmd, state.Omega),
                                  state.Omega)
    batch = state.Omega.shape[1:]
    wanted = Desired(*(broadcast(x, x.ndim - len(batch), batch) for x in wanted))
    J = broadcast(so3.batch_like(inertia(scenario, t, p), 2, state.Omega), 2, batch)
    return Observation(t, tau, wanted, sample(state, tau, wanted), J, tau_cmd)


# --- the sampled wiring's control tick ----------------------------------------------------


def period(scenario: Scenario, loop: Loop):
    """Delta_c = m dt [s] in the scenario's dtype."""
    return jnp.asarray(loop.period_steps * scenario.dt, scenario.R0.dtype)


def tick(scenario: Scenario, loop: Loop, controller: Controller, gains, key, state: State, j):
    """Control tick j at step k = j m (docs/model.md §8.1): sensors sample the true state, the
    estimator updates, the controller commands from the estimate (its state advanced by
    its ``update``, else by forward Euler over the period), the actuator turns the
    command into the held input. Faults (``loop.faults``) act on the measurements, the
    actuator and the thrusters of the ticks at or after their times (docs/model.md §8.7)."""
    k = j * loop.period_steps
    t, p, dc = time(scenario, k), phase(scenario, k), period(scenario, loop)
    sensors, measured = loop.sensors.measure(state.sensors, state.R, state.Omega, key, j, dc)
    faults, actuator, momentum = loop.faults, loop.actuator, loop.momentum
    if faults is not None:
        rate = loop.sensors.rate
        measured = faults.measured(measured, t, rate is None or j >= rate.first_reading)
        actuator = faults.actuator(actuator, t)
        momentum = None if momentum is None else faults.momentum(momentum, t)
    truth = (state.R, state.Omega) if loop.estimator.reads_truth else None  # only an estimator that reads it
    estimator, estimate = loop.estimator.update(state.estimator, measured, dc, truth)
    wanted = desired(scenario, t, p, state.R_d, state.Omega)
    h_w = loop.actuator.uncompensated_momentum(state.actuator, estimate.Omega_hat)
    structural, Omega_read = state.filter, estimate.Omega_hat
    shaping = None if loop.filter is None else loop.filter.at_phase(p)  # the phase's section (per-phase parameters)
    if shaping is not None and shaping.signal == "rate":
        structural, Omega_read = shaping.apply(state.filter, estimate.Omega_hat)
    feedback = Feedback(estimate.R_hat, Omega_read, h_w)
    tau_cmd, controller_dot = controller.torque(gains, state.controller, feedback, wanted, t)
    if shaping is not None and shaping.signal == "torque":
        structural, tau_cmd = shaping.apply(state.filter, tau_cmd)
    manager, managed = state.manager, state.managed
    if momentum is not None:
        manager, managed = manage(scenario, loop, state, t, key, j, momentum)
    held = actuator.command(state.actuator, _less_feedforward(loop, tau_cmd, managed), estimate.Omega_hat)
    if faults is not None and momentum is not None:  # the body gets the commanded pulses less the failed ones'
        managed = faults.delivered(managed, t)
    if controller.update is None:
        controller_state = jax.tree.map(lambda x, dx: x + dc * dx, state.controller, controller_dot)
    else:
        controller_state = controller.update(gains, state.controller, feedback, wanted, t, dc)
    new = state._replace(
        controller=controller_state,
        sensors=sensors,
        estimator=estimator,
        held=held,
        manager=manager,
        managed=managed,
        filter=structural,
    )
    bias = loop.sensors.true_bias(state.sensors, state.Omega)
    if faults is not None:
        bias = faults.true_bias(bias, t)
    tau_applied = actuator.delivered(state.actuator, held, state.Omega)  # the first step's sample
    return new, Tick(t, wanted, estimate, bias, tau_cmd, tau_applied)


def check_loop(loop: Loop, inertias: dict) -> None:
    """One-line ValueErrors, before compilation: the control period, each component's
    own checks, and the wiring (docs/model.md §8). inertias: name -> J (3, 3) the plant will use.
    Values are read only where concrete (NumPy on the host), so a rollout under jit,
    vmap or grad is checked by shape and static data alone."""
    m = loop.period_steps
    if m is not None and (isinstance(m, bool) or not isinstance(m, int) or m < 1):
        raise ValueError(f"the control period must be a whole number (>= 1) of steps, got {m!r}")
    flown = tuple(q for q, sensor in zip(components.MEASUREMENTS, (loop.sensors.rate, loop.sensors.attitude))
                  if sensor is not None)
    # a slot without a sensor is perfect: the estimator reads that measurement exactly
    check_wiring(m is None, flown, components.MEASUREMENTS, type(loop.estimator), type(loop.estimator).__name__)
    for part in (loop.sensors, loop.estimator, loop.actuator):
        part.check()
    if loop.faults is not None:
        if m is None:
            raise ValueError("faults act at the control ticks: they need the sampled loop (control.mode = 'sampled')")
        if loop.faults.wheel is not None and not isinstance(loop.actuator, Wheels):
            raise ValueError(f"a wheel fault needs wheels (actuator.kind = 'wheels'), not the "
                             f"{type(loop.actuator).__name__} actuator")
        if loop.faults.thruster_axis is not None and not isinstance(loop.momentum, Thrusters):
            manager = "none" if loop.momentum is None else type(loop.momentum).__name__
            raise ValueError(f"a thruster fault needs thrusters (momentum.kind = 'thrusters'); the loop's momentum "
                             f"manager is {manager}")
    if loop.filter is not None:
        if m is None:
            raise ValueError("a structural filter acts at the control ticks: it needs the sampled loop "
                             "(control.mode = 'sampled')")
        loop.filter.check()
    if loop.momentum is not None:
        if loop.actuator.stored_momentum(loop.actuator.init((), jnp.float32)) is None:  # by structure
            raise ValueError(f"momentum management (momentum.kind) needs an actuator that stores momentum "
                             f"(actuator.kind = 'wheels'); the {type(loop.actuator).__name__} actuator stores none "
                             "(with it: momentum.kind = 'none')")
        loop.momentum.check()
        capacity = loop.actuator.momentum_capacity()
        if capacity is not None:
            loop.momentum.check_capacity(capacity)
    spin = loop.actuator.spin_inertia_values()  # NumPy, None where traced: nothing is added to a trace
    if spin is not None:
        for name, J in inertias.items():
            J = concrete_values(J)
            if J is not None and np.any(np.linalg.eigvalsh(J - spin) <= 0):
                raise ValueError(f"inertia {name} minus the wheels' spin inertia (J - G_s J_s G_s^T) "
                                 "is not positive definite")


def check_wiring(continuous: bool, sensors: tuple, measured: tuple, estimator: type[Estimator], name: str) -> None:
    """One-line ValueErrors on the wiring (docs/model.md §8), from what the components
    declare, before anything is built or compiled: the continuous wiring reads the true
    state (no sensors, an estimator with ``reads_truth``); the sampled wiring gives the
    estimator every measurement it ``needs``. sensors: the measurements a sensor makes
    (``rate``, ``attitude``); measured: those the estimator can read (a loop's empty slot
    reads the truth, a mission's sensor left out reads nothing); name: the estimator's."""
    if continuous:
        if sensors or not estimator.reads_truth:
            raise ValueError("a continuous-time controller (control.mode = 'continuous') reads the true state: "
                             "it takes "
                             "no sensors (sensors.NAME=false) and an estimator that reads the truth "
                             "(estimator.kind='truth'); sensors and other estimators need a control period")
        return
    missing = [q for q in estimator.needs if q not in measured]
    if missing:
        offered = [n for n in components.names("sensor") if components.get("sensor", n).provides == missing[0]]
        raise ValueError(f"estimator '{name}' needs a sensor of the {' and the '.join(missing)} "
                         f"(registered: {', '.join(f'[sensors.{n}]' for n in offered) or 'none'})")
