"""A scenario's space environment (docs/model.md §4): the orbit and the external torques
it puts on the body, each a registered model (:mod:`so3jax.components.environment`) summed
with the scenario's disturbance in every RK4 stage, at the stage's attitude and true inertia.

The physics is :mod:`so3jax.dynamics.environment`'s; this module is the shape a torque
model takes and the container the loop reads (:func:`so3jax.sim.loop.external_torque`).
"""

from __future__ import annotations

import abc
import math
from typing import Any

import jax
import jax.numpy as jnp

from so3jax.core.pytree import pytree_dataclass
from so3jax.dynamics import environment as env


class EnvironmentTorque(abc.ABC):
    """An environmental torque model: torque(orbit, t, R, J) -> (3,) [N m], body frame, from
    the orbit (:class:`so3jax.dynamics.environment.CircularOrbit`), t [s], the attitude R
    (3, 3) (body -> inertial N) and the true inertia J (3, 3) [kg m^2]. A subclass is a
    pytree; its parameters have no batch axes."""

    @abc.abstractmethod
    def torque(self, orbit, t, R, J): ...


@pytree_dataclass
class Environment:
    """The orbit and the torque models flown (a tuple, possibly empty: the orbit alone, for
    a magnetorquer's field)."""

    orbit: Any  # so3jax.dynamics.environment.CircularOrbit
    torques: tuple = ()

    def torque(self, t, R, J):
        """The sum of the models' torques (3, *b) [N m] at attitude R (3, 3, *b) and J
        (3, 3, *b or unit axes); batch axes last, as in the loop."""
        if not self.torques:
            return jnp.zeros(R.shape[:1] + R.shape[2:], R.dtype)

        def one(environment, R, J):
            total = environment.torques[0].torque(environment.orbit, t, R, J)
            for model in environment.torques[1:]:
                total = total + model.torque(environment.orbit, t, R, J)
            return total

        return _batched(one, self, R, J)

    def magnetic_field_body(self, t, R):
        """The geomagnetic field in body axes, R^T B_N (3, *b) [T]."""
        return _batched(lambda environment, R, J: R.T @ env.magnetic_field_n(environment.orbit, t), self, R, R)


def _batched(fn, environment, R, J):
    """fn(environment, R (3, 3), J (3, 3)) -> (3,) over the trailing batch axes b of R. In a
    natively batched rollout every leaf of the scenario, the environment's too, carries
    them (of size 1 where the batch shares it): each is broadcast to b and mapped over."""
    batch = R.shape[2:]
    if not batch:
        return fn(environment, R, J)
    size = math.prod(batch)

    def spread(x, core):
        x = jnp.asarray(x)
        return jnp.broadcast_to(x, x.shape[:core] + batch).reshape(x.shape[:core] + (size,))

    leaves = jax.tree.map(lambda x: spread(x, jnp.ndim(x) - len(batch)), environment)
    J = J.reshape(J.shape + (1,) * (R.ndim - J.ndim))
    out = jax.vmap(fn, in_axes=-1, out_axes=-1)(leaves, spread(R, 2), spread(J, 2))
    return out.reshape((3,) + batch)
