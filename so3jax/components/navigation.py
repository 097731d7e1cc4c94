"""Navigation errors as Basilisk's ``simpleNav`` draws them (docs/model.md §8.2): the true
attitude and rate at each tick, each off by an error that walks from tick to tick,

    e_j = clip(e_{j-1} + sigma eta_{s,j}, -bound, bound),   e_{-1} = 0,

per axis (a bound of 0: unbounded), the step drawn before it is applied, as simpleNav's
Gauss-Markov model does with its propagation matrix the identity. Two sensors:

* ``nav_attitude``: the error is a modified Rodrigues parameter vector s_j composed after the
  true attitude (simpleNav's addMRP): R_m = R C(s_j)^T, C(s) the direction cosine matrix
  of s, a rotation of 4 arctan|s| [rad] about s; a sample every tick. Stream 4.
* ``nav_rate``: omega_m = Omega + e_j [rad/s]. Stream 5.

Noise eta_{s,j}: :func:`so3jax.components.sensors.sensor_noise`. A state is e_{j-1}, the
error before tick j's step (zeros at tick 0); the rate sensor's "bias" is that error.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from so3jax.components import registry as components
from so3jax.components.base import Sensor
from so3jax.components.sensors import check_values, like_dtype, sensor_noise
from so3jax.core import so3
from so3jax.core.params import Param
from so3jax.core.pytree import pytree_dataclass

NAV_ATTITUDE, NAV_RATE = 4, 5  # noise streams s (docs/model.md §8.2)


def mrp_rotation(s):
    """C(s)^T (3, 3, *b) for MRPs s (3, *b): the rotation by 4 arctan|s| [rad] about s,

        I + (8 hat(s)^2 + 4 (1 - |s|^2) hat(s)) / (1 + |s|^2)^2   (Schaub and Junkins, 3.153)."""
    S = so3.hat(s)
    n2 = so3.dot(s, s)
    return so3.eye_like(s) + (8.0 * so3.matmul(S, S) + 4.0 * (1.0 - n2) * S) / (1.0 + n2) ** 2


def walk(error, sigma, bound, key, stream: int, j):
    """e_j = clip(e_{j-1} + sigma eta_{s,j}, +-bound) (3, *b); bound 0: unbounded."""
    eta = sensor_noise(key, stream, j, error.dtype)
    stepped = error + like_dtype(sigma, eta) * eta
    bound = like_dtype(bound, eta)
    return jnp.where(bound > 0, jnp.clip(stepped, -bound, bound), stepped)


@pytree_dataclass
class NavAttitude(Sensor):
    """R_m,j = R(t_j) C(s_j)^T, s_j the MRP error's walk (module docstring)."""

    sigma: jax.Array  # per-axis step of the MRP error [-]
    bound: jax.Array  # per-axis bound of the MRP error [-], 0: unbounded

    def init(self, batch_shape, dtype):
        return jnp.zeros((3,) + tuple(batch_shape), dtype)

    def measure(self, state, R, Omega, key, j, period):
        """(s_j, (R_m (3, 3, *b), a sample at every tick))."""
        s = walk(state, self.sigma, self.bound, key, NAV_ATTITUDE, j)
        return s, (so3.matmul(R, mrp_rotation(s)), jnp.asarray(True))

    def check(self) -> None:
        check_values("sensors.nav_attitude.sigma", self.sigma)
        check_values("sensors.nav_attitude.bound", self.bound)


@pytree_dataclass
class NavRate(Sensor):
    """omega_m,j = Omega(t_j) + e_j, e_j the rate error's walk (module docstring)."""

    sigma: jax.Array  # per-axis step of the rate error [rad/s]
    bound: jax.Array  # per-axis bound of the rate error [rad/s], 0: unbounded

    def init(self, batch_shape, dtype):
        return jnp.zeros((3,) + tuple(batch_shape), dtype)

    def measure(self, state, R, Omega, key, j, period):
        """(e_j, omega_m (3, *b))."""
        e = walk(state, self.sigma, self.bound, key, NAV_RATE, j)
        return e, Omega + e

    def bias(self, state, Omega):
        """e_{j-1} (3, *b) [rad/s]: the rate error before tick j's step."""
        return state

    def check(self) -> None:
        check_values("sensors.nav_rate.sigma [rad/s]", self.sigma)
        check_values("sensors.nav_rate.bound [rad/s]", self.bound)


def _params(unit: str, what: str) -> tuple:
    return (Param("sigma", 0.0, unit, low=0.0, doc=f"per-axis standard deviation of the {what} error's step per tick"),
            Param("bound", 0.0, unit, low=0.0, doc=f"per-axis bound of the {what} error (0: unbounded)"))


components.register(components.ComponentSpec(
    kind="sensor", name="nav_attitude", component=NavAttitude, provides="attitude", params=_params("-", "MRP attitude"),
    build=lambda v, ctx: NavAttitude(ctx.as_array(v["sigma"]), ctx.as_array(v["bound"])),
    doc="the true attitude with simpleNav's MRP error walk (docs/model.md §8.2)",
))
components.register(components.ComponentSpec(
    kind="sensor", name="nav_rate", component=NavRate, provides="rate", params=_params("rad/s", "rate"),
    build=lambda v, ctx: NavRate(ctx.as_array(v["sigma"]), ctx.as_array(v["bound"])),
    doc="the true rate with simpleNav's error walk (docs/model.md §8.2)",
))
