"""The margins see the structural modes (so3jax.sim.margins, so3jax.jobs.margins, docs/flexible.md
(F.21), (F.24), docs/commands/margins.md): the one-period map linearized with the modal
coordinates in, its free modes (the command disconnected: A alone) at the closed forms of a
hinged panel and a slosh particle on a free hub, as flexible.modes has them; the report names
the modes at each time (JSON, table, units), a rigid mission's report has no such key; the
frequency grid resolves a lightly damped resonance and the figures mark it; a lightly damped
panel above the loop's crossover lowers the disk margin, and a torque notch at its frequency
recovers it.

One geometry, planar about the hub's z axis: a hub of diagonal inertia, the panel hinged on
the x axis about z, the particle at the hub's centre of mass B moving along x (its line
passes through the centre of mass of the rest: the panel's plane motion, v_y and omega_z,
and the particle's, v_x, do not couple at rest). Three programs are compiled (the rigid
mission, the flexible one, the flexible one with a notch), at t = 0 on an inertial
reference at rest (an equilibrium); the soft and the stiff panel share one."""

import json
import math

import numpy as np
import pytest

from so3jax.dynamics import flexible as fx
from so3jax.jobs import margins as margins_job
from so3jax.missions import mission as missions
from so3jax.sim import margins as mg

HUB_J = [[600.0, 0.0, 0.0], [0.0, 500.0, 0.0], [0.0, 0.0, 400.0]]  # diagonal: J_z = 400 kg m^2
HUB_MASS = 800.0  # M [kg]
R, D = 1.0, 1.5  # the hinge at r along x [m], the panel's centre of mass d beyond it [m]
M_PANEL, I_C = 50.0, 30.0  # m [kg], I_c [kg m^2] about its centre of mass, about the hinge axis
PANEL = {"mass": M_PANEL, "inertia": [[20.0, 0.0, 0.0], [0.0, I_C, 0.0], [0.0, 0.0, 10.0]],  # s2 = the hinge axis
         "hinge": [R, 0.0, 0.0], "axis": [0.0, 0.0, 1.0], "direction": [1.0, 0.0, 0.0], "distance": D, "angle": 0.0}
M_SLOSH = 20.0  # [kg], at B, moving along x
SLOSH = {"mass": M_SLOSH, "location": [0.0, 0.0, 0.0], "direction": [1.0, 0.0, 0.0], "displacement": 0.0}
# a PD of crossover about 1 rad/s on a truth estimator and an ideal actuator, sampled at 0.1 s, dt = 0.01 s
BASE = {"T": 1.0, "controllers": ["pd"], "sensors": {"gyro": False, "star_tracker": False},
        "estimator": {"kind": "truth"}, "actuator": {"kind": "ideal"}, "momentum": {"kind": "none"},
        "disturbance": {"amplitude": 0.0, "noise_std": 0.0}, "reference": {"kind": "inertial"},
        "initial": {"attitude": [0.0, 0.0, 0.0], "rate": [0.0, 0.0, 0.0]}, "inertia": {"J": HUB_J},
        "gains": {"pd": {"k_R": 60.0, "k_Omega": 640.0}}}


def panel_inertia(J_z=HUB_J[2][2], hub_mass=HUB_MASS + M_SLOSH, r=R, d=D, m=M_PANEL, I_c=I_C):
    """I_eff of (F.21): the panel's effective inertia about its hinge once the free hub's
    translation and rotation are condensed out (the particle at B moves with the hub in y)."""
    mu = hub_mass * m / (hub_mass + m)
    return (J_z * (I_c + mu * d * d) + mu * I_c * r * r) / (J_z + I_c + mu * (r + d) ** 2)


def slosh_mass(m_p=M_SLOSH, rest=HUB_MASS + M_PANEL):
    """The particle's effective mass on its line through the rest's centre of mass (F.24):
    the reduced mass m_p M / (m_p + M), M the hub's with the panel."""
    return m_p * rest / (m_p + rest)


def closed_forms(panel_k, panel_c, slosh_k, slosh_c):
    """[(omega [rad/s], zeta)] of the panel and the particle, ascending: omega^2 = k / I_eff,
    zeta = c / (2 sqrt(k I_eff)) (F.21), and the same with the particle's effective mass (F.24)."""
    out = [(math.sqrt(k / m), c / (2 * math.sqrt(k * m)))
           for k, c, m in ((panel_k, panel_c, panel_inertia()), (slosh_k, slosh_c, slosh_mass()))]
    return sorted(out)


