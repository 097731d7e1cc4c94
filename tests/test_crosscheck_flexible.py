"""so3jax crosscheck basilisk with [[appendages]] and [[slosh]] (docs/model.md §8.9): the
hinged panel as Basilisk's hingedRigidBodyStateEffector, the slosh particle as its
linearSpringMassDamper, on the hub of the mission's mass and inertia J(t) with the wheels,
the sampled mrpFeedback loop and an inertia step (missions/crosscheck_flexible.toml): the two
fly the same trajectory, hinge angle and slosh displacement included, to round-off, also
with springs and dampers per phase; what Basilisk cannot fly so is refused in one line."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from so3jax import commands as cli
from so3jax.jobs import crosscheck
from so3jax.jobs.crosscheck import basilisk

MISSIONS = Path(__file__).resolve().parent.parent / "missions"
FLEXIBLE = str(MISSIONS / "crosscheck_flexible.toml")


def _refused(sets, in_process, capsys, monkeypatch):
    """(exit code, stderr's lines) of crosscheck on the flexible mission with ``sets``,
    Basilisk's import refused (nothing reaches it)."""
    monkeypatch.setitem(sys.modules, "Basilisk", None)
    argv = ["crosscheck", "basilisk", FLEXIBLE, "--out", str(in_process / "out")]
    code = cli.main([*argv, *(x for s in sets for x in ("--set", s))])
    err = [line for line in capsys.readouterr().err.splitlines() if ": warning: " not in line]
    assert not (in_process / "out").exists()
    return code, err


def test_the_orbit_frame_with_appendages_is_one_line(in_process, capsys, monkeypatch):
    """hillPoint reads the hub's point B, which the panel and particle move about the centre
    of mass on the orbit."""
    code, err = _refused(['reference.kind="lvlh"', "reference.lvlh={offset=[0.0, 0.0, 0.0]}", "orbit.n=0.0011"],
                         in_process, capsys, monkeypatch)
    assert code == 2 and len(err) == 1 and err[0].startswith("so3jax crosscheck: error: "), err
    assert "the orbit frame" in err[0] and "[[appendages]]" in err[0], err


# Round-off, as for the rigid hub (tests/test_crosscheck.py: RK4 at dt = 0.01 s on both sides,
# so3jax on SO(3), Basilisk on MRPs with its effectors' states): measured over the 20 s
# 1.4e-15 rad, 4.9e-17 rad/s, 1.8e-14 rad/s in wheel speed, 2.1e-15 relative in torque,
# 8.5e-17 rad in hinge angle, 6.4e-17 m in slosh displacement. The bounds sit 100x above.
BOUNDS = {"max_attitude": 1e-13, "max_rate": 1e-15, "max_wheel_speed": 1e-11, "max_torque_relative": 1e-12,
          "max_hinge_angle": 1e-14, "max_slosh_displacement": 1e-14}


def test_a_hinged_panel_and_a_slosh_particle_are_flown_by_both_at_round_off(cli_env, capsys, monkeypatch):
    """missions/crosscheck_flexible.toml over its 20 s (200 ticks, the inertia step at 10 s
    included): every quantity within BOUNDS while the panel and the particle oscillate."""
    pytest.importorskip("Basilisk")
    flown, honest = [], basilisk.fly
    monkeypatch.setattr(basilisk, "fly", lambda *args, **kwargs: flown.append(honest(*args, **kwargs)) or flown[-1])
    out = cli_env / "out"
    code = cli.main(["crosscheck", "basilisk", FLEXIBLE, "--out", str(out), "--json", "--no-figures"])
    assert code == 0
    stdout = capsys.readouterr().out.strip().splitlines()
    report = json.loads(stdout[-1])
    result = report["mrp_feedback"]
    for key, bound in BOUNDS.items():
        assert result[key] <= bound, (key, result[key])
    assert result["ticks_compared"] == 200 and result["max_torque_command"] > 0.01
    assert report["units"]["max_hinge_angle"] == "rad" and report["units"]["max_slosh_displacement"] == "m"
    (run,) = flown
    assert run.hinge_angle.shape == (200, 1) and run.slosh_displacement.shape == (200, 1)
    assert run.hinge_angle[0, 0] == 0.05 and run.slosh_displacement[0, 0] == 0.02  # released there
    assert np.ptp(run.hinge_angle) > 0.08 and np.ptp(run.slosh_displacement) > 0.03  # they oscillate
    with np.load(out / "differences.npz") as arrays:
        assert {"mrp_feedback/hinge_angle", "mrp_feedback/slosh_displacement"} <= set(arrays.files)
        assert arrays["mrp_feedback/hinge_angle"].shape == (200,)
    table = crosscheck.format_table({"mrp_feedback": result})
    assert "hinge_angle [rad]" in table and "slosh_displacement [m]" in table


# A spring and a damper per phase, the second phase from 3.05 s (on the dt grid, off the
# control ticks): the effectors' k and c set once Basilisk has run to that step, as so3jax's
# loop switches them at the phase's first step. Without the switch Basilisk is 9.6e-2 rad
# apart in hinge angle, with it a dynamics step early or late 1.0e-3 rad.
PANEL = ('appendages=[{mass=50.0, inertia=[[20.0, 0.0, 0.0], [0.0, 10.0, 0.0], [0.0, 0.0, 12.0]], '
         'hinge=[0.8, 0.0, 0.0], axis=[0.0, 0.0, 1.0], direction=[1.0, 0.0, 0.0], distance=1.5, k=[1000.0, 400.0], '
         'c=[6.0, 2.0], angle=0.05}]')
PARTICLE = ('slosh=[{mass=30.0, location=[0.0, 0.0, -0.2], direction=[0.0, 1.0, 0.0], k=[100.0, 300.0], c=1.0, '
            'displacement=0.02}]')
PER_PHASE = ["T=8.0", "phases.start=[0.0, 3.05]", PANEL, PARTICLE]


def test_springs_per_phase_are_switched_at_the_phases_step_by_both(cli_env, capsys, monkeypatch):
    """The bounds above over 8 s; Basilisk's effectors take the second phase's k and c from
    step 305 on (springs()), and hold the first phase's before."""
    pytest.importorskip("Basilisk")
    from so3jax.missions import mission as missions

    initial, changes = basilisk.springs(missions.load(FLEXIBLE, PER_PHASE))
    assert initial == [(1000.0, 6.0), (100.0, 1.0)] and changes == [(305, [(400.0, 2.0), (300.0, 1.0)])]
    code = cli.main(["crosscheck", "basilisk", FLEXIBLE, "--out", str(cli_env / "out"), "--json", "--no-figures",
                     *(x for s in PER_PHASE for x in ("--set", s))])
    assert code == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["mrp_feedback"]
    for key, bound in BOUNDS.items():
        assert result[key] <= bound, (key, result[key])
    assert result["ticks_compared"] == 80
