"""The rollout: disturbance recipe, in-scan metrics, phases, vmap/grad, divergence."""

import dataclasses
import importlib
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import so3jax as sj
from so3jax.core import so3
from so3jax.sim import metrics
from so3jax.sim.loop import initial_state
from so3jax.sim.rollout import disturbance_at, disturbances, observe, rollout, step
from tests._shared_programs import fast_jit
from tests.helpers import custom_scenario, sinusoidal_rate

warnings.filterwarnings("ignore", category=sj.InertiaWarning)

SHORT_T = 20.0
SHORT = sj.paper_scenario(T=SHORT_T)
# The adaptive law on SHORT recording every step: one compiled program, shared by the tests
# that fly it (the seed is traced).
ADAPTIVE = (sj.adaptive_backstepping(), sj.PAPER_ADAPTIVE_GAINS)


def fly_adaptive(seed, scenario=SHORT):
    """simulate(scenario, the adaptive law, its paper gains, seed, record_every=1)."""
    return sj.simulate(scenario, *ADAPTIVE, seed, record_every=1)


def test_disturbance_follows_the_fold_in_recipe():
    """d_k = 0.1 sin(0.001 t_k) [1,1,1] + 0.025 normal(fold_in(key(seed), k)) (docs/model.md §4)."""
    d = SHORT.disturbance
    for k in (0, 1, 12345):
        t = k * 0.01
        eta = jax.random.normal(jax.random.fold_in(jax.random.key(7), k), (3,), jnp.float64)
        expected = 0.1 * np.sin(0.001 * t) + 0.025 * np.asarray(eta)
        np.testing.assert_allclose(d(jax.random.key(7), jnp.asarray(k), jnp.asarray(t)), expected, rtol=1e-15)



@pytest.mark.optimized  # XLA's erf_inv as a user's program computes it
@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_noise_is_jax_random_normal(dtype):
    """so3jax's written-out draw = jax.random.normal(fold_in(key, k), (3,)): every bit in
    float32 and for a single key; for a batch of keys in float64 (its own vectorized
    inverse error function) within 3 ulp and the same double in nearly all draws. A batch
    of keys, a block of steps (the rollout's vmap over k), large k."""
    from so3jax.dynamics.disturbance import noise

    seeds = jnp.array([0, 1, 7, 2**31 - 1, 123456], jnp.int32)
    keys = jax.vmap(jax.random.key)(seeds)
    ks = jnp.concatenate([jnp.arange(2000, dtype=jnp.int32), jnp.array([2**20 + 3, 2**31 - 1], jnp.int32)])
    expected = jax.vmap(lambda k: jax.vmap(
        lambda key: jax.random.normal(jax.random.fold_in(key, k), (3,), dtype))(keys))(ks)
    got = jax.jit(jax.vmap(lambda k: noise(keys, k, dtype)))(ks)  # (K, 3, B)
    one = noise(jax.random.key(7), jnp.int32(12345), dtype)  # a single key: (3,)
    one_expected = jax.random.normal(jax.random.fold_in(jax.random.key(7), 12345), (3,), dtype)
    assert got.dtype == dtype
    got, expected = np.asarray(got), np.asarray(expected).transpose(0, 2, 1)
    if dtype == jnp.float32:
        np.testing.assert_array_equal(got, expected)
        np.testing.assert_array_equal(one, one_expected)
    else:
        np.testing.assert_array_max_ulp(got, expected, maxulp=3)  # erf_inv's 2, then sqrt(2) x
        assert np.mean(got == expected) > 0.98, np.mean(got == expected)
        np.testing.assert_array_equal(one, one_expected)  # one key: XLA's erf_inv
    # other PRNG implementations take jax.random's own path, same recipe
    rbg = jax.random.key(3, impl="rbg")
    np.testing.assert_array_equal(noise(rbg, 5, dtype), jax.random.normal(jax.random.fold_in(rbg, 5), (3,), dtype))


