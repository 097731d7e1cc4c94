"""Actuators (docs/model.md §8.4): the reaction-wheel plant against scipy and closed forms, the
command's distribution and limits, the paper's ideal torque bit for bit, checks, and
jit / vmap / grad."""

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from so3jax.components.actuators import Ideal, Saturated, WheelCommand, Wheels, momentum, pyramid_axes
from so3jax.core import so3
from so3jax.core._fusion import materialize
from so3jax.core.integrate import lie_rk4_step
from so3jax.dynamics import plant
from so3jax.dynamics.plant import angular_acceleration

J_SC = np.array([[12.0, 0.6, -0.4], [0.6, 10.0, 0.8], [-0.4, 0.8, 8.0]])  # kg m^2, wheels locked
SPIN = np.array([0.16, 0.12, 0.2, 0.16])  # kg m^2
OMEGA0 = np.array([0.3, -0.2, 0.25])  # rad/s
WHEEL0 = np.array([40.0, -25.0, 15.0, 60.0])  # rad/s


def wheels(G=None, spin=None, u_max=0.25, speed=628.0, initial=None, compensation=True) -> Wheels:
    """Wheels on axes G (3, N), by default the 4-wheel pyramid; J_s and Omega_w(0) default
    to the first N of SPIN and WHEEL0."""
    G = pyramid_axes(4) if G is None else G
    n = np.shape(G)[1]
    spin = SPIN[:n] if spin is None else spin
    initial = WHEEL0[:n] if initial is None else initial
    per_wheel = lambda x: jnp.asarray(np.broadcast_to(np.asarray(x, float), (n,)))
    return Wheels(jnp.asarray(G, float), per_wheel(spin), per_wheel(u_max), per_wheel(speed), per_wheel(initial),
                  compensation)


