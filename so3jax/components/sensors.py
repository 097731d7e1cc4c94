"""Sensors: the true state in, measurements out, sampled at the control ticks (docs/model.md §8.2).

Noise: eta_{s,j} = jax.random.normal(fold_in(fold_in(K_sens, s), j), (3,), dtype) with
K_sens = fold_in(key(seed), 2^32 - 1), stream s = 1 (gyro white noise), 2 (gyro bias walk),
3 (star tracker), j the tick. The disturbance draws fold_in(key(seed), k) at step k < 2^32 - 1,
so turning sensors on changes no disturbance draw, and no key is both folded and drawn from.
Arrays follow :mod:`so3jax.core.so3` (batch axes last); a parameter is shared by a batch
(no batch axes) or per trajectory (its core shape, then the batch axes).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.components import registry as components
from so3jax.components.base import Measurements, Sensor
from so3jax.core import checks, so3
from so3jax.core.params import Param
from so3jax.core.pytree import pytree_dataclass, static_field
from so3jax.dynamics.disturbance import noise_components

GYRO_WHITE, GYRO_BIAS_WALK, STAR_TRACKER = 1, 2, 3  # noise streams s (docs/model.md §8.2)
SENSOR_ROOT = np.uint32(2**32 - 1)  # K_sens = fold_in(key(seed), SENSOR_ROOT): a step never reached


def sensor_noise(key, stream: int, j, dtype):
    """eta_{s,j} (3, *key.shape): normal(fold_in(fold_in(K_sens, s), j), (3,), dtype),
    K_sens = fold_in(key, 2^32 - 1) (docs/model.md §8.2)."""
    fold = lambda k: jax.random.fold_in(jax.random.fold_in(k, SENSOR_ROOT), stream)
    folded = fold(key) if key.ndim == 0 else jax.vmap(fold)(key.reshape(-1)).reshape(key.shape)
    return jnp.stack(noise_components(folded, j, dtype))


def like_dtype(x, like):
    """A scalar parameter, shared (()) or per trajectory (*b), cast and shaped to broadcast
    against ``like`` (3, *b)."""
    return so3.batch_like(jnp.asarray(x).astype(like.dtype), 0, like)


def check_values(name: str, x, shape=()) -> None:
    v = checks.concrete(x, name)
    if v is None:
        return
    if v.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {v.shape}")
    if not np.all(np.isfinite(v)) or (shape == () and v < 0):
        raise ValueError(f"{name} must be a finite{' non-negative' if shape == () else ''} number, got {v.tolist()}")


@pytree_dataclass
class Gyro(Sensor):
    """Sampled-rate gyro, Farrenkopf model at the ticks (docs/model.md §8.2):
    omega_m,j = Omega(t_j) + b_j + (arw / sqrt(Delta_c)) eta_1,j;  b_{j+1} = b_j + rrw sqrt(Delta_c) eta_2,j."""

    arw: jax.Array  # sigma_v, angle random walk [rad/sqrt(s)]
    rrw: jax.Array  # sigma_u, rate random walk [rad/s^(3/2)]
    bias0: jax.Array  # (3,) b_0 [rad/s]

    def init(self, batch_shape, dtype):
        """b_0 as (3, *batch_shape) [rad/s]."""
        return so3.broadcast(jnp.asarray(self.bias0).astype(dtype), 1, batch_shape)

    def measure(self, bias, R, Omega, key, j, period):
        """(b_{j+1}, omega_m) from the true rate Omega (3, *b) at tick j [rad/s]."""
        dtype = Omega.dtype
        period = jnp.asarray(period, dtype)
        white = sensor_noise(key, GYRO_WHITE, j, dtype)
        walk = sensor_noise(key, GYRO_BIAS_WALK, j, dtype)
        omega_m = Omega + bias + like_dtype(self.arw, Omega) / jnp.sqrt(period) * white
        return bias + like_dtype(self.rrw, Omega) * jnp.sqrt(period) * walk, omega_m

    def bias(self, state, Omega):
        """The true bias b_j (3, *b) [rad/s]."""
        return state

    def check(self) -> None:
        check_values("sensors.gyro.arw [rad/sqrt(s)]", self.arw)
        check_values("sensors.gyro.rrw [rad/s^(3/2)]", self.rrw)
        check_values("sensors.gyro.bias0 [rad/s]", self.bias0, (3,))


@pytree_dataclass
class IntegratingGyro(Sensor):
    """Rate-integrating gyro: the angle increment over each control period, Farrenkopf model
    on increments (docs/model.md §8.2), delivered as the mean rate over the period:
    omega_m,j = log(R_{j-1}^T R_j)^v / Delta_c + (b_{j-1} + b_j) / 2
    + sqrt(arw^2 / Delta_c + rrw^2 Delta_c / 12) eta_1,j;  b_{j+1} = b_j + rrw sqrt(Delta_c) eta_2,j.
    At tick 0 no period has elapsed: omega_m,0 = 0. State: (b_{j-1}, b_j, R_{j-1})."""

    first_reading = 1

    arw: jax.Array  # sigma_v, angle random walk [rad/sqrt(s)]
    rrw: jax.Array  # sigma_u, rate random walk [rad/s^(3/2)]
    bias0: jax.Array  # (3,) b_0 [rad/s]

    def init(self, batch_shape, dtype):
        """(b_0, b_0, I): the previous tick's bias and attitude are not read at tick 0."""
        b = Gyro.init(self, batch_shape, dtype)  # b_0 as (3, *batch_shape), as the sampled-rate gyro's
        return b, b, so3.eye_like(b)

    def measure(self, state, R, Omega, key, j, period):
        """((b_j, b_{j+1}, R_j), omega_m,j) from the true attitudes R_{j-1} (the state's) and R_j (3, 3, *b)."""
        b_prev, b, R_prev = state
        dtype = Omega.dtype
        period = jnp.asarray(period, dtype)
        white = sensor_noise(key, GYRO_WHITE, j, dtype)
        walk = sensor_noise(key, GYRO_BIAS_WALK, j, dtype)
        arw, rrw = like_dtype(self.arw, Omega), like_dtype(self.rrw, Omega)
        increment = so3.log(so3.rmatmul(R_prev, R), select=True)  # the true rotation vector over the period
        sigma = jnp.sqrt(arw**2 / period + rrw**2 * period / 12.0)
        omega_m = jnp.where(j == 0, jnp.zeros_like(Omega), increment / period + 0.5 * (b_prev + b) + sigma * white)
        return (b, b + rrw * jnp.sqrt(period) * walk, R), omega_m

    def bias(self, state, Omega):
        """The true bias b_j (3, *b) [rad/s] at the tick about to be measured."""
        return state[1]

    check = Gyro.check  # the same parameters, the same checks


