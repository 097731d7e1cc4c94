"""The two benchmark baselines (NumPy loop, Numba scalar) compute the same closed loop.

Both implement docs/model.md §3-§6 independently; here they must agree to 1e-10 (relative) at
the paper's dt, and across both phase switches at a coarse dt. The Numba baseline is
also checked alone at the paper's dt across the first switch (t = 500 s) and over the
full mission for the SO(3) drift bound of docs/model.md §5.
"""

import jax
import numpy as np
import pytest

from benchmarks.baselines import numpy_loop
from benchmarks.baselines.noise import paper_noise, paper_noise_batch

SEEDS = [0, 1, 2]
CONTROLLERS = ["pd", "adaptive"]
METRICS = ["rmse", "rmse_unrotated", "effort", "rmse_phase", "effort_phase", "max_torque",
           "max_torque_phase", "angle_rms_phase", "angle_max_phase", "R", "Omega", "Theta"]  # fmt: skip


@pytest.fixture(scope="module")
def numba_loop():
    return pytest.importorskip("benchmarks.baselines.numba_loop", reason="numba is not installed")


def assert_results_close(a, b, rtol=1e-10):
    """Every metric and final state equal to rtol, relative to each array's largest entry."""
    for key in METRICS:
        if b[key] is None:
            assert a[key] is None, key
            continue
        scale = np.nanmax(np.abs(b[key])) if np.isfinite(b[key]).any() else 0.0
        np.testing.assert_allclose(a[key], b[key], rtol=rtol, atol=rtol * scale, err_msg=key)
    assert not a["diverged"].any() and not b["diverged"].any()


def test_noise_is_the_spec_recipe():
    eta = paper_noise_batch([3, 11], 50)
    assert eta.shape == (2, 50, 3) and eta.dtype == np.float64
    np.testing.assert_array_equal(eta[1], paper_noise(11, 50))
    with jax.enable_x64(True):
        for k in (0, 1, 49):
            key = jax.random.fold_in(jax.random.key(3), k)
            np.testing.assert_array_equal(eta[0, k], jax.random.normal(key, (3,), np.float64))
    assert paper_noise(3, 5, np.float32).dtype == np.float32


@pytest.mark.parametrize("controller", CONTROLLERS)
def test_numpy_and_numba_agree_at_paper_dt(numba_loop, controller):
    n_steps = 2000
    noise = paper_noise_batch(SEEDS, n_steps)
    scale = np.array([1.0, 0.7, 1.6])
    a = numpy_loop.simulate(controller, n_steps, SEEDS, noise=noise, inertia_scale=scale)
    b = numba_loop.simulate(controller, n_steps, SEEDS, noise=noise, inertia_scale=scale)
    assert_results_close(b, a)
    assert (a["Theta"] is None) == (controller == "pd")


@pytest.mark.parametrize("controller", CONTROLLERS)
def test_numpy_and_numba_agree_across_both_switches(numba_loop, controller):
    """dt = 1 s: K1 = 500, K2 = 2600, so 2700 steps visit all three phases."""
    a = numpy_loop.simulate(controller, 2700, SEEDS[:2], dt=1.0)
    b = numba_loop.simulate(controller, 2700, SEEDS[:2], dt=1.0)
    assert_results_close(b, a)
    assert np.isfinite(a["rmse_phase"]).all()


@pytest.mark.parametrize("controller", CONTROLLERS)
def test_numba_across_first_switch_at_paper_dt(numba_loop, controller):
    """Phase sums are step-indexed (a longer run has the same phase-0 metrics) and add up."""
    k1 = 50_000
    noise = paper_noise_batch(SEEDS, k1 + 200)
    short = numba_loop.simulate(controller, k1, SEEDS, noise=noise[:, :k1])
    long = numba_loop.simulate(controller, k1 + 200, SEEDS, noise=noise)
    for key in ("rmse_phase", "effort_phase", "angle_rms_phase", "angle_max_phase", "max_torque_phase"):
        np.testing.assert_array_equal(long[key][:, 0], short[key][:, 0], err_msg=key)
    assert np.isnan(short["rmse_phase"][:, 1]).all() and np.isfinite(long["rmse_phase"][:, 1]).all()
    np.testing.assert_allclose(long["effort"], long["effort_phase"][:, :2].sum(axis=1), rtol=1e-14)
    np.testing.assert_allclose(
        long["rmse"] ** 2 * (k1 + 200),
        long["rmse_phase"][:, 0] ** 2 * k1 + long["rmse_phase"][:, 1] ** 2 * 200,
        rtol=1e-12,
    )


@pytest.mark.parametrize("controller", CONTROLLERS)
def test_numba_full_mission_stays_on_so3(numba_loop, controller):
    """docs/model.md §5: ||R^T R - I||_F < 1e-12 after N = 400 000 steps in float64."""
    r = numba_loop.simulate(controller, 400_000, [0])
    R = r["R"][0]
    assert np.linalg.norm(R.T @ R - np.eye(3)) < 1e-12
    assert np.isfinite(r["rmse_phase"]).all() and not r["diverged"].any()


def test_bad_arguments():
    with pytest.raises(ValueError, match="controller"):
        numpy_loop.simulate("pid", 10, [0])
    with pytest.raises(ValueError, match="unknown gains"):
        numpy_loop.simulate("pd", 10, [0], gains={"K_r": 1.0})
    with pytest.raises(ValueError, match="positive"):
        numpy_loop.simulate("adaptive", 10, [0], gains={"Gamma": -1.0})
    with pytest.raises(ValueError, match="noise"):
        numpy_loop.simulate("pd", 10, [0], noise=np.zeros((1, 9, 3)))


def test_numba_is_float64_only(numba_loop):
    with pytest.raises(ValueError, match="float64"):
        numba_loop.simulate("pd", 10, [0], dtype=np.float32)


def test_divergence_is_flagged(numba_loop):
    """k_Omega dt / J far beyond RK4's stability bound: non-finite state, flagged per element."""
    for module in (numpy_loop, numba_loop):
        r = module.simulate("pd", 50, [0, 1], gains={"k_Omega": 1e9})
        assert r["diverged"].all(), module.__name__