SOFT = dict(panel_k=80.0, panel_c=0.8, slosh_k=60.0, slosh_c=0.6)  # about 1.0 and 1.8 rad/s: (omega dt)^4 / 120 < 1e-9
OMEGA_STIFF, ZETA_STIFF = 6.0, 0.002  # the panel above the crossover, lightly damped
NOTCH = {"zeta_zero": 0.002, "zeta_pole": 0.05}


def flexible(panel_k, panel_c, slosh_k, slosh_c, **extra):
    return missions.from_dict({**BASE, "hub": {"mass": HUB_MASS},
                               "appendages": [{**PANEL, "k": panel_k, "c": panel_c}],
                               "slosh": [{**SLOSH, "k": slosh_k, "c": slosh_c}], **extra})


def stiff():
    """The panel at OMEGA_STIFF rad/s, damping ratio ZETA_STIFF (F.21)."""
    I_eff = panel_inertia()
    k = I_eff * OMEGA_STIFF**2
    return dict(panel_k=k, panel_c=2 * ZETA_STIFF * math.sqrt(k * I_eff), slosh_k=60.0, slosh_c=0.6)


def _run(mission):
    reports, lins, _ = margins_job.run(mission, (0.0,))
    return reports["pd"], lins["pd"][0.0]


@pytest.fixture(scope="module")
def soft():
    mission = flexible(**SOFT)
    return (mission, *_run(mission))


@pytest.fixture(scope="module")
def rigid():
    mission = missions.from_dict(BASE)
    return (mission, *_run(mission))


@pytest.fixture(scope="module")
def stiff_panel():
    mission = flexible(**stiff())
    return (mission, *_run(mission))


@pytest.fixture(scope="module")
def notched():
    parameters = stiff()
    f = math.sqrt(parameters["panel_k"] / panel_inertia()) / (2 * math.pi)
    mission = flexible(**parameters, filter={"kind": "notch", "notch": {"frequency": f, **NOTCH}})
    return (mission, *_run(mission))


# --- the closed forms ----------------------------------------------------------------------


def test_the_closed_forms_limits():
    """(F.21) tends to the pendulum about the hinge on an immovable hub, to the translating
    hub's k / (I_c + mu d^2) as J_z grows; (F.22) to the particle's own mass on a heavy hub."""
    big = 1e12
    assert panel_inertia(J_z=big, hub_mass=big) == pytest.approx(I_C + M_PANEL * D * D, rel=1e-9)
    mu = (HUB_MASS + M_SLOSH) * M_PANEL / (HUB_MASS + M_SLOSH + M_PANEL)
    assert panel_inertia(J_z=big) == pytest.approx(I_C + mu * D * D, rel=1e-9)
    assert slosh_mass(rest=big) == pytest.approx(M_SLOSH, rel=1e-9)


def test_flexible_modes_are_the_closed_forms(soft):
    mission = soft[0]
    modes = fx.modes(mission.scenario().flexible)
    expected = np.array(closed_forms(**SOFT))
    np.testing.assert_allclose(np.asarray(modes.frequency), expected[:, 0], rtol=1e-12)
    np.testing.assert_allclose(np.asarray(modes.damping_ratio), expected[:, 1], rtol=1e-12)


def _free_modes(lin):
    """s = log(z) / Delta_c of the oscillatory eigenvalues z of A (the loop broken at the
    actuator input, its command w held: nothing feeds back), upper half-plane, ascending |s|."""
    z = np.linalg.eigvals(lin.A)
    z = z[np.abs(z) > 1e-6]
    s = np.log(z.astype(complex)) / lin.period
    s = s[s.imag > 0.1]
    return s[np.argsort(np.abs(s))]


def test_the_linearization_carries_the_modal_states(soft):
    _, _, lin = soft
    for name in (".flexible.theta[0]", ".flexible.theta_dot[0]", ".flexible.rho[0]", ".flexible.rho_dot[0]"):
        assert any(label.endswith(name) for label in lin.labels), (name, lin.labels)


def test_the_open_loops_modes_are_the_closed_forms(soft):
    """The free modes of the one-period map (A: the command disconnected) at the closed forms:
    |s| = omega to the plant's RK4 step (its phase lag (omega dt)^4 / 120 < 1e-9, exactly),
    the damping ratio -Re s / |s| flexible.modes'."""
    mission, _, lin = soft
    s = _free_modes(lin)
    expected = np.array(closed_forms(**SOFT))
    assert len(s) == 2, s
    np.testing.assert_allclose(np.abs(s), expected[:, 0], rtol=1e-8)
    # what is left is RK4's phase lag per step, arg R(i x) = x (1 - x^4 / 120 + ...), x = omega dt
    x = expected[:, 0] * mission.dt
    np.testing.assert_allclose(np.abs(s) / expected[:, 0] - 1, -(x**4) / 120, rtol=0, atol=1e-12)
    np.testing.assert_allclose(-s.real / np.abs(s), expected[:, 1], rtol=1e-6)
    assert np.all(expected[:, 1] > 1e-3)  # damped: c > 0