def hat(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def reference_rhs(J, G, spin, u):
    """docs/model.md §8.4's plant in numpy on y = (R flattened, Omega, Omega_w)."""
    J_B = J - G @ np.diag(spin) @ G.T

    def rhs(t, y):
        R, Omega, speed = y[:9].reshape(3, 3), y[9:12], y[12:]
        Omega_dot = np.linalg.solve(J_B, -np.cross(Omega, J @ Omega + G @ (spin * speed)) - G @ u)
        return np.concatenate([(R @ hat(Omega)).ravel(), Omega_dot, u / spin - G.T @ Omega_dot])

    return rhs


@partial(jax.jit, static_argnums=(6,))
def integrate_held(actuator, J, u, R0, Omega0, speed0, n_steps, dt):
    """n_steps of lie_rk4_step of the plant (so3jax.dynamics.plant.derivative) with the motor torques
    u (N,) or the wheels' command held and d = 0. Returns the final
    (R, Omega, Omega_w) and, at every step start and the end, the total angular momentum
    in the inertial frame R (J Omega + G_s J_s Omega_w) and the rotational kinetic energy."""

    held = u if isinstance(u, WheelCommand) else WheelCommand(u, jnp.zeros_like(Omega0))

    def field(t, rotations, vectors):
        Omega, speed = vectors
        Omega_dot, speed_dot = plant.derivative(actuator, J, Omega, speed, held, jnp.zeros_like(Omega), t)
        return (Omega,), (Omega_dot, speed_dot), ()

    def invariants(R, Omega, speed):
        h = actuator.momentum(speed, Omega)  # G_s J_s (G_s^T Omega + Omega_w)
        J_B = actuator.locked_wheel_inertia(J)
        body = J_B @ Omega
        wheel_spin = actuator.spin_inertia * (actuator.axes.T @ Omega + speed)
        energy = 0.5 * Omega @ body + 0.5 * jnp.sum(wheel_spin * (actuator.axes.T @ Omega + speed))
        return R @ (body + h), energy

    def step(carry, k):
        R, Omega, speed = carry
        (R,), (Omega, speed), _ = lie_rk4_step(field, k * dt, dt, (R,), (Omega, speed))
        return (R, Omega, speed), invariants(*carry)

    final, (momentum, energy) = jax.lax.scan(step, (R0, Omega0, speed0), jnp.arange(n_steps, dtype=Omega0.dtype))
    last_momentum, last_energy = invariants(*final)
    return final, jnp.concatenate([momentum, last_momentum[None]]), jnp.append(energy, last_energy)


@pytest.mark.parametrize("u", [np.zeros(4), np.array([0.05, -0.03, 0.02, -0.04])], ids=["u=0", "u=const"])
def test_open_loop_wheels_match_solve_ivp_and_conserve_momentum(u):
    """4 skewed wheels on a body with products of inertia, spinning and tumbling: Lie RK4
    at dt = 2 ms agrees with DOP853 (rtol = atol = 1e-12) to 1e-11 after 6 s; total momentum in the
    inertial frame is conserved (the motor torques are internal), and with u = 0 the
    kinetic energy too."""
    actuator = wheels()
    G = pyramid_axes(4)
    T, n_steps = 6.0, 3000
    final, momentum, energy = integrate_held(actuator, jnp.asarray(J_SC), jnp.asarray(u), jnp.eye(3),
                                             jnp.asarray(OMEGA0), jnp.asarray(WHEEL0), n_steps, T / n_steps)
    y0 = np.concatenate([np.eye(3).ravel(), OMEGA0, WHEEL0])
    ref = solve_ivp(reference_rhs(J_SC, G, SPIN, u), (0.0, T), y0, method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1]
    R, Omega, speed = (np.asarray(x) for x in final)
    assert np.abs(Omega - OMEGA0).max() > 0.1 and np.abs(R - np.eye(3)).max() > 0.5  # a real tumble
    np.testing.assert_allclose(R, ref[:9].reshape(3, 3), rtol=0, atol=1e-11)
    np.testing.assert_allclose(Omega, ref[9:12], rtol=0, atol=1e-11)
    np.testing.assert_allclose(speed, ref[12:], rtol=0, atol=1e-11 * np.abs(WHEEL0).max())
    momentum = np.asarray(momentum)
    h0 = np.linalg.norm(momentum[0])
    assert np.abs(momentum - momentum[0]).max() <= 1e-12 * h0
    energy = np.asarray(energy)
    if np.any(u):
        assert np.ptp(energy) > 1e-3 * energy[0]  # the motors do work
    else:
        assert np.ptp(energy) <= 1e-12 * energy[0]


def test_single_wheel_spin_up_about_a_principal_axis_matches_closed_form():
    """From rest, one wheel along z with motor torque u: Omega_z = -u t / (J_zz - J_s),
    Omega_w = u t (1 / J_s + 1 / (J_zz - J_s)), the body turning about z by -u t^2 / (2 (J_zz - J_s))."""
    J = np.diag([10.0, 12.0, 8.0])
    spin, u, T, n_steps = 0.16, 0.2, 20.0, 200
    actuator = wheels(np.array([[0.0], [0.0], [1.0]]), spin=spin, initial=0.0)
    (R, Omega, speed), _, _ = integrate_held(actuator, jnp.asarray(J), jnp.asarray([u]), jnp.eye(3), jnp.zeros(3),
                                             jnp.zeros(1), n_steps, T / n_steps)
    body = J[2, 2] - spin
    angle = -u * T**2 / (2.0 * body)
    expected_R = np.array([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(np.asarray(Omega), [0.0, 0.0, -u * T / body], rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(np.asarray(speed), [u * T * (1.0 / spin + 1.0 / body)], rtol=1e-13)
    np.testing.assert_allclose(np.asarray(R), expected_R, rtol=0, atol=1e-12)


def test_minimum_norm_distribution_reproduces_the_command():
    """No limit binding: u = -pinv(G_s) tau_c, so -G_s u = tau_c, for a batch (3, 2, 3)."""
    actuator = wheels(compensation=False)
    tau = 0.1 * jax.random.normal(jax.random.key(0), (3, 2, 3), jnp.float64)
    state = actuator.init((2, 3), jnp.float64)
    held = actuator.command(state, tau, jnp.zeros_like(tau))
    u = held.u
    assert u.shape == (4, 2, 3) and u.dtype == jnp.float64
    expected = -np.einsum("ij,j...->i...", np.linalg.pinv(pyramid_axes(4)), np.asarray(tau))
    np.testing.assert_allclose(np.asarray(u), expected, rtol=1e-13, atol=1e-16)
    for torque in (actuator.body_torque(state, held, tau), actuator.delivered(state, held, tau)):
        np.testing.assert_allclose(np.asarray(torque), np.asarray(tau), rtol=1e-13, atol=1e-16)
    np.testing.assert_allclose(np.asarray(actuator.effort(held)), np.sum(expected**2, axis=0), rtol=1e-13)
    at_torque, at_speed = actuator.limits(state, held, tau)
    assert at_torque.shape == at_speed.shape == (2, 3) and not at_torque.any() and not at_speed.any()
    assert np.asarray(actuator.speed_ratio(state)).shape == (2, 3)


def test_motor_torque_is_clipped_at_u_max():
    actuator = wheels(u_max=[0.25, 0.3, 0.25, 0.2], compensation=False)
    tau = jnp.asarray([0.8, -0.1, 0.3])
    state = actuator.init((), jnp.float64)
    held = actuator.command(state, tau, jnp.zeros(3))
    u = np.asarray(held.u)
    unclipped = -np.linalg.pinv(pyramid_axes(4)) @ np.asarray(tau)
    u_max = np.array([0.25, 0.3, 0.25, 0.2])
    assert np.any(np.abs(unclipped) > u_max) and np.any(np.abs(unclipped) < u_max)
    np.testing.assert_allclose(u, np.clip(unclipped, -u_max, u_max), rtol=1e-14)
    at_torque, at_speed = actuator.limits(state, held, tau)
    assert bool(at_torque) and not bool(at_speed)


def test_speed_limit_stops_a_wheel_spinning_faster_but_not_slower():
    """u_i = 0 where |Omega_w,i| >= Omega_max,i and u_i Omega_w,i > 0 (docs/model.md §8.4)."""
    limit = 600.0
    actuator = wheels(speed=limit, compensation=False)
    tau = jnp.asarray([0.05, -0.08, 0.03])
    free = np.asarray(actuator.command(actuator.init((), jnp.float64), tau, jnp.zeros(3)).u)
    assert np.all(np.abs(free) > 1e-3)
    sign = np.sign(free)
    # wheel 0: at the limit, spinning up -> stopped; 1: at the limit, slowing -> kept;
    # 2: just below the limit, spinning up -> kept; 3: past the limit, spinning up -> stopped
    speed = jnp.asarray([limit * sign[0], -limit * sign[1], 0.999 * limit * sign[2], 1.2 * limit * sign[3]])
    held = actuator.command(speed, tau, jnp.zeros(3))
    np.testing.assert_array_equal(np.asarray(held.u), [0.0, free[1], free[2], 0.0])
    at_torque, at_speed = actuator.limits(speed, held, tau)
    assert bool(at_speed) and not bool(at_torque)
    assert float(actuator.speed_ratio(speed)) == pytest.approx(1.2)


def test_momentum_compensation_adds_Omega_hat_cross_wheel_momentum():
    """tau = tau_c + Omega_hat x G_s J_s (G_s^T Omega_hat + Omega_w), then distributed."""
    actuator = wheels(compensation=True)
    tau_c, Omega_hat = np.array([0.02, -0.01, 0.03]), np.array([0.05, -0.02, 0.04])
    speed = np.array([30.0, -10.0, 5.0, 20.0])
    G = pyramid_axes(4)
    h = G @ (SPIN * (G.T @ Omega_hat + speed))
    tau = tau_c + np.cross(Omega_hat, h)
    held = actuator.command(jnp.asarray(speed), jnp.asarray(tau_c), jnp.asarray(Omega_hat))
    np.testing.assert_allclose(np.asarray(held.u), -np.linalg.pinv(G) @ tau, rtol=1e-13)
    np.testing.assert_allclose(np.asarray(actuator.body_torque(jnp.asarray(speed), held, Omega_hat)), tau, rtol=1e-13)
    np.testing.assert_allclose(np.asarray(actuator.delivered(jnp.asarray(speed), held, Omega_hat)), tau_c, rtol=1e-12)
    for stored in (actuator.momentum(jnp.asarray(speed), jnp.asarray(Omega_hat)),
                   momentum(actuator, jnp.asarray(speed), jnp.asarray(Omega_hat))):  # J_locked omega + h_rel
        np.testing.assert_allclose(np.asarray(stored), h, rtol=1e-14)
    assert np.abs(np.cross(Omega_hat, h)).max() > 0.1 * np.abs(tau_c).max()  # the term matters here
    off = wheels(compensation=False).command(jnp.asarray(speed), jnp.asarray(tau_c), jnp.asarray(Omega_hat))
    np.testing.assert_allclose(np.asarray(off.u), -np.linalg.pinv(G) @ tau_c, rtol=1e-13)
    np.testing.assert_array_equal(np.asarray(off.compensation), np.zeros(3))


def test_saturated_clips_per_axis_and_ideal_is_the_identity():
    tau = jnp.asarray([[0.3, -0.01], [-0.7, 0.02], [0.05, 0.04]])  # (3, 2)
    sat = Saturated(jnp.asarray([0.2, 0.5, 0.05]))
    held = sat.command((), tau, jnp.zeros_like(tau))
    np.testing.assert_array_equal(np.asarray(held), [[0.2, -0.01], [-0.5, 0.02], [0.05, 0.04]])
    np.testing.assert_array_equal(np.asarray(sat.body_torque((), held, tau)), np.asarray(held))
    np.testing.assert_array_equal(np.asarray(sat.delivered((), held, tau)), np.asarray(held))
    at_torque, at_speed = sat.limits((), held, tau)
    np.testing.assert_array_equal(np.asarray(at_torque), [True, False])
    assert at_speed.shape == (2,) and not at_speed.any()
    ideal = Ideal()
    assert ideal.init((2,), jnp.float64) == () and sat.init((2,), jnp.float64) == ()
    assert ideal.command((), tau, tau) is tau and ideal.body_torque((), tau, tau) is tau
    assert not np.any(np.asarray(ideal.limits((), tau, tau)))
    assert ideal.stored_momentum(()) is None and sat.stored_momentum(()) is None
    np.testing.assert_array_equal(np.asarray(momentum(ideal, (), tau)), np.zeros((3, 2)))
    from so3jax.components import registry as components

    assert components.names("actuator") == ("ideal", "saturated", "wheels")
    assert isinstance(components.get("actuator", "wheels").build(
        components.get("actuator", "wheels").parse({}, "actuator.wheels"),
        components.BuildContext(np.asarray, {})), Wheels)


def test_rigid_body_derivatives_are_bit_for_bit_the_paper_plant():
    """The plant with Ideal and Saturated (no stored momentum): angular_acceleration(J, Omega,
    materialize(held + d, t), J_dot), the paper's mode's expression, to the bit eagerly (where
    it equals the plain held + d) and under jit, with a shared J (3, 3, 1) against a batch."""
    key = jax.random.split(jax.random.key(1), 4)
    Omega, held, d = (jax.random.normal(k, (3, 5), jnp.float64) for k in key[:3])
    J_dot = 0.1 * jax.random.normal(key[3], (3, 3, 1), jnp.float64)
    J = jnp.asarray(J_SC).reshape(3, 3, 1)
    t = jnp.asarray(0.7)
    for J_rate in (None, J_dot):
        eager = np.asarray(angular_acceleration(J, Omega, held + d, J_rate))
        paper = jax.jit(lambda h, J_rate=J_rate: angular_acceleration(J, Omega, materialize(h + d, t), J_rate))
        for actuator in (Ideal(), Saturated(jnp.full(3, 10.0))):
            Omega_dot, state_dot = plant.derivative(actuator, J, Omega, (), held, d, t, J_rate)
            jitted, _ = jax.jit(lambda a, h, J_rate=J_rate: plant.derivative(a, J, Omega, (), h, d, t, J_rate))(
                actuator, held)
            assert state_dot == ()
            np.testing.assert_array_equal(np.asarray(Omega_dot), eager)
            np.testing.assert_array_equal(np.asarray(jitted), np.asarray(paper(held)))


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"G": np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0 + 1e-6]])}, "unit"),
        ({"G": np.array([[1.0, 0.0, np.sqrt(0.5)], [0.0, 1.0, np.sqrt(0.5)], [0.0, 0.0, 0.0]])}, "every axis"),
        ({"G": pyramid_axes(2)}, "every axis"),
        ({"speed": -1.0}, "max_speed"),
        ({"speed": 0.0}, "max_speed"),
        ({"spin": 0.0}, "spin_inertia"),
        ({"u_max": -0.1}, "max_torque"),
        ({"u_max": 0.0}, "max_torque"),
        ({"initial": np.nan}, "initial_speed"),
        ({"u_max": np.inf}, "max_torque"),
    ],
)
def test_check_rejects_bad_wheels(change, message):
    with pytest.raises(ValueError, match=message):
        wheels(**change).check()


