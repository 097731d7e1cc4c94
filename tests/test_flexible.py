"""Hinged panels and slosh particles on a free hub (so3jax.dynamics.flexible, docs/flexible.md):
the back-substitution solves the mass matrix (F.10), energy (F.16) and angular momentum
(F.15) are conserved without damping and torque, damping dissipates energy but not
momentum, a locked (or very stiff) panel turns with the hub as one rigid body, the
linearization's modal frequencies are the closed forms (F.21)-(F.23), a free flight
matches Basilisk's hingedRigidBodyStateEffector and linearSpringMassDamper on their
spacecraft hub at round-off, and gradients through a flight with respect to k and c are
finite and match central differences."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from so3jax.dynamics import flexible as fx
from tests._shared_programs import FAST_COMPILE

# Basilisk's own test geometry: a hinge 0.5 m out along x, the panel outward (h1 = -x), hinging about -z
DCM_HB = [[-1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, -1.0, 0.0]]
# a hinge axis off the body axes (h2 = (0.6, 0, 0.8))
TILTED_HB = [[0.0, 1.0, 0.0], [0.6, 0.0, 0.8], [0.8, 0.0, -0.6]]
HUB_INERTIA = [[900.0, 10.0, -5.0], [10.0, 800.0, 8.0], [-5.0, 8.0, 600.0]]
PANEL_INERTIA = [[100.0, 0.0, 0.0], [0.0, 50.0, 0.0], [0.0, 0.0, 50.0]]
SKEWED_INERTIA = [[40.0, 3.0, -2.0], [3.0, 25.0, 1.5], [-2.0, 1.5, 30.0]]  # products of inertia in S
P_HAT = [3.0**-0.5] * 3
DT, STEPS = 0.01, 1000  # every flight: 10 s, the modes' periods 3-8 s
NO_TORQUE = np.zeros(3)


def _a(x):
    return jnp.asarray(x, jnp.float64)


def _hub(mass=750.0, inertia=HUB_INERTIA, r_BcB=(0.0, 0.0, 1.0)):
    return fx.Hub(_a(mass), _a(inertia), _a(r_BcB))


def _panel(k=100.0, c=0.0, r_HB=(0.5, 0.0, 1.0), dcm_HB=DCM_HB, inertia=PANEL_INERTIA, mass=100.0, d=1.5,
           locked=False):
    return fx.HingedPanel(_a(mass), _a(inertia), _a(d), _a(k), _a(c), _a(r_HB), _a(dcm_HB), locked=locked)


def _slosh(k=100.0, c=0.0, r_PB=(0.1, 0.0, -0.1), p_hat=P_HAT, mass=100.0):
    return fx.SloshParticle(_a(mass), _a(r_PB), _a(p_hat), _a(k), _a(c))


def _skewed_body(c_panel=0.0, c_slosh=0.0):
    """A hub with its centre of mass off B and products of inertia, a panel with products of
    inertia on a hinge off the body axes, and a particle: each term of (F.4)-(F.9) at work."""
    panel = _panel(k=150.0, c=c_panel, r_HB=(-0.3, 0.7, 0.2), dcm_HB=TILTED_HB, mass=60.0, d=1.1,
                   inertia=SKEWED_INERTIA)
    return fx.FlexibleBody(_hub(), (panel,), (_slosh(k=120.0, c=c_slosh),))


def _start(body, omega=(0.1, -0.1, 0.1)):
    n, m = len(body.panels), len(body.slosh)
    return fx.initial_state(body, _a(omega), theta=_a([0.1, -0.2][:n]), theta_dot=_a([0.01, 0.03][:n]),
                            rho=_a([0.05][:m]), rho_dot=_a([-0.02][:m]))


_PROGRAMS = {}


def _compiled(fn, *args):
    """fn jitted and compiled with FAST_COMPILE once per argument structure and shapes: the
    flights of one panel and one particle share one program, whatever their values."""
    key = (fn, jax.tree.structure(args), tuple((np.shape(x), jnp.result_type(x)) for x in jax.tree.leaves(args)))
    if key not in _PROGRAMS:
        _PROGRAMS[key] = jax.jit(fn).lower(*args).compile(FAST_COMPILE)
    return _PROGRAMS[key]


def _flight_program(body, x0, torque):
    """RK4 states after each of STEPS steps of DT (the torque [N m] held), with the energy
    (F.16) and angular momentum (F.15) there."""

    def step(x, _):
        x = fx.rk4_step(body, x, DT, torque)
        return x, (x, fx.energy(body, x), fx.angular_momentum(body, x))

    return jax.lax.scan(step, x0, None, length=STEPS)[1]


def _flight(body, x0, torque=NO_TORQUE):
    args = (body, x0, _a(torque))
    return _compiled(_flight_program, *args)(*args)


# --- the equations of motion ---------------------------------------------------------------


def test_the_back_substitution_solves_the_mass_matrix_in_any_batch():
    """(F.10)-(F.13); a batch's samples apart (a diverged one leaves the others), float32 kept."""
    base = _skewed_body(c_panel=3.0, c_slosh=2.0)
    body = fx.FlexibleBody(base.hub, (_panel(k=80.0, c=3.0),) + base.panels, base.slosh)  # two panels
    x = _start(body)
    torque = _a([0.3, -0.1, 0.2])
    M = fx.mass_matrix(body, x)
    assert np.allclose(M, M.T, rtol=0, atol=1e-12) and np.all(np.linalg.eigvalsh(M) > 0)
    accelerations = lambda body, x, torque: _compiled(fx.accelerations, body, x, torque)(body, x, torque)
    acc = accelerations(body, x, torque)
    # the torque enters the rotation's rows only, linearly: the change it makes is M^{-1} (0, L, 0)
    free = accelerations(body, x, jnp.zeros(3))
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
    diverged = accelerations(body, batched._replace(omega=batched.omega.at[0, 0].set(jnp.nan)),
                             jnp.stack([torque, torque], axis=-1))
    assert np.all(np.isnan(diverged.omega_dot[:, 0])) and np.array_equal(diverged.omega_dot[:, 1], both.omega_dot[:, 1])
    single = accelerations(body, jax.tree.map(lambda v: v.astype(jnp.float32), x), torque.astype(jnp.float32))
    assert all(leaf.dtype == jnp.float32 for leaf in single)
    assert np.allclose(single.omega_dot, acc.omega_dot, rtol=1e-4, atol=1e-7)


