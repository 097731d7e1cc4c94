"""Hinged panels and slosh particles on a free hub (so3jax.dynamics.flexible, docs/flexible.md):
the back-substitution solves the mass matrix (F.10), energy (F.16) and angular momentum
(F.15) are conserved without damping and torque, damping dissipates energy but not
momentum, a locked (or very stiff) panel turns with the hub as one rigid body, the
linearization's modal frequencies are the closed forms (F.21)-(F.23), a free flight
matches Basilisk's hingedRigidBodyStateEffector and linearSpringMassDamper on their
spacecraft hub at round-off, and gradients through a flight with respect to k and c are
finite and match central differences."""

import functools

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.dynamics import flexible as fx
from so3jax.dynamics.plant import angular_acceleration

# Basilisk's own test geometry: a hinge 0.5 m out along x, the panel outward (h1 = -x), hinging about -z
DCM_HB = [[-1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, -1.0, 0.0]]
HUB_INERTIA = [[900.0, 10.0, -5.0], [10.0, 800.0, 8.0], [-5.0, 8.0, 600.0]]
PANEL_INERTIA = [[100.0, 0.0, 0.0], [0.0, 50.0, 0.0], [0.0, 0.0, 50.0]]
P_HAT = [3.0**-0.5] * 3


def _a(x):
    return jnp.asarray(x, jnp.float64)


def _hub(mass=750.0, inertia=HUB_INERTIA, r_BcB=(0.0, 0.0, 1.0)):
    return fx.Hub(_a(mass), _a(inertia), _a(r_BcB))


def _panel(k=100.0, c=0.0, r_HB=(0.5, 0.0, 1.0), dcm_HB=DCM_HB, inertia=PANEL_INERTIA, mass=100.0, d=1.5,
           locked=False):
    return fx.HingedPanel(_a(mass), _a(inertia), _a(d), _a(k), _a(c), _a(r_HB), _a(dcm_HB), locked=locked)


def _slosh(k=100.0, c=0.0, r_PB=(0.1, 0.0, -0.1), p_hat=P_HAT, mass=100.0):
    return fx.SloshParticle(_a(mass), _a(r_PB), _a(p_hat), _a(k), _a(c))


def _two_panels_and_a_particle(c_panel=0.0, c_slosh=0.0):
    """A hub with its centre of mass off B, two panels (the second with products of inertia
    and a hinge axis off the body axes) and one particle."""
    tilted = np.array([[0.0, 1.0, 0.0], [0.6, 0.0, 0.8], [0.8, 0.0, -0.6]])
    panels = (_panel(k=80.0, c=c_panel),
              _panel(k=150.0, c=c_panel, r_HB=(-0.3, 0.7, 0.2), dcm_HB=tilted, mass=60.0, d=1.1,
                     inertia=[[40.0, 3.0, -2.0], [3.0, 25.0, 1.5], [-2.0, 1.5, 30.0]]))
    return fx.FlexibleBody(_hub(), panels, (_slosh(k=120.0, c=c_slosh),))


def _start(body, omega=(0.1, -0.1, 0.1)):
    n, m = len(body.panels), len(body.slosh)
    return fx.initial_state(body, _a(omega), theta=_a([0.1, -0.2][:n]), theta_dot=_a([0.01, 0.03][:n]),
                            rho=_a([0.05][:m]), rho_dot=_a([-0.02][:m]))


@functools.partial(jax.jit, static_argnames="steps")
def _flight(body, x0, dt, steps, torque=None):
    """RK4 states after each step (the torque [N m] held), with the energy (F.16) and angular
    momentum (F.15) there."""

    def step(x, _):
        x = fx.rk4_step(body, x, dt, torque)
        return x, (x, fx.energy(body, x), fx.angular_momentum(body, x))

    return jax.lax.scan(step, x0, None, length=steps)[1]


# --- the equations of motion ---------------------------------------------------------------


