"""A new component of each kind is one definition plus its registration: a sensor, an
estimator and a controller defined here and an actuator defined in
tests/test_actuator_interface.py, each a subclass of its kind's base
(so3jax.components.base), registered here and flown from a mission file with no edit of
the library."""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from so3jax.components import registry as components
from so3jax.components.base import Actuator, Estimate, Estimator, Sensor
from so3jax.components.registry import ComponentSpec
from so3jax.components.sensors import sensor_noise
from so3jax.controllers import registry
from so3jax.controllers.base import Controller, tracking_error
from so3jax.core.params import Param
from so3jax.core.pytree import pytree_dataclass
from so3jax.jobs import fly
from so3jax.missions import mission
from tests.test_actuator_interface import FirstOrderLag

# --- a sensor: a rate gyro with a scale-factor error ---------------------------------------


@pytree_dataclass
class ScaledGyro(Sensor):
    """omega_m = (1 + scale_factor) Omega + (arw / sqrt(Delta_c)) eta, no bias."""

    scale_factor: jnp.ndarray
    arw: jnp.ndarray

    def init(self, batch_shape, dtype):
        return ()

    def measure(self, state, R, Omega, key, j, period):
        eta = sensor_noise(key, 7, j, Omega.dtype)  # its own noise stream
        scale = jnp.asarray(self.scale_factor, Omega.dtype)
        return state, (1.0 + scale) * Omega + jnp.asarray(self.arw, Omega.dtype) / jnp.sqrt(period) * eta


# --- an estimator: the star tracker's sample and a low-pass filtered rate -------------------


@pytree_dataclass
class LowPass(Estimator):
    """R_hat = R_m; Omega_hat_j = Omega_hat_{j-1} + gain (omega_m - Omega_hat_{j-1})."""

    gain: jnp.ndarray
    needs = ("rate", "attitude")

    def init(self, R0, batch_shape, dtype):
        return jnp.zeros((3, *batch_shape), dtype)

    def update(self, state, measured, period, truth=None):
        omega = state + jnp.asarray(self.gain, state.dtype) * (measured.omega_m - state)
        zeros = jnp.zeros_like(omega)
        return omega, Estimate(measured.R_m, omega, zeros, jnp.zeros((6, *omega.shape[1:]), omega.dtype))


# --- an actuator: a first-order lag (tests/test_actuator_interface.py writes its interface out) ---

# --- a controller: a rate damper ---------------------------------------------------------------


class DamperGains(NamedTuple):
    c: float  # N m s / rad


@dataclasses.dataclass(frozen=True)
class Damper(Controller):
    """tau = -sign c Omega_e: a subclass of so3jax.controllers.Controller, its options
    (sign) the dataclass's fields."""

    sign: float = 1.0

    gains_type = DamperGains

    def init(self, gains):
        return ()

    def torque(self, gains, state, feedback, desired, t):
        return -self.sign * gains.c * tracking_error(feedback, desired).Omega_e, ()


def _no_check(gains):
    pass


SPECS = [
    ComponentSpec(kind="sensor", name="scaled_gyro", component=ScaledGyro, provides="rate",
                  params=(Param("scale_factor", 0.0, low=-0.5, high=0.5), Param("arw", 0.0, "rad/sqrt(s)", low=0.0)),
                  build=lambda v, ctx: ScaledGyro(ctx.as_array(v["scale_factor"]), ctx.as_array(v["arw"]))),
    ComponentSpec(kind="estimator", name="lowpass", component=LowPass,
                  params=(Param("gain", 1.0, low=0.0, high=1.0),),
                  build=lambda v, ctx: LowPass(ctx.as_array(v["gain"]))),
    ComponentSpec(kind="actuator", name="lag", component=FirstOrderLag,
                  params=(Param("time_constant", 0.5, "s", low=1e-6),),
                  build=lambda v, ctx: FirstOrderLag(ctx.as_array(v["time_constant"]))),
]
CONTROLLER = registry.ControllerSpec(name="damper", label="damper", factory=Damper, gains_type=DamperGains,
                                     defaults=DamperGains(c=50.0), check=_no_check,
                                     options=(Param("sign", 1.0, low=-1.0, high=1.0),))