def test_check_rejects_bad_shapes_and_accepts_good_parameters():
    good = wheels()
    good.check()
    with pytest.raises(ValueError, match="spin_inertia"):
        Wheels(good.axes, good.spin_inertia[:3], good.max_torque, good.max_speed, good.initial_speed).check()
    with pytest.raises(ValueError, match=r"\(3, N\)"):
        Wheels(good.axes.T, good.spin_inertia, good.max_torque, good.max_speed, good.initial_speed).check()
    jax.jit(lambda w: w.check() or w.axes)(good)  # traced: the shapes checked, the values when concrete
    with pytest.raises(ValueError, match="initial_speed"):
        jax.jit(lambda w: Wheels(w.axes, w.spin_inertia, w.max_torque, w.max_speed, w.axes[:, 0]).check())(good)
    Saturated(jnp.full(3, 0.1)).check()
    Saturated(jnp.asarray(0.1)).check()
    Ideal().check()
    for bad in (jnp.asarray([0.1, -0.1, 0.1]), jnp.full(2, 0.1), jnp.asarray([0.1, np.nan, 0.1])):
        with pytest.raises(ValueError, match="max_torque"):
            Saturated(bad).check()


def test_pyramid_axes_geometry():
    G = pyramid_axes(4)
    assert G.shape == (3, 4)
    np.testing.assert_allclose(np.linalg.norm(G, axis=0), 1.0, rtol=1e-15)
    np.testing.assert_allclose(np.degrees(np.arccos(G[2])), 54.74, rtol=1e-12)
    np.testing.assert_allclose(np.degrees(np.arctan2(G[1], G[0])), [0.0, 90.0, 180.0, -90.0], atol=1e-12)
    np.testing.assert_allclose(G @ G.T, 4.0 / 3.0 * np.eye(3), atol=5e-4)  # 54.74 deg: the "magic" angle
    six = pyramid_axes(6, 30.0, 15.0)
    np.testing.assert_allclose(np.degrees(np.arctan2(six[1, 0], six[0, 0])), 15.0)
    np.testing.assert_allclose(np.diff(np.unwrap(np.arctan2(six[1], six[0]))), np.pi / 3)