@pytest.mark.optimized  # XLA's erf_inv as a user's program computes it
def test_erf_inv_matches_xla_and_scipy():
    """so3jax.core._erfinv.erf_inv (no scalar log calls) against jax.lax.erf_inv (<= 2 ulp) over
    (-1, 1) and into each tail branch (w >= 6.25, w >= 16), and scipy.special.erfinv."""
    from scipy.special import erfinv

    from so3jax.core._erfinv import erf_inv

    rng = np.random.default_rng(0)
    x = np.concatenate([
        rng.uniform(-1, 1, 200_000),
        rng.uniform(0.998, 1, 20_000) * rng.choice([-1, 1], 20_000),  # w >= 6.25
        1 - np.exp(rng.uniform(np.log(2.0**-53), np.log(1e-7), 2_000)),  # w >= 16
        [0.0, 1e-300, 2.0**-1022, 0.5, -0.6435942529055827, 1 - 2.0**-53, -(1 - 2.0**-53)],
    ])  # fmt: skip
    w = -np.log1p(-x * x)
    assert (w >= 16).sum() > 1000 and ((w >= 6.25) & (w < 16)).sum() > 1000
    got = np.asarray(jax.jit(erf_inv)(jnp.asarray(x)))
    np.testing.assert_array_max_ulp(got, np.asarray(jax.jit(jax.lax.erf_inv)(jnp.asarray(x))), maxulp=2)
    # Giles' algorithm rounds -x^2 before 1 - x^2, as XLA does: accurate to round-off away
    # from |x| = 1, ill-conditioned towards it (there it is held to XLA's values above)
    inner = np.abs(x) < 0.99
    np.testing.assert_allclose(got[inner], erfinv(x[inner]), rtol=1e-14, atol=1e-300)


def test_block_draw_equals_step_draws():
    """The disturbance a block draws ahead (per axis) is what the step would draw itself."""
    keys = jax.vmap(jax.random.key)(jnp.arange(4, dtype=jnp.int32))
    block = jax.jit(lambda k0: disturbances(SHORT, keys, k0, 50))(jnp.int32(100))
    each = jax.jit(jax.vmap(lambda k: disturbance_at(SHORT, keys, k)))(100 + jnp.arange(50, dtype=jnp.int32))
    assert len(block) == 3 and block[0].shape == (50, 4)
    np.testing.assert_allclose(np.stack(block, 1), each, rtol=1e-15, atol=1e-18)


def test_disturbance_reaches_the_plant():
    """One step with and without noise differs by dt/J-scaled noise, as the plant says."""
    controller = sj.geometric_pd()
    gains = jax.tree.map(jnp.asarray, sj.PAPER_PD_GAINS)
    s0 = sj.State(SHORT.R0, SHORT.Omega0, (), ())  # the rollout's state at k = 0
    quiet = dataclasses.replace(SHORT, disturbance=sj.no_disturbance())
    k = jnp.asarray(0, jnp.int32)
    one_step = jax.jit(lambda sc: step(sc, controller, gains, disturbance_at(sc, jax.random.key(5), k), s0, k)[0])
    noisy_next, quiet_next = one_step(SHORT), one_step(quiet)
    eta = np.asarray(jax.random.normal(jax.random.fold_in(jax.random.key(5), 0), (3,), jnp.float64))
    J0 = np.asarray(SHORT.inertia.J0)
    # at rest, Omega' = J^-1 (tau + d) to first order; the torque is the same in both runs
    dOmega = np.asarray(noisy_next.Omega - quiet_next.Omega)
    np.testing.assert_allclose(dOmega, 0.01 * np.linalg.solve(J0, 0.025 * eta), rtol=1e-3)


def test_in_scan_metrics_match_the_recorded_trajectory():
    """With record_every=1 the history holds every step start: recompute docs/model.md §6 from it."""
    scenario = SHORT
    r = fly_adaptive(2)
    h, m = r.history, r.metrics
    n = scenario.n_steps
    assert h.t.shape == (n,)
    np.testing.assert_allclose(m.rmse, np.sqrt(np.mean(np.sum(np.asarray(h.Omega_e) ** 2, -1))), rtol=1e-12)
    np.testing.assert_allclose(
        m.rmse_unrotated, np.sqrt(np.mean(np.sum((np.asarray(h.Omega) - np.asarray(h.Omega_d)) ** 2, -1))), rtol=1e-12
    )
    np.testing.assert_allclose(m.effort, np.sum(np.asarray(h.tau) ** 2) * scenario.dt, rtol=1e-12)
    np.testing.assert_allclose(m.max_torque, np.max(np.linalg.norm(h.tau, axis=-1)), rtol=1e-12)
    np.testing.assert_allclose(m.max_angle_phase[0], np.max(h.angle), rtol=1e-12)
    # the angle is |log(R_d^T R)|
    Re = np.swapaxes(np.asarray(h.R_d), -1, -2) @ np.asarray(h.R)
    np.testing.assert_allclose(h.angle, np.linalg.norm(so3.log(np.moveaxis(Re, 0, -1)), axis=0), atol=1e-14)


