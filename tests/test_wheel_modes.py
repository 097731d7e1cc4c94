"""A wheel's bearing friction (docs/model.md (8.13a)) and the wheel faults that change its
dynamics (§8.7): a wheel stuck at its speed (8.22) and a wheel whose friction is scaled
(8.23). Friction against Basilisk's law written out and the closed-form spin-down; a stuck
wheel against the body with that wheel's spin inertia locked to it (the mission without
the wheel), its speed constant and the angular momentum's magnitude conserved."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import so3jax as sj
from so3jax.components.actuators import WheelCommand, Wheels, pyramid_axes
from so3jax.dynamics import plant
from so3jax.missions import batched, draw
from so3jax.missions import mission as missions

J = np.array([[625.0, 5.5, 3.0], [5.5, 350.0, 4.0], [3.0, 4.0, 900.0]])  # [kg m^2], the wheels' spin inertia in it
F_C, C_V, OMEGA_LC = 5e-4, 2e-5, 1e-4  # Coulomb [N m], viscous [N m s/rad], limit-cycle speed [rad/s]


def wheels(axes=None, friction=(F_C, C_V, OMEGA_LC), **kwargs) -> Wheels:
    axes = pyramid_axes() if axes is None else axes
    n = axes.shape[1]
    per = lambda x: jnp.full(n, x)
    f_c, c_v, limit = (None,) * 3 if friction is None else (per(x) for x in friction)
    return Wheels(jnp.asarray(axes), per(0.16), per(0.25), per(628.0), per(0.0), False,
                  coulomb_friction=f_c, viscous_friction=c_v, friction_speed=limit, **kwargs)


def basilisk_friction(omega, f_c, c_v, limit):
    """reactionWheelStateEffector::updateContributions' friction torque (Stribeck off), as its C++ reads."""
    sign = float(int(omega > 0) - int(omega < 0))
    force, at_limit = sign * f_c + c_v * omega, f_c + c_v * limit
    if abs(omega) < limit:
        force = at_limit / limit * omega
    return -force


def test_the_friction_torque_is_basilisks_law():
    speeds = np.array([0.0, 3e-5, -3e-5, OMEGA_LC, -OMEGA_LC, 2e-4, -0.7, 50.0, -628.0])
    w = wheels(axes=np.tile(np.eye(3)[:, :1], (1, speeds.size)))
    for k in (1.0, 3.5):
        factor = None if k == 1.0 else jnp.full(speeds.size, k)
        ours = np.asarray(w.friction_torque(jnp.asarray(speeds), factor))
        theirs = [basilisk_friction(s, k * F_C, k * C_V, OMEGA_LC) for s in speeds]
        np.testing.assert_array_equal(ours, theirs)
    grad = jax.grad(lambda s: w.friction_torque(s)[0])(jnp.zeros(speeds.size))
    assert np.all(np.isfinite(np.asarray(grad)))


def rk4(field, x, dt, steps):
    def one(x, _):
        k1 = field(x)
        k2 = field(jax.tree.map(lambda a, b: a + dt / 2 * b, x, k1))
        k3 = field(jax.tree.map(lambda a, b: a + dt / 2 * b, x, k2))
        k4 = field(jax.tree.map(lambda a, b: a + dt * b, x, k3))
        new = jax.tree.map(lambda a, b1, b2, b3, b4: a + dt / 6 * (b1 + 2 * b2 + 2 * b3 + b4), x, k1, k2, k3, k4)
        return new, new
    return jax.lax.scan(one, x, None, length=steps)[1]


def flight(w: Wheels, J_body, held: WheelCommand, Omega0, speeds0, dt=0.01, steps=1000):
    """(Omega (K, 3), Omega_w (K, N)) of the body and its wheels, no external torque."""
    J_body = jnp.asarray(J_body)

    def field(x):
        Omega, speeds = x
        return plant.derivative(w, J_body, Omega, speeds, held, jnp.zeros(3), jnp.zeros(()))

    Omega, speeds = jax.jit(lambda x: rk4(field, x, dt, steps))((jnp.asarray(Omega0), jnp.asarray(speeds0)))
    return np.asarray(Omega), np.asarray(speeds)


