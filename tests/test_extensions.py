"""A new component of each kind is one definition plus its registration: a sensor, an
estimator and a controller defined here and an actuator defined in
tests/test_actuator_interface.py, registered here and flown from a mission file with no
edit of the library."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
import pytest

from so3jax.components import registry as components

from so3jax.jobs import fly

from so3jax.missions import mission
from so3jax.core.pytree import pytree_dataclass
from so3jax.components.registry import ComponentSpec
from so3jax.core.params import Param
from so3jax.controllers import registry
from so3jax.controllers.base import Controller, tracking_error
from so3jax.components.estimators import Estimate
from so3jax.components.sensors import sensor_noise
from tests.test_actuator_interface import FirstOrderLag

# --- a sensor: a rate gyro with a scale-factor error ---------------------------------------


@pytree_dataclass
class ScaledGyro:
    """omega_m = (1 + scale_factor) Omega + (arw / sqrt(Delta_c)) eta, no bias."""

    scale_factor: jnp.ndarray
    arw: jnp.ndarray

    def init(self, batch_shape, dtype):
        return ()

    def measure(self, state, R, Omega, key, j, period):
        eta = sensor_noise(key, 7, j, Omega.dtype)  # its own noise stream
        scale = jnp.asarray(self.scale_factor, Omega.dtype)
        return state, (1.0 + scale) * Omega + jnp.asarray(self.arw, Omega.dtype) / jnp.sqrt(period) * eta

    def bias(self, state, Omega):
        return jnp.zeros_like(Omega)

    def check(self):
        pass


# --- an estimator: the star tracker's sample and a low-pass filtered rate -------------------


@pytree_dataclass
class LowPass:
    """R_hat = R_m; omega_hat_j = omega_hat_{j-1} + gain (omega_m - omega_hat_{j-1})."""

    gain: jnp.ndarray
    reads_truth = False

    def init(self, R0, batch_shape, dtype):
        return jnp.zeros((3, *batch_shape), dtype)

    def update(self, state, measured, period, truth=None):
        omega = state + jnp.asarray(self.gain, state.dtype) * (measured.omega_m - state)
        zeros = jnp.zeros_like(omega)
        return omega, Estimate(measured.R_m, omega, zeros, jnp.zeros((6, *omega.shape[1:]), omega.dtype))

    def check(self):
        pass


# --- an actuator: a first-order lag (tests/test_actuator_interface.py writes its interface out) ---

# --- a controller: a rate damper ---------------------------------------------------------------


class DamperGains(NamedTuple):
    c: float  # N m s / rad


def damper(sign: float = 1.0) -> Controller:
    """tau = -sign c Omega_e."""

    def torque(gains, state, measured, desired, t):
        return -sign * gains.c * tracking_error(measured, desired).Omega_e, ()

    return Controller(lambda gains: (), torque, DamperGains)


def _no_check(gains):
    pass


SPECS = [
    ComponentSpec(kind="sensor", name="scaled_gyro", provides="rate",
                  params=(Param("scale_factor", 0.0, low=-0.5, high=0.5), Param("arw", 0.0, "rad/sqrt(s)", low=0.0)),
                  build=lambda v, ctx: ScaledGyro(ctx.as_array(v["scale_factor"]), ctx.as_array(v["arw"]))),
    ComponentSpec(kind="estimator", name="lowpass", needs=("rate", "attitude"),
                  params=(Param("gain", 1.0, low=0.0, high=1.0),),
                  build=lambda v, ctx: LowPass(ctx.as_array(v["gain"]))),
    ComponentSpec(kind="actuator", name="lag", params=(Param("time_constant", 0.5, "s", low=1e-6),),
                  build=lambda v, ctx: FirstOrderLag(ctx.as_array(v["time_constant"]))),
]
CONTROLLER = registry.ControllerSpec(name="damper", label="damper", factory=damper, gains_type=DamperGains,
                                     defaults=DamperGains(c=50.0), style={"label": "damper"}, check=_no_check,
                                     options=(Param("sign", 1.0, low=-1.0, high=1.0),))


@pytest.fixture(scope="module")
def registered():
    for spec in SPECS:
        components.register(spec)
    registry.register(CONTROLLER)
    yield
    for spec in SPECS:
        components._REGISTRY[spec.kind].pop(spec.name)
    registry._REGISTRY.pop(CONTROLLER.name)


MISSION = """
T = 2.0
dt = 0.01
controllers = ["damper"]
record_every = 10
[control]
period = 0.1
[initial]
rate = [0.02, -0.01, 0.03]
[sensors]
gyro = false
[sensors.scaled_gyro]
scale_factor = 0.05
[sensors.star_tracker]
sigma = 1e-5
[estimator]
kind = "lowpass"
[actuator]
kind = "ideal"
[gains.damper]
c = 1000.0
"""


def test_extra_sensor_estimator_and_controller_fly_from_a_mission_file(registered, tmp_path):
    path = tmp_path / "mission.toml"
    path.write_text(MISSION)
    m = mission.load(path)
    assert m.sensors["scaled_gyro"]["scale_factor"] == 0.05 and m.estimator == {"kind": "lowpass", "lowpass": {"gain": 1.0}}
    results, _ = fly.fly(m)
    h = results["damper"].history
    # the sensor's reading reached the estimate, and the estimate the law: omega_hat = 1.05 Omega at the ticks
    np.testing.assert_allclose(np.asarray(h.Omega_hat), 1.05 * np.asarray(h.Omega), rtol=1e-12, atol=1e-15)
    error = np.linalg.norm(np.asarray(h.Omega_e), axis=1)
    assert error[-1] < 0.2 * error[0]  # the damper damps (J / c ~ 0.6 s)
    # the option reaches the factory: a negative sign drives the rate error away
    pumped, _ = fly.fly(mission.load(path, ["controller.damper.sign=-1.0"]))
    assert np.linalg.norm(np.asarray(pumped["damper"].history.Omega_e)[-1]) > 2.0 * error[0]


def test_extra_components_are_checked_like_the_built_in_ones(registered, tmp_path):
    path = tmp_path / "mission.toml"
    path.write_text(MISSION)
    with pytest.raises(ValueError, match=r"sensors.scaled_gyro.scale_factor"):
        mission.load(path, ["sensors.scaled_gyro.scale_factor=2.0"])
    with pytest.raises(ValueError, match="both measure the rate"):
        mission.load(path, ["sensors.gyro={}"])
    with pytest.raises(ValueError, match="estimator 'lowpass' needs a sensor of the rate"):
        mission.load(path, ["sensors.scaled_gyro=false"])
    with pytest.raises(ValueError, match=r"gains.damper.c"):
        mission.load(path, ["gains.damper.c='big'"])
    with pytest.raises(ValueError, match="controller.damper"):
        mission.load(path, ["controller.damper.sign=true"])


def test_extra_actuator_flies_from_a_mission_file_in_both_wirings(registered, tmp_path):
    """The lag's body torque follows the command with its time constant: after a step in
    the command (the open-loop law), tau(t) = tau_c (1 - exp(-t / time_constant)); the
    continuous and the sampled wiring report it alike."""
    path = tmp_path / "lag.toml"
    path.write_text(MISSION.replace('kind = "ideal"', 'kind = "lag"\n[actuator.lag]\ntime_constant = 0.5')
                    .replace('controllers = ["damper"]', 'controllers = ["open_loop"]')
                    .replace("[gains.damper]\nc = 1000.0", "[controller.open_loop]\ntorque = [0.1, -0.2, 0.05]"))
    sampled = mission.load(path)
    continuous = mission.load(path, ["control.mode=continuous", "sensors.scaled_gyro=false",
                                     "sensors.star_tracker=false", "estimator.kind=truth"])
    tau_c = np.array([0.1, -0.2, 0.05])
    for m in (sampled, continuous):
        h = fly.fly(m)[0]["open_loop"].history
        t = np.asarray(h.t)
        np.testing.assert_allclose(np.asarray(h.tau), tau_c * (1 - np.exp(-t / 0.5))[:, None], rtol=0, atol=1e-9)
