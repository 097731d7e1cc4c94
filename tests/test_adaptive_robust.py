"""The adaptive law's robustness options (sigma-modification, projection): off by default
(the paper's law bit for bit), each rate against a NumPy transcription of its formula, the
projection's invariance, and finite gradients through short rollouts."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import so3jax as sj
from so3jax.controllers import Desired, Feedback, regressor_parameters
from so3jax.controllers.adaptive import _apply_gamma, adaptive_terms, leakage_rate, project
from so3jax.core import so3
from so3jax.missions import mission
from so3jax.sim.loop import Loop
from tests.helpers import J_BODY, custom_scenario

B = 6  # batch of random inputs (trailing axis)
M0 = 50.0  # switching sigma's bound [kg m^2]
SIGMA = 2e-6  # [1/(kg m^2 s^3)]
# ||Theta_hat - Theta_0||: at Theta_0, below M0, at M0, between, at 2 M0, above
NORMS = np.array([0.0, 0.5, 1.0, 1.5, 2.0, 3.0]) * M0


# --- inputs and the NumPy transcription of the law ------------------------------------------


def _gammas(rng):
    """Gamma of each shape with the trailing batch axis B [kg m^2 s^2]."""
    a = rng.normal(size=(9, 9, B))
    full = np.einsum("ikb,jkb->ijb", a, a) + 9.0 * np.eye(9)[..., None]
    return {"scalar": rng.uniform(1e3, 1e4, B), "diagonal": rng.uniform(1e3, 1e4, (9, B)), "full": 1e3 * full}


@pytest.fixture(scope="module")
def inputs():
    """Random attitudes, rates, reference and estimates with norms NORMS about Theta_0 (batch last)."""
    rng = np.random.default_rng(11)
    R = Rotation.from_rotvec(rng.normal(size=(B, 3))).as_matrix().transpose(1, 2, 0)
    R_d = Rotation.from_rotvec(rng.normal(size=(B, 3))).as_matrix().transpose(1, 2, 0)
    Omega, Omega_d, Omega_d_dot = (0.1 * rng.normal(size=(3, B)) for _ in range(3))
    theta_0 = np.asarray(regressor_parameters(np.eye(3)))
    direction = rng.normal(size=(9, 3, B))
    direction /= np.sqrt(np.sum(direction**2, axis=(0, 1)))
    theta_hat = theta_0[..., None] + NORMS * direction
    K_r, K_w = rng.uniform(0.1, 1.0, B), rng.uniform(10.0, 100.0, B)
    return dict(R=R, R_d=R_d, Omega=Omega, Omega_d=Omega_d, Omega_d_dot=Omega_d_dot, theta_hat=theta_hat,
                theta_0=theta_0, K_r=K_r, K_w=K_w, gammas=_gammas(rng))


def _hat(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _numpy_law(x, Gamma, b):
    """Batch element b of the paper's law: tau (3,), y = -Gamma Phi z^T (9, 3), Phi (9,), z (3,)."""
    R, R_d, Omega = x["R"][..., b], x["R_d"][..., b], x["Omega"][:, b]
    R_e = R_d.T @ R
    Omega_r = R_e.T @ x["Omega_d"][:, b]
    Omega_e = Omega - Omega_r
    e = Rotation.from_matrix(R_e).as_rotvec()
    th = np.linalg.norm(e)
    Jr_inv = np.eye(3) + 0.5 * _hat(e) + (1 / th**2 - (1 + np.cos(th)) / (2 * th * np.sin(th))) * _hat(e) @ _hat(e)
    K_r, K_w = x["K_r"][b], x["K_w"][b]
    beta_dot = -K_r * Jr_inv @ Omega_e - np.cross(Omega, Omega_r) + R_e.T @ x["Omega_d_dot"][:, b]
    z = Omega - (-K_r * e + Omega_r)
    wx, wy, wz = Omega
    Phi = np.concatenate([[wy * wz, wz * wx, wx * wy, wx * wx, wy * wy, wz * wz], beta_dot])
    tau = -K_r * e - K_w * z + x["theta_hat"][..., b].T @ Phi
    return tau, -_gamma_np(Gamma, b) @ np.outer(Phi, z), Phi, z