DT, STEPS = 0.005, 2000  # 10 s: the modes' periods are 3-8 s


@pytest.mark.parametrize("change, message", [
    (lambda b: b.hub.__class__(_a(0.0), b.hub.inertia, b.hub.r_BcB), "hub mass"),
    (lambda b: fx.FlexibleBody(b.hub, (_panel(inertia=np.diag([1.0, -1.0, 1.0])),), b.slosh), "symmetric positive"),
    (lambda b: fx.FlexibleBody(b.hub, (_panel(dcm_HB=np.diag([1.0, 1.0, -1.0])),), b.slosh), "rotation"),
    (lambda b: fx.FlexibleBody(b.hub, (_panel(k=-1.0),), b.slosh), r"k \[N m/rad\] must be non-negative"),
    (lambda b: fx.FlexibleBody(b.hub, b.panels, (_slosh(p_hat=(1.0, 1.0, 0.0)),)), "unit vector"),
    (lambda b: fx.FlexibleBody(b.hub, b.panels, (_slosh(c=np.nan),)), "finite"),
    (lambda b: fx.FlexibleBody(b.hub, b.panels, (fx.SloshParticle(_a(1.0), _a([0.0, 0.0]), _a(P_HAT), _a(1.0),
                                                                  _a(0.0)),)), "shape"),
])
def test_check_refuses_bad_parameters_in_one_line(change, message):
    body = _skewed_body()
    fx.check(body)
    bad = change(body)
    bad = bad if isinstance(bad, fx.FlexibleBody) else fx.FlexibleBody(bad, body.panels, body.slosh)
    with pytest.raises(ValueError, match=message) as error:
        fx.check(bad)
    assert "\n" not in str(error.value)


