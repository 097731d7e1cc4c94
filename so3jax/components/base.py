"""One shape per kind of loop component: the abstract bases :class:`Sensor`,
:class:`Estimator`, :class:`Actuator` and :class:`MomentumManager`, and the values passed between them
(:class:`Measurements`, :class:`Estimate`, :class:`StoredMomentum`).

A component subclasses its kind's base and defines the abstract methods (sensor: ``init``,
``measure``; estimator: ``init``, ``update``; actuator: ``command``); the base gives the
rest, so the loop calls every method without probing for it. A component is a pytree:
decorate the subclass with :func:`so3jax.core.pytree.pytree_dataclass` (or
``jax.tree_util.register_dataclass``); the bases hold no fields. What an estimator reads is
declared once, by class attributes (``needs``, ``reads_truth``), which the loop's wiring
check (:func:`so3jax.sim.loop.check_wiring`) and the registry read.

Arrays follow :mod:`so3jax.core.so3`: components first, batch axes last; parameters have
no batch axes.
"""

from __future__ import annotations

import abc
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp

from so3jax.core import so3


class Measurements(NamedTuple):
    """What the sensor suite read at a tick."""

    omega_m: jax.Array  # (3, *b) rad/s
    R_m: jax.Array  # (3, 3, *b)
    star_valid: jax.Array  # bool scalar: a star-tracker sample exists at this tick


class Estimate(NamedTuple):
    """What an estimator gives the controller at a tick."""

    R_hat: jax.Array  # (3, 3, *b)
    Omega_hat: jax.Array  # (3, *b) rad/s
    bias_hat: jax.Array  # (3, *b) rad/s (zeros without a bias estimate)
    std: jax.Array  # (6, *b): sqrt(diag P) after the update (attitude rad, bias rad/s); zeros without a filter
    covariance: Any = ()  # (6, 6, *b): P after the update (a filter's), or ()


class StoredMomentum(NamedTuple):
    """Angular momentum an actuator stores, J_locked Omega + h_rel, body frame (docs/model.md §8.4)."""

    locked_inertia: jax.Array  # J_locked (3, 3) kg m^2: the part of J that spins with the body's rate
    relative: jax.Array  # h_rel (3, *b) N m s: the momentum of its motion relative to the body


def no_limit(held):
    """False of the batch shape of a (3 or N, *b) array."""
    return jnp.zeros(held.shape[1:], bool)


class Sensor(abc.ABC):
    """A sensor, sampled at the control ticks (docs/model.md §8.2). A rate sensor's
    reading is omega_m (3, *b) [rad/s]; an attitude sensor's is (R_m (3, 3, *b), whether
    tick j has a sample). Noise keys: :func:`so3jax.components.sensors.sensor_noise`.
    first_reading: the first tick with a reading (one that measures over a period, a
    rate-integrating gyro: 1, its reading at tick 0 is 0)."""

    first_reading: ClassVar[int] = 0

    @abc.abstractmethod
    def init(self, batch_shape, dtype):
        """Its state at tick 0, batch axes ``batch_shape`` last, or ()."""

    @abc.abstractmethod
    def measure(self, state, R, Omega, key, j, period):
        """(its state at tick j + 1, its reading at tick j) from the true R (3, 3, *b) and
        Omega (3, *b) [rad/s] at t_j; key: the run's key, period: Delta_c [s]."""

    def bias(self, state, Omega):
        """A rate sensor's true bias b_j (3, *b) [rad/s]: zeros without one."""
        return jnp.zeros_like(Omega)

    def check(self) -> None:
        """One-line ValueErrors on bad parameters, before compilation (values read only where concrete)."""


class Estimator(abc.ABC):
    """An estimator, updated once per control tick (docs/model.md §8.3).

    needs: the measurements it reads (``rate``, ``attitude``), a sensor of each must be
    flown in a mission; reads_truth: it gets the true state (R, Omega) at the tick as
    ``truth`` (None for every other estimator); the continuous wiring takes only such an
    estimator."""

    needs: ClassVar[tuple[str, ...]] = ()
    reads_truth: ClassVar[bool] = False

    @abc.abstractmethod
    def init(self, R0, batch_shape, dtype):
        """Its state at tick 0 (the prior), batch axes ``batch_shape`` last, or ()."""

    @abc.abstractmethod
    def update(self, state, measured: Measurements, period, truth=None):
        """(its state for the next tick, the :class:`Estimate` at this tick); period: Delta_c [s]."""

    def check(self) -> None:
        """One-line ValueErrors on bad parameters, before compilation (values read only where concrete)."""