def _gamma_np(Gamma, b):
    """Batch element b of Gamma as a (9, 9) matrix."""
    g = Gamma[..., b]
    return g * np.eye(9) if g.ndim == 0 else np.diag(g) if g.ndim == 1 else g


def _evaluate(controller, x, Gamma, theta_hat=None):
    gains = sj.AdaptiveGains(jnp.asarray(x["K_r"]), jnp.asarray(x["K_w"]), jnp.asarray(Gamma))
    feedback = Feedback(jnp.asarray(x["R"]), jnp.asarray(x["Omega"]))
    desired = Desired(jnp.asarray(x["R_d"]), jnp.asarray(x["Omega_d"]), jnp.asarray(x["Omega_d_dot"]))
    theta = jnp.asarray(x["theta_hat"] if theta_hat is None else theta_hat)
    tau, rate = controller.torque(gains, theta, feedback, desired, jnp.asarray(0.0))
    return np.asarray(tau), np.asarray(rate), (gains, feedback, desired)


def _sigma_s_np(norm, leakage):
    if leakage == "fixed":
        return SIGMA
    return 0.0 if norm <= M0 else SIGMA * (norm / M0 - 1.0) if norm <= 2 * M0 else SIGMA


# --- defaults: the paper's law ---------------------------------------------------------------


@pytest.mark.parametrize("shape", ["scalar", "diagonal", "full"])
def test_defaults_are_the_papers_law(inputs, shape):
    """Default options: torque and rate equal the paper's formula (NumPy) and, bit for bit,
    the law's own unmodified rate -Gamma Phi z^T; every option's 'off' value gives the same."""
    Gamma = inputs["gammas"][shape]
    tau, rate, (gains, feedback, desired) = _evaluate(sj.adaptive_backstepping(), inputs, Gamma)
    for b in range(B):
        tau_np, rate_np, _, _ = _numpy_law(inputs, Gamma, b)
        np.testing.assert_allclose(tau[:, b], tau_np, rtol=1e-11, atol=1e-12 * np.abs(tau_np).max())
        np.testing.assert_allclose(rate[..., b], rate_np, rtol=1e-11, atol=1e-12 * np.abs(rate_np).max())
    terms = adaptive_terms(gains, feedback, desired, "exact", jnp.asarray(0.0))
    np.testing.assert_array_equal(rate, -_apply_gamma(gains.Gamma, terms.Phi)[:, None] * terms.z[None, :])
    off = sj.adaptive_backstepping(leakage="none", sigma=1.0, projection_bound=None, projection_eps=0.5)
    assert off.update is None and sj.adaptive_backstepping().update is None  # Euler at the ticks, as before
    tau_off, rate_off, _ = _evaluate(off, inputs, Gamma)
    np.testing.assert_array_equal(tau_off, tau)
    np.testing.assert_array_equal(rate_off, rate)


def test_mission_without_options_is_unchanged_and_with_them_builds_the_law():
    """The options default to absent: a mission's description keeps only log_derivative;
    given, they reach the factory, and bad ones are one-line errors naming the table."""
    assert mission.load().options["adaptive"] == {"log_derivative": "exact"}
    m = mission.from_dict({"controller": {"adaptive": {"leakage": "switching", "sigma": 1e-9, "theta_bound": 100.0,
                                                       "projection_bound": 500.0}}})
    assert m.options["adaptive"] == {"log_derivative": "exact", "leakage": "switching", "sigma": 1e-9,
                                     "theta_bound": 100.0, "projection_bound": 500.0}
    assert m.controller("adaptive")[0].update is not None  # the projection's tick
    for table, match in [({"leakage": "fixed"}, "needs sigma"), ({"leakage": "switching", "sigma": 1.0}, "theta_bound"),
                         ({"sigma": -1.0}, "sigma"), ({"projection_bound": 0.0}, "projection_bound"),
                         ({"projection_bound": 1.0, "projection_eps": 0.0}, "projection_eps"),
                         ({"leakage": "e-mod"}, "leakage")]:
        with pytest.raises(ValueError, match=match) as err:
            mission.from_dict({"controller": {"adaptive": table}})
        assert "\n" not in str(err.value) and "controller.adaptive" in str(err.value)


