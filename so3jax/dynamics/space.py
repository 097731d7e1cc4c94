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

        def one(orbit, R, J):
            total = self.torques[0].torque(orbit, t, R, J)
            for model in self.torques[1:]:
                total = total + model.torque(orbit, t, R, J)
            return total

        return _batched(one, self.orbit, R, J)

    def magnetic_field_body(self, t, R):
        """The geomagnetic field in body axes, R^T B_N (3, *b) [T]."""
        return _batched(lambda orbit, R, J: R.T @ env.magnetic_field_n(orbit, t), self.orbit, R, R)


def _batched(fn, orbit, R, J):
    """fn(orbit, R (3, 3), J (3, 3)) -> (3,) over the trailing batch axes of R; J and the
    orbit's leaves (scalars) broadcast to them."""
    batch = R.shape[2:]
    if not batch:
        squeeze = lambda x, core: x.reshape(x.shape[:core]) if x.ndim > core else x
        return fn(jax.tree.map(lambda x: squeeze(jnp.asarray(x), 0), orbit), R, squeeze(J, 2))
    size = math.prod(batch)

    def spread(x, core):
        x = jnp.asarray(x)
        x = x.reshape(x.shape + (1,) * (core + len(batch) - x.ndim))
        return jnp.broadcast_to(x, x.shape[:core] + batch).reshape(x.shape[:core] + (size,))

    out = jax.vmap(fn, in_axes=-1, out_axes=-1)(jax.tree.map(lambda x: spread(x, 0), orbit), spread(R, 2),
                                                 spread(J, 2))
    return out.reshape((3,) + batch)
