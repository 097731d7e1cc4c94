"""Bad input gets a clear ValueError naming the field, before anything compiles (SPEC 6)."""

import dataclasses
import importlib
import warnings

import jax.numpy as jnp
import numpy as np
import pytest

import so3jax as sj
from so3jax.scenario import check_inertia

pytestmark = pytest.mark.filterwarnings("ignore::so3jax.scenario.InertiaWarning")
rollout_module = importlib.import_module("so3jax.rollout")  # the package re-exports a function of that name
GOOD = sj.paper_scenario(T=1.0)


@pytest.fixture(autouse=True)
def no_compilation(monkeypatch):
    """Any call that reaches the jitted rollout fails the test."""

    def compiled(*args, **kwargs):
        raise AssertionError("reached compilation")

    monkeypatch.setattr(rollout_module, "_simulate_jit", compiled)


def with_inertia(**matrices):
    return dataclasses.replace(GOOD, inertia=dataclasses.replace(GOOD.inertia, **{k: jnp.asarray(v) for k, v in matrices.items()}))


J_OK = np.diag([100.0, 120.0, 150.0])


@pytest.mark.parametrize(
    "scenario,match",
    [
        (with_inertia(J2=J_OK + np.triu(np.ones((3, 3)), 1)), "inertia J2 is not symmetric"),
        (with_inertia(J0=np.diag([100.0, -1.0, 150.0])), "inertia J0 is not positive definite"),
        (with_inertia(J1=np.diag([100.0, 0.0, 150.0])), "inertia J1 is not positive definite"),
        (with_inertia(J0=np.full((3, 3), np.nan)), "inertia J0 has non-finite"),
        (dataclasses.replace(GOOD, dt=0.0), "dt must be positive"),
        (dataclasses.replace(GOOD, dt=-0.01), "dt must be positive"),
        (dataclasses.replace(GOOD, R0=2 * jnp.eye(3)), "R0 is not a rotation"),
    ],
)
def test_bad_scenarios(scenario, match):
    with pytest.raises(ValueError, match=match):
        sj.simulate(scenario, sj.geometric_pd(), sj.PAPER_PD_GAINS)


@pytest.mark.parametrize(
    "controller,gains,match",
    [
        (sj.geometric_pd(), sj.PDGains(-1.0, 25.0), "gain k_R must be positive"),
        (sj.geometric_pd(), sj.PDGains(0.5, 0.0), "gain k_Omega must be positive"),
        (sj.geometric_pd(), sj.PDGains(np.inf, 25.0), "gain k_R must be finite"),
        (sj.adaptive_backstepping(), sj.AdaptiveGains(0.005, np.nan, 1e8), "gain K_w must be finite"),
        (sj.adaptive_backstepping(), sj.AdaptiveGains(0.005, 75.0, -1e8), "gain Gamma must be positive"),
        (sj.adaptive_backstepping(), sj.AdaptiveGains(0.005, 75.0, np.r_[np.ones(8), -1.0]), "gain Gamma must be positive"),
        (sj.adaptive_backstepping(), sj.AdaptiveGains(0.005, 75.0, np.diag(np.r_[np.ones(8), -1.0])), "Gamma is not positive definite"),
        (sj.adaptive_backstepping(), sj.AdaptiveGains(0.005, 75.0, np.eye(9) + np.eye(9, k=1)), "Gamma is not symmetric"),
        (sj.adaptive_backstepping(), sj.AdaptiveGains(0.005, 75.0, np.eye(4)), "Gamma must be a scalar"),
    ],
)
def test_bad_gains(controller, gains, match):
    with pytest.raises(ValueError, match=match):
        sj.simulate(sj.paper_scenario(T=1.0, J0=J_OK, J2=J_OK), controller, gains)


@pytest.mark.parametrize(
    "T,dt,match",
    [(1.0, 0.0, "dt must be a positive"), (1.0, -0.1, "dt must be a positive"), (1.005, 0.01, "not a multiple of dt"),
     (0.0, 0.01, "T \\(horizon\\) must be"), (float("nan"), 0.01, "T \\(horizon\\) must be")],
)
def test_bad_horizons(T, dt, match):
    with pytest.raises(ValueError, match=match):
        sj.paper_scenario(T=T, dt=dt)


def test_horizon_tolerance_is_relative():
    assert sj.steps_for_horizon(4000.0, 0.01) == 400_000
    assert sj.steps_for_horizon(0.3, 0.1) == 3  # 0.3 / 0.1 = 2.9999999999999996


def test_bad_log_derivative_and_record_every():
    with pytest.raises(ValueError, match="log_derivative"):
        sj.adaptive_backstepping(log_derivative="approximate")
    with pytest.raises(ValueError, match="record_every"):
        sj.simulate(GOOD, sj.geometric_pd(), sj.PAPER_PD_GAINS, record_every=0)


def test_paper_inertia_warns_but_is_accepted():
    with pytest.warns(sj.InertiaWarning, match="J0 breaks the triangle inequality"):
        check_inertia("J0", np.asarray(GOOD.inertia.J0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_inertia("J2", np.asarray(GOOD.inertia.J2))  # the docked body is physical