@pytest.mark.parametrize(
    "options,match",
    [
        (dict(leakage="sigma"), "leakage must be one of"),
        (dict(leakage="fixed"), "needs sigma"),
        (dict(leakage="fixed", sigma=-1e-9), "sigma .* must be finite and >= 0"),
        (dict(leakage="fixed", sigma=float("nan")), "sigma .* must be finite"),
        (dict(leakage="switching", sigma=1e-9), "needs theta_bound"),
        (dict(leakage="switching", sigma=1e-9, theta_bound=0.0), "theta_bound .* must be finite and > 0"),
        (dict(projection_bound=-1.0), "projection_bound .* must be finite and > 0"),
        (dict(projection_bound=10.0, projection_eps=0.0), "projection_eps must be finite and > 0"),
        (dict(projection_bound=10.0, projection_eps=1.5), r"projection_eps must be in \(0, 1\]"),
    ],
)
def test_bad_options_are_refused_at_the_factory(options, match):
    with pytest.raises(ValueError, match=match) as err:
        sj.adaptive_backstepping(**options)
    assert "\n" not in str(err.value)


# --- sigma-modification ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def leaky():
    return {"fixed": sj.adaptive_backstepping(leakage="fixed", sigma=SIGMA),
            "switching": sj.adaptive_backstepping(leakage="switching", sigma=SIGMA, theta_bound=M0)}


@pytest.mark.parametrize("shape", ["scalar", "diagonal", "full"])
@pytest.mark.parametrize("leakage", ["fixed", "switching"])
def test_leakage_rate_is_the_formula(inputs, leaky, leakage, shape):
    """Theta_hat' = -Gamma (Phi z^T + sigma_s (Theta_hat - Theta_0)) at norms 0, M0/2, M0,
    3 M0/2, 2 M0, 3 M0 (every branch of the switching sigma); the torque is the paper's."""
    Gamma = inputs["gammas"][shape]
    tau, rate, _ = _evaluate(leaky[leakage], inputs, Gamma)
    for b in range(B):
        tau_np, _, Phi, z = _numpy_law(inputs, Gamma, b)
        d = inputs["theta_hat"][..., b] - inputs["theta_0"]
        expected = -_gamma_np(Gamma, b) @ (np.outer(Phi, z) + _sigma_s_np(np.linalg.norm(d), leakage) * d)
        np.testing.assert_allclose(tau[:, b], tau_np, rtol=1e-11, atol=1e-12 * np.abs(tau_np).max())
        np.testing.assert_allclose(rate[..., b], expected, rtol=1e-10, atol=1e-12 * np.abs(expected).max())
    if leakage == "switching":  # no leak at or below M0: the paper's rate
        for b in np.flatnonzero(NORMS <= M0):
            np.testing.assert_allclose(rate[..., b], _numpy_law(inputs, Gamma, b)[1], rtol=1e-11, atol=1e-9)


def test_switching_sigma_is_continuous():
    """sigma_s at M0 (1 -+ delta) and 2 M0 (1 -+ delta) differs by O(sigma delta); 0 below, sigma beyond."""
    direction = np.random.default_rng(3).normal(size=(9, 3))
    direction /= np.linalg.norm(direction)
    delta = 1e-9
    scales = np.array([1 - delta, 1 + delta, 2 * (1 - delta), 2 * (1 + delta), 0.3, 5.0]) * M0
    d = jnp.asarray(direction[..., None] * scales)
    s = np.asarray(leakage_rate(d, "switching", SIGMA, M0))
    assert abs(s[1] - s[0]) <= 2 * SIGMA * delta and s[0] == 0.0
    assert abs(s[3] - s[2]) <= 2 * SIGMA * delta and s[3] == SIGMA
    assert s[4] == 0.0 and s[5] == SIGMA
    np.testing.assert_allclose(np.asarray(leakage_rate(d, "fixed", SIGMA)), SIGMA)


