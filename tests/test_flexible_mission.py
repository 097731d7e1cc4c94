"""Appendages and slosh across a mission's phases and a sweep's samples (docs/model.md §8.9): a
spring or damper given as one value per phase switches at the phases' steps (the loop flies
flexible.rk4_step with each phase's body); a list of the wrong length is a one-line error and one
number compiles as before; dispersed springs and dampers (appendages.I.k, slosh.J.c, ...) fly each
sample as its mission flown alone; missions/flexible.toml and sweeps/flexible.toml parse, and a
short flexible flight flies."""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import so3jax as sj
from so3jax.dynamics import flexible as fx
from so3jax.jobs.sweep.config import load_config
from so3jax.missions import batched, draw
from so3jax.missions import mission as missions
from tests._shared_programs import fast_jit
from tests.test_flexible_loop import DT, HUB_J, PANEL, RATE, SLOSH, TORQUE, _flexible, _fly, _mission

ROOT = Path(__file__).resolve().parents[1]
PHASES = {"names": ["stowed", "deploying", "deployed"], "start": [0.0, 0.5, 1.2]}
PANEL_K = [100.0, 40.0, 15.0]  # N m/rad per phase
SLOSH_C = [2.0, 0.5, 4.0]  # N s/m per phase


def _phased(**extra):
    return _flexible(panel={"k": PANEL_K}, slosh={"c": SLOSH_C}, phases=PHASES, reference={"kind": "inertial"},
                     **extra)


def test_per_phase_springs_switch_at_the_phases_steps():
    """k and c given per phase: the loop's trajectory is flexible.rk4_step's with each step's
    phase's body (the phase of step k: k >= 50, k >= 120), to 1e-12."""
    m = _mission(_phased())
    result, scenario, _ = _fly(m)
    body = scenario.flexible
    assert body.phases == 3 and np.asarray(body.panels[0].k).tolist() == PANEL_K
    assert np.asarray(body.slosh[0].k).tolist() == [SLOSH["k"]] * 3  # a number beside a list: repeated
    body = fx.FlexibleBody(fx.Hub(body.hub.mass, jnp.asarray(HUB_J), body.hub.r_BcB), body.panels, body.slosh,
                           phases=body.phases)
    x0 = fx.initial_state(body, jnp.asarray(RATE), theta=jnp.asarray([PANEL["angle"]]),
                          rho=jnp.asarray([SLOSH["displacement"]]))
    steps = scenario.phase_steps
    assert steps == (50, 120)

    def flight(x):
        def step(x, k):
            p = (k >= steps[0]).astype(jnp.int32) + (k >= steps[1]).astype(jnp.int32)
            return fx.rk4_step(fx.at_phase(body, p), x, DT, jnp.asarray(TORQUE)), x
        return jax.lax.scan(step, x, jnp.arange(scenario.n_steps))

    final, xs = fast_jit(flight, x0)(x0)
    h = result.history
    errors = [np.abs(np.asarray(a) - np.asarray(b)).max() for a, b in (
        (h.Omega, xs.omega), (h.flexible.theta, xs.theta), (h.flexible.rho_dot, xs.rho_dot),
        (result.final.flexible.theta, final.theta), (result.final.Omega, final.omega))]
    assert max(errors) < 1e-12, errors
    # the deployed phase's softer hinge: not the stowed body's flight
    stowed = fast_jit(lambda x: jax.lax.scan(lambda x, _: (fx.rk4_step(fx.at_phase(body, 0), x, DT,
                                                                        jnp.asarray(TORQUE)), x),
                                             x, None, length=scenario.n_steps), x0)(x0)[1]
    assert np.abs(np.asarray(stowed.theta) - np.asarray(xs.theta)).max() > 1e-3


def test_one_number_compiles_as_before_and_a_wrong_length_is_a_one_line_error():
    plain = _mission(_flexible(phases=PHASES, reference={"kind": "inertial"}))
    assert plain.scenario().flexible.phases == 0 and np.ndim(plain.scenario().flexible.panels[0].k) == 0
    phased = _mission(_phased())
    assert phased.describe()["appendages"][0]["k"] == PANEL_K and phased.fingerprint != plain.fingerprint
    for where, bad in (("appendages[0].k", {"panel": {"k": [1.0, 2.0]}}),
                       ("slosh[0].c", {"slosh": {"c": [1.0, 2.0, 3.0, 4.0]}})):
        with pytest.raises(ValueError, match=r"has \d values: give one number, or one per phase") as err:
            _mission(_flexible(**bad, phases=PHASES, reference={"kind": "inertial"}))
        assert str(err.value).startswith(where) and "\n" not in str(err.value)
    with pytest.raises(ValueError, match="pass at_phase"):
        fx.modes(phased.scenario().flexible)
    per_phase = [fx.modes(fx.at_phase(phased.scenario().flexible, p)).frequency for p in range(3)]
    assert per_phase[0][0] > per_phase[1][0] > per_phase[2][0] or per_phase[0][1] > per_phase[2][1]


