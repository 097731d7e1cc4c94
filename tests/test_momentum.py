"""Momentum management beside the wheels (docs/model.md §8.6) and the environment's torques
(§4) in the loop: the external torques they put on the body are the only change of its
total angular momentum, thrusters dump between their thresholds, magnetorquers unload
at the rate the cross-product law predicts on an orbit."""

from pathlib import Path

import jax
import numpy as np
import pytest

import so3jax as sj
from so3jax.dynamics import environment as env
from so3jax.missions import mission as missions

J = [[900.0, 6.0, -4.0], [6.0, 800.0, 5.0], [-4.0, 5.0, 600.0]]
HOLD = ["dt=0.1", "control.period=1.0", "record_every=10", "controllers=['pd']", f"inertia.J={J}",
        "reference.kind='inertial'", "disturbance.amplitude=0.0", "disturbance.noise_std=0.0",
        "sensors.gyro=false", "sensors.star_tracker=false", "estimator.kind='truth'",
        "actuator.wheels.initial_speed=[300.0, 300.0, 300.0, 300.0]"]


def fly(overrides):
    """(mission, history) of a mission that holds an inertial attitude on its wheels."""
    m = missions.load(None, HOLD + overrides)
    controller, gains = m.controller("pd")
    result = sj.simulate(m.scenario(), controller, gains, m.seed, loop=m.loop(), record_every=m.record_every)
    return m, jax.tree.map(np.asarray, result.history)


def total_momentum(m, h):
    """R (J Omega + h_w) (M, 3) [N m s] in the inertial frame, h_w the wheels' (relative) momentum."""
    wheels = m.actuator["wheels"]
    G = np.asarray(wheels["axes"], float).T
    h_w = (G @ (np.broadcast_to(wheels["spin_inertia"], (4,)) * h.actuator).T).T
    return np.einsum("mij,mj->mi", h.R, np.einsum("mij,mj->mi", h.J, h.Omega) + h_w), h_w


def integral(t, f):
    """The trapezoid integral of f (M, 3) from t[0] to each t (M, 3)."""
    steps = 0.5 * (f[1:] + f[:-1]) * np.diff(t)[:, None]
    return np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)])


@pytest.fixture(scope="module")
def dumped():
    return fly(["T=600.0", "momentum.kind='thrusters'", "momentum.thrusters.torque=0.2",
                "momentum.thrusters.start=60.0", "momentum.thrusters.stop=20.0",
                "momentum.thrusters.min_on_time=3.0"])


def test_thrusters_change_the_total_momentum_by_their_pulses_alone(dumped):
    m, h = dumped
    H, _ = total_momentum(m, h)
    # each record is a tick; the pulse fired there is held over the period, in body axes
    impulse = np.cumsum(np.einsum("mij,mj->mi", h.R, h.managed) * m.period, axis=0)
    np.testing.assert_allclose(H[1:] - H[0], impulse[:-1], atol=1e-3 * np.abs(impulse).max())
    assert np.abs(impulse).max() > 50.0  # N m s: the thrusters did the work


def test_thrusters_dump_from_above_start_to_below_stop_and_then_rest(dumped):
    m, h = dumped
    _, h_w = total_momentum(m, h)
    size = np.linalg.norm(h_w, axis=1)
    firing = np.any(h.managed != 0.0, axis=1)
    assert size[0] > 60.0 and firing[0]
    below = np.flatnonzero(size < 20.0)
    assert below.size and size[-1] < 20.0 and size[-1] > 20.0 - 0.2 * 3.0 * 2
    assert not np.any(firing[below[0] + 3:])  # a firing begun lasts its minimum on-time, then dumping stops
    runs = np.diff(np.flatnonzero(np.diff(np.concatenate([[0], firing[:below[0] + 3].astype(int), [0]]))))[::2]
    assert runs.min() >= 3  # min_on_time = 3 s: three ticks
    np.testing.assert_array_equal(np.abs(h.managed[firing]).max(axis=1), 0.2)


@pytest.fixture(scope="module")
def unloaded():
    """Half an orbit of magnetorquer unloading, noise-free, the dipole never at its limit, under
    the environment's torques: gravity gradient, drag, solar pressure and a residual dipole."""
    return fly(["T=2800.0", "orbit.inclination=60.0", "orbit.raan=30.0", "orbit.earth_angle=45.0",
                "momentum.kind='magnetorquers'", "momentum.magnetorquers.gain=8e-4",
                "momentum.magnetorquers.max_dipole=1e4", "momentum.magnetorquers.magnetometer_noise=0.0",
                "environment.gravity_gradient={}", "environment.solar_pressure={}",
                "environment.aerodynamic={area=4.0, centre_of_pressure=[0.3, 0.1, -0.2]}",
                "environment.magnetic={dipole=[1.0, -2.0, 0.5]}"])