def test_phases_switch_on_step_boundaries():
    """Per-phase sums split at K = round(t_switch / dt): phase sums add up to the total."""
    base = sj.paper_scenario(T=3.0)
    inertia = dataclasses.replace(base.inertia, t_deploy=jnp.asarray(1.004))  # J(t) deploys with the phase
    scenario = dataclasses.replace(base, inertia=inertia, phase_times=(1.004, 2.0))
    assert scenario.phase_steps == (100, 200)
    assert scenario.steps_per_phase == (100, 100, 100)
    r = sj.simulate(scenario, sj.geometric_pd(), sj.PAPER_PD_GAINS, 0, record_every=1)
    m = r.metrics
    np.testing.assert_allclose(np.sum(m.effort_phase), m.effort, rtol=1e-12)
    tau2 = np.sum(np.asarray(r.history.tau) ** 2, -1) * scenario.dt
    np.testing.assert_allclose(m.effort_phase, [tau2[:100].sum(), tau2[100:200].sum(), tau2[200:].sum()], rtol=1e-12)
    # Omega_d drops to zero at the docking step exactly (phase 3 of the paper's reference)
    assert np.all(np.asarray(r.history.Omega_d)[200:] == 0) and np.all(np.asarray(r.history.Omega_d)[:200] != 0)


def test_closed_form_and_integrated_reference_agree():
    rate = SHORT.reference.rates[0]
    integrated = dataclasses.replace(SHORT, reference=sj.RateFunction(lambda t: rate + 0.0 * t))
    a = fly_adaptive(1)
    b = fly_adaptive(1, integrated)
    np.testing.assert_allclose(a.final.R, b.final.R, atol=1e-13)
    np.testing.assert_allclose(a.metrics.rmse, b.metrics.rmse, rtol=1e-10)
    # the paper's R_d(t) = exp(hat(Omega_d) t)
    np.testing.assert_allclose(b.final.R_d, so3.exp(rate * SHORT_T), atol=1e-13)


def test_vmap_over_seeds_and_inertias_matches_single_runs():
    controller, gains = sj.geometric_pd(), jax.tree.map(jnp.asarray, sj.PAPER_PD_GAINS)
    scales = jnp.array([1.0, 1.5])
    seeds = jnp.array([0, 4])

    def scaled(s):
        inertia = SHORT.inertia
        return dataclasses.replace(
            SHORT, inertia=dataclasses.replace(inertia, J0=s * inertia.J0, J1=s * inertia.J1, J2=s * inertia.J2)
        )

    batched = jax.jit(jax.vmap(lambda s, seed: rollout(scaled(s), controller, gains, seed).metrics.rmse))(scales, seeds)
    singles = [
        float(sj.simulate(scaled(s), controller, gains, int(seed)).metrics.rmse) for s, seed in zip(scales, seeds)
    ]
    np.testing.assert_allclose(batched, singles, rtol=1e-13)
    assert abs(singles[0] - singles[1]) > 1e-6  # the inertia and the seed reach the rollout


@pytest.mark.parametrize(
    # the adaptive law in reverse mode is slow (compilation); PD here and the flight loop
    # (tests/test_loop.py) check reverse mode in the default run
    ("name", "mode"),
    [("pd", "reverse"), ("adaptive", "forward"), pytest.param("adaptive", "reverse", marks=pytest.mark.slow)],
)
def test_gradient_wrt_log_gains_matches_finite_differences(name, mode):
    scenario = sj.paper_scenario(T=10.0)
    controller, gains = {
        "pd": (sj.geometric_pd(), sj.PAPER_PD_GAINS),
        "adaptive": (sj.adaptive_backstepping(), sj.PAPER_ADAPTIVE_GAINS),
    }[name]
    cls = type(gains)
    log_g = jnp.log(jnp.array([float(g) for g in gains]))

    def cost(lg):
        m = rollout(scenario, controller, cls(*jnp.exp(lg)), 0).metrics
        return m.rmse / 1e-3 + m.effort

    # one compiled program: the derivative with the cost alongside (the central differences
    # read the cost from it at the shifted points), XLA's backend optimizations off
    derivative = (jax.grad if mode == "reverse" else jax.jacfwd)(lambda lg: (c := cost(lg), c), has_aux=True)
    program = fast_jit(derivative, log_g)
    grad = np.asarray(program(log_g)[0])
    assert np.all(np.isfinite(grad))
    h = 1e-5
    at = lambda lg: program(lg)[1]
    fd = [(at(log_g.at[i].add(h)) - at(log_g.at[i].add(-h))) / (2 * h) for i in range(log_g.size)]
    np.testing.assert_allclose(grad, np.asarray(fd), rtol=1e-4, atol=1e-8 * np.max(np.abs(grad)))