def _final_wheel_speed(spin, tau_c, dtype=jnp.float64, n_steps=100, dt=0.05):
    """Wheel 0's speed after n_steps with the command distributed once at t = 0 and held."""
    actuator = Wheels(jnp.asarray(pyramid_axes(4), dtype), spin, jnp.full(4, 0.25, dtype), jnp.full(4, 628.0, dtype),
                      jnp.asarray(WHEEL0, dtype))
    Omega0 = jnp.asarray(OMEGA0, dtype)
    speed0 = actuator.init((), dtype)
    u = actuator.command(speed0, tau_c, Omega0)
    (_, _, speed), _, _ = integrate_held(actuator, jnp.asarray(J_SC, dtype), u, jnp.eye(3, dtype=dtype), Omega0, speed0,
                                         n_steps, jnp.asarray(dt, dtype))
    return speed[0]


def test_gradient_of_wheel_speed_with_respect_to_spin_inertia():
    """jit(grad) of a final wheel speed (command with momentum compensation, then the
    plant) is finite and matches a central difference."""
    spin, tau_c = jnp.asarray(SPIN), jnp.asarray([0.01, -0.02, 0.015])
    grad = np.asarray(jax.jit(jax.grad(_final_wheel_speed))(spin, tau_c))
    assert np.all(np.isfinite(grad)) and np.abs(grad).max() > 1.0
    h = 1e-6
    central = [(_final_wheel_speed(spin.at[i].add(h), tau_c) - _final_wheel_speed(spin.at[i].add(-h), tau_c)) / (2 * h)
               for i in range(4)]
    np.testing.assert_allclose(grad, np.asarray(central), rtol=1e-6, atol=1e-6 * np.abs(grad).max())