@pytest.fixture(scope="module")
def registered():
    for spec in SPECS:
        components.register(spec)
    registry.register(CONTROLLER)
    yield
    for spec in SPECS:
        components.unregister(spec.kind, spec.name)
    registry.unregister(CONTROLLER.name)


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
    assert m.sensors["scaled_gyro"]["scale_factor"] == 0.05
    assert m.estimator == {"kind": "lowpass", "lowpass": {"gain": 1.0}}
    results, _ = fly.fly(m)
    h = results["damper"].history
    # the sensor's reading reached the estimate, and the estimate the law: Omega_hat = 1.05 Omega at the ticks
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


# --- the bases: the required methods, the defaults, pytrees -------------------------------


def test_a_component_missing_a_required_method_cannot_be_made():
    """Each base declares its kind's required methods abstract: a subclass without one is
    refused when it is instantiated, naming the method; the rest is the base's."""

    @pytree_dataclass
    class NoMeasure(Sensor):
        def init(self, batch_shape, dtype):
            return ()

    @pytree_dataclass
    class NoUpdate(Estimator):
        def init(self, R0, batch_shape, dtype):
            return ()

    @pytree_dataclass
    class NoCommand(Actuator):
        pass

    for cls, method in ((NoMeasure, "measure"), (NoUpdate, "update"), (NoCommand, "command")):
        with pytest.raises(TypeError, match=method):
            cls()
    for base in (Sensor, Estimator, Actuator):
        with pytest.raises(TypeError, match="abstract"):
            base()
    lag = FirstOrderLag(jnp.asarray(0.5))  # only init, command, body_torque, derivative defined
    zero = jnp.zeros(3)
    assert lag.stored_momentum(zero) is None and lag.uncompensated_momentum(zero, zero) is None
    assert lag.spin_inertia_values() is None and lag.speed_ratio(zero) == 0.0 and lag.check() is None
    np.testing.assert_array_equal(ScaledGyro(0.1, 0.0).bias((), jnp.ones(3)), jnp.zeros(3))
    assert LowPass.needs == ("rate", "attitude") and not LowPass.reads_truth and not Estimator.reads_truth


def test_a_component_subclassing_its_base_is_a_pytree_and_a_jit_argument():
    """A pytree_dataclass subclass of an ABC flattens and unflattens as before, passes
    through jit as a dynamic argument (its fields traced) and as a static one (hashed)."""
    lag = FirstOrderLag(jnp.asarray(0.5))
    leaves, tree = jax.tree.flatten(lag)
    assert len(leaves) == 1 and jax.tree.unflatten(tree, leaves) == lag
    assert isinstance(jax.tree.map(lambda x: 2 * x, lag), FirstOrderLag)
    rate = jax.jit(lambda a, s: a.derivative(s, jnp.ones(3), None, None))(lag, jnp.zeros(3))
    np.testing.assert_allclose(rate, 2.0 * np.ones(3))
    static = FirstOrderLag(0.25)  # hashable fields: a static argument
    f = jax.jit(lambda a, s: a.derivative(s, jnp.ones(3), None, None), static_argnums=0)
    np.testing.assert_allclose(f(static, jnp.zeros(3)), 4.0 * np.ones(3))


def test_registering_a_component_checks_its_base():
    """A registration names the class it builds, a subclass of its kind's base."""
    with pytest.raises(ValueError, match="subclass of so3jax.components.base.Estimator"):
        components.register(ComponentSpec(kind="estimator", name="not_an_estimator", component=ScaledGyro, params=(),
                                          build=lambda v, ctx: None))
    assert "not_an_estimator" not in components.names("estimator")