def test_without_damping_or_torque_energy_and_momentum_are_conserved():
    body = _skewed_body()
    x0 = _start(body)
    xs, E, H = _flight(body, x0)
    E0, H0 = float(fx.energy(body, x0)), float(np.linalg.norm(fx.angular_momentum(body, x0)))
    drift_E = np.abs(np.asarray(E) - E0).max() / E0
    drift_H = np.abs(np.linalg.norm(H, axis=1) - H0).max() / H0
    assert drift_E < 1e-10 and drift_H < 1e-10, (drift_E, drift_H)
    # the appendages moved: the exchange is there to conserve
    assert np.ptp(np.asarray(xs.theta), axis=0).min() > 0.05 and np.ptp(np.asarray(xs.rho)) > 0.02


def test_damping_dissipates_energy_and_keeps_the_momentum():
    body = _skewed_body(c_panel=20.0, c_slosh=30.0)
    x0 = _start(body)
    _, E, H = _flight(body, x0)
    E, E0 = np.asarray(E), float(fx.energy(body, x0))
    H0 = float(np.linalg.norm(fx.angular_momentum(body, x0)))
    assert np.abs(np.linalg.norm(H, axis=1) - H0).max() / H0 < 1e-10
    steps = np.diff(np.concatenate([[E0], E]))
    assert steps.max() < 0.0, steps.max()  # decreasing at every step
    springs = 0.5 * (150.0 * float(x0.theta[0]) ** 2 + 120.0 * float(x0.rho[0]) ** 2)
    assert E0 - E[-1] > 0.5 * springs  # the appendages' energy dissipated; the hub's turn (H fixed) keeps its own


def _rigid_flight(J, omega, torque, dt, steps):
    """omega (steps, 3) [rad/s] of the rigid body J (3, 3) under a constant torque,
    J omega' = L - omega x J omega, RK4."""
    f = lambda w: np.linalg.solve(J, torque - np.cross(w, J @ w))
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
    """The inertia of hub, panels frozen at the angles theta and particles at rest (rho = 0)
    about their common centre of mass [kg m^2], written out from (F.1): s = M2(theta) h, the
    panel's centre of mass at r_HB - d s1."""
    parts = [(float(body.hub.mass), np.asarray(body.hub.r_BcB), np.asarray(body.hub.inertia))]
    for panel, angle in zip(body.panels, theta):
        h = np.asarray(panel.dcm_HB)
        s = np.array([np.cos(angle) * h[0] - np.sin(angle) * h[2], h[1], np.sin(angle) * h[0] + np.cos(angle) * h[2]])
        r = np.asarray(panel.r_HB) - float(panel.d) * s[0]
        parts.append((float(panel.mass), r, s.T @ np.asarray(panel.inertia) @ s))
    parts += [(float(p.mass), np.asarray(p.r_PB), np.zeros((3, 3))) for p in body.slosh]
    mass = sum(m for m, _, _ in parts)
    c = sum(m * r for m, r, _ in parts) / mass
    return sum(J + m * ((r - c) @ (r - c) * np.eye(3) - np.outer(r - c, r - c)) for m, r, J in parts)


def test_a_locked_panel_turns_with_the_hub_as_one_rigid_body():
    body = fx.FlexibleBody(_hub(), (_panel(k=80.0, locked=True),))
    torque = _a([0.5, -0.2, 0.3])
    x0 = fx.initial_state(body, _a([0.1, -0.1, 0.1]), theta=_a([0.3]), theta_dot=_a([0.2]))  # a rate it ignores
    xs, _, _ = _flight(body, x0, torque)
    assert np.all(np.asarray(xs.theta) == 0.3)
    assert fx.modes(body).frequency.shape == (0,)  # nothing flexible
    rigid = _rigid_flight(_combined_inertia(body, [0.3]), np.asarray(x0.omega), np.asarray(torque), DT, STEPS)
    gap = np.abs(np.asarray(xs.omega) - rigid).max()
    assert gap < 1e-13 * np.abs(rigid).max(), gap
    assert np.abs(rigid - np.asarray(x0.omega)).max() > 0.01  # it turned