def test_the_back_substitution_solves_the_mass_matrix_in_any_batch():
    body = _two_panels_and_a_particle(c_panel=3.0, c_slosh=2.0)
    x = _start(body)
    torque = _a([0.3, -0.1, 0.2])
    M = fx.mass_matrix(body, x)
    assert np.allclose(M, M.T, rtol=0, atol=1e-12) and np.all(np.linalg.eigvalsh(M) > 0)
    accelerations = fx.accelerations  # once each: eager is sooner than a compilation
    acc = accelerations(body, x, torque)
    # the torque enters the rotation's rows only, linearly: the change it makes is M^{-1} (0, L, 0)
    free = accelerations(body, x)
    order = ("hub_acceleration", "omega_dot", "theta_ddot", "rho_ddot")
    change = np.concatenate([getattr(acc, name) - getattr(free, name) for name in order])
    assert np.allclose(change, np.linalg.solve(M, np.concatenate([np.zeros(3), torque, np.zeros(3)])), rtol=1e-10,
                       atol=1e-16)
    x_other = _start(body, omega=(-0.2, 0.05, 0.3))
    batched = jax.tree.map(lambda p, q: jnp.stack([p, q], axis=-1), x, x_other)
    both = accelerations(body, batched, jnp.stack([torque, torque], axis=-1))
    other = accelerations(body, x_other, torque)
    for name in acc._fields:
        assert np.allclose(getattr(both, name)[..., 0], getattr(acc, name), rtol=1e-13, atol=1e-16)
        assert np.allclose(getattr(both, name)[..., 1], getattr(other, name), rtol=1e-13, atol=1e-16)
    single = fx.derivative(body, jax.tree.map(lambda v: v.astype(jnp.float32), x), torque.astype(jnp.float32))
    assert all(leaf.dtype == jnp.float32 for leaf in single)


DT, STEPS = 0.005, 2000  # 10 s: the modes' periods are 3-8 s


def test_without_damping_or_torque_energy_and_momentum_are_conserved():
    body = _two_panels_and_a_particle()
    x0 = _start(body)
    xs, E, H = _flight(body, x0, DT, STEPS)
    E0, H0 = float(fx.energy(body, x0)), float(np.linalg.norm(fx.angular_momentum(body, x0)))
    drift_E = np.abs(np.asarray(E) - E0).max() / E0
    drift_H = np.abs(np.linalg.norm(H, axis=1) - H0).max() / H0
    assert drift_E < 1e-10 and drift_H < 1e-10, (drift_E, drift_H)
    # the appendages moved: the exchange is there to conserve
    assert np.ptp(np.asarray(xs.theta), axis=0).min() > 0.05 and np.ptp(np.asarray(xs.rho)) > 0.02


def test_damping_dissipates_energy_and_keeps_the_momentum():
    body = _two_panels_and_a_particle(c_panel=20.0, c_slosh=30.0)
    x0 = _start(body)
    _, E, H = _flight(body, x0, DT, STEPS)
    E, E0 = np.asarray(E), float(fx.energy(body, x0))
    H0 = float(np.linalg.norm(fx.angular_momentum(body, x0)))
    assert np.abs(np.linalg.norm(H, axis=1) - H0).max() / H0 < 1e-10
    steps = np.diff(np.concatenate([[E0], E]))
    assert steps.max() < 0.0, steps.max()  # decreasing at every step
    assert E[-1] < 0.9 * E0


def _rigid_flight(J, omega, torque, dt, steps):
    """omega (steps, 3) [rad/s] of the rigid body J (3, 3) under a constant torque, RK4."""
    f = lambda w: np.asarray(angular_acceleration(J, w, torque))
    out = []
    for _ in range(steps):
        k1 = f(omega)
        k2 = f(omega + 0.5 * dt * k1)
        k3 = f(omega + 0.5 * dt * k2)
        k4 = f(omega + dt * k3)
        omega = omega + dt / 6.0 * (k1 + 2.0 * (k2 + k3) + k4)
        out.append(omega)
    return np.array(out)


def _combined_inertia(body, theta):
    """The inertia of hub and panels frozen at the angles theta about their common centre of
    mass [kg m^2], written out from (F.1): s = M2(theta) h, the panel's centre of mass at r_HB - d s1."""
    parts = [(float(body.hub.mass), np.asarray(body.hub.r_BcB), np.asarray(body.hub.inertia))]
    for panel, angle in zip(body.panels, theta):
        h = np.asarray(panel.dcm_HB)
        s = np.array([np.cos(angle) * h[0] - np.sin(angle) * h[2], h[1], np.sin(angle) * h[0] + np.cos(angle) * h[2]])
        r = np.asarray(panel.r_HB) - float(panel.d) * s[0]
        parts.append((float(panel.mass), r, s.T @ np.asarray(panel.inertia) @ s))
    mass = sum(m for m, _, _ in parts)
    c = sum(m * r for m, r, _ in parts) / mass
    return sum(J + m * ((r - c) @ (r - c) * np.eye(3) - np.outer(r - c, r - c)) for m, r, J in parts)


