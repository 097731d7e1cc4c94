"""Bad input gets a clear ValueError naming the field, before anything compiles (docs/model.md §6)."""

import dataclasses
import importlib
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import so3jax as sj
from so3jax.dynamics.inertia import check_inertia, is_paper_inertia
from so3jax.dynamics.scenario import check_scenario

pytestmark = pytest.mark.filterwarnings("ignore::so3jax.dynamics.inertia.InertiaWarning")
rollout_module = importlib.import_module("so3jax.sim.rollout")  # the package re-exports a function of that name
GOOD = sj.paper_scenario(T=1.0)


@pytest.fixture(autouse=True)
def no_compilation(monkeypatch):
    """Any call that reaches the jitted rollout fails the test."""

    def compiled(*args, **kwargs):
        raise AssertionError("reached compilation")

    monkeypatch.setattr(rollout_module, "_simulate_jit", compiled)


def with_inertia(**matrices):
    return dataclasses.replace(GOOD, inertia=dataclasses.replace(GOOD.inertia,
                                                                 **{k: jnp.asarray(v) for k, v in matrices.items()}))


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
        (sj.adaptive_backstepping(), sj.AdaptiveGains(0.005, 75.0, np.r_[np.ones(8), -1.0]),
         "gain Gamma must be positive"),
        (sj.adaptive_backstepping(), sj.AdaptiveGains(0.005, 75.0, np.diag(np.r_[np.ones(8), -1.0])),
         "Gamma is not positive definite"),
        (sj.adaptive_backstepping(), sj.AdaptiveGains(0.005, 75.0, np.eye(9) + np.eye(9, k=1)),
         "Gamma is not symmetric"),
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