def test_a_very_stiff_panel_and_particle_turn_with_the_hub_nearly_as_one_rigid_body():
    torque, omega0 = _a([0.5, -0.2, 0.3]), _a([0.1, -0.1, 0.1])
    rigid_body = fx.FlexibleBody(_hub(), (_panel(),), (_slosh(),))
    rigid = _rigid_flight(_combined_inertia(rigid_body, [0.0]), np.asarray(omega0), np.asarray(torque), DT, STEPS)
    gaps = []
    for k in (1e5, 1e6):  # damped near critically (M_eff ~ 200 kg m^2, 90 kg): the start-up transient dies in 0.3 s
        body = fx.FlexibleBody(_hub(), (_panel(k=k, c=2.0 * np.sqrt(k * 200.0)),),
                               (_slosh(k=k, c=2.0 * np.sqrt(k * 90.0)),))
        xs, _, _ = _flight(body, fx.initial_state(body, omega0), torque)
        assert 0 < np.abs(np.asarray(xs.theta)).max() < 10.0 / k and 0 < np.abs(np.asarray(xs.rho)).max() < 10.0 / k
        gaps.append(np.abs(np.asarray(xs.omega) - rigid)[round(1.0 / DT):].max() / np.abs(rigid).max())
    assert gaps[1] < 1e-5 and 5.0 < gaps[0] / gaps[1] < 20.0, gaps  # the gap falls as 1/k


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


# --- Basilisk ------------------------------------------------------------------------------

def _basilisk_body():
    """One panel and one particle, both damped, on a hub with products of inertia and its
    centre of mass off B."""
    return fx.FlexibleBody(_hub(), (_panel(k=100.0, c=5.0),), (_slosh(k=100.0, c=8.0),))


def _basilisk_flight(body, x0, dt, steps):
    """Basilisk's spacecraft hub with one hingedRigidBodyStateEffector and one
    linearSpringMassDamper, RK4 at dt, no gravity, no force or torque: omega (steps + 1, 3),
    theta (steps + 1,), rho (steps + 1,), the rotational energy [J] and |H_C| [N m s]."""
    from Basilisk.simulation import hingedRigidBodyStateEffector, linearSpringMassDamper, spacecraft
    from Basilisk.utilities import SimulationBaseClass, macros

    column = lambda v: [[float(x)] for x in np.asarray(v)]
    sim = SimulationBaseClass.SimBaseClass()
    sim.CreateNewProcess("dynamics").addTask(sim.CreateNewTask("dynamicsTask", macros.sec2nano(dt)))
    sc = spacecraft.Spacecraft()  # RK4 is its default integrator
    sc.ModelTag = "spacecraft"
    sc.hub.mHub = float(body.hub.mass)
    sc.hub.IHubPntBc_B = np.asarray(body.hub.inertia).tolist()
    sc.hub.r_BcB_B = column(body.hub.r_BcB)
    sc.hub.omega_BN_BInit = column(x0.omega)
    (p,), (s,) = body.panels, body.slosh
    panel = hingedRigidBodyStateEffector.HingedRigidBodyStateEffector()
    panel.mass, panel.d, panel.k, panel.c = float(p.mass), float(p.d), float(p.k), float(p.c)
    panel.IPntS_S = np.asarray(p.inertia).tolist()
    panel.r_HB_B, panel.dcm_HB = column(p.r_HB), np.asarray(p.dcm_HB).tolist()
    panel.thetaInit, panel.thetaDotInit = float(x0.theta[0]), float(x0.theta_dot[0])
    slosh = linearSpringMassDamper.LinearSpringMassDamper()
    slosh.massInit, slosh.k, slosh.c = float(s.mass), float(s.k), float(s.c)  # massInit: its mass is a state
    slosh.r_PB_B, slosh.pHat_B = column(s.r_PB), column(s.p_hat)
    slosh.rhoInit, slosh.rhoDotInit = float(x0.rho[0]), float(x0.rho_dot[0])
    for effector in (panel, slosh):
        sc.addStateEffector(effector)
    for model in (sc, panel, slosh):
        sim.AddModelToTask("dynamicsTask", model)
    states, angles = sc.scStateOutMsg.recorder(), panel.hingedRigidBodyOutMsg.recorder()
    totals = sc.logger(["totRotEnergy", "totRotAngMomPntC_N"])
    for log in (states, angles, totals):
        sim.AddModelToTask("dynamicsTask", log)
    sim.InitializeSimulation()
    rho_state = sc.dynManager.getStateObject(slosh.nameOfRhoState)
    rho = [rho_state.getState()[0][0]]
    for k in range(1, steps + 1):  # rho has no output message: read the state after each step
        sim.ConfigureStopTime(macros.sec2nano(k * dt))
        sim.ExecuteSimulation()
        rho.append(rho_state.getState()[0][0])
    momentum = np.linalg.norm(np.asarray(totals.totRotAngMomPntC_N, float), axis=1)
    return (np.asarray(states.omega_BN_B, float), np.asarray(angles.theta, float), np.array(rho),
            np.asarray(totals.totRotEnergy, float), momentum)


