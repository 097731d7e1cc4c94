"""so3jax against the independent NumPy implementation of docs/model.md §3-§6 (benchmarks/baselines)."""

import warnings

import jax.numpy as jnp
import numpy as np
import pytest

import so3jax as sj
from benchmarks.baselines import numpy_loop

SEEDS = [0, 7]


@pytest.mark.parametrize("name", ["pd", "adaptive"])
def test_so3jax_matches_the_numpy_baseline(name):
    n_steps = 600
    controller, gains = {"pd": (sj.geometric_pd(), sj.PAPER_PD_GAINS),
                         "adaptive": (sj.adaptive_backstepping(), sj.PAPER_ADAPTIVE_GAINS)}[name]
    scenario = sj.paper_scenario(T=n_steps * 0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sj.InertiaWarning)
        ours = [sj.simulate(scenario, controller, gains, seed) for seed in SEEDS]
    theirs = numpy_loop.simulate(name, n_steps, SEEDS)
    for i, r in enumerate(ours):
        np.testing.assert_allclose(r.metrics.rmse, theirs["rmse"][i], rtol=1e-10)
        np.testing.assert_allclose(r.metrics.effort, theirs["effort"][i], rtol=1e-10)
        np.testing.assert_allclose(r.metrics.max_torque, theirs["max_torque"][i], rtol=1e-10)
        np.testing.assert_allclose(r.final.R, theirs["R"][i], atol=1e-13)
        np.testing.assert_allclose(r.final.Omega, theirs["Omega"][i], rtol=1e-9, atol=1e-15)
        if name == "adaptive":
            np.testing.assert_allclose(jnp.asarray(r.final.controller), theirs["Theta"][i], rtol=1e-9,
                                       atol=1e-12 * np.abs(theirs["Theta"][i]).max())