def test_the_environment_and_the_magnetorquers_change_the_total_momentum_alone(unloaded):
    """R (J Omega + h_w) changes by the integral of R times the environment's torques plus
    m x B, each recomputed from the records."""
    m, h = unloaded
    H, _ = total_momentum(m, h)
    environment = m.scenario().environment
    B_N = np.asarray(jax.vmap(lambda t: env.magnetic_field_n(environment.orbit, t))(h.t))
    managed = np.cross(np.einsum("mij,mj->mi", h.R, h.managed), B_N)  # R (m x R^T B) = (R m) x B
    torque = np.asarray(jax.vmap(lambda t, R, J: environment.torque(t, R, J))(h.t, h.R, h.J))
    external = np.einsum("mij,mj->mi", h.R, torque)
    assert np.abs(integral(h.t, external)).max() > 1e-2  # N m s: the environment did something
    np.testing.assert_allclose(H - H[0], integral(h.t, managed + external), atol=2e-3 * np.abs(H - H[0]).max())


def test_magnetorquers_unload_at_the_rate_of_the_cross_product_law(unloaded):
    """dh/dt = -k (h - b^ (b^ . h)) along the orbit's field (the attitude held near R = I): the
    total momentum, which the wheels hold but for the body's share (J Omega, under 1 %),
    follows that equation integrated on its own (the environment's torques store under 1 %)."""
    m, h = unloaded
    h_w, _ = total_momentum(m, h)
    orbit, k = m.scenario().environment.orbit, 8e-4
    field = jax.jit(lambda t: env.magnetic_field_n(orbit, t))

    def rate(t, x):
        b = np.asarray(field(t))
        b = b / np.linalg.norm(b)
        return -k * (x - b * (b @ x))

    predicted, x = [h_w[0]], h_w[0]
    for t0, t1 in zip(h.t[:-1], h.t[1:]):  # RK4 between the records
        dt = t1 - t0
        k1 = rate(t0, x)
        k2 = rate(t0 + dt / 2, x + dt / 2 * k1)
        k3 = rate(t0 + dt / 2, x + dt / 2 * k2)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + rate(t1, x + dt * k3))
        predicted.append(x)
    assert np.linalg.norm(h_w[-1]) < 0.3 * np.linalg.norm(h_w[0])  # unloaded
    np.testing.assert_allclose(h_w, predicted, atol=0.02 * np.linalg.norm(h_w[0]))


def test_thrusters_tick_every_step_in_the_continuous_wiring():
    """The continuous wiring (the law in every RK4 stage) with wheels: the thrusters decide at
    every step (a record holds the step's), and their pulses are again the only change of the
    total momentum."""
    m, h = fly(["T=40.0", "record_every=1", "control.mode='continuous'", "momentum.kind='thrusters'",
                "momentum.thrusters.torque=0.2", "momentum.thrusters.start=60.0", "momentum.thrusters.stop=20.0"])
    H, _ = total_momentum(m, h)
    impulse = np.cumsum(np.einsum("mij,mj->mi", h.R, h.managed) * m.dt, axis=0)
    assert np.all(np.abs(h.managed[:, 2]) == 0.2)  # |h_w| ~ 111 N m s > start: firing about z throughout
    np.testing.assert_allclose(H[1:] - H[0], impulse[:-1], atol=1e-3 * np.abs(impulse).max())


def test_the_flight_mission_s_thrusters_come_with_its_wheels():
    """Another actuator without a [momentum] table flies no momentum management; the
    thrusters named beside it are refused (below)."""
    assert missions.load().momentum["kind"] == "thrusters"
    for kind in ("ideal", "saturated"):
        assert missions.load(None, [f"actuator.kind='{kind}'"]).momentum == {"kind": "none", "none": {}}
    assert missions.load(None, ["actuator.kind='wheels'"]).momentum["kind"] == "thrusters"
    flight = Path(__file__).resolve().parents[1] / "missions" / "flight.toml"
    assert missions.load(flight, ["actuator.kind='ideal'"]).momentum["kind"] == "none"
    assert missions.load(flight, ["actuator.kind='ideal'", "momentum.kind='none'"]).momentum["kind"] == "none"


@pytest.mark.parametrize("overrides, message", [
    (["actuator.kind='ideal'"], "needs an actuator that stores momentum"),
    (["actuator.kind='saturated'", "momentum.kind='magnetorquers'"], "the Saturated actuator stores none"),
    (["momentum.thrusters.start=20.0", "momentum.thrusters.stop=30.0"], "must be below start"),
])
def test_momentum_management_s_bad_settings_are_one_line_errors_before_compiling(overrides, message):
    """A manager beside an actuator that stores no momentum, thresholds the wrong way round:
    refused by the mission's checks (nothing traced)."""
    with pytest.raises(ValueError, match=message):
        missions.load(None, ["momentum.kind='thrusters'", *overrides])