# --- the report ----------------------------------------------------------------------------


def test_the_report_names_the_modes_with_appendages_only(soft, rigid, tmp_path):
    _, flexible_report, _ = soft
    _, rigid_report, _ = rigid
    (row,) = flexible_report["times"]
    expected = closed_forms(**SOFT)
    assert [m.keys() for m in row["modes"]] == [{"frequency_hz", "frequency", "damping_ratio"}] * 2
    for mode, (omega, zeta) in zip(row["modes"], expected):
        assert mode["frequency"] == pytest.approx(omega, rel=1e-12)
        assert mode["frequency_hz"] == pytest.approx(omega / (2 * math.pi), rel=1e-12)
        assert mode["damping_ratio"] == pytest.approx(zeta, rel=1e-12)
    assert list(row) == ["t", "phase", "modes", "loop_at_a_time", "disk"]
    assert all("modes" not in r for r in rigid_report["times"])
    assert list(rigid_report["times"][0]) == ["t", "phase", "loop_at_a_time", "disk"]

    table = margins_job.format_table({"pd": flexible_report})
    line = next(x for x in table.splitlines() if "structural modes:" in x)
    assert f"{expected[0][0] / (2 * math.pi):.3g} Hz ζ {expected[0][1]:.3g}" in line, line
    assert "structural modes" not in margins_job.format_table({"pd": rigid_report})

    for name, report, units in (("flexible", flexible_report, {**mg.UNITS, **margins_job.MODE_UNITS}),
                                ("rigid", rigid_report, mg.UNITS)):
        margins_job.write(tmp_path / name, {"pd": report}, {}, {}, with_figures=False)
        written = json.loads((tmp_path / name / "margins.json").read_text())
        assert written["units"] == units


def test_the_modes_at_a_time_take_the_hubs_inertia_then(soft):
    """structural_modes: flexible.modes on the body whose hub has the loop's J(t)."""
    mission = soft[0]
    scenario = mission.scenario()
    body = scenario.flexible
    modes = mg.structural_modes(scenario, 0.0)
    reference = fx.modes(body)
    np.testing.assert_allclose([m.frequency for m in modes], np.asarray(reference.frequency), rtol=1e-14)
    bigger = flexible(**SOFT, inertia={"J": (2.0 * np.asarray(HUB_J)).tolist()})
    panel = mg.structural_modes(bigger.scenario(), 0.0)[0]  # the panel's mode, the lower
    assert panel.frequency == pytest.approx(math.sqrt(SOFT["panel_k"] / panel_inertia(J_z=800.0)), rel=1e-12)


def test_the_grid_resolves_a_lightly_damped_resonance_and_the_figures_mark_it(stiff_panel):
    _, report, lin = stiff_panel
    modes = mg.structural_modes(stiff_panel[0].scenario(), 0.0)
    panel = modes[-1]
    assert panel.frequency == pytest.approx(OMEGA_STIFF, rel=1e-12)
    assert panel.damping_ratio == pytest.approx(ZETA_STIFF, rel=1e-12)
    plain, resolved = mg.default_omegas(lin.period, 800), mg.resolving_omegas(lin.period, modes, 800)
    assert set(plain) <= set(resolved) and np.all(np.diff(resolved) > 0)
    for u in (0.0, ZETA_STIFF, -ZETA_STIFF):
        assert np.isclose(resolved, OMEGA_STIFF * (1 + u), rtol=1e-14, atol=0).any()
    # the resonance of the z axis's loop: on the plain grid its peak is missed by far
    window = lambda omegas: omegas[np.abs(omegas / OMEGA_STIFF - 1) <= 0.02]
    peak = lambda omegas: np.abs(mg.axis_response(lin, window(omegas))[:, 2]).max()
    dense = np.linspace(OMEGA_STIFF * 0.98, OMEGA_STIFF * 1.02, 20001)
    assert peak(resolved) > 0.9 * peak(dense) and peak(plain) < 0.5 * peak(dense)

    figures = margins_job.figures({"pd": {0.0: lin}}, margins_job.report_modes({"pd": report}))
    bode = figures["bode_pd.png"]
    magnitude = bode.axes[2]  # axis z's gain
    marked = [line.get_xdata()[0] for line in magnitude.lines if line.get_linestyle() == ":"]
    assert any(np.isclose(x, OMEGA_STIFF, rtol=1e-12) for x in marked), marked
    assert any("Hz" in text.get_text() for text in magnitude.texts)
    nichols = figures["nichols_pd.png"].axes[2]
    assert any(line.get_marker() == "x" for line in nichols.lines)
    rigid_figures = margins_job.figures({"pd": {0.0: lin}})
    assert not [line for line in rigid_figures["bode_pd.png"].axes[2].lines if line.get_linestyle() == ":"]


