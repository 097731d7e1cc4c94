"""Hinged panels and slosh in a mission's closed loop (docs/model.md §8.9, so3jax.dynamics.plant.flexible_derivative):
a mission without [[appendages]] and [[slosh]] describes and fingerprints as before; flown open
loop on an ideal actuator, the loop's trajectory is flexible.rk4_step's iterated directly; clamped
(stiff, damped) appendages fly the rigid mission of the combined inertia about the system's
centre of mass, the difference falling as 1/k; with reaction wheels driven by the sampled
loop the total angular momentum (the flexible body's about its centre of mass plus the
wheels') is conserved in inertial space while the panel and the particle oscillate; bad
entries are one-line errors, before anything compiles (so3jax fly: exit 2)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from so3jax import commands as cli
from so3jax.components import actuators
from so3jax.dynamics import flexible as fx
from so3jax.dynamics import plant
from so3jax.jobs.fly import trajectory_arrays
from so3jax.missions import mission as missions
from so3jax.sim.rollout import rollout
from tests._shared_programs import compiled, fast_jit

HUB_J = [[900.0, 10.0, -5.0], [10.0, 800.0, 8.0], [-5.0, 8.0, 600.0]]
HUB_MASS = 750.0
PANEL = {"mass": 100.0, "inertia": [[100.0, 2.0, 0.0], [2.0, 50.0, 1.0], [0.0, 1.0, 60.0]], "hinge": [0.5, 0.2, 1.0],
         "axis": [0.0, 0.6, 0.8], "direction": [1.0, 0.0, 0.0], "distance": 1.5, "k": 100.0, "c": 1.0, "angle": 0.1}
SLOSH = {"mass": 100.0, "location": [0.1, 0.0, -0.1], "direction": [3**-0.5] * 3, "k": 100.0, "c": 2.0,
         "displacement": 0.05}
TORQUE = [2.0, -1.0, 1.5]  # the open loop's constant body torque [N m]
RATE = [0.05, -0.03, 0.04]  # Omega(0) [rad/s]
DT, T = 0.01, 2.0
# the open loop on an ideal actuator in the paper's continuous wiring, no disturbance, a constant J
OPEN_LOOP = {"T": T, "dt": DT, "controllers": ["open_loop"], "record_every": 1, "inertia": {"J": HUB_J},
             "controller": {"open_loop": {"torque": TORQUE}}, "disturbance": {"amplitude": 0.0, "noise_std": 0.0},
             "initial": {"rate": RATE}}


def _flexible(panel=None, slosh=None, **extra):
    return {**OPEN_LOOP, "hub": {"mass": HUB_MASS}, "appendages": [{**PANEL, **(panel or {})}],
            "slosh": [{**SLOSH, **(slosh or {})}], **extra}


def _mission(d, base=missions.PAPER):
    return missions.from_dict(d, base)


_RUNNERS = {}


def _fly(m: missions.Mission):
    """The mission's first controller's rollout (seed 0), one program per controller and
    structure of (scenario, gains, loop) (tests/_shared_programs.compiled: a stiffer panel's
    flight reuses the program)."""
    scenario, loop = m.scenario(), m.loop()
    law, gains = m.controller(m.controllers[0])
    key = (law, m.record_every)
    if key not in _RUNNERS:
        _RUNNERS[key] = compiled(lambda s, g, lp: rollout(s, law, g, 0, loop=lp, record_every=m.record_every))
    return _RUNNERS[key](*jax.tree.map(jnp.asarray, (scenario, gains, loop))), scenario, loop


@pytest.fixture(scope="module")
def open_loop_flight():
    return _fly(_mission(_flexible()))


# --- the mission -------------------------------------------------------------------------


def test_a_mission_without_appendages_describes_and_fingerprints_as_before():
    for base, fingerprint in ((missions.FLIGHT, "0c0035dff0fddc4a"), (missions.PAPER, "16b319ec13aa2fb3")):
        plain = _mission({}, base)
        empty = _mission({"appendages": [], "slosh": []}, base)
        assert plain.describe() == empty.describe() and plain.fingerprint == empty.fingerprint == fingerprint
        assert not ({"hub_mass", "appendages", "slosh"} & set(plain.describe()))
        assert plain.scenario().flexible is None
    flexible = _mission(_flexible())
    described = flexible.describe()
    assert described["hub_mass"] == HUB_MASS and described["appendages"][0]["axis"] == PANEL["axis"]
    assert flexible.fingerprint != _mission(_flexible(panel={"k": 101.0})).fingerprint


def test_the_panel_frame_is_right_handed_with_the_centre_of_mass_along_direction():
    m = _mission(_flexible())
    panel = m.scenario().flexible.panels[0]
    H = np.asarray(panel.dcm_HB)
    assert np.allclose(H @ H.T, np.eye(3), atol=1e-15) and np.linalg.det(H) > 0
    assert np.allclose(H[1], PANEL["axis"]) and np.allclose(H[0], -np.asarray(PANEL["direction"]))
    s1, _, _ = fx.panel_axes(panel, jnp.zeros(()), jnp.zeros(3))
    centre = np.asarray(panel.r_HB) - float(panel.d) * np.asarray(s1)
    assert np.allclose(centre, np.asarray(PANEL["hinge"]) + PANEL["distance"] * np.asarray(PANEL["direction"]))


# --- the loop against the model ----------------------------------------------------------


def test_the_open_loop_flies_the_flexible_bodys_own_rk4_steps(open_loop_flight):
    result, scenario, _ = open_loop_flight
    body = scenario.flexible
    body = fx.FlexibleBody(fx.Hub(body.hub.mass, jnp.asarray(HUB_J), body.hub.r_BcB), body.panels, body.slosh)
    x0 = fx.initial_state(body, jnp.asarray(RATE), theta=jnp.asarray([PANEL["angle"]]),
                          rho=jnp.asarray([SLOSH["displacement"]]))

    def flight(x):
        def step(x, _):
            return fx.rk4_step(body, x, DT, jnp.asarray(TORQUE)), x
        return jax.lax.scan(step, x, None, length=scenario.n_steps)

    final, xs = fast_jit(flight, x0)(x0)
    h = result.history
    errors = [np.abs(np.asarray(a) - np.asarray(b)).max() for a, b in (
        (h.Omega, xs.omega), (h.flexible.theta, xs.theta), (h.flexible.theta_dot, xs.theta_dot),
        (h.flexible.rho, xs.rho), (h.flexible.rho_dot, xs.rho_dot), (result.final.Omega, final.omega),
        (result.final.flexible.theta, final.theta), (result.final.flexible.rho, final.rho))]
    assert max(errors) < 1e-12, errors
    assert np.ptp(np.asarray(h.flexible.theta)) > 0.05 and np.ptp(np.asarray(h.flexible.rho)) > 0.01  # it moves
    arrays = trajectory_arrays({"open_loop": result}, T)  # fly's trajectory.npz
    np.testing.assert_array_equal(arrays["open_loop/hinge_angle"], np.asarray(h.flexible.theta))
    assert arrays["open_loop/slosh_rate"].shape == (scenario.n_steps, 1)


def test_without_panels_and_particles_the_hub_moves_as_the_rigid_plant():
    """plant.flexible_derivative of a bare hub (no panels, no particles) is plant.derivative's:
    the wheels' locked inertia, relative momentum and the J' Omega term in the torque on the hub."""
    loop = missions.load(None).loop()  # four wheels in a pyramid
    wheels = loop.actuator
    J, J_dot = jnp.asarray(HUB_J), jnp.asarray([[1.0, 0.2, 0.0], [0.2, -0.5, 0.1], [0.0, 0.1, 0.3]])
    Omega, d = jnp.asarray([0.05, -0.02, 0.03]), jnp.asarray([0.01, 0.02, -0.03])
    state = wheels.init((), Omega.dtype)
    state = jax.tree.map(lambda x: x + jnp.asarray([300.0, -200.0, 100.0, 50.0][:x.shape[0]]), state)
    held = wheels.command(state, jnp.asarray([0.1, -0.05, 0.02]), Omega)
    hub = fx.FlexibleBody(fx.Hub(jnp.asarray(HUB_MASS), J, jnp.zeros(3)))
    modal = fx.initial_modal(hub, (), Omega.dtype)
    for rate in (None, J_dot):
        rigid = plant.derivative(wheels, J, Omega, state, held, d, jnp.zeros(()), rate)
        ours = plant.flexible_derivative(wheels, hub, J, Omega, modal, state, held, d, jnp.zeros(()), rate)
        for a, b in zip(jax.tree.leaves(rigid), jax.tree.leaves(ours[:2])):
            np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-13, atol=1e-18)


def _rigid_inertia(m: missions.Mission) -> np.ndarray:
    """The hub, the panel at theta = 0 and the particle at rest as one rigid body: the inertia
    about the system's centre of mass (parallel axes, the hub's centre of mass at B)."""
    panel, particle = m.appendages[0], m.slosh[0]
    s1, s2 = -np.asarray(panel["direction"]), np.asarray(panel["axis"])
    S = np.stack([s1, s2, np.cross(s1, s2)])
    parts = [(m.hub_mass, np.zeros(3), np.asarray(HUB_J)),
             (panel["mass"], np.asarray(panel["hinge"]) + panel["distance"] * np.asarray(panel["direction"]),
              S.T @ np.asarray(panel["inertia"]) @ S),
             (particle["mass"], np.asarray(particle["location"]), np.zeros((3, 3)))]
    total = sum(mass for mass, _, _ in parts)
    centre = sum(mass * r for mass, r, _ in parts) / total
    return sum(inertia + mass * (np.dot(r - centre, r - centre) * np.eye(3) - np.outer(r - centre, r - centre))
               for mass, r, inertia in parts)


def test_clamped_appendages_fly_the_rigid_body_of_the_combined_inertia():
    """Stiff hinge and particle (k = 1e4, 1e5; damping ratio ~0.5: c = sqrt(k I), I = 275 kg m^2
    about the hinge, 100 kg), at rest relative to the hub at t = 0: Omega differs from the rigid
    mission's by the start's transient, whose rate amplitude scales as 1 / sqrt(k), then (once it
    has decayed, t >= 1 s) by the quasi-static deflections, as 1 / k."""
    whole, settled = [], []
    for k in (1e4, 1e5):
        m = _mission(_flexible(panel={"k": k, "c": np.sqrt(k * 275.0), "angle": 0.0},
                               slosh={"k": k, "c": np.sqrt(k * 100.0), "displacement": 0.0}))
        rigid = _mission({**OPEN_LOOP, "inertia": {"J": _rigid_inertia(m).tolist()}})
        flexible, _, _ = _fly(m)
        reference, _, _ = _fly(rigid)
        assert np.ptp(np.asarray(reference.history.Omega)) > 1e-3  # the torque turns it
        error = np.abs(np.asarray(flexible.history.Omega) - np.asarray(reference.history.Omega)).max(axis=1)
        whole.append(error.max())
        settled.append(error[len(error) // 2:].max())
    assert whole[1] < 1e-5 and 2.5 < whole[0] / whole[1] < 4.0, whole  # sqrt(10) = 3.16
    assert settled[1] < 2e-7 and 8.0 < settled[0] / settled[1] < 12.0, settled


def test_wheels_conserve_the_total_angular_momentum_while_the_panel_oscillates():
    """The sampled loop (truth estimator, PD) on four wheels, undamped panel and particle
    started off rest, no external torque: R (H_C + h_w) constant, H_C the flexible body's about
    its centre of mass (the hub's inertia J - J_locked), h_w = J_locked Omega + h_rel the wheels'."""
    d = _flexible(panel={"c": 0.0}, slosh={"c": 0.0}, T=10.0, controllers=["pd"], control={"mode": "sampled",
                                                                                          "period": 0.1},
                  sensors={"gyro": False, "star_tracker": False}, estimator={"kind": "truth"},
                  actuator={"kind": "wheels", "wheels": {"initial_speed": [100.0, -50.0, 30.0, 0.0]}},
                  momentum={"kind": "none"})
    d.pop("controller")
    m = _mission(d)
    result, scenario, loop = _fly(m)
    h = result.history
    last = lambda x: jnp.moveaxis(jnp.asarray(x), 0, -1)  # records (M, ...) -> batch axis last
    Omega, wheels = last(h.Omega), last(h.actuator)
    stored = loop.actuator.stored_momentum(wheels)
    J_hub = jnp.asarray(HUB_J) - jnp.asarray(stored.locked_inertia)
    body = scenario.flexible
    body = fx.FlexibleBody(fx.Hub(body.hub.mass, J_hub, body.hub.r_BcB), body.panels, body.slosh)
    state = fx.FlexState(Omega, *(last(x) for x in h.flexible))
    H = fx.angular_momentum(body, state) + actuators.momentum(loop.actuator, wheels, Omega)
    inertial = np.einsum("mij,jm->mi", np.asarray(h.R), np.asarray(H))
    drift = np.abs(inertial - inertial[0]).max() / np.linalg.norm(inertial[0])
    wheel_momentum = np.asarray(actuators.momentum(loop.actuator, wheels, Omega))
    assert np.ptp(np.asarray(h.flexible.theta)) > 0.1 and np.ptp(np.asarray(h.flexible.rho)) > 0.05
    assert np.ptp(wheel_momentum, axis=1).max() > 0.1  # the wheels exchange momentum with the body
    assert drift < 1e-10, drift


# --- bad input -----------------------------------------------------------------------------


@pytest.mark.parametrize("change,message", [
    ({"panel": {"axis": [0.0, 0.0, 2.0]}}, r"appendages\[0\]\.axis must be a unit vector"),
    ({"panel": {"direction": [0.0, 0.6, 0.8]}}, r"appendages\[0\]\.direction must be perpendicular"),
    ({"panel": {"direction": [2.0, 0.0, 0.0]}}, r"appendages\[0\]\.direction must be a unit vector"),
    ({"panel": {"k": -1.0}}, r"appendages\[0\]\.k \[N m/rad\] must be"),
    ({"panel": {"c": -1.0}}, r"appendages\[0\]\.c \[N m s/rad\] must be"),
    ({"panel": {"distance": -0.5}}, r"appendages\[0\]\.distance \[m\] must be"),
    ({"panel": {"mass": 0.0}}, r"appendages\[0\]\.mass \[kg\] must be > 0"),
    ({"panel": {"inertia": [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]]}},
     r"appendages\[0\]\.inertia .*positive definite"),
    ({"panel": {"hinge": [0.0, 1.0]}}, r"appendages\[0\]\.hinge \[m\] must have shape \(3,\)"),
    ({"panel": {"spring": 1.0}}, r"unknown key\(s\) in \[appendages\[0\]\]: spring"),
    ({"slosh": {"direction": [1.0, 1.0, 0.0]}}, r"slosh\[0\]\.direction must be a unit vector"),
    ({"slosh": {"k": -5.0}}, r"slosh\[0\]\.k \[N/m\] must be"),
    ({"hub": {}}, r"need the hub's mass: give hub\.mass"),
    ({"hub": {"mass": -1.0}}, r"hub\.mass \[kg\] must be"),
])
def test_bad_entries_are_one_line_errors(change, message):
    d = _flexible(panel=change.get("panel"), slosh=change.get("slosh"))
    if "hub" in change:
        d["hub"] = change["hub"]
    with pytest.raises(ValueError, match=message) as err:
        _mission(d)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("d,message", [
    ({"hub": {"mass": 500.0}}, r"hub\.mass \[kg\] is read only with \[\[appendages\]\] or \[\[slosh\]\]"),
    ({"hub": {"mass": 500.0}, "appendages": [{"mass": 1.0}]}, r"appendages\[0\]\.inertia \[kg m\^2\] is required"),
    ({"hub": {"mass": 500.0}, "appendages": {"mass": 1.0}}, r"appendages must be a list of tables"),
    ({"hub": {"mass": 500.0}, "slosh": [3.0]}, r"slosh\[0\] must be a table"),
])
def test_bad_tables_are_one_line_errors(d, message):
    with pytest.raises(ValueError, match=message):
        _mission(d, missions.FLIGHT)


def test_fly_refuses_a_bad_file_in_one_line(tmp_path, in_process, capsys):
    path = tmp_path / "bad.toml"
    path.write_text("[hub]\nmass = 500.0\n[[appendages]]\nmass = 10.0\ninertia = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], "
                    "[0.0, 0.0, 1.0]]\nhinge = [1.0, 0.0, 0.0]\naxis = [0.0, 0.0, 1.0]\ndirection = [0.0, 0.0, 1.0]\n"
                    "distance = 1.0\nk = 10.0\n")
    code = cli.main(["fly", str(path), "--out", str(tmp_path / "out"), "--no-figures"])
    lines = [line for line in capsys.readouterr().err.splitlines() if ": warning: " not in line]
    assert code == 2 and len(lines) == 1 and "appendages[0].direction must be perpendicular" in lines[0], lines
