"""The time terms a natively batched step computes once per step (so3jax.dynamics.stepped) against
the reference and inertia evaluated at each stage time, in every phase."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import so3jax as sj
from so3jax.dynamics import stepped
from so3jax.dynamics.plant import ConstantInertia
from so3jax.jobs import sweep
from so3jax.missions import batched, build, draw
from so3jax.sim.rollout import _batch_last


@pytest.fixture(scope="module")
def batch():
    """Four samples of the default sweep as one scenario, batch axis last."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sj.InertiaWarning)
        config = sweep.load_config(None, ("T=3000.0",))
        samples = draw.draw(config.dispersions, config.leaves, config.seed, 4, config.max_draws)
    params, _ = batched.inputs(samples, np.float64)
    scenarios = jax.vmap(lambda p: build.scenario(config.mission, p))(params)
    return scenarios, _batch_last(scenarios, 0)


@pytest.mark.parametrize("t", [120.0, 1234.5, 2900.0])  # phases 0, 1, 2
def test_stage_terms_equal_the_stagewise_evaluation(batch, t):
    scenarios, scenario = batch
    consts = stepped.constants(scenario)
    p = sum(t >= x for x in (500.0, 2600.0))
    h = scenario.dt
    terms = stepped.stage_terms(scenario, consts, jnp.asarray(t), jnp.asarray(p), with_inverse=True)
    for c, term in zip((0.0, 0.5, 1.0), terms):
        for i in range(4):  # each sample, evaluated as one trajectory would
            one = jax.tree.map(lambda x, i=i: x[i], scenarios)
            R_d = one.reference.attitude(t + c * h, p)
            J = one.inertia(t + c * h, p)
            # the closed form's own round-off at angles of ~10 rad
            np.testing.assert_allclose(term.R_d[..., i], R_d, rtol=0, atol=1e-14)
            np.testing.assert_allclose(term.J[..., i], J, rtol=1e-15)
            np.testing.assert_allclose(term.J_inv[..., i], np.linalg.inv(J), rtol=1e-13)


def test_constant_inertia_and_shared_scenarios(batch):
    _, scenario = batch
    constant = scenario.__class__(**{**scenario.__dict__, "inertia": ConstantInertia(scenario.inertia.J2)})
    terms = stepped.stage_terms(constant, stepped.constants(constant), jnp.asarray(3.0), jnp.asarray(0), True)
    for term in terms:
        np.testing.assert_array_equal(term.J, scenario.inertia.J2)
        np.testing.assert_allclose(jnp.einsum("ijb,jkb->ikb", term.J, term.J_inv),
                                   np.broadcast_to(np.eye(3)[..., None], (3, 3, 4)), atol=1e-15)
    shared = jax.tree.map(lambda x: x[..., :1], scenario)  # one scenario for the whole batch
    assert stepped.constants(shared) is None