@pytest.mark.parametrize(("start", "limit"), [(50.0, OMEGA_LC), (0.5, 1.0)])
def test_a_wheel_spins_down_as_the_closed_form_says(start, limit):
    """One wheel on the body's principal z axis, the body at rest, no motor torque: with
    H = J_z w + J_s Omega_w constant, Omega_w' = K tau_f(Omega_w), K = J_z / (J_s (J_z - J_s)).
    Above the limit-cycle speed, Omega_w = (Omega_0 + f_c/c_v) e^{-K c_v t} - f_c/c_v; below
    it, Omega_0 e^{-K (f_c + c_v omega_lc) t / omega_lc}."""
    J_diag, J_s = np.diag([625.0, 350.0, 900.0]), 0.16
    w = wheels(axes=np.eye(3), friction=(F_C, C_V, limit))
    held = WheelCommand(jnp.zeros(3), jnp.zeros(3))
    Omega, speeds = flight(w, J_diag, held, np.zeros(3), [0.0, 0.0, start], dt=0.01, steps=2000)
    t = 0.01 * np.arange(1, 2001)
    K = 900.0 / (J_s * (900.0 - J_s))
    if start > limit:
        expected = (start + F_C / C_V) * np.exp(-K * C_V * t) - F_C / C_V
        assert expected[-1] > limit  # never reaches the linear band
    else:
        expected = start * np.exp(-K * (F_C + C_V * limit) / limit * t)
    np.testing.assert_allclose(speeds[:, 2], expected, rtol=1e-11, atol=0)
    assert start - speeds[-1, 2] > 1e-3 * start  # friction spends a part of the speed 1e8 times the tolerance
    np.testing.assert_allclose(Omega[:, 2], J_s * (start - speeds[:, 2]) / 900.0, rtol=1e-11, atol=1e-18)
    np.testing.assert_array_equal(Omega[:, :2], 0.0)


def test_a_stuck_wheel_spins_with_the_body_as_part_of_it():
    """The four wheels with wheel 2 stuck at rest give the body and the other three the
    rates of the three wheels without it on the same body (J holds every wheel's spin
    inertia: the stuck one's spins with the body), for random states and motor torques."""
    rng = np.random.default_rng(7)
    G = pyramid_axes()
    four, three = wheels(), wheels(axes=G[:, [0, 2, 3]])
    for _ in range(5):
        Omega, speeds, u = rng.normal(0, 0.05, 3), rng.normal(0, 40, 4), rng.normal(0, 0.1, 4)
        speeds[1], u[1] = 0.0, 0.3  # a stuck wheel's command delivers nothing
        stuck = jnp.asarray([0.0, 1.0, 0.0, 0.0])
        a = plant.derivative(four, jnp.asarray(J), jnp.asarray(Omega), jnp.asarray(speeds),
                             WheelCommand(jnp.asarray(u), jnp.zeros(3), stuck), jnp.zeros(3), jnp.zeros(()))
        b = plant.derivative(three, jnp.asarray(J), jnp.asarray(Omega), jnp.asarray(speeds[[0, 2, 3]]),
                             WheelCommand(jnp.asarray(u[[0, 2, 3]]), jnp.zeros(3)), jnp.zeros(3), jnp.zeros(()))
        np.testing.assert_allclose(a[0], b[0], rtol=1e-12, atol=1e-18)
        np.testing.assert_allclose(np.asarray(a[1])[[0, 2, 3]], b[1], rtol=1e-12, atol=1e-15)
        assert a[1][1] == 0.0


def test_a_stuck_wheel_keeps_its_speed_and_the_body_its_angular_momentum():
    """Wheel 2 stuck at 30 rad/s, the others driven and rubbing, no external torque: its
    speed is constant bit for bit and |H_B| = |J Omega + G_s J_s Omega_w| (the body frame's
    dH/dt = -Omega x H) is conserved to round-off, also through the body's tumble."""
    w = wheels()
    G, J_s = pyramid_axes(), 0.16
    held = WheelCommand(jnp.asarray([0.02, 0.0, -0.015, 0.01]), jnp.zeros(3), jnp.asarray([0.0, 1.0, 0.0, 0.0]))
    Omega, speeds = flight(w, J, held, [0.05, -0.03, 0.04], [40.0, 30.0, -20.0, 5.0], steps=3000)
    np.testing.assert_array_equal(speeds[:, 1], 30.0)
    H = Omega @ J.T + (speeds * J_s) @ G.T
    norm = np.linalg.norm(H, axis=1)
    np.testing.assert_allclose(norm, norm[0], rtol=1e-12)
    assert np.ptp(speeds[:, 0]) > 1.0 and np.ptp(Omega[:, 0]) > 1e-3  # the others drive, the body turns