def test_vmap_matches_batch_axes_and_float32_stays_float32():
    """The derivative and command vmapped over a leading axis equal the same call with the
    batch as trailing axes; float32 in, float32 out."""
    actuator = wheels()
    key = jax.random.split(jax.random.key(2), 4)
    Omega = 0.3 * jax.random.normal(key[0], (3, 6), jnp.float64)
    speed = 50.0 * jax.random.normal(key[1], (4, 6), jnp.float64)
    tau = 0.3 * jax.random.normal(key[2], (3, 6), jnp.float64)
    d = 0.01 * jax.random.normal(key[3], (3, 6), jnp.float64)
    J, t = jnp.asarray(J_SC), jnp.asarray(0.0)

    def one(Omega, speed, tau, d):
        held = actuator.command(speed, tau, Omega)
        derivative = plant.derivative(actuator, so3.batch_like(J.astype(Omega.dtype), 2, Omega), Omega, speed, held, d,
                                      t)
        return (held.u, actuator.body_torque(speed, held, Omega), actuator.momentum(speed, Omega),
                actuator.speed_ratio(speed), *actuator.limits(speed, held, tau), *derivative)

    batched = jax.jit(one)(Omega, speed, tau, d)
    J_batch = jnp.broadcast_to(J[..., None], (3, 3, 6))
    held = WheelCommand(batched[0], actuator.command(speed, tau, Omega).compensation)
    assert np.allclose(plant.derivative(actuator, J_batch, Omega, speed, held, d, t)[0], batched[6], rtol=1e-14, atol=0)
    mapped = jax.vmap(one, in_axes=-1, out_axes=-1)(Omega, speed, tau, d)
    for a, b in zip(batched, mapped):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-13, atol=1e-15)
    assert np.any(np.asarray(batched[4]))  # some commands hit the torque limit
    single = jax.jit(one)(*(x.astype(jnp.float32) for x in (Omega, speed, tau, d)))
    assert all(x.dtype == jnp.float32 for x in single[:4] + single[6:])
    for a, b in zip(single[6:], batched[6:]):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-4 * np.abs(np.asarray(b)).max())
    assert actuator.init((2,), jnp.float32).dtype == jnp.float32


