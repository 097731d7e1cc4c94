"""The library's entry points under JAX's transformations, with every registered component.

``rollout``, ``rollout_batch`` and ``simulate`` on a tiny sampled-data mission (T = 0.3 s,
dt = 0.05 s, control period 0.1 s: three ticks) under ``jax.jit``, ``jax.vmap`` and
``jax.grad`` or ``jax.jacfwd``, each trajectory of a batch flying its own loop (the
mission's, and the mission's with every parameter but the wheels' axes 0.1 % larger).
Every estimator (truth, raw, mekf), actuator (ideal, saturated, wheels), momentum manager,
environment torque and registered controller appears in one of the loops, so that few
programs compile: per loop, the un-jitted ``rollout`` (the reference), one jitted program
holding the rollout under ``vmap`` (over seeds and loops) of its derivative and
``rollout_batch``, and ``simulate``. Reverse mode, the costly one to compile, in one loop
(every component's reverse mode is also checked where it is tested: tests/test_loop.py
for the MEKF); forward mode in the others. The results are finite and equal to the
un-jitted call (to round-off: XLA fuses the programs differently); the derivative equals
central differences of the jitted rollout.
"""

from __future__ import annotations

import dataclasses
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import so3jax as sj
from so3jax.components import registry as components
from so3jax.controllers import registry
from so3jax.missions import mission as missions
from tests._shared_programs import fast_jit

TINY = ["T=0.3", "dt=0.05", "control.period=0.1", "record_every=6"]
# Each registered component in one loop (estimator, actuator, controller, derivative), the
# heavy parts (MEKF, wheels, the adaptive law, reverse mode) spread over the loops.
LOOPS = [("mekf", "ideal", "pd", "forward"), ("truth", "wheels", "adaptive", "reverse"),
         ("raw", "saturated", "open_loop", "forward"), ("raw", "wheels", "mrp_feedback", "forward"),
         ("truth", "saturated", "sliding_mode", "forward")]
# the momentum managers beside the wheels, and the environment's torques, in the loops with wheels
MANAGED = {"mrp_feedback": ["momentum.kind='magnetorquers'", "environment.gravity_gradient={}",
                            "environment.aerodynamic={}", "environment.solar_pressure={}", "environment.magnetic={}"],
           "adaptive": ["momentum.kind='thrusters'", "momentum.thrusters.start=1e-3", "momentum.thrusters.stop=0.0"]}
SEEDS = jnp.arange(2)  # trajectory i: seed i, loop i (Setup.loops)
OMEGA0 = jnp.asarray([2e-3, -1e-3, 5e-4])  # a non-zero initial rate: every law has something to do
RTOL, ATOL = 1e-9, 1e-13


def test_every_registered_component_is_flown():
    estimators, actuators, controllers, _ = (set(parts) for parts in zip(*LOOPS))
    assert estimators == set(components.names("estimator")) and actuators == set(components.names("actuator"))
    assert controllers == set(registry.names())
    flown = " ".join(" ".join(overrides) for overrides in MANAGED.values())
    assert all(f"'{name}'" in flown for name in components.names("momentum") if name != "none")
    assert all(f"environment.{name}=" in flown for name in components.names("environment"))


class Setup:
    """A tiny mission's scenario, loop, controller and gains; the loop is closed over by
    the traced functions (as benchmarks/flight.py does), its checks run under the trace."""

    def __init__(self, estimator, actuator, controller, mode):
        overrides = [*TINY, f'estimator.kind="{estimator}"', f'actuator.kind="{actuator}"',
                     f'controllers=["{controller}"]', *MANAGED.get(controller, [])]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", sj.InertiaWarning)
            m = missions.load(None, overrides)
            self.scenario = dataclasses.replace(m.scenario(), Omega0=OMEGA0)
        self.loop = m.loop()
        scaled = lambda path, x: (x * 1.001 if jnp.issubdtype(jnp.asarray(x).dtype, jnp.floating)
                                  and "axes" not in jax.tree_util.keystr(path) else x)  # wheel axes stay unit
        larger = jax.tree_util.tree_map_with_path(scaled, self.loop)
        self.loops = jax.tree.map(lambda a, b: jnp.stack([a, b]), self.loop, larger)  # one per trajectory
        self.controller, self.gains = m.controller(controller)
        self.gains = jax.tree.map(lambda g: jnp.asarray(g, jnp.float64), self.gains)
        self.mode = mode

    def with_omega0(self, omega0):
        return dataclasses.replace(self.scenario, Omega0=omega0)

    def rollout(self, gains, omega0, seed, loop=None):
        return sj.rollout(self.with_omega0(omega0), self.controller, gains, seed, loop=loop or self.loop,
                          record_every=6)

    def transformed(self, gains, omega0, seeds):
        """The jitted program: the rollout under vmap over seeds and loops of its derivative
        (its rmse differentiated in gains and Omega0 by jax.grad or jax.jacfwd, the whole
        Result alongside), and rollout_batch over the same seeds and loops."""

        def rmse(gains, omega0, seed, loop):
            result = self.rollout(gains, omega0, seed, loop)
            return result.metrics.rmse, result

        derivative = (jax.grad if self.mode == "reverse" else jax.jacfwd)(rmse, argnums=(0, 1), has_aux=True)
        grad, mapped = jax.vmap(derivative, in_axes=(None, None, 0, 0))(gains, omega0, seeds, self.loops)
        batch = sj.rollout_batch(self.with_omega0(omega0), self.controller, gains, seeds, scenario_axes=None,
                                 loop=self.loops, loop_axes=0, record_every=6)
        return mapped, grad, batch