# --- in the mission ---------------------------------------------------------------------------------

FAULT = 5.0  # [s]
BASE = {"T": 20.0, "controllers": ["pd"], "record_every": 10, "momentum": {"kind": "none"},
        "initial": {"attitude": [0.01, -0.02, 0.015]},
        "disturbance": {"amplitude": 0.02, "noise_std": 0.005},
        "actuator": {"kind": "wheels", "wheels": {"coulomb_friction": F_C, "viscous_friction": C_V,
                                                  "initial_speed": [40.0, -25.0, 15.0, 8.0]}}}


def with_faults(stuck: float, rubbing: float) -> dict:
    """The base mission with wheel 2 stuck at ``stuck`` [s] and wheel 3's friction tripled
    at ``rubbing`` [s], detected a second later."""
    return {**BASE, "fdir": {"latency": 1.0}, "faults": [{"time": stuck, "wheel": 2, "mode": "stuck"},
                                                         {"time": rubbing, "wheel": 3, "mode": "friction",
                                                          "factor": 3.0}]}


def fly(d: dict):
    m = missions.from_dict(d)
    controller, gains = m.controller("pd")
    result = sj.simulate(m.scenario(), controller, gains, m.seed, loop=m.loop(), record_every=m.record_every)
    return jax.tree.map(lambda x: None if x is None else np.asarray(x), result.history)


@pytest.fixture(scope="module")
def flights():
    """Two programs: the base mission's (friction as stated, and wheel 3's tripled), and the
    faulted one's (the faults in flight)."""
    scaled = {**BASE, "actuator": {"kind": "wheels", "wheels": {**BASE["actuator"]["wheels"],
                                                               "coulomb_friction": [F_C, F_C, 3.0 * F_C, F_C],
                                                               "viscous_friction": [C_V, C_V, 3.0 * C_V, C_V]}}}
    return {"nominal": fly(BASE), "scaled": fly(scaled), "faulted": fly(with_faults(FAULT, 0.0))}


@pytest.mark.optimized
def test_faults_past_the_horizon_change_nothing():
    """Every record bit for bit, the filter's covariance to round-off (its fusion may move)."""
    nominal, late = fly(BASE), fly(with_faults(1e6, 1e6))
    for field in nominal._fields:
        for x, y in zip(jax.tree.leaves(getattr(nominal, field)), jax.tree.leaves(getattr(late, field)), strict=True):
            if field == "covariance":
                np.testing.assert_allclose(x, y, rtol=0, atol=1e-18 * np.abs(x).max())
            else:
                np.testing.assert_array_equal(x, y, err_msg=field)


def test_a_friction_fault_flies_as_the_wheel_with_that_friction(flights):
    """Wheel 3's friction tripled from t = 0 flies as the mission whose wheel 3 has it,
    up to the stuck wheel's fault; the friction is seen (it moves wheel 3's speed)."""
    faulted, scaled, nominal = flights["faulted"], flights["scaled"], flights["nominal"]
    before = faulted.t < FAULT
    for field in ("R", "Omega", "actuator"):
        np.testing.assert_allclose(getattr(faulted, field)[before], getattr(scaled, field)[before], rtol=1e-12,
                                   atol=1e-13)
    assert np.max(np.abs(scaled.actuator[before, 2] - nominal.actuator[before, 2])) > 1e-2


def test_a_stuck_wheel_keeps_its_speed_from_its_fault_tick(flights):
    h = flights["faulted"]
    after = h.t >= FAULT
    np.testing.assert_array_equal(h.actuator[after, 1], h.actuator[after, 1][0])
    assert np.ptp(h.actuator[~after, 1]) > 1e-3  # before, its motor and friction move it


EQUIVALENT = {**BASE, "actuator": {"kind": "wheels", "wheels": {
    "coulomb_friction": F_C, "viscous_friction": C_V, "momentum_compensation": False,
    "initial_speed": [40.0, 0.0, 15.0, 8.0]}}}