@pytree_dataclass
class StarTracker(Sensor):
    """R_m,j = R(t_j) exp(hat(sigma eta_3,j)), a sample every ``every`` ticks (docs/model.md §8.2)."""

    sigma: jax.Array  # per axis [rad]
    every: int = static_field(default=1)

    def init(self, batch_shape, dtype):
        return ()

    def measure(self, state, R, Omega, key, j, period):
        """((), (R_m (3, 3, *b), whether tick j has a sample))."""
        eta = sensor_noise(key, STAR_TRACKER, j, R.dtype)
        error = like_dtype(self.sigma, eta) * eta
        return state, (so3.matmul(R, so3.exp(error, select=True)), (j % self.every) == 0)

    def check(self) -> None:
        check_values("sensors.star_tracker.sigma [rad]", self.sigma)
        if isinstance(self.every, bool) or not isinstance(self.every, int) or self.every < 1:
            raise ValueError(f"sensors.star_tracker.every must be an integer >= 1, got {self.every!r}")


@pytree_dataclass
class Sensors:
    """The sensor suite by measured quantity; a slot that is None is perfect (reads the
    true state). Each sensor is a :class:`~so3jax.components.base.Sensor`: a rate sensor
    reads omega_m (3, *b) [rad/s] and gives its true bias; an attitude sensor reads (R_m,
    whether tick j has a sample). Noise keys: :func:`sensor_noise`, one stream per noise source."""

    rate: Sensor | None = None
    attitude: Sensor | None = None

    def init(self, batch_shape, dtype):
        """(the rate sensor's state, the attitude sensor's state); () for a perfect slot."""
        return tuple(() if s is None else s.init(batch_shape, dtype) for s in (self.rate, self.attitude))

    def measure(self, state, R, Omega, key, j, period):
        """(state at tick j + 1, Measurements at tick j) from the true R, Omega at t_j."""
        rate_state, attitude_state = state
        if self.rate is None:
            omega_m = Omega
        else:
            rate_state, omega_m = self.rate.measure(rate_state, R, Omega, key, j, period)
        if self.attitude is None:
            R_m, valid = R, jnp.asarray(True)
        else:
            attitude_state, (R_m, valid) = self.attitude.measure(attitude_state, R, Omega, key, j, period)
        return (rate_state, attitude_state), Measurements(omega_m, R_m, valid)

    def true_bias(self, state, like):
        """The rate sensor's true bias b_j (3, *b) [rad/s], zeros for a perfect rate
        (``like``: a (3, *b) array)."""
        return jnp.zeros_like(like) if self.rate is None else self.rate.bias(state[0], like)

    def check(self) -> None:
        for part in (self.rate, self.attitude):
            if part is not None:
                part.check()


GYRO_OUTPUTS = ("increment", "rate")  # what the gyro delivers: the angle increment over a period, or the sampled rate


def _gyro(v: dict, ctx):
    kind = IntegratingGyro if v["output"] == "increment" else Gyro
    return kind(ctx.as_array(v["arw"]), ctx.as_array(v["rrw"]), ctx.as_array(v["bias0"]))


components.register(components.ComponentSpec(
    kind="sensor", name="gyro", component=Sensor, provides="rate",
    params=(
        Param("arw", 1e-6, "rad/sqrt(s)", low=0.0, doc="angle random walk sigma_v"),
        Param("rrw", 1e-9, "rad/s^(3/2)", low=0.0, doc="rate random walk sigma_u"),
        Param("bias0", [1e-4, 1e-4, 1e-4], "rad/s", shapes=((3,),), doc="initial bias b_0"),
        Param("output", "increment", choices=GYRO_OUTPUTS,
              doc="increment: the angle increment over each period (a rate-integrating gyro); rate: the rate "
                  "sampled at the tick"),
    ),
    build=_gyro,
    noise=lambda v: {"arw": v["arw"], "rrw": v["rrw"], "gyro_output": v["output"]},
    doc="gyro, Farrenkopf model on the angle increment or on the sampled rate (docs/model.md §8.2)",
))

components.register(components.ComponentSpec(
    kind="sensor", name="star_tracker", component=StarTracker, provides="attitude",
    params=(
        Param("sigma", 3e-5, "rad", low=0.0, doc="per-axis attitude noise"),
        Param("every", 1, "ticks", low=1, integer=True, doc="a sample every `every` ticks"),
    ),
    build=lambda v, ctx: StarTracker(ctx.as_array(v["sigma"]), int(v["every"])),
    noise=lambda v: {"sigma_st": v["sigma"]},
    doc="star tracker: R_m = R exp(hat(sigma eta)) (docs/model.md §8.2)",
))