def test_a_free_flight_matches_basilisks_effectors_at_round_off():
    pytest.importorskip("Basilisk")
    body = _basilisk_body()
    x0 = _start(body)
    xs, E, H = _flight(body, x0)
    omega, theta, rho, energy, momentum = _basilisk_flight(body, x0, DT, STEPS)
    ours = lambda x0_part, part: np.concatenate([np.asarray(x0_part)[None], np.asarray(part)])
    gaps = {"omega": np.abs(ours(x0.omega, xs.omega) - omega).max(),
            "theta": np.abs(ours(x0.theta, xs.theta)[:, 0] - theta).max(),
            "rho": np.abs(ours(x0.rho, xs.rho)[:, 0] - rho).max()}
    assert max(gaps.values()) < 1e-14, gaps  # |omega| 0.17 rad/s, |theta| 0.1 rad, |rho| 0.05 m
    assert np.ptp(theta) > 0.1 and np.ptp(rho) > 0.05 and np.ptp(omega) > 0.01  # a flight that moves
    E_ours, H_ours = ours(fx.energy(body, x0), E), np.linalg.norm(ours(fx.angular_momentum(body, x0), H), axis=1)
    assert np.abs(E_ours - energy).max() < 1e-12 * energy[0]
    assert np.abs(H_ours - momentum).max() < 1e-12 * momentum[0]


# --- gradients -------------------------------------------------------------------------------


def _rolled_rk4_flight(body, x0, dt, steps):
    """The state after ``steps`` classical RK4 steps, its four stages a loop: the reverse
    program holds one derivative (F.10), not four (a quarter of the compilation)."""
    a, w = jnp.array([0.0, 0.5, 0.5, 1.0]), jnp.array([1.0, 2.0, 2.0, 1.0]) / 6.0

    def step(x, _):
        def stage(carry, coefficients):
            k, total = carry
            k = fx.derivative(body, jax.tree.map(lambda xi, ki: xi + coefficients[0] * dt * ki, x, k))
            return (k, jax.tree.map(lambda s, ki: s + coefficients[1] * dt * ki, total, k)), None

        return jax.lax.scan(stage, (jax.tree.map(jnp.zeros_like, x), x), (a, w))[0][1], None

    return jax.lax.scan(step, x0, None, length=steps)[0]


def test_gradients_through_a_flight_are_finite_and_match_central_differences():
    x0 = _start(_basilisk_body())
    body = lambda k, c: fx.FlexibleBody(_hub(), (_panel(k=k, c=5.0),), (_slosh(k=100.0, c=c),))
    final = lambda x: x.omega[..., 2] + x.theta[..., 0] + 10.0 * x.rho[..., 0]
    # the panel's stiffness k [N m/rad] and the particle's damping c [N s/m]
    of_k_c = lambda k, c: final(_rolled_rk4_flight(body(k, c), x0, DT, STEPS))
    k, c = _a(100.0), _a(8.0)
    value, grads = _compiled(jax.value_and_grad(of_k_c, argnums=(0, 1)), k, c)(k, c)
    assert all(np.isfinite(float(g)) and float(g) != 0.0 for g in grads)
    flown = lambda k, c: float(final(_flight(body(_a(k), _a(c)), x0)[0])[-1])  # the module's rk4_step
    assert np.isclose(float(value), flown(k, c), rtol=1e-12, atol=0)
    for i, h in enumerate((1e-5 * k, 1e-5 * c)):  # truncation ~ h^2: 2e-10 relative here
        step = np.eye(2)[i] * float(h)
        central = (flown(k + step[0], c + step[1]) - flown(k - step[0], c - step[1])) / (2.0 * float(h))
        assert np.isclose(float(grads[i]), central, rtol=1e-8, atol=0), (i, float(grads[i]), central)