# --- the modes matter ------------------------------------------------------------------------


def _disk(report):
    (row,) = report["times"]
    disk = row["disk"]
    return disk["axes"][2]["alpha"], disk["multiloop"]["alpha"]


def test_a_lightly_damped_panel_lowers_the_margins_and_a_notch_recovers_them(rigid, stiff_panel, notched):
    """The panel's mode at 6 rad/s (zeta 0.002), above the PD's crossover near 1 rad/s, sets
    the z axis's disk margin (its peak at the resonance) below the rigid hub's; a torque notch at
    its frequency (zeta_zero 0.002, zeta_pole 0.05) recovers most of it."""
    z_rigid, all_rigid = _disk(rigid[1])
    z_flex, all_flex = _disk(stiff_panel[1])
    z_notch, all_notch = _disk(notched[1])
    (row,) = stiff_panel[1]["times"]
    assert row["disk"]["axes"][2]["frequency"] == pytest.approx(OMEGA_STIFF, rel=0.2)  # the resonance sets it
    assert z_flex < z_rigid - 0.15 and all_flex < all_rigid - 0.15, (z_rigid, z_flex)
    assert z_notch > z_flex + 0.1 and all_notch > all_flex + 0.05, (z_flex, z_notch, all_flex, all_notch)


def test_the_modes_follow_the_inertia_timeline():
    """On the flight mission's timeline (capture J0, deployment towards 2 J0, docked J2 from
    2600 s: missions/flight.toml) the modes at t are flexible.modes on the hub of J(t)."""
    mission = missions.from_dict({"T": 3000.0, "hub": {"mass": HUB_MASS},
                                  "appendages": [{**PANEL, "k": SOFT["panel_k"], "c": SOFT["panel_c"]}]})
    scenario = mission.scenario()
    body = scenario.flexible
    J0 = np.asarray(mission.J0)
    J2 = np.asarray(mission.J2)
    found = {}
    for t, J in ((0.0, J0), (2900.0, J2)):
        hub = body.hub.__class__(body.hub.mass, J, body.hub.r_BcB)
        expected = fx.modes(body.__class__(hub, body.panels, body.slosh))
        (mode,) = mg.structural_modes(scenario, t)
        assert mode.frequency == pytest.approx(float(expected.frequency[0]), rel=1e-13), t
        assert mode.damping_ratio == pytest.approx(float(expected.damping_ratio[0]), rel=1e-13), t
        found[t] = mode.frequency
    (deploying,) = mg.structural_modes(scenario, 1500.0)
    assert found[0.0] != found[2900.0] and deploying.frequency not in found.values()


def test_a_sweep_resolves_each_sample_s_own_modes():
    """A sweep's margins take each sample's on a grid through its own structural modes: the
    panel's and the particle's k and c drawn per sample, each sample's grid holds the
    frequencies of (F.21), (F.24) with its values (the modes of its mission written out and
    built alone), which differ between the samples."""
    from so3jax.jobs.sweep import margins as sweep_margins
    from so3jax.missions import batched, draw

    m = flexible(**SOFT)
    scale = {"dist": "uniform", "low": 0.5, "high": 2.0, "relative": "scale"}
    parsed, leaves = draw.parse({"appendages": {"0": {"k": scale, "c": scale}},
                                 "slosh": {"0": {"k": scale}}}, m)
    samples = draw.draw(parsed, leaves, 0, 2, 20, mission=m)
    inputs = batched.inputs(samples, np.float64)
    grids = []
    for i in range(2):
        grid = sweep_margins._resolving(m, inputs, i, 0.0)
        values = {name: float(samples.leaves[f"{name}.0.k"][i]) for name in ("appendages", "slosh")}
        c = float(samples.leaves["appendages.0.c"][i])
        for omega, zeta in closed_forms(values["appendages"], c, values["slosh"], SOFT["slosh_c"]):
            assert np.min(np.abs(grid / omega - 1.0)) < 1e-12
            assert np.min(np.abs(grid / (omega * (1.0 + zeta * mg.MODE_BAND[0])) - 1.0)) < 1e-12
        grids.append(grid)
    assert not np.array_equal(grids[0], grids[1])