def test_a_per_wheel_motor_torque_command_clips_each_wheel_on_its_own():
    """[actuator.wheels] motor_torque: wheel 1 commanded above its limit gets exactly u_max,
    the others nothing; every wheel then obeys Omega_w,i(t) = u_i t / J_s - g_i^T (Omega(t) - Omega(0))."""
    import warnings

    from so3jax.dynamics.inertia import InertiaWarning
    from so3jax.jobs import fly
    from so3jax.missions import mission as missions

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InertiaWarning)
        m = missions.load(None, ["T=1.0", "controllers=open_loop", "record_every=10", "initial.rate=[0.01, 0.0, -0.02]",
                                 "actuator.wheels.motor_torque=[0.3, 0.0, 0.0, -0.1]"])
        h = fly.fly(m)[0]["open_loop"].history
    t, Omega, speed = np.asarray(h.t), np.asarray(h.Omega), np.asarray(h.actuator)
    G = np.asarray(pyramid_axes())
    u = np.array([0.25, 0.0, 0.0, -0.1])  # 0.3 clipped at u_max = 0.25
    expected = u * t[:, None] / 0.16 - (Omega - Omega[0]) @ G
    np.testing.assert_allclose(speed, expected, rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.asarray(h.tau)[1:], np.broadcast_to(-G @ u, (len(t) - 1, 3)), rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="motor_torque"):
        missions.load(None, ["actuator.wheels.motor_torque=[0.1, 0.1]"])


