"""The Numba baseline of the dispersed sweep (benchmarks/baselines/numba_dispersed.py) computes
the metrics so3jax's sweep computes, sample by sample: eight samples of the default sweep
(sweeps/default.toml) over T = 510 s, so phases 0 and 1 (from t = 500 s) both count, for
both controllers, to 1e-12 relative. With every sample the paper's nominal scenario, it is
numba_loop's closed loop."""

import functools
import warnings

import jax
import numpy as np
import pytest

pytest.importorskip("numba")

from benchmarks.baselines import numba_loop  # noqa: E402
from benchmarks.baselines.numba_dispersed import FIELDS, simulate_dispersed  # noqa: E402
from benchmarks.baselines.numpy_loop import J0, J1, J2, ORBITAL_RATE  # noqa: E402
from so3jax.dynamics.inertia import InertiaWarning  # noqa: E402
from so3jax.dynamics.scenario import steps_for_horizon  # noqa: E402
from so3jax.jobs import sweep  # noqa: E402
from so3jax.missions import batched, draw

T = 510.0  # s: across the first phase switch (500 s)
N_SAMPLES = 8
CONTROLLERS = ["pd", "adaptive"]


@pytest.fixture(scope="module")
def sweep_samples():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InertiaWarning)
        config = sweep.load_config(None, (f"T={T}",))
    assert not np.any(config.mission.initial["attitude"]) and not np.any(config.mission.initial["rate"])
    samples = draw.draw(config.dispersions, config.leaves, config.seed, N_SAMPLES, config.max_draws)
    assert samples.valid.all() and not samples.leaves
    return config, samples


@pytest.mark.parametrize("controller", CONTROLLERS)
def test_matches_so3jax_sweep_metrics(sweep_samples, controller):
    config, samples = sweep_samples
    gains = jax.tree.map(lambda g: np.asarray(g, np.float64), config.gains[controller])
    run = functools.partial(batched.sample_metrics, controller=config.mission.controller(controller)[0],
                            mission=config.mission)
    ours = {k: np.asarray(v) for k, v in jax.jit(run)(batched.inputs(samples, np.float64), gains).items()}
    theirs = simulate_dispersed(controller, samples.params, steps_for_horizon(config.T, config.dt), dt=config.dt,
                                gains=config.gains[controller])
    assert sorted(theirs) == sorted(ours)
    for key, expected in ours.items():
        got = theirs[key]
        assert got.shape == expected.shape and got.dtype == expected.dtype, key
        if key == "diverged":
            assert not expected.any() and not got.any()
        elif key == "orthogonality_error":  # round-off: |R^T R - I|_F ~ 1e-14
            assert np.all(expected < 1e-12) and np.all(got < 1e-12)
        else:
            assert np.isfinite(expected).all() and np.isfinite(got).all(), key
            np.testing.assert_allclose(got, expected, rtol=1e-12, atol=0, err_msg=key)
    assert np.all(ours["rmse_phase"][:, :2] > 0) and np.all(ours["rmse_phase"][:, 2] == 0)  # phases 0 and 1 flown
    assert np.ptp(ours["rmse"]) > 0.01 * ours["rmse"].mean()  # the samples differ


@pytest.mark.parametrize("controller", CONTROLLERS)
def test_nominal_samples_are_numba_loop(controller):
    """Every sample the paper's scenario: numba_loop's results (its R_d(t) is formed otherwise)."""
    seeds = [3, 8]
    B, n_steps = len(seeds), 50_200
    nominal = {"J0": J0, "J1": J1, "J2": J2, "tau_J": 300.0, "n": ORBITAL_RATE, "amplitude": 0.1,
               "frequency": 0.001, "noise_std": 0.025, "R0": np.eye(3), "Omega0": np.zeros(3)}  # fmt: skip
    samples = {k: np.broadcast_to(np.asarray(v, np.float64), (B, *np.shape(v))) for k, v in nominal.items()}
    ours = simulate_dispersed(controller, {**samples, "seed": np.array(seeds, np.int32)}, n_steps)
    theirs = numba_loop.simulate(controller, n_steps, seeds, noise="draw")
    names = {"rms_angle_phase": "angle_rms_phase", "max_angle_phase": "angle_max_phase"}
    for key in ("rmse", "rmse_unrotated", "effort", "max_torque", "rmse_phase", "effort_phase", "max_torque_phase",
                "rms_angle_phase", "max_angle_phase"):
        expected = np.nan_to_num(theirs[names.get(key, key)], nan=0.0)  # a phase not reached: NaN there, 0 here
        np.testing.assert_allclose(ours[key], expected, rtol=1e-12, atol=0, err_msg=key)
    np.testing.assert_array_equal(ours["diverged"], theirs["diverged"])


def test_bad_samples():
    with pytest.raises(ValueError, match="fields"):
        simulate_dispersed("pd", {"J0": np.zeros((1, 3, 3))}, 10)
    fields = {name: np.zeros(2) for name in FIELDS}
    with pytest.raises(ValueError, match="J0"):
        simulate_dispersed("pd", fields, 10)