def test_a_locked_panel_turns_with_the_hub_as_one_rigid_body():
    body = fx.FlexibleBody(_hub(), (_panel(k=80.0, locked=True),))
    torque = _a([0.5, -0.2, 0.3])
    x0 = fx.initial_state(body, _a([0.1, -0.1, 0.1]), theta=_a([0.3]))
    xs, _, _ = _flight(body, x0, DT, STEPS, torque)
    assert np.all(np.asarray(xs.theta) == 0.3)
    rigid = _rigid_flight(_combined_inertia(body, [0.3]), np.asarray(x0.omega), np.asarray(torque), DT, STEPS)
    gap = np.abs(np.asarray(xs.omega) - rigid).max()
    assert gap < 1e-13 * np.abs(rigid).max(), gap
    assert np.abs(rigid - np.asarray(x0.omega)).max() > 0.01  # it turned


def test_a_very_stiff_panel_turns_with_the_hub_nearly_as_one_rigid_body():
    torque, omega0 = _a([0.5, -0.2, 0.3]), _a([0.1, -0.1, 0.1])
    rigid = _rigid_flight(_combined_inertia(fx.FlexibleBody(_hub(), (_panel(),)), [0.0]), np.asarray(omega0),
                          np.asarray(torque), DT, STEPS)
    gaps = []
    for k in (1e6, 1e7):  # the hinge damped near critically (M_eff ~ 200 kg m^2): its start-up transient dies in 0.1 s
        body = fx.FlexibleBody(_hub(), (_panel(k=k, c=2.0 * np.sqrt(k * 200.0)),))
        xs, _, _ = _flight(body, fx.initial_state(body, omega0), DT, STEPS, torque)
        assert 0 < np.abs(np.asarray(xs.theta)).max() < 10.0 / k
        gaps.append(np.abs(np.asarray(xs.omega) - rigid)[round(1.0 / DT):].max() / np.abs(rigid).max())
    assert gaps[0] < 1e-5 and 5.0 < gaps[0] / gaps[1] < 20.0, gaps  # the gap falls as 1/k


# --- the linearization about rest ------------------------------------------------------------


def test_the_modes_of_one_panel_and_of_one_particle_are_the_closed_forms():
    I_B, m_B, R = 600.0, 750.0, 0.8
    hub = _hub(mass=m_B, inertia=np.diag([900.0, 800.0, I_B]), r_BcB=(0.0, 0.0, 0.0))
    m, d, I_p, k, c = 100.0, 1.5, 35.0, 120.0, 4.0
    panel = _panel(k=k, c=c, r_HB=(R, 0.0, 0.0), dcm_HB=[[-1.0, 0, 0], [0, 0, 1.0], [0, 1.0, 0]], mass=m, d=d,
                   inertia=np.diag([60.0, I_p, 45.0]))
    mu = m_B * m / (m_B + m)
    rigid = I_B + I_p + mu * (R + d) ** 2
    M_eff = (I_B * (I_p + mu * d**2) + mu * I_p * R**2) / rigid  # (F.21)
    found = fx.modes(fx.FlexibleBody(hub, (panel,)))
    assert np.allclose(found.frequency, [np.sqrt(k / M_eff)], rtol=1e-12)
    assert np.allclose(found.damping_ratio, [c / (2.0 * np.sqrt(k * M_eff))], rtol=1e-12)
    # a particle of mass m_p at a from the hub's centre of mass, moving radially (F.22) or tangentially (F.23)
    m_p, a, k_p, c_p = 80.0, 1.2, 300.0, 5.0
    mu = m_B * m_p / (m_B + m_p)
    for p_hat, M_eff in (([1.0, 0.0, 0.0], mu), ([0.0, 1.0, 0.0], I_B * mu / (I_B + mu * a**2))):
        particle = _slosh(k=k_p, c=c_p, r_PB=(a, 0.0, 0.0), p_hat=p_hat, mass=m_p)
        found = fx.modes(fx.FlexibleBody(hub, (), (particle,)))
        assert np.allclose(found.frequency, [np.sqrt(k_p / M_eff)], rtol=1e-12)
        assert np.allclose(found.damping_ratio, [c_p / (2.0 * np.sqrt(k_p * M_eff))], rtol=1e-12)
    # on a hub that cannot move (infinite mass and inertia) the panel is a pendulum about its hinge
    pinned = fx.modes(fx.FlexibleBody(_hub(mass=1e12, inertia=1e12 * np.eye(3), r_BcB=(0.0, 0.0, 0.0)), (panel,)))
    assert np.allclose(pinned.frequency, [np.sqrt(k / (I_p + m * d**2))], rtol=1e-8)
