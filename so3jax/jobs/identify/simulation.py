"""The output-error method: the inertia fitted by Gauss-Newton through a simulation of
the flown spacecraft, over short windows (multiple shooting).

Between star-tracker samples the body follows the plant of docs/model.md §8.4 in momentum form (§17.4):
with L = J Omega + h the body's angular momentum in the body frame and h = G_s J_s Omega_w
the wheels' momentum relative to the body (read by the tachometers, linear between samples),

    Omega = J^{-1} (L - h),   R' = R hat(Omega),   L' = -Omega x L + d(t),

d a disturbance torque fixed in the body, polynomial in s = (t - t_0) / (t_N - t_0) as in
:mod:`so3jax.jobs.identify.regression`. It is integrated by the simulator's RK4 on SO(3)
(:func:`so3jax.core.integrate.rk4_step`) at the sample spacing. The record is cut into windows
of ``window`` seconds, each with its own initial attitude and momentum as free parameters,
so that a wrong inertia never integrates for long (no divergence from a poor first guess)
and the disturbance's noise, which the model cannot know, accumulates only within a window.
Residuals: the gyro's reading against Omega + b (a rate-integrating gyro's against
log(R_k^T R_{k+1})^v / Delta + b, the model's own increment over the sample interval,
docs/model.md (8.2)), and the star tracker's attitude against R (its rotation vector), each
divided by its noise level, estimated from the data's second differences. Unknowns: the
log-Cholesky parameters of J (physical by construction), the gyro bias b, the disturbance's
coefficients, and 6 per window.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.core import integrate, so3
from so3jax.jobs.identify import fit, inertia, regression


def noise_levels(tm) -> tuple[float, float]:
    """(sigma_gyro [rad/s], sigma_star [rad]) per axis, from second differences of the
    readings (a white noise's second difference has 6 times its variance; the smooth
    motion's is far smaller), by the median absolute deviation (robust to the torque's
    switching instants)."""
    def mad_sigma(d2):
        return float(np.mean(1.4826 * np.median(np.abs(d2 - np.median(d2, 0)), 0)) / np.sqrt(6.0))

    gyro = tm.gyro
    sigma_g = mad_sigma(gyro[2:] - 2 * gyro[1:-1] + gyro[:-2])
    idx = np.nonzero(tm.valid)[0]
    run = idx[2:][(idx[2:] - idx[:-2]) == 2]  # three consecutive star-tracker samples ending here
    R = tm.R
    delta = lambda a, b: np.asarray(so3.log(jnp.asarray(np.einsum("nji,njk->ikn", R[a], R[b]))).T)
    d2 = delta(run - 1, run) - delta(run - 2, run - 1)
    sigma_st = mad_sigma(d2) if len(d2) >= 3 else 1e-5
    # floors: readings free of noise (a simulated perfect sensor) still give finite weights
    return max(sigma_g, 1e-15), max(sigma_st, 1e-15)


MAX_WINDOWS = 500  # each window adds 6 unknowns to the dense normal matrix solved at every step (500: 3000, 72 MB)


def windows(tm, window: float, bias: bool, degree: int) -> tuple[int, int, int]:
    """(K, n_w, n_g): the samples per window, the windows of ``window`` [s] the record holds,
    and the global unknowns. ValueError unless the samples are uniformly spaced (as the
    integration assumes), a window spans at least two sample intervals, and there are
    from 1 to ``MAX_WINDOWS`` windows, with more residuals than unknowns."""
    t = tm.t
    h = float(np.median(np.diff(t)))
    if np.max(np.abs(np.diff(t) - h)) > 1e-6 * h:
        raise ValueError("the simulation method needs uniformly spaced samples (t)")
    if tm.gyro_output == "increment" and np.max(np.abs(tm.gyro_interval[1:] - h)) > 1e-6 * h:
        raise ValueError(f"the simulation method reads a rate-integrating gyro's increments over the sample "
                         f"interval ({h:g} s); these cover {np.median(tm.gyro_interval):g} s: the regression method")
    if not window >= 2.0 * h * (1 - 1e-9):
        raise ValueError(f"--window {window:g} s is shorter than two sample intervals ({h:g} s each); "
                         "a window integrates over at least two")
    K = int(round(min(window / h, len(t)))) + 1
    n_w = len(t) // K
    if n_w > MAX_WINDOWS:
        raise ValueError(f"--window {window:g} s cuts the record into {n_w} windows; at most {MAX_WINDOWS}, as each "
                         "adds 6 unknowns to a dense normal matrix solved at every step: a longer --window")
    n_g = 6 + (3 if bias else 0) + 3 * (degree + 1)
    if n_w < 1 or n_w * K * 3 < n_g + 6 * n_w:
        raise ValueError(f"the telemetry holds {n_w} window(s) of {window:g} s; more samples or a shorter --window")
    return K, n_w, n_g


def check(tm, *, bias: bool = True, degree: int = 3, window: float = 10.0, initial=None) -> None:
    """ValueError where :func:`identify` would refuse the telemetry or options (``initial``
    is checked by the caller), before its fit: the windows (:func:`windows`), and whether
    the data determine J (the regression's test, :func:`so3jax.jobs.identify.regression.check`)."""
    n_g = windows(tm, window, bias, degree)[2]
    regression.check(tm, bias=bias, degree=degree, interval=_interval(tm, n_g))


def _interval(tm, n_g) -> float:
    """The regression's block length [s] for the first guess and the test of whether the data
    determine J: 5 s, or shorter where the record holds too few blocks of 5 s for the
    regression's n_g // 3 + 1 block pairs, but at least two star-tracker samples long."""
    spacing = float(np.median(np.diff(tm.t[tm.valid]))) if np.count_nonzero(tm.valid) > 1 else 0.0
    return max(min(5.0, float(tm.t[-1] - tm.t[0]) / (n_g // 3 + 3)), 2.0 * spacing)


def identify(tm, *, bias: bool = True, degree: int = 3, window: float = 10.0, initial=None) -> dict:
    """The fit (the keys of :func:`so3jax.jobs.identify.regression.identify`, plus "sigma_gyro",
    "sigma_star", "sigma_momentum_jump", "windows"; "constancy" is the regression's test on
    blocks of its first guess's length); initial: the first guess of J (3, 3),
    default the regression's estimate (with its bias and disturbance). The disturbance is a
    cubic by default: fitted sample by sample, the output error follows a disturbance the
    polynomial misses (the flight mission's sinusoid over 600 s) into J, where the
    regression's block averages do not (a linear one biased J_xy by 1.7 sigma on average)."""
    t = tm.t
    h = float(np.median(np.diff(t)))
    increment = tm.gyro_output == "increment"
    K, n_w, n_g = windows(tm, window, bias, degree)
    k_d = 3 * (degree + 1)
    if initial is None:  # the regression refuses telemetry that does not determine J
        first = regression.identify(tm, bias=bias, degree=degree, interval=_interval(tm, n_g))
        J0, b0 = first["J"], (first["bias"] if bias else np.zeros(3))
        d0 = first["disturbance"].reshape(-1) if degree >= 0 else np.zeros(0)
    else:
        J0, b0, d0 = np.asarray(initial, float), np.zeros(3), np.zeros(k_d)
        if not inertia.is_physical(J0):
            raise ValueError("the initial inertia is not physical")
        regression.check(tm, bias=bias, degree=degree, interval=_interval(tm, n_g))
    sigma_g, sigma_st = noise_levels(tm)
    # each window's K samples and the next window's first (where its momentum must arrive)
    rows = np.arange(n_w)[:, None] * K + np.arange(K + 1)[None]
    take = np.minimum(rows, len(t) - 1)
    cut = lambda x: jnp.asarray(x[take])
    s = regression.normalized_time(t)
    first_valid = np.array([np.argmax(tm.valid[i * K:(i + 1) * K]) for i in range(n_w)])
    data = dict(gyro=cut(tm.gyro), R=cut(tm.R), valid=cut(tm.valid.astype(float)), h=cut(tm.wheel_momentum), s=cut(s),
                in_record=jnp.asarray((rows < len(t)).astype(float)),
                R_ref=jnp.asarray(tm.R[np.arange(n_w) * K + first_valid]),
                scale=jnp.asarray([h, t[-1] - t[0], 1.0 / sigma_g, 1.0 / sigma_st, 0.0]))
    start = np.arange(n_w) * K
    L0 = (tm.gyro[start] - b0) @ J0.T + tm.wheel_momentum[start]
    local0 = np.concatenate([np.zeros((n_w, 3)), L0], axis=1)
    p0 = np.concatenate([inertia.to_params(J0), b0 if bias else np.zeros(0), d0, local0.reshape(-1)])
    static = dict(n_g=n_g, bias=bias, degree=degree, increment=increment)
    # Windows are joined by the momentum's continuity, each jump weighted by its own
    # scatter (the disturbance's noise, which the model does not know): a first fit
    # without the joins, then the joins at the scatter they leave, twice.
    solution = fit.levenberg_marquardt(lambda p: _evaluate(p, data, **static)[:3],
                                       lambda p: _cost(p, data, **static), p0)
    for _ in range(2):
        jumps = np.asarray(_jumps(jnp.asarray(solution.p), data, **static))
        sigma_c = max(float(np.sqrt(np.mean(jumps ** 2))), 1e-12) if len(jumps) else 1.0
        data["scale"] = data["scale"].at[4].set(1.0 / sigma_c)
        solution = fit.levenberg_marquardt(lambda p: _evaluate(p, data, **static)[:3],
                                           lambda p: _cost(p, data, **static), solution.p)
    _, H, _, scores = _evaluate(jnp.asarray(solution.p), data, **static)
    # windows as clusters: the sandwich H^-1 (sum_w s_w s_w^T) H^-1 keeps the disturbance's
    # noise, correlated within a window, from making the estimate look more certain than it is
    # (with the small-sample factor n_w / (n_w - 1); the scores sum to zero at the minimum)
    H_inv = np.linalg.pinv(np.asarray(H), hermitian=True)
    scores = np.asarray(scores)
    cov = H_inv @ (scores.T @ scores) @ H_inv * n_w / max(n_w - 1, 1)
    r = np.asarray(_residuals(jnp.asarray(solution.p), data, **static)[0]).reshape(n_w * K, 2, 3)
    star = np.where(tm.valid[: n_w * K, None], r[:, 1] * sigma_st, np.nan)
    gyro = r[:, 0] * sigma_g
    if increment:  # row k's gyro residual is the reading at sample k + 1's
        gyro = np.concatenate([np.full((1, 3), np.nan), gyro[:-1]])
    out = fit.estimate(solution.p[:n_g], cov[:n_g, :n_g], bias, degree, solution, tm.wheel_inertia,
                       residual_rms=float(np.sqrt(np.mean(r ** 2))), windows=n_w,
                       residuals={"t": t[: n_w * K], "gyro [rad/s]": gyro, "star tracker [rad]": star})
    out.update(sigma_gyro=sigma_g, sigma_star=sigma_st, sigma_momentum_jump=sigma_c)
    regression.add_constancy(out, tm, bias=bias, degree=degree, interval=_interval(tm, n_g))
    if n_w < 2 * n_g:
        fit.add_warning(out, f"{n_w} windows for {n_g} global parameters: the covariance (a sandwich over windows) "
                             f"understates the uncertainty; a longer record or a shorter --window")
    return out


def _window_residual(g, local, w, bias: bool, degree: int, increment: bool):
    """The weighted residuals (K * 6,) of one window (gyro then star tracker per sample; with
    a rate-integrating gyro, row k's gyro residual is that of the reading at sample k + 1)
    and its momentum propagated to the next window's first sample (3,) [N m s]."""
    h, span, weight_g, weight_a, _ = w["scale"]
    J = inertia.from_params(g[:6])
    J_inv = jnp.linalg.inv(J)
    b = g[6:9] if bias else jnp.zeros(3, g.dtype)
    coeffs = g[6 + (3 if bias else 0):].reshape(degree + 1, 3)

    def torque(s):
        return sum(coeffs[p] * s ** p for p in range(degree + 1)) if degree >= 0 else jnp.zeros(3, g.dtype)

    def step(state, k):
        def field(tau, x):
            frac = tau / h
            hw = (1 - frac) * w["h"][k] + frac * w["h"][k + 1]
            Omega = J_inv @ (x[1] - hw)
            return (integrate.OnSO3(Omega), -so3.cross(Omega, x[1]) + torque(w["s"][k] + tau / span)), ()

        (R, L), _ = integrate.rk4_step(field, 0.0, h, (integrate.OnSO3(state[0]), state[1]))
        return (R.R, L), (R.R, L)

    R0 = w["R_ref"] @ so3.exp(local[:3])
    _, (Rs, Ls) = jax.lax.scan(step, (R0, local[3:]), jnp.arange(w["gyro"].shape[0] - 1))
    L_end = Ls[-1]
    path = jnp.concatenate([R0[None], Rs])  # at the window's K samples and the next window's first
    Rs = path[:-1]
    if increment:
        model = jax.vmap(lambda Ra, Rb: so3.log(Ra.T @ Rb))(path[:-1], path[1:]) / h
        r_g = (w["gyro"][1:] - model - b) * weight_g * w["in_record"][1:, None]
    else:
        Ls = jnp.concatenate([local[3:][None], Ls[:-1]])
        Omega = (Ls - w["h"][:-1]) @ J_inv.T
        r_g = (w["gyro"][:-1] - Omega - b) * weight_g
    err = jax.vmap(lambda Rm, Rp: so3.log(Rp.T @ Rm))(w["R"][:-1], Rs)
    r_a = err * weight_a * w["valid"][:-1, None]
    return jnp.concatenate([r_g, r_a], axis=1).reshape(-1), L_end


def _split(p, n_g):
    return p[:n_g], p[n_g:].reshape(-1, 6)


def _shared(data):
    """The per-window arrays (leading window axis): ``data`` without its shared scales."""
    return {k: v for k, v in data.items() if k != "scale"}


def _residuals(p, data, n_g, bias, degree, increment):
    """(per-window residuals (n_w, 6 K), each window's momentum at the next one's start (n_w, 3))."""
    g, local = _split(p, n_g)
    per = lambda loc, w: _window_residual(g, loc, {**w, "scale": data["scale"]}, bias, degree, increment)
    return jax.vmap(per)(local, _shared(data))


@partial(jax.jit, static_argnames=("n_g", "bias", "degree", "increment"))
def _jumps(p, data, n_g, bias, degree, increment):
    """L_end of window i - L(0) of window i + 1 (n_w - 1, 3) [N m s]."""
    _, local = _split(p, n_g)
    L_end = _residuals(p, data, n_g, bias, degree, increment)[1]
    return L_end[:-1] - local[1:, 3:]


@partial(jax.jit, static_argnames=("n_g", "bias", "degree", "increment"))
def _cost(p, data, n_g, bias, degree, increment):
    r = _residuals(p, data, n_g, bias, degree, increment)[0]
    c = _jumps(p, data, n_g, bias, degree, increment) * data["scale"][4]
    return 0.5 * (jnp.sum(r ** 2) + jnp.sum(c ** 2))


@partial(jax.jit, static_argnames=("n_g", "bias", "degree", "increment"))
def _evaluate(p, data, n_g, bias, degree, increment):
    """(cost, H = A^T A, A^T r, the windows' scores (n_w, k)), H assembled from each
    window's Jacobian (global and its own 6 parameters) and the joins' (window i's
    parameters and the next window's momentum) without forming A."""
    g, local = _split(p, n_g)
    n_w = local.shape[0]
    k = n_g + 6 * n_w
    def per(gg, loc, w):  # the outputs twice: differentiated, and as they are (one pass)
        out = _window_residual(gg, loc, {**w, "scale": data["scale"]}, bias, degree, increment)
        return out, out

    derivatives, (r, L_end) = jax.vmap(jax.jacfwd(per, argnums=(0, 1), has_aux=True),
                                        in_axes=(None, 0, 0))(g, local, _shared(data))
    (Jg, Jl), (Jgc, Jlc) = derivatives
    H_gg = jnp.einsum("wrg,wrh->gh", Jg, Jg)
    H_gl = jnp.einsum("wrg,wrl->gwl", Jg, Jl).reshape(n_g, 6 * n_w)
    H_ll = _block_diag(jnp.einsum("wrl,wrm->wlm", Jl, Jl))
    H = jnp.block([[H_gg, H_gl], [H_gl.T, H_ll]])
    s_g = jnp.einsum("wrg,wr->wg", Jg, r)
    s_l = jnp.einsum("wrl,wr->wl", Jl, r)
    scores = jnp.concatenate([s_g, (jnp.eye(n_w, dtype=r.dtype)[:, :, None] * s_l[None]).reshape(n_w, 6 * n_w)], 1)
    # the joins c_i = w_c (L_end_i - L(0)_{i+1}), i < n_w - 1, as dense rows of A
    w_c = data["scale"][4]
    c = w_c * (L_end[:-1] - local[1:, 3:])
    A_c = jnp.zeros((n_w - 1, 3, k), r.dtype)
    A_c = A_c.at[:, :, :n_g].set(w_c * Jgc[:-1])
    rows = jnp.arange(n_w - 1)
    own = n_g + 6 * rows[:, None] + jnp.arange(6)[None]  # window i's parameters
    nxt = n_g + 6 * (rows[:, None] + 1) + 3 + jnp.arange(3)[None]  # window i + 1's momentum
    A_c = A_c.at[rows[:, None, None], jnp.arange(3)[None, :, None], own[:, None, :]].set(w_c * Jlc[:-1])
    A_c = A_c.at[rows[:, None], jnp.arange(3)[None, :], nxt].add(-w_c)
    H = H + jnp.einsum("irk,irl->kl", A_c, A_c)
    scores = scores.at[:-1].add(jnp.einsum("irk,ir->ik", A_c, c))
    cost = 0.5 * (jnp.sum(r * r) + jnp.sum(c * c))
    return cost, H, scores.sum(0), scores


def _block_diag(blocks):
    """A block-diagonal matrix of blocks (n, m, m)."""
    n, m, _ = blocks.shape
    eye = jnp.eye(n, dtype=blocks.dtype)
    return jnp.einsum("ij,ilm->iljm", eye, blocks).reshape(n * m, n * m)
