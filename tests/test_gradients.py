"""Gradients of the docs/model.md §6 tuning cost through whole rollouts, against central finite
differences in float64, in both differentiation modes.

Short horizons (T = 20 s) keep the default run fast; the shapes match tests/test_tune.py
so the compiled functions are shared. The full-mission checks (minutes of compilation
each) are marked slow.
"""

import dataclasses
import warnings

import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

from so3jax.dynamics.inertia import InertiaWarning
from so3jax.dynamics.scenario import paper_scenario
from so3jax.jobs import tune
from so3jax.sim import gradients

T_SHORT = 20.0
TRAIN = {"inertia_scales": [1.0], "seeds": [0, 1]}  # B = 2, as in test_tune.py


def scenario(T=T_SHORT):
    return paper_scenario(T=T)


def batch():
    return gradients.make_batch(TRAIN["inertia_scales"], TRAIN["seeds"], jnp.float64)


def f64(x):
    """As tune builds its arrays: float64, not weakly typed (same jit cache entries)."""
    return jnp.asarray(x, jnp.float64)


def refs():
    return tune.CostRefs(f64(1e-3), f64(1.0), f64(0.5))


def fd_gradient(controller, params, sc, b, r, mode="weighted", h=1e-4):
    """Central differences of the batch cost in each log-gain (2 x n forward rollouts)."""
    flat, unravel = ravel_pytree(params)

    def cost(x):
        metrics = tune.batch_cost_metrics(sc, tune.CONTROLLERS[controller], tune.to_gains(unravel(x)), b, None)
        return float(jnp.mean(tune.scenario_costs(metrics, r, mode)))

    steps = np.eye(flat.size) * h
    return np.array([(cost(flat + e) - cost(flat - e)) / (2 * h) for e in steps])


def relative_error(a, b):
    return float(np.linalg.norm(np.asarray(a) - np.asarray(b)) / np.linalg.norm(np.asarray(b)))


@pytest.fixture(scope="module")
def pd_case():
    params = tune.to_params(tune.resolve_gains("pd", "paper", jnp.float64))
    sc, b, r = scenario(), batch(), refs()
    return params, sc, b, r, fd_gradient("pd", params, sc, b, r)


@pytest.mark.parametrize("mode", gradients.MODES)
def test_pd_gradient_matches_central_differences(pd_case, mode):
    params, sc, b, r, fd = pd_case
    evaluation, grad = tune.cost_and_grad(params, sc, tune.CONTROLLERS["pd"], b, r, "weighted", mode, None)
    grad = ravel_pytree(grad)[0]
    assert np.all(np.isfinite(grad))
    assert relative_error(grad, fd) < 1e-4
    # the value returned with the gradient is the cost itself
    metrics = tune.batch_cost_metrics(sc, tune.CONTROLLERS["pd"], tune.to_gains(params), b, None)
    assert float(evaluation.cost) == pytest.approx(
        float(jnp.mean(tune.scenario_costs(metrics, r, "weighted"))), rel=1e-12
    )


def test_adaptive_gradient_matches_central_differences():
    """K_r, K_w and a scalar Gamma; equal-effort cost with the penalty active."""
    params = tune.to_params(tune.resolve_gains("adaptive", "paper", jnp.float64))
    sc, b = scenario(), batch()
    metrics = tune.batch_cost_metrics(sc, tune.CONTROLLERS["adaptive"], tune.to_gains(params), b, None)
    r = tune.CostRefs(f64(1e-3), 0.8 * metrics.effort, f64(10.0))  # budget below the effort
    _, grad = tune.cost_and_grad(params, sc, tune.CONTROLLERS["adaptive"], b, r, "equal_effort", "forward", None)
    grad = ravel_pytree(grad)[0]
    fd = fd_gradient("adaptive", params, sc, b, r, "equal_effort")
    assert relative_error(grad, fd) < 1e-4
    assert all(abs(g - f) <= 1e-4 * abs(f) + 1e-9 for g, f in zip(grad, fd))


def test_batch_is_the_product_of_inertias_and_seeds():
    b = gradients.make_batch([0.9, 1.1], [3, 4, 5], jnp.float64)
    assert b.inertia_scale.tolist() == [0.9, 0.9, 0.9, 1.1, 1.1, 1.1]
    assert b.seed.tolist() == [3, 4, 5, 3, 4, 5]
    scaled = gradients.scale_inertia(scenario(), 2.0)
    np.testing.assert_allclose(scaled.inertia.J2, 2.0 * scenario().inertia.J2)
    assert scaled.inertia.t_deploy == scenario().inertia.t_deploy


def test_unknown_mode_is_rejected():
    with pytest.raises(ValueError, match="gradient mode"):
        gradients.value_and_grad(lambda p: (p, ()), "sideways")


@pytest.mark.slow
def test_full_mission_gradients_match_central_differences():
    """N = 400 000 steps, both controllers, forward mode; the PD in reverse mode too."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InertiaWarning)
        sc = scenario(4000.0)
    b = gradients.make_batch([1.0], [0], jnp.float64)
    r = refs()
    for controller, modes in (("pd", ("forward", "reverse")), ("adaptive", ("forward",))):
        params = tune.to_params(tune.resolve_gains(controller, "paper", jnp.float64))
        fd = fd_gradient(controller, params, sc, b, r)
        for mode in modes:
            _, grad = tune.cost_and_grad(params, sc, tune.CONTROLLERS[controller], b, r, "weighted", mode, None)
            assert relative_error(ravel_pytree(grad)[0], fd) < 1e-4, (controller, mode)


@pytest.mark.slow
def test_diagonal_gamma_gradient_sums_to_the_scalar_one():
    """With all nine entries equal, d cost / d log Gamma = sum of the diagonal's gradients."""
    sc, b, r = scenario(), batch(), refs()
    scalar = tune.to_params(tune.resolve_gains("adaptive", "paper", jnp.float64))
    diagonal = tune.to_params(tune.resolve_gains("adaptive", "paper", jnp.float64, diagonal_gamma=True))
    _, g_scalar = tune.cost_and_grad(scalar, sc, tune.CONTROLLERS["adaptive"], b, r, "weighted", "forward", None)
    _, g_diag = tune.cost_and_grad(diagonal, sc, tune.CONTROLLERS["adaptive"], b, r, "weighted", "reverse", None)
    assert g_diag.Gamma.shape == (9,)
    np.testing.assert_allclose(jnp.sum(g_diag.Gamma), g_scalar.Gamma, rtol=1e-6)
    np.testing.assert_allclose([g_diag.K_r, g_diag.K_w], [g_scalar.K_r, g_scalar.K_w], rtol=1e-6)


@pytest.mark.slow
def test_reverse_mode_memory_grows_sublinearly_with_the_horizon():
    """XLA's own accounting of the compiled gradient: temporaries for N and 16 N steps."""
    params = tune.to_params(tune.resolve_gains("pd", "paper", jnp.float64))
    sizes = []
    for T in (100.0, 1600.0):
        sc = dataclasses.replace(scenario(), n_steps=round(T / 0.01))
        compiled = tune.cost_and_grad.lower(
            params, sc, tune.CONTROLLERS["pd"], batch(), refs(), "weighted", "reverse", None
        ).compile()
        sizes.append(compiled.memory_analysis().temp_size_in_bytes)
    assert sizes[1] < 6 * sizes[0], sizes  # sqrt(16) = 4; linear growth would be 16