@pytest.fixture(scope="module", params=LOOPS, ids=["-".join(parts) for parts in LOOPS])
def flown(request):
    """(setup, un-jitted rollout at seed 0, the compiled program, its outputs)."""
    setup = Setup(*request.param)
    reference = jax.tree.map(np.asarray, setup.rollout(setup.gains, OMEGA0, 0))
    # XLA's backend optimizations and fusion emitters off: about a third of the compile time
    # of this large program, the same values to round-off (what the comparisons allow between
    # differently fused programs)
    program = fast_jit(setup.transformed, setup.gains, OMEGA0, SEEDS)
    outputs = jax.tree.map(np.asarray, program(setup.gains, OMEGA0, SEEDS))
    return setup, reference, program, outputs


def first(tree, i=0):
    return jax.tree.map(lambda x: x[i], tree)


def assert_trees_close(a, b, rtol=RTOL, atol=ATOL):
    leaves_a, tree_a = jax.tree.flatten(a)
    leaves_b, tree_b = jax.tree.flatten(b)
    assert tree_a == tree_b
    for x, y in zip(leaves_a, leaves_b):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=rtol, atol=atol, equal_nan=True)


def assert_finite(result):
    m = result.metrics
    for leaf in jax.tree.leaves((m.rmse, m.effort, result.final, result.flight.command_effort)):
        assert np.all(np.isfinite(leaf))


def test_the_reference_flies_the_whole_loop(flown):
    setup, reference, _, _ = flown
    assert_finite(reference)
    assert not bool(reference.metrics.diverged)
    assert reference.history.t.shape == (1,)  # one block of 6 steps: 3 ticks of 2 steps
    if setup.loop.period_steps is not None:
        assert setup.loop.period_steps == 2 and setup.scenario.n_steps == 6


def test_jit_and_vmap_equal_the_unjitted_rollout(flown):
    _, reference, _, (mapped, _, _) = flown
    assert_finite(first(mapped))
    assert_trees_close(first(mapped), reference)
    assert not np.array_equal(mapped.metrics.rmse[0], mapped.metrics.rmse[1])  # the seeds draw different noise


def test_simulate_equals_the_unjitted_rollout_and_vmap(flown):
    """simulate (jitted inside) at seed 0 against the un-jitted rollout, at seed 1 with the
    second loop (the same compiled program) against the vmapped rollout's second
    trajectory; in the loops with wheels (simulate is rollout under jit: its own
    compilation per loop)."""
    setup, reference, _, (mapped, _, _) = flown
    if not isinstance(setup.loop.actuator, sj.Wheels):
        pytest.skip("simulate is checked in the loops with wheels")
    simulate = lambda seed: jax.tree.map(np.asarray, sj.simulate(setup.scenario, setup.controller, setup.gains, seed,
                                                                 loop=first(setup.loops, seed), record_every=6))
    assert_trees_close(simulate(0), reference)
    assert_trees_close(simulate(1), first(mapped, 1))


def test_rollout_batch_equals_vmap(flown):
    """Each trajectory with its own loop: natively batched (the components' parameters with
    a batch axis) as vmapped."""
    _, _, _, (mapped, _, batch) = flown
    assert_finite(first(batch))
    for part in ("metrics", "final", "flight", "history"):
        assert_trees_close(getattr(batch, part), getattr(mapped, part), rtol=1e-12, atol=1e-15)


def test_grad_is_finite_and_matches_central_differences(flown):
    """The gradient in (gains, Omega0), seed by seed, against central differences of the
    jitted rollout (the same program at other inputs: nothing compiles again)."""
    setup, _, program, (_, grad, _) = flown
    assert all(np.all(np.isfinite(g)) for g in jax.tree.leaves(grad))
    rmse = lambda gains, omega0: program(gains, omega0, SEEDS)[0].metrics.rmse  # (seeds,)
    gains_grad, omega_grad = grad
    for i in range(3):
        h = 1e-4 * abs(float(OMEGA0[i]))
        e = jnp.zeros(3).at[i].set(h)
        fd = (rmse(setup.gains, OMEGA0 + e) - rmse(setup.gains, OMEGA0 - e)) / (2 * h)
        np.testing.assert_allclose(omega_grad[:, i], fd, rtol=1e-6)
    for name, value in setup.gains._asdict().items():
        h = 1e-4 * float(value) if float(value) != 0 else 1e-8  # a gain at 0 (mrp_feedback's K_i)
        bump = lambda s: setup.gains._replace(**{name: value + s * h})
        fd = (rmse(bump(1.0), OMEGA0) - rmse(bump(-1.0), OMEGA0)) / (2 * h)
        np.testing.assert_allclose(getattr(gains_grad, name), fd, rtol=1e-4)  # Gamma's is ~1e-18: FD noise
    assert np.all(np.abs(omega_grad) > 0)


def test_checks_under_tracing_read_no_traced_value():
    """Every component's check and the loop's check run under jit (shapes and static
    data only): building the programs above traced them; here the wheel inertia check,
    which reads the scenario's inertias, with the wheels' parameters traced."""
    setup = Setup("truth", "wheels", "adaptive", "forward")
    wheels = setup.loop.actuator

    def rmse_of_spin(spin):
        loop = dataclasses.replace(setup.loop, actuator=dataclasses.replace(wheels, spin_inertia=spin))
        return sj.rollout(setup.scenario, setup.controller, setup.gains, 0, loop=loop).metrics.rmse

    assert jax.eval_shape(jax.jit(rmse_of_spin), jnp.asarray(wheels.spin_inertia)).shape == ()
    bad = dataclasses.replace(wheels, spin_inertia=jnp.full(4, 1e4))
    with pytest.raises(ValueError, match="minus the wheels' spin inertia"):
        sj.rollout(setup.scenario, setup.controller, setup.gains, 0, loop=dataclasses.replace(setup.loop, actuator=bad))