def test_gradient_is_finite_at_zero_rotation():
    """R = R_d and Omega = Omega_d exactly at t = 0: the log, norms and max must not NaN.
    One step of the rollout (the adaptive law's log inside RK4, the sample's angle, the
    metrics' norms, square roots and maxima) differentiated at the reference itself, with
    respect to the gains and to offsets of R and Omega (zero: R = R_d exactly); the
    rollout's scan repeats this step."""
    scenario = custom_scenario(1.0, 0.01, rate_fn=lambda t: 0.0 * sinusoidal_rate(t))
    gains = sj.AdaptiveGains(*map(jnp.asarray, (0.5, 10.0, 100.0)))
    controller = sj.adaptive_backstepping()

    def one_step_metrics(g, dR, dOmega):
        state = initial_state(scenario, controller, g)
        state = state._replace(R=state.R + so3.hat(dR), Omega=state.Omega + dOmega)
        new, phase, sample = step(scenario, controller, g, jnp.zeros(3), state, jnp.asarray(0, jnp.int32))
        acc = metrics.update(metrics.init(1, jnp.float64), phase, sample, jnp.asarray(True))
        m = metrics.finalize(acc, (1,), scenario.dt, new.R)
        return (m.rmse_phase[0] + m.rmse_unrotated + m.rms_angle_phase[0] + m.max_angle_phase[0] + m.max_torque
                + m.effort)

    zero = jnp.zeros(3)
    g = jax.jit(jax.grad(one_step_metrics, argnums=(0, 1, 2)))(gains, zero, zero)
    assert all(np.all(np.isfinite(x)) for x in jax.tree.leaves(g))


def test_divergence_is_reported_not_raised():
    scenario = dataclasses.replace(sj.paper_scenario(T=50.0), dt=1.0, n_steps=50)
    r = sj.simulate(scenario, sj.geometric_pd(), sj.PDGains(5000.0, 1e5), 0)
    assert bool(r.metrics.diverged)
    ok = sj.simulate(scenario, sj.geometric_pd(), sj.PAPER_PD_GAINS, 0)  # the same compiled rollout
    assert not bool(ok.metrics.diverged)
    gains = sj.PDGains(jnp.array([0.5714, 5000.0]), jnp.array([25.0, 1e5]))
    batched = jax.jit(jax.vmap(lambda g: rollout(scenario, sj.geometric_pd(), g, 0).metrics.diverged))(gains)
    assert batched.tolist() == [False, True]


def test_observe_matches_the_step_sample():
    controller, gains = ADAPTIVE[0], jax.tree.map(jnp.asarray, ADAPTIVE[1])
    state = fly_adaptive(0).final
    k = jnp.asarray(SHORT.n_steps, jnp.int32)

    @jax.jit
    def both(state):
        _, _, sample = step(SHORT, controller, gains, disturbance_at(SHORT, jax.random.key(0), k), state, k)
        seen = observe(SHORT, controller, gains, state, k)
        return sample, seen.tau, seen.sample

    sample, tau, observed = both(state)
    np.testing.assert_allclose(tau, sample.tau, rtol=1e-14)
    np.testing.assert_allclose(observed.Omega_e, sample.Omega_e, rtol=1e-14)


def test_float32_follows_the_scenario_dtype():
    with jax.numpy_dtype_promotion("strict"):
        r = fly_adaptive(0, sj.paper_scenario(T=SHORT_T, dtype="float32"))
    assert r.metrics.rmse.dtype == jnp.float32 and r.final.R.dtype == jnp.float32
    r64 = fly_adaptive(0)
    np.testing.assert_allclose(r.metrics.rmse, r64.metrics.rmse, rtol=1e-3)