def test_vmap_equals_the_trailing_batch(inputs):
    """Both modifications on, a full Gamma: jax.vmap over the batch (one element at a time)
    gives the trailing-batch evaluation."""
    controller = sj.adaptive_backstepping(leakage="switching", sigma=SIGMA, theta_bound=M0, projection_bound=2.5 * M0)
    Gamma = inputs["gammas"]["full"]
    tau, rate, (gains, feedback, desired) = _evaluate(controller, inputs, Gamma)
    last = lambda tree: jax.tree.map(lambda x: jnp.moveaxis(x, -1, 0), tree)
    one = lambda g, th, m, d: controller.torque(g, th, m, d, jnp.asarray(0.0))
    theta = last(jnp.asarray(inputs["theta_hat"]))
    tau_v, rate_v = jax.jit(jax.vmap(one))(last(gains), theta, last(feedback), last(desired))
    for batched, trailing in ((tau_v, tau), (rate_v, rate)):
        np.testing.assert_allclose(np.moveaxis(np.asarray(batched), 0, -1), trailing, rtol=1e-12,
                                   atol=1e-12 * np.abs(trailing).max())


# --- projection ----------------------------------------------------------------------------------

BOUND, EPS = 10.0, 0.2  # theta_max [kg m^2], boundary layer


def _f(d):
    return ((1 + EPS) * np.sum(d**2, axis=(0, 1)) - BOUND**2) / (EPS * BOUND**2)


def _ball_points(rng, norms):
    direction = rng.normal(size=(9, 3, len(norms)))
    return direction / np.sqrt(np.sum(direction**2, axis=(0, 1))) * norms


@pytest.mark.parametrize("shape", ["scalar", "diagonal", "full"])
def test_projection_is_identity_inside_and_inward(shape):
    """Proj(theta, y) = y for f <= 0 (any y), and for f > 0 with y pointing inward (<grad f, y> <= 0)."""
    rng = np.random.default_rng(5)
    Gamma = _gammas(rng)[shape]
    inner = BOUND / np.sqrt(1 + EPS)
    d = _ball_points(rng, np.array([0.0, 0.3, 0.9, 0.999]) * inner)
    d = np.concatenate([d, _ball_points(rng, np.array([0.5, 1.0]) * (inner + BOUND))], axis=-1)  # in the layer
    y = rng.normal(size=d.shape)
    inward = np.sum(d * y, axis=(0, 1)) > 0
    y[..., -2:] = np.where(inward[-2:], -y[..., -2:], y[..., -2:])  # the layer's points: y inward
    projected = project(jnp.asarray(d), jnp.asarray(y), jnp.asarray(Gamma), BOUND, EPS)
    np.testing.assert_array_equal(np.asarray(projected), y)


@pytest.mark.parametrize("shape", ["scalar", "diagonal", "full"])
def test_projection_bounds_the_outward_rate(shape):
    """y outward in the boundary layer: Proj equals the formula with the 27-vector gain
    I_3 kron Gamma (NumPy); <grad f, Proj> = (1 - f) <grad f, y>: reduced in the layer, 0 on
    ||theta|| = theta_max (f = 1, the bound is invariant), < 0 beyond."""
    rng = np.random.default_rng(6)
    Gamma = _gammas(rng)[shape]
    inner = BOUND / np.sqrt(1 + EPS)
    d = _ball_points(rng, np.array([inner * 1.001, 0.5 * (inner + BOUND), BOUND, BOUND, 1.01 * BOUND, 1.3 * BOUND]))
    y = rng.normal(size=d.shape)
    y = np.where(np.sum(d * y, axis=(0, 1)) < 0, -y, y)  # outward
    proj = np.asarray(project(jnp.asarray(d), jnp.asarray(y), jnp.asarray(Gamma), BOUND, EPS))
    f = _f(d)
    for b in range(B):
        g = d[..., b].T.reshape(-1)  # vec: the columns stacked (grad f's scale cancels)
        G = np.kron(np.eye(3), _gamma_np(Gamma, b))
        v = y[..., b].T.reshape(-1)
        expected = v - G @ g * (g @ v) * f[b] / (g @ G @ g)
        np.testing.assert_allclose(proj[..., b].T.reshape(-1), expected, rtol=1e-10, atol=1e-12 * np.abs(v).max())
    outward, before = np.sum(d * proj, axis=(0, 1)), np.sum(d * y, axis=(0, 1))
    np.testing.assert_allclose(outward, (1 - f) * before, rtol=1e-9, atol=1e-12 * np.abs(before).max())
    assert np.all(outward[f < 1 - 1e-9] > 0) and np.all(outward[f < 1 - 1e-9] < before[f < 1 - 1e-9])
    assert np.all(np.abs(outward[np.abs(f - 1) < 1e-12]) <= 1e-12 * np.abs(before).max())  # on the bound: tangent
    assert np.all(outward[f > 1 + 1e-9] < 0)