class Actuator(abc.ABC):
    """An actuator: the controller's command tau_c in, the torque on the body out
    (docs/model.md §8.4). Only :meth:`command` is required; the defaults are those of a
    stateless actuator without stored momentum or limits whose held input is the torque
    on the body and the control torque delivered. The plant
    (:func:`so3jax.dynamics.plant.derivative`) integrates its state with the body's."""

    def init(self, batch_shape, dtype):
        """Its state, () or e.g. the wheel speeds Omega_w (N, *batch_shape) [rad/s]."""
        return ()

    @abc.abstractmethod
    def command(self, state, tau_c, Omega_hat):
        """The input held over a control period, from the command tau_c (3, *b) [N m] and
        the estimated rate Omega_hat (3, *b) [rad/s] (at a tick; in every RK4 stage in the
        continuous wiring)."""

    def body_torque(self, state, held, Omega):
        """The torque it puts on the body, tau_body (3, *b) [N m]."""
        return held

    def stored_momentum(self, state) -> StoredMomentum | None:
        """None, or (J_locked (3, 3) [kg m^2], h_rel (3, *b) [N m s]): it stores
        J_locked Omega + h_rel of angular momentum, body frame; the plant then solves
        (J - J_locked) Omega' = -Omega x (J Omega + h_rel) + tau_body + d [- J' Omega]."""
        return None

    def constrained_inertia(self, held):
        """None, or the part of J_locked the held input ties to the body (3, 3, *b) [kg m^2]
        (a wheel stuck at its speed, docs/model.md (8.22)): the plant then solves with
        J - J_locked + it."""
        return None

    def derivative(self, state, held, Omega, Omega_dot):
        """Its state's rate given the body's (() without state)."""
        return ()

    def delivered(self, state, held, Omega):
        """The control torque the command became (3, *b) [N m]: tau_c where no limit
        binds; the metrics' torque sample at every step start in both wirings."""
        return self.body_torque(state, held, Omega)

    def effort(self, held):
        """|held input|^2 [N^2 m^2], of the batch shape (the flight metrics' actuator effort)."""
        return so3.sum_leading(held * held)

    def limits(self, state, held, tau_c):
        """(at a torque limit, at a speed limit), bool of the batch shape."""
        return no_limit(held), no_limit(held)

    def speed_ratio(self, state):
        """max_i |Omega_w,i| / Omega_max,i (0 without wheels)."""
        return 0.0

    def uncompensated_momentum(self, state, Omega_hat):
        """The stored momentum a control law must account for itself (3, *b) [N m s]:
        None where the actuator stores none or compensates it in its command."""
        return None

    def spin_inertia_values(self):
        """J_locked (3, 3) [kg m^2] as a NumPy array for the host-side check that
        J - J_locked is positive definite; None without stored momentum or where a
        parameter is traced."""
        return None

    def momentum_capacity(self) -> float | None:
        """The most momentum |h_rel| [N m s] it can store relative to the body (a float, for
        the host-side checks of a momentum manager's thresholds); None without stored
        momentum or where a parameter is traced."""
        return None

    def check(self) -> None:
        """One-line ValueErrors on bad parameters, before compilation (values read only where concrete)."""


class MomentumManager(abc.ABC):
    """A momentum-management device beside the actuator (docs/model.md §8.6): magnetorquers,
    thrusters. At each control tick (every step in the continuous wiring) it reads the
    momentum the actuator stores relative to the body, h_rel (3, *b) [N m s], and commands
    an input held until the next; in every RK4 stage it puts an external torque on the body.
    ``environment``: the scenario's :class:`so3jax.dynamics.space.Environment` (the orbit and
    the field a magnetorquer needs), or None; ``reads_field``: the device reads the
    geomagnetic field (a mission then builds its orbit)."""

    reads_field: ClassVar[bool] = False

    @abc.abstractmethod
    def init(self, batch_shape, dtype):
        """(its state at tick 0, or (); an input that puts no torque on the body), batch axes
        ``batch_shape`` last."""

    @abc.abstractmethod
    def command(self, state, h_rel, environment, t, R, key, j):
        """(its state for the next tick, the input held until then) at tick j, time t [s],
        true attitude R (3, 3, *b) (body -> inertial); key: the run's key (sensor noise)."""

    @abc.abstractmethod
    def body_torque(self, held, environment, t, R):
        """The external torque on the body (3, *b) [N m] at t [s], attitude R (3, 3, *b)."""

    def feedforward(self, held):
        """The torque the flight software expects the device to put on the body (3, *b) [N m],
        taken off the actuator's command so that the wheels absorb it; None: none."""
        return None

    def check(self) -> None:
        """One-line ValueErrors on bad parameters, before compilation (values read only where concrete)."""

    def check_capacity(self, capacity: float) -> None:
        """One-line ValueErrors on settings the actuator's capacity makes moot (a threshold
        |h_rel| never reaches: the actuator stores at most ``capacity`` [N m s],
        :meth:`Actuator.momentum_capacity`), before compilation."""


class Filter(abc.ABC):
    """A structural filter at the control tick (docs/model.md §8.8): a linear discrete-time
    filter on each axis of the commanded torque (``signal = "torque"``, between the
    controller and the actuator) or of the estimated rate the controller reads
    (``signal = "rate"``). Its state is carried by the loop from tick to tick."""

    signal: str = "torque"

    @abc.abstractmethod
    def init(self, batch_shape, dtype):
        """Its state at tick 0 (the filter at rest), batch axes ``batch_shape`` last."""

    @abc.abstractmethod
    def apply(self, state, x):
        """(its state for the next tick, the filtered x (3, *b)) of this tick's input x (3, *b)."""

    def at_phase(self, phase) -> Filter:
        """The filter flown in mission phase ``phase`` (an index, possibly traced): itself, unless
        its parameters are given per phase."""
        return self

    def check(self) -> None:
        """One-line ValueErrors on bad parameters, before compilation (values read only where concrete)."""