def test_misaligned_wheels_act_along_the_plant_s_axes_while_the_command_uses_the_nominal():
    """actuator.wheels.misalignment and spin_inertia_error: the motor torques (distribution,
    momentum compensation, limits) are the nominal wheels'; the body torque, the wheels'
    rates and the stored momentum follow the axes rotated by scipy's Rotation and
    J_s (1 + error)."""
    from scipy.spatial.transform import Rotation

    from so3jax.missions import mission

    theta = np.array([[0.01, -0.02, 0.005], [0.0, 0.03, 0.0], [-0.01, 0.0, 0.02], [0.004, 0.004, -0.004]])  # rad
    error = np.array([0.05, -0.1, 0.0, 0.2])
    flight = mission.load(None, ["T=1.0"])
    nominal = mission.build_loop(flight, jnp.asarray).actuator
    tilted = mission.build_loop(mission.load(None, ["T=1.0", f"actuator.wheels.misalignment={theta.tolist()}",
                                                     f"actuator.wheels.spin_inertia_error={error.tolist()}"]),
                                 jnp.asarray).actuator
    speed, tau_c, omega = jnp.asarray(WHEEL0), jnp.asarray([0.05, -0.02, 0.03]), jnp.asarray(OMEGA0)
    held = tilted.command(speed, tau_c, omega)
    nominal_held = nominal.command(speed, tau_c, omega)
    np.testing.assert_array_equal(held.u, nominal_held.u)
    np.testing.assert_array_equal(held.compensation, nominal_held.compensation)

    G = Rotation.from_rotvec(theta).apply(pyramid_axes(4).T).T  # (3, N): the body's spin axes
    spin = 0.16 * (1 + error)
    np.testing.assert_allclose(tilted.body_torque(speed, held, omega), -G @ np.asarray(held.u), rtol=1e-12, atol=1e-15)
    difference = tilted.body_torque(speed, held, omega) - nominal.body_torque(speed, held, omega)
    assert np.linalg.norm(np.asarray(difference)) > 1e-4
    Omega_dot = np.array([1e-3, -2e-3, 5e-4])
    np.testing.assert_allclose(tilted.derivative(speed, held, omega, jnp.asarray(Omega_dot)),
                               np.asarray(held.u) / spin - G.T @ Omega_dot, rtol=1e-12)
    stored = tilted.stored_momentum(speed)
    np.testing.assert_allclose(stored.locked_inertia, G @ np.diag(spin) @ G.T, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(stored.relative, G @ (spin * WHEEL0), rtol=1e-12)