# --- rollouts: the bound held, finite gradients ---------------------------------------------------

GAINS = sj.AdaptiveGains(K_r=jnp.asarray(0.2), K_w=jnp.asarray(30.0), Gamma=jnp.asarray(1e5))
THETA_MAX, THETA_EPS = 5.0, 0.5  # [kg m^2]: ||Theta(J_BODY) - Theta(I)|| ~ 180 kg m^2, the unprojected estimate
# reaches ~180 here: it would leave the ball


def _deviation(history):
    theta_0 = np.asarray(regressor_parameters(np.eye(3)))
    return np.sqrt(np.sum((np.asarray(history.controller) - theta_0) ** 2, axis=(1, 2)))


def test_projection_holds_the_bound_in_rollouts():
    """Continuous wiring (RK4, dt = 0.01 s) and sampled wiring (ticks of 0.05 s), the paper's
    disturbance, an estimate that would leave the ball. The continuous flow keeps
    ||Theta_hat - Theta_0|| <= theta_max; RK4 may leave it by its step error: a step of
    length s tangent to the sphere ends s^2 / (2 theta_max) outside, the tolerance (s: the
    longest step taken within the boundary layer). The sampled wiring's tick scales the
    estimate back onto the ball: the bound holds to round-off."""
    controller = sj.adaptive_backstepping(projection_bound=THETA_MAX, projection_eps=THETA_EPS)
    scenario = custom_scenario(20.0, 0.01, noise=True, Omega0=(0.05, -0.03, 0.02))
    r = sj.simulate(scenario, controller, GAINS, 1, record_every=1)
    norm = _deviation(r.history)
    steps = np.sqrt(np.sum(np.diff(np.asarray(r.history.controller), axis=0) ** 2, axis=(1, 2)))
    s = steps[norm[:-1] > THETA_MAX / np.sqrt(1 + THETA_EPS)].max()
    assert norm.max() > 0.99 * THETA_MAX  # it reaches the bound ...
    assert norm.max() <= THETA_MAX + s**2 / (2 * THETA_MAX), (norm.max() - THETA_MAX, s)  # ... and stays within
    sampled = _deviation(sj.simulate(scenario, controller, GAINS, 1, loop=Loop(period_steps=5), record_every=5).history)
    assert sampled.max() > 0.99 * THETA_MAX and sampled.max() <= THETA_MAX * (1 + 1e-12)


# A short rollout of the law alone (regulation onto a uniformly rotating frame, J_BODY,
# a sinusoidal disturbance, explicit Euler): a few seconds to compile per law where the
# library's rollout takes ~30 s under jax.grad (test_library_rollout_gradient: slow).
N_MINI, DT_MINI = 150, 0.02
W_MINI = jnp.array([0.02, -0.03, 0.01])  # rad/s
X_MINI = jnp.log(jnp.asarray([0.5, 50.0, 1e3]))  # log K_r, K_w, Gamma
MINI_OPTIONS = {  # bounds the estimate crosses (its deviation peaks near 3 kg m^2 unmodified)
    "fixed": dict(leakage="fixed", sigma=1e-3),
    "switching": dict(leakage="switching", sigma=2e-4, theta_bound=0.8),
    "projection": dict(projection_bound=3.0, projection_eps=0.5),
}