TINY = sj.paper_scenario(T=0.2)  # 20 steps: blocks of 5 (four), or of 3 (seven, the last one masked)
LAWS = ((sj.geometric_pd(), sj.PAPER_PD_GAINS), (sj.adaptive_backstepping(), sj.PAPER_ADAPTIVE_GAINS))


_VMAPPED = {}


def _vmapped_rollout(controller, record_every, *args):
    """jit(vmap(rollout)) over scenarios and seeds at ``args``, one compilation per controller
    and block size (XLA's backend optimizations off: the batching, not XLA's, is checked)."""
    if (controller, record_every) not in _VMAPPED:
        vmapped = jax.vmap(lambda s, seed, gains: rollout(s, controller, gains, seed, record_every=record_every),
                           in_axes=(_tiny_axes(), 0, None))
        _VMAPPED[controller, record_every] = fast_jit(vmapped, *args)
    return _VMAPPED[controller, record_every](*args)


def _tiny_axes():
    return dataclasses.replace(
        TINY,
        inertia=dataclasses.replace(TINY.inertia, J0=0, J1=0, J2=0, t_deploy=None, tau_J=None),
        reference=None,
        disturbance=None,
        R0=None,
        Omega0=None,
    )


@pytest.mark.parametrize(("sub_batch", "unroll", "record_every"),
                         [(None, 1, 5), (2, 1, 5), pytest.param(None, 2, 3, marks=pytest.mark.slow)])
def test_rollout_batch_equals_vmap_of_rollout(sub_batch, unroll, record_every, monkeypatch):
    """The natively batched path (batch axis last inside) gives vmap's values, shared or batched leaves;
    also in sub-batches (the last one padded) and with an unrolled scan over blocks of an odd
    number of steps (properties of the batching and of the scan: checked with the PD law alone)."""
    from so3jax.sim.rollout import rollout_batch

    scales = jnp.array([1.0, 1.3, 0.8])
    inertia = TINY.inertia
    batched = dataclasses.replace(
        TINY,
        inertia=dataclasses.replace(
            inertia,
            J0=scales[:, None, None] * inertia.J0,
            J1=scales[:, None, None] * inertia.J1,
            J2=scales[:, None, None] * inertia.J2,
        ),
    )
    axes = _tiny_axes()
    seeds = jnp.array([0, 5, 9])
    if sub_batch:  # on CPU: sub-batches of 2, the last one padded
        monkeypatch.setattr(importlib.import_module("so3jax.sim.rollout"), "CPU_SUB_BATCH", sub_batch)
    for controller, gains in LAWS if unroll == 1 and not sub_batch else LAWS[:1]:
        gains = jax.tree.map(jnp.asarray, gains)
        native = fast_jit(  # traced here, so under this test's CPU_SUB_BATCH
            lambda b, s, g: rollout_batch(b, controller, g, s, scenario_axes=axes, record_every=record_every,
                                          unroll=unroll), batched, seeds, gains
        )(batched, seeds, gains)
        vmapped = _vmapped_rollout(controller, record_every, batched, seeds, gains)
        for a, b in zip(jax.tree.leaves(native), jax.tree.leaves(vmapped)):
            assert a.shape == b.shape
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)
        assert len(set(np.asarray(native.metrics.rmse).tolist())) == 3  # the samples differ


def test_seeds_give_the_batch_first_and_absent_records_are_none():
    """``simulate`` over seeds (B,) is the batch of single runs, batch axis first (the public
    convention, as ``rollout_batch``); what a wiring does not record is None."""
    controller, gains = LAWS[0]
    seeds = jnp.array([3, 4])
    batch = sj.simulate(TINY, controller, gains, seeds, record_every=5)
    for i, seed in enumerate(seeds.tolist()):
        one = sj.simulate(TINY, controller, gains, seed, record_every=5)
        for a, b in zip(jax.tree.leaves(batch), jax.tree.leaves(one)):
            assert a.shape == (2,) + b.shape
            np.testing.assert_allclose(a[i], b, rtol=1e-12, atol=1e-15)
    assert batch.flight is None and batch.history.R_hat is None and batch.history.covariance is None
    assert batch.history.actuator is None  # the ideal actuator has no state