DISPERSIONS = {"appendages": {"0": {"k": {"dist": "uniform", "low": 0.5, "high": 1.5, "relative": "scale"},
                                    "c": {"dist": "uniform", "low": 0.5, "high": 2.0}}},
               "slosh": {"0": {"k": {"dist": "normal", "mean": 100.0, "std": 20.0},
                               "c": {"dist": "uniform", "low": 0.5, "high": 1.5, "relative": "scale"}}}}


def test_dispersed_springs_fly_each_sample_as_its_mission_alone():
    """appendages.0.k (per phase, each phase's scale drawn on its own), appendages.0.c,
    slosh.0.k and slosh.0.c (per phase) drawn per sample (each sample's flexible body with the
    batch axis): each sample's metrics are those of its mission, written with its values, flown
    alone, to 1e-12."""
    base = _phased(controllers=["pd"], T=1.5, record_every=10)
    m = missions.from_dict(base, missions.PAPER)
    parsed, leaves = draw.parse(DISPERSIONS, m)
    assert {leaf.key: leaf.shape for leaf in leaves} == {"appendages.0.k": (3,), "appendages.0.c": (),
                                                         "slosh.0.k": (), "slosh.0.c": (3,)}
    samples = draw.draw(parsed, leaves, 0, 3, 20, mission=m)
    assert samples.valid.all()
    k = samples.leaves["appendages.0.k"]
    assert np.all((k >= 0.5 * np.asarray(PANEL_K)) & (k <= 1.5 * np.asarray(PANEL_K)))
    inputs = batched.inputs(samples, np.float64)
    controller, gains = m.controller("pd")
    batch = batched.sample_metrics(inputs, gains, controller=controller, mission=m)
    assert len(np.unique(np.asarray(batch["rmse"]))) == 3
    for i in range(3):
        appendage, particle = dict(base["appendages"][0]), dict(base["slosh"][0])
        appendage["k"] = samples.leaves["appendages.0.k"][i].tolist()
        appendage["c"] = float(samples.leaves["appendages.0.c"][i])
        particle["k"] = float(samples.leaves["slosh.0.k"][i])
        particle["c"] = samples.leaves["slosh.0.c"][i].tolist()
        alone = missions.from_dict({**base, "appendages": [appendage], "slosh": [particle]}, missions.PAPER)
        result = sj.simulate(alone.scenario(), controller, gains, alone.seed, loop=alone.loop())
        for name in ("rmse", "effort", "max_torque", "max_angle_phase"):
            np.testing.assert_allclose(batch[name][i], getattr(result.metrics, name), rtol=1e-12, atol=0,
                                       err_msg=name)


@pytest.mark.parametrize(("table", "message"), [
    ({"appendages": {"1": {"k": 1.0}}}, r"no appendages entry '1' \(its \[\[appendages\]\] entries are 0 to 0\)"),
    ({"slosh": {"0": {"mass": 1.0}}}, "disperses k, c, not 'mass'"),
    ({"appendages": {"k": 1.0}}, "must name an entry's value"),
    ({"slosh": {"0": {"k": {"dist": "uniform", "low": -2.0, "high": -1.0}}}}, "outside that domain|>= 0"),
])
def test_bad_flexible_dispersions_are_one_line_errors(table, message):
    with pytest.raises(ValueError, match=message) as err:
        draw.parse(table, _mission(_phased()))
    assert "\n" not in str(err.value)


# --- the shipped mission and sweep -----------------------------------------------------------


def test_the_shipped_flexible_mission_and_sweep_parse():
    m = missions.load(ROOT / "missions" / "flexible.toml")
    assert m.flexible and len(m.appendages) == 1 and len(m.slosh) == 1
    body = m.scenario().flexible
    assert body.phases == len(m.phase_names) == 3
    k = np.asarray(m.appendages[0]["k"])
    assert k[0] > k[1] == k[2]  # the boom's hinge softens as it deploys
    config = load_config(ROOT / "sweeps" / "flexible.toml")
    assert {leaf.key for leaf in config.leaves} >= {"appendages.0.k", "appendages.0.c", "slosh.0.k", "slosh.0.c"}


def test_the_shipped_flexible_mission_flies(cli_env):
    """so3jax fly missions/flexible.toml over a short horizon (its capture phase, the boom
    stowed): exit 0, the boom and the tank's mass moving, the trajectory finite."""
    from so3jax import commands as cli

    code = cli.main(["fly", str(ROOT / "missions" / "flexible.toml"), "--T", "2", "--controllers", "pd",
                     "--record-every", "10", "--out", "out", "--no-figures"])
    assert code == 0
    arrays = np.load(cli_env / "out" / "trajectory.npz")
    theta, rho = arrays["pd/hinge_angle"], arrays["pd/slosh_displacement"]
    assert theta.shape[1] == rho.shape[1] == 1 and np.isfinite(theta).all() and np.isfinite(rho).all()
    assert np.abs(theta).max() > 0 and np.abs(rho).max() > 0