def test_a_wheel_stuck_at_rest_flies_as_the_mission_without_it():
    """Wheel 2 stuck at rest from t = 0, dropped at once (latency 0), flies as the three
    other wheels on the same body: the loop's attitude, rates and wheel speeds to round-off."""
    stuck = fly({**EQUIVALENT, "fdir": {"latency": 0.0}, "faults": [{"time": 0.0, "wheel": 2, "mode": "stuck"}]})
    wheels3 = {**EQUIVALENT["actuator"]["wheels"], "axes": pyramid_axes().T[[0, 2, 3]].tolist(),
               "initial_speed": [40.0, 15.0, 8.0]}
    three = fly({**EQUIVALENT, "actuator": {"kind": "wheels", "wheels": wheels3}})
    np.testing.assert_allclose(stuck.R, three.R, rtol=0, atol=1e-12)
    np.testing.assert_allclose(stuck.Omega, three.Omega, rtol=0, atol=1e-14)
    np.testing.assert_allclose(stuck.actuator[:, [0, 2, 3]], three.actuator, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(stuck.actuator[:, 1], 0.0)


# --- sweeps and bad input ----------------------------------------------------------------------------


def test_a_friction_fault_s_factor_is_dispersible_above_one():
    m = missions.from_dict(with_faults(FAULT, 1.0))
    _, leaves = draw.parse({"faults": {"1": {"factor": {"dist": "uniform", "low": 1.5, "high": 8.0}}}}, m)
    assert [leaf.key for leaf in leaves] == ["faults.1.factor"]
    with pytest.raises(ValueError, match="wheel 2 sticks"):
        draw.parse({"faults": {"0": {"factor": {"dist": "uniform", "low": 0.1, "high": 0.5}}}}, m)


SPREAD = {"faults": {"0": {"time": {"dist": "uniform", "low": 2.0, "high": 15.0}},
                     "1": {"factor": {"dist": "uniform", "low": 1.5, "high": 6.0}}},
          "actuator": {"wheels": {"misalignment": {"dist": "normal", "mean": 0.0, "std": 1e-3},
                                  "coulomb_friction": {"dist": "uniform", "low": 2e-4, "high": 8e-4}}}}


def test_dispersed_wheel_modes_fly_each_sample_as_its_mission_alone():
    """The stuck wheel's time, the friction fault's factor, the wheels' friction and their
    misalignment (the plant's axes) drawn per sample: each sample's metrics are those of its
    mission, written with its values, flown alone."""
    base = with_faults(FAULT, 1.0)
    m = missions.from_dict(base)
    samples = draw.draw(*draw.parse(SPREAD, m), 0, 3, 20, mission=m)
    assert np.all(samples.valid)
    controller, gains = m.controller("pd")
    batch = batched.sample_metrics(batched.inputs(samples, np.float64), gains, controller=controller, mission=m)
    assert len(np.unique(np.asarray(batch["rmse"]))) == 3
    for i in range(3):
        own = [dict(f) for f in base["faults"]]
        own[0]["time"], own[1]["factor"] = (float(samples.leaves[k][i]) for k in ("faults.0.time", "faults.1.factor"))
        drawn = {k: samples.leaves[f"actuator.wheels.{k}"][i].tolist() for k in ("misalignment", "coulomb_friction")}
        wheels = {**base["actuator"]["wheels"], **drawn}
        alone = missions.from_dict({**base, "faults": own, "actuator": {"kind": "wheels", "wheels": wheels}})
        result = sj.simulate(alone.scenario(), controller, gains, alone.seed, loop=alone.loop())
        expected = {**result.metrics._asdict(), **result.flight._asdict()}
        for name in ("rmse", "effort", "max_torque", "max_angle_phase"):
            np.testing.assert_allclose(batch[name][i], expected[name], rtol=1e-12, atol=0, err_msg=name)


def test_stuck_wheels_that_leave_less_than_three_axes_are_refused():
    d = {**BASE, "fdir": {"latency": 1.0},
         "faults": [{"time": 1.0, "wheel": i, "mode": mode} for i, mode in ((1, "stuck"), (2, "off"))]}
    with pytest.raises(ValueError, match="no longer controllable"):
        missions.from_dict(d)