@pytest.mark.parametrize("overrides, message", [
    (["momentum.thrusters.torque=0.0"], "momentum.thrusters.torque = 0.0 N m: no pair gives a torque and the "
                                        "thrusters never act; give a positive torque (or momentum.kind = 'none')"),
    (["momentum.thrusters.start=250.0"], "momentum.thrusters.start = 250.0 N m s is never exceeded: the wheels store "
                                         "at most 232.061 N m s (|G_s J_s Omega_w| with every wheel at its "
                                         "actuator.wheels.max_speed); set start below it"),
    (["actuator.wheels.max_speed=100.0"], "momentum.thrusters.start = 50.0 N m s is never exceeded: the wheels store "
                                          "at most 36.9524 N m s"),
    (["momentum.kind='magnetorquers'", "momentum.magnetorquers.gain=0.0"],
     "momentum.magnetorquers.gain = 0 1/s: the magnetorquers never act"),
    (["momentum.kind='magnetorquers'", "momentum.magnetorquers.max_dipole=[0.0, 0.0, 0.0]"],
     "momentum.magnetorquers.max_dipole = [0.0, 0.0, 0.0] A m^2: every coil is failed (limit 0)"),
    (["momentum.kind='magnetorquers'", "momentum.magnetorquers.target=[0.0, 240.0, 0.0]"],
     "momentum.magnetorquers.target = [0.0, 240.0, 0.0] N m s (|target| = 240) is out of reach: the wheels store "
     "at most 232.061 N m s"),
])
def test_a_momentum_manager_that_can_never_act_is_refused_when_parsed(overrides, message):
    """No torque, a start threshold the wheels' momentum never exceeds (their capacity: the
    largest |G_s J_s Omega_w| at their speed limits), no gain, every coil failed, a target out
    of reach: one-line errors naming the key, when the mission is read."""
    with pytest.raises(ValueError) as err:
        missions.load(None, ["T=1.0", *overrides])
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


def test_the_wheels_capacity_is_the_largest_momentum_at_their_speed_limits():
    """The flight mission's pyramid: a corner of the speed box, below sum J_s Omega_max, above
    any momentum a random speed inside the box gives; a start just below it is accepted."""
    wheels = missions.load(None, ["T=1.0"]).loop(np.float64).actuator
    G, reach = np.asarray(wheels.axes), np.asarray(wheels.spin_inertia) * np.asarray(wheels.max_speed)
    capacity = wheels.momentum_capacity()
    speeds = np.random.default_rng(0).uniform(-1.0, 1.0, (20000, 4))
    inside = np.linalg.norm((speeds * reach) @ G.T, axis=1)
    assert inside.max() < capacity < reach.sum()
    assert capacity == pytest.approx(np.max(np.linalg.norm((np.sign(speeds) * reach) @ G.T, axis=1)), rel=1e-12)
    missions.load(None, ["T=1.0", f"momentum.thrusters.start={capacity * 0.999}"])


def test_a_thruster_pair_of_no_torque_beside_others_warns_and_a_set_of_none_is_refused():
    from so3jax.components.momentum import MomentumWarning, Thrusters

    with pytest.warns(MomentumWarning, match=r"^momentum.thrusters.torque = \[0.2, 0.0, 0.2\] N m: the y pair gives "
                                             r"no torque, so the wheels' momentum about body y is never dumped$"):
        missions.load(None, ["T=1.0", "momentum.thrusters.torque=[0.2, 0.0, 0.2]"])
    with pytest.raises(ValueError, match="no pair gives a torque"):
        Thrusters(np.zeros(3), np.float64(50.0), np.float64(20.0)).check()


def test_fly_refuses_thrusters_that_never_fire_with_exit_2(in_process, capsys):
    from so3jax import commands as cli

    assert cli.main(["fly", "--T", "1", "--set", "momentum.thrusters.start=250.0", "--out", "o"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("so3jax fly: error: momentum.thrusters.start = 250.0 N m s is never exceeded")
    assert err.count("\n") == 1 and "Traceback" not in err and not (in_process / "o").exists()


def test_a_failed_magnetorquer_coil_gives_no_dipole_and_the_others_theirs():
    """max_dipole 0 on one coil (the domain allows it): that coil's dipole is 0, the others'
    the cross-product law's scaled to their limits, finite with finite derivatives, also
    where the law asks for no dipole at all (h_w at its target)."""
    from so3jax.components.momentum import Magnetorquers

    B = np.array([2e-5, -1e-5, 3e-5])  # [T], body frame

    class Field:
        def magnetic_field_body(self, t, R):
            return jax.numpy.asarray(B)

    coils = Magnetorquers(np.float64(1e-3), np.array([1.0, 1.0, 0.0]), np.zeros(3), np.float64(0.0))
    dipole = lambda h: coils.command((), h, Field(), 0.0, np.eye(3), jax.random.key(0), 0)[1]
    for h in (np.zeros(3), np.array([5.0, -3.0, 2.0])):
        m, gradient = np.asarray(dipole(h)), np.asarray(jax.jacfwd(dipole)(h))
        assert np.all(np.isfinite(m)) and np.all(np.isfinite(gradient)) and m[2] == 0.0
    law = 1e-3 * np.cross(B, -h) / (B @ B)
    law[2] = 0.0
    np.testing.assert_allclose(m, law / np.abs(law).max(), rtol=1e-12)  # the larger coil at its limit