def test_a_users_unphysical_inertia_warns_the_papers_do_not():
    """The paper's J0 and J1 = 2 J0 break the triangle inequality as the paper gives them: no
    warning for those; the same kind of matrix from a user warns, and is accepted."""
    J0 = np.asarray(GOOD.inertia.J0)
    assert not check_inertia("J0", J0, warn=False) and is_paper_inertia(J0) and is_paper_inertia(2.0 * J0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_inertia("J0", J0)
        check_inertia("J1", 2.0 * J0)
        check_inertia("J2", np.asarray(GOOD.inertia.J2))  # the docked body is physical
        check_scenario(sj.paper_scenario(T=10.0))
    mine = J0.copy()
    mine[2, 2] += 1.0
    assert not is_paper_inertia(mine)
    with pytest.warns(sj.InertiaWarning, match="J0 breaks the triangle inequality"):
        check_inertia("J0", mine)


# --- every inertia the run will use ---------------------------------------------------


@pytest.fixture
def no_tracing(monkeypatch):
    """Any call that reaches the unchecked rollout (tracing) fails the test."""

    def traced(*args, **kwargs):
        raise AssertionError("reached tracing")

    monkeypatch.setattr(rollout_module, "_rollout", traced)


def with_profile(fn):
    return dataclasses.replace(GOOD, inertia=sj.InertiaFunction(fn), n_steps=1000)  # T = 10 s, phases at 500, 2600 s


@pytest.mark.parametrize(
    "fn,match",
    [
        (lambda t: jnp.asarray(J_OK) * (1.0 - t / 5.0),
         "J\\(t\\) of phase 1 of 3 \\(from t = 0 s\\) is not positive definite"),
        (lambda t: -jnp.asarray(J_OK), "J\\(t\\) of phase 1 of 3 .* not positive definite"),
        (lambda t: jnp.asarray(J_OK) + jnp.triu(jnp.ones((3, 3)), 1), "J\\(t\\) of phase 1 of 3 .* not symmetric"),
        (lambda t: jnp.ones((2, 3)), "J\\(t\\) of phase 1 of 3 .* must be a \\(3, 3\\) matrix"),
    ],
)
def test_a_user_inertia_law_is_checked_over_the_horizon(fn, match, no_tracing):
    scenario = with_profile(fn)
    with pytest.raises(ValueError, match=match):
        sj.simulate(scenario, sj.geometric_pd(), sj.PAPER_PD_GAINS)
    with pytest.raises(ValueError, match=match):
        sj.rollout(scenario, sj.geometric_pd(), sj.PAPER_PD_GAINS, 0)


def test_an_unphysical_user_inertia_law_warns_once():
    scenario = with_profile(lambda t: jnp.diag(jnp.asarray([100.0, 120.0, 300.0])) + 0.0 * t)
    with pytest.warns(sj.InertiaWarning, match="J\\(t\\) of phase 1 of 3 .* breaks the triangle inequality") as record:
        rollout_module.check_inputs(scenario, sj.geometric_pd(), sj.PAPER_PD_GAINS, sj.PAPER_LOOP, None)
    assert len(record) == 1 and "check the matrix" in str(record[0].message)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rollout_module.check_inputs(with_profile(lambda t: jnp.asarray(J_OK) * (1.0 + t)), sj.geometric_pd(),
                                    sj.PAPER_PD_GAINS, sj.PAPER_LOOP, None)


@pytest.mark.parametrize("tau_J", [-50.0, 0.0, float("nan")])
def test_the_deployment_time_constant_must_be_positive(tau_J):
    with pytest.raises(ValueError, match="tau_J .* must be a positive number of seconds"):
        sj.paper_scenario(T=1.0, tau_J=tau_J)
    scenario = dataclasses.replace(GOOD, inertia=dataclasses.replace(GOOD.inertia, tau_J=jnp.asarray(tau_J)))
    with pytest.raises(ValueError, match="tau_J"):
        sj.simulate(scenario, sj.geometric_pd(), sj.PAPER_PD_GAINS)


def test_the_deployment_blend_is_checked_from_its_first_step():
    """Phase 2 moved to t = 1 s while the blend starts at t_deploy = 500 s: J(t) there
    extrapolates far beyond J0 (w = exp(499 / 300)), which the phase endpoints J0, J1
    alone would not show."""
    scenario = dataclasses.replace(sj.paper_scenario(T=3.0), phase_times=(1.0, 2.0))
    with pytest.raises(ValueError, match="J\\(t\\) of phase 2 of 3 \\(from t = 1 s\\) is not positive definite"):
        sj.simulate(scenario, sj.geometric_pd(), sj.PAPER_PD_GAINS)


def test_paper_scenario_checks_its_inertias_when_built():
    with pytest.raises(ValueError, match="inertia J0 must be a \\(3, 3\\) matrix .* got shape \\(2, 3\\)"):
        sj.paper_scenario(T=1.0, J0=np.ones((2, 3)))
    with pytest.raises(ValueError, match="inertia J2 is not positive definite"):
        sj.paper_scenario(T=1.0, J2=-J_OK)
    with pytest.raises(ValueError, match="inertia J1 is not symmetric"):
        sj.paper_scenario(T=1.0, J1=J_OK + np.triu(np.ones((3, 3)), 1))


# --- shapes and types at the library's entry points -------------------------------------


@pytest.mark.parametrize(
    "scenario,match",
    [
        (dataclasses.replace(GOOD, inertia=sj.ConstantInertia(jnp.ones((2, 3)))), "inertia J must be a \\(3, 3\\)"),
        (dataclasses.replace(GOOD, R0=jnp.eye(2)), "scenario.R0 must have shape \\(3, 3\\)"),
        (dataclasses.replace(GOOD, Omega0=jnp.zeros(4)), "scenario.Omega0 must have shape \\(3,\\)"),
    ],
)
def test_wrong_shapes_are_named(scenario, match, no_tracing):
    for run in (lambda: sj.simulate(scenario, sj.geometric_pd(), sj.PAPER_PD_GAINS),
                lambda: sj.rollout(scenario, sj.geometric_pd(), sj.PAPER_PD_GAINS, 0)):
        with pytest.raises(ValueError, match=match):
            run()


@pytest.mark.parametrize(
    "controller,gains,match",
    [
        (sj.adaptive_backstepping(), sj.PAPER_PD_GAINS,
         "gains must be AdaptiveGains\\(K_r, K_w, Gamma\\) .* got PDGains"),
        (sj.geometric_pd(), sj.PAPER_ADAPTIVE_GAINS, "gains must be PDGains\\(k_R, k_Omega\\) .* got AdaptiveGains"),
        (sj.geometric_pd(), {"k_R": 0.5, "k_Omega": 25.0}, "gains must be PDGains\\(k_R, k_Omega\\) .* got dict"),
    ],
)
def test_gains_of_another_controller_are_a_type_error(controller, gains, match, no_tracing):
    with pytest.raises(TypeError, match=match):
        sj.simulate(GOOD, controller, gains)
    with pytest.raises(TypeError, match=match):
        sj.rollout(GOOD, controller, gains, 0)
    with pytest.raises(TypeError, match=match):
        sj.rollout_batch(GOOD, controller, gains, jnp.arange(2), scenario_axes=None)


def test_rollout_batch_checks_the_batch_axes(no_tracing):
    J = jnp.stack([jnp.asarray(J_OK)] * 3)
    batched = dataclasses.replace(GOOD, inertia=sj.ConstantInertia(J))
    axes = dataclasses.replace(jax.tree.map(lambda _: None, batched), inertia=sj.ConstantInertia(0))
    pd, gains = sj.geometric_pd(), sj.PAPER_PD_GAINS
    with pytest.raises(ValueError,
                       match="scenario.inertia.J must have a leading batch axis of size 4 .* got shape \\(3, 3, 3\\)"):
        sj.rollout_batch(batched, pd, gains, jnp.arange(4), scenario_axes=axes)
    with pytest.raises(ValueError, match="gains.k_R must have a leading batch axis of size 3 .* got shape \\(2,\\)"):
        sj.rollout_batch(batched, pd, sj.PDGains(jnp.ones(2), jnp.ones(3)), jnp.arange(3), scenario_axes=axes,
                         gains_axes=0)
    with pytest.raises(ValueError, match="seeds must be a \\(B,\\) array of integers"):
        sj.rollout_batch(batched, pd, gains, jnp.zeros((3, 1), jnp.int32), scenario_axes=axes)
    bad = dataclasses.replace(batched, inertia=sj.ConstantInertia(J.at[1].set(-jnp.asarray(J_OK))))
    with pytest.raises(ValueError, match="inertia J is not positive definite"):
        sj.rollout_batch(bad, pd, gains, jnp.arange(3), scenario_axes=axes)


def test_checks_compose_with_jit_vmap_and_grad():
    """Under tracing, shapes are checked and values left alone (eval_shape: traced, not compiled)."""
    pd = sj.geometric_pd()
    short = dataclasses.replace(GOOD, n_steps=4)
    cost = lambda g: rollout_module.rollout(short, pd, g, 0).metrics.rmse
    jax.eval_shape(jax.grad(cost), sj.PDGains(jnp.asarray(0.5), jnp.asarray(25.0)))
    scaled = lambda s: dataclasses.replace(short, inertia=dataclasses.replace(short.inertia, J0=s * short.inertia.J0))
    jax.eval_shape(jax.vmap(lambda s: rollout_module.rollout(scaled(s), pd, sj.PAPER_PD_GAINS, 0).metrics.rmse),
                   jnp.ones(2))
    with pytest.raises(ValueError, match="inertia J0 must be a \\(3, 3\\) matrix"):
        jax.eval_shape(lambda J: rollout_module.rollout(
            dataclasses.replace(short, inertia=dataclasses.replace(short.inertia, J0=J)), pd, sj.PAPER_PD_GAINS, 0),
            jnp.ones((2, 3)))


# --- Monte Carlo dispersions ------------------------------------------------------------


@pytest.mark.parametrize(
    "override,match",
    [
        ("dispersions.deployment.tau_J=-50.0", "deployment.tau_J \\[s\\] must be > 0"),
        ("dispersions.deployment.tau_J=0.0", "deployment.tau_J \\[s\\] must be > 0"),
        ('dispersions.deployment.tau_J={dist="uniform", low=-100.0, high=400.0}',
         "deployment.tau_J \\[s\\] must be > 0"),
        ('dispersions.deployment.tau_J={dist="normal", mean=-300.0, std=10.0}', "deployment.tau_J \\[s\\] must be > 0"),
        ('dispersions.deployment.tau_J={dist="uniform", low=400.0, high=200.0}', "uniform needs low <= high"),
        ('dispersions.disturbance.noise_std={dist="normal", mean=0.025, std=-1.0}', "std / sigma >= 0"),
        ('dispersions.disturbance.noise_std={dist="uniform", low=-0.1, high=0.1}',
         "disturbance.noise_std \\[N m\\] must be >= 0"),
        ("dispersions.inertia.J0.scale=0.0", "inertia.J0.scale must be > 0"),
        ('dispersions.inertia.J1.scale={dist="uniform", low=-1.0, high=2.0}', "inertia.J1.scale must be > 0"),
        ("dispersions.inertia.J2.axis_scale=-1.0", "inertia.J2.axis_scale must be > 0"),
        ("dispersions.orbit.n=-1e-3", "orbit.n \\[rad/s\\] must be >= 0"),
        ("dispersions.orbit.n=2e-3", "dispersions.orbit.n = 0.002 rad/s is a circular orbit of radius 4636 km"),
        ('dispersions.orbit.n={dist="normal", mean=1.3e-3, std=1e-5}',
         "dispersions.orbit.n \\(the mean of .*\\) = 0.0013 rad/s .* below the least altitude, 100 km"),
        ('dispersions.deployment.tau_J={dist="lognormal", median=300.0, sigma=200.0}',
         "dispersions.deployment.tau_J: .* draws values beyond what a float holds \\(normal variates reach 6.76\\)"),
        ('dispersions.disturbance.amplitude={dist="uniform", low=-1e308, high=1e308}',
         "dispersions.disturbance.amplitude: .* draws values beyond what a float holds: narrow it"),
        ('dispersions.initial.rate={norm={dist="uniform", low=-0.1, high=0.1}}',
         "initial.rate \\[rad/s\\] must be >= 0"),
    ],
)
def test_impossible_dispersions_are_errors(override, match):
    from so3jax.jobs import sweep

    with pytest.raises(ValueError, match=match):
        sweep.load_config(None, ("sweep.samples=8", override))


def test_possible_dispersions_are_accepted():
    """A normal's tails below the domain are redrawn or rejected sample by sample."""
    from so3jax.jobs import sweep

    sweep.load_config(None, ('dispersions.deployment.tau_J={dist="normal", mean=300.0, std=200.0}',
                             "dispersions.inertia.J0.scale=1.0",
                             'dispersions.orbit.n={dist="lognormal", median=1e-3, sigma=0.1}'))


def test_draw_samples_checks_its_dispersions():
    from so3jax.missions import distributions, draw

    bad = dataclasses.replace(draw.Dispersions(), tau_J=distributions.Fixed(0.0))
    with pytest.raises(ValueError, match="deployment.tau_J \\[s\\] must be > 0"):
        draw.draw_samples(bad, 0, 8, 20)
    with pytest.raises(ValueError, match="n_samples must be a positive integer"):
        draw.draw_samples(draw.Dispersions(), 0, 0, 20)


def test_tune_checks_its_mission_values():
    from so3jax.jobs import tune

    campaign = {"tune": {"controller": "pd", "iterations": 1, "train": {"seeds": [0]}, "validation": {"seeds": [1]}}}
    with pytest.raises(ValueError, match=r"deployment\.tau_J \[s\] must be positive"):
        tune.parse_config({**campaign, "T": 1.0, "deployment": {"tau_J": -5.0}})
    with pytest.raises(ValueError, match=r"tune\.iterations"):
        tune.parse_config({"T": 1.0, "tune": {**campaign["tune"], "iterations": 0}})


@pytest.mark.parametrize(
    "args,error,match",
    [
        ((GOOD, sj.geometric_pd(), sj.PDGains("stiff", 25.0)), TypeError, "gain k_R must be a real numeric array"),
        ((dataclasses.replace(GOOD, inertia=sj.ConstantInertia(jnp.asarray(np.eye(3) * (1 + 1j)))),
          sj.geometric_pd(), sj.PAPER_PD_GAINS),
         TypeError, "inertia J must be a real numeric array"),
        ((GOOD, sj.geometric_pd(), sj.PAPER_PD_GAINS, 0.5), TypeError, "seed must be an integer"),
        ((GOOD, "pd", sj.PAPER_PD_GAINS), TypeError, "controller must be a so3jax Controller"),
        (("paper", sj.geometric_pd(), sj.PAPER_PD_GAINS), TypeError, "scenario must be a so3jax.Scenario"),
    ],
)
def test_wrong_types_are_named(args, error, match, no_tracing):
    with pytest.raises(error, match=match):
        sj.simulate(*args)
    with pytest.raises(error, match=match):
        sj.rollout(*args, *(() if len(args) == 4 else (0,)))