def _mini_rollout(controller, log_gains):
    """(cost, ||Theta_hat - Theta_0|| per step) of N_MINI steps from Theta_hat = Theta_0."""
    gains = sj.AdaptiveGains(*jnp.exp(log_gains))
    J = jnp.asarray(J_BODY)
    theta_0 = controller.init(gains)

    def step(carry, t):
        R, Omega, theta = carry
        desired = Desired(so3.exp(W_MINI * t), W_MINI, jnp.zeros(3))
        tau, theta_dot = controller.torque(gains, theta, Feedback(R, Omega), desired, t)
        d = 0.05 * jnp.stack([jnp.sin(t), jnp.cos(2 * t), jnp.sin(3 * t)])
        Omega_dot = jnp.linalg.solve(J, tau + d - jnp.cross(Omega, J @ Omega))
        rate_error = Omega - (desired.R_d.T @ R).T @ W_MINI
        cost = DT_MINI * (jnp.sum(rate_error**2) / 1e-4 + jnp.sum(tau**2))
        new = (R @ so3.exp(Omega * DT_MINI), Omega + DT_MINI * Omega_dot, theta + DT_MINI * theta_dot)
        return new, (cost, jnp.sqrt(jnp.sum((theta - theta_0) ** 2)))

    start = (so3.exp(jnp.array([0.2, -0.1, 0.15])), jnp.array([0.02, 0.0, -0.01]), theta_0)
    _, (cost, deviation) = jax.lax.scan(step, start, DT_MINI * jnp.arange(N_MINI, dtype=jnp.float64))
    return jnp.sum(cost), deviation


@pytest.mark.parametrize("name", sorted(MINI_OPTIONS))
def test_gradients_are_finite_with_each_modification(name):
    """jax.grad of a short rollout's cost w.r.t. the log-gains, from Theta_hat = Theta_0 (the
    norm's singular point) through every branch (switching sigma past M0 and 2 M0, the
    projection's layer): finite and equal to central differences; and the rate's Jacobian
    in Theta_hat at Theta_0 itself finite in both modes."""
    controller = sj.adaptive_backstepping(**MINI_OPTIONS[name])
    run = jax.jit(jax.value_and_grad(lambda x: _mini_rollout(controller, x), has_aux=True))  # one program for all
    (_, deviation), grad = run(X_MINI)
    if name == "switching":
        assert deviation.max() > 2 * MINI_OPTIONS[name]["theta_bound"]
    if name == "projection":
        bound, eps = MINI_OPTIONS[name]["projection_bound"], MINI_OPTIONS[name]["projection_eps"]
        assert deviation.max() > bound / np.sqrt(1 + eps)  # in the boundary layer
    h = 1e-6
    central = [(run(X_MINI.at[i].add(h))[0][0] - run(X_MINI.at[i].add(-h))[0][0]) / (2 * h) for i in range(3)]
    assert np.all(np.isfinite(np.asarray(grad)))
    np.testing.assert_allclose(grad, np.asarray(central), rtol=1e-6)

    gains = jax.tree.map(jnp.asarray, GAINS)
    feedback = Feedback(so3.exp(jnp.array([0.1, -0.2, 0.3])), jnp.array([0.01, 0.02, -0.03]))
    desired = Desired(jnp.eye(3), jnp.array([0.0, 0.01, 0.0]), jnp.zeros(3))
    rate = lambda theta: controller.torque(gains, theta, feedback, desired, jnp.asarray(0.0))[1]
    theta_0 = controller.init(gains)
    both = lambda th: (jax.jacfwd(rate)(th), jax.grad(lambda x: jnp.sum(rate(x) ** 2))(th))
    forward, reverse = jax.jit(both)(theta_0)
    assert np.all(np.isfinite(np.asarray(forward))) and np.all(np.isfinite(np.asarray(reverse)))


@pytest.mark.slow
def test_library_rollout_gradient():
    """jax.grad through so3jax.sim.rollout (RK4, the paper's disturbance) with the switching sigma
    and the projection both on and active, against central differences."""
    controller = sj.adaptive_backstepping(leakage="switching", sigma=1e-5, theta_bound=5.0, projection_bound=20.0,
                                   projection_eps=0.5)
    scenario = custom_scenario(2.0, 0.01, noise=True, Omega0=(0.05, -0.03, 0.02))

    def cost(log_gains):
        m = sj.rollout(scenario, controller, sj.AdaptiveGains(*jnp.exp(log_gains)), 0, record_every=20).metrics
        return m.rmse / 1e-3 + m.effort

    x = jnp.log(jnp.asarray([0.2, 30.0, 1e5]))
    grad = np.asarray(jax.jit(jax.grad(cost))(x))
    f, h = jax.jit(cost), 1e-5
    central = [(f(x.at[i].add(h)) - f(x.at[i].add(-h))) / (2 * h) for i in range(3)]
    np.testing.assert_allclose(grad, np.asarray(central), rtol=1e-6)
