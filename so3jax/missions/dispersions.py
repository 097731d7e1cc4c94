"""Monte Carlo dispersions of the paper's mission (docs/model.md §4, §15): what varies from sample to
sample, by which distribution, and the sampler.

Sample k's values depend only on (seed, k): its random words are
``jax.random.bits(fold_in(key(seed), k), (L,), uint32)`` (threefry, partitionable, so
word i depends only on the key and i). Word 0 is its disturbance seed; then two words
per variate, first those of the quantities drawn once per sample, then those of each
attempt at the physical parameters (inertias, tau_J). Each quantity reads its own
variates, so adding a dispersion (appended last) moves no other. The words become
uniform and normal variates and then parameters on the host, in float64 NumPy.

An attempt whose J0, J1 or J2 is not positive definite, or whose tau_J is not positive,
is drawn again from the next attempt's variates, up to ``max_draws`` attempts; then the
sample is rejected: never simulated. A distribution that cannot draw its quantity's
domain (a fixed tau_J <= 0, a uniform scale reaching 0, ...) is a ValueError
(:func:`check`), before anything is drawn.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.dynamics.inertia import check_inertia
from so3jax.dynamics.orbit import MAX_MEAN_MOTION, check_mean_motion, orbital_rate
from so3jax.dynamics.paper import PAPER_J0, PAPER_J2

BLOCK = 512  # samples per call of the (compiled) word generator
MAX_SAMPLES = 2**32  # samples 0 .. 2^32 - 1: sample k's words are keyed by k as a 32-bit integer
OTHER_VARIATES = 12  # n, amplitude, frequency, noise_std, initial attitude (4) and rate (4)
PHYSICAL_VARIATES = 3 * 11 + 1  # per attempt: J0, J1, J2 (11 each), tau_J


# --- distributions ----------------------------------------------------------------------
# Each maps a variate (u uniform on (0, 1), z standard normal) to a value.


@dataclasses.dataclass(frozen=True)
class Fixed:
    """Always ``value``."""

    value: float

    def sample(self, u, z):
        return np.full_like(u, self.value)


@dataclasses.dataclass(frozen=True)
class Uniform:
    """Uniform on [low, high]."""

    low: float
    high: float

    def sample(self, u, z):
        return self.low + (self.high - self.low) * u


@dataclasses.dataclass(frozen=True)
class Normal:
    """Gaussian with mean ``mean`` and standard deviation ``std``."""

    mean: float
    std: float

    def sample(self, u, z):
        return self.mean + self.std * z


@dataclasses.dataclass(frozen=True)
class LogNormal:
    """exp(N(log median, sigma^2)): positive, median ``median``, log-space std ``sigma``."""

    median: float
    sigma: float

    def sample(self, u, z):
        return self.median * np.exp(self.sigma * z)


@dataclasses.dataclass(frozen=True)
class Choice:
    """One of ``values``, each with probability 1 / len(values): value floor(u len(values))."""

    values: tuple

    def sample(self, u, z):
        values = np.asarray(self.values, float)
        return values[np.minimum((np.asarray(u) * len(values)).astype(np.int64), len(values) - 1)]


DISTRIBUTIONS = {"fixed": Fixed, "uniform": Uniform, "normal": Normal, "lognormal": LogNormal, "choice": Choice}
Distribution = Fixed | Uniform | Normal | LogNormal | Choice


def parse_distribution(value, where: str) -> Distribution:
    """A number (fixed) or a table ``{dist = "uniform", low = .., high = ..}`` (``{dist =
    "choice", values = [..]}``: one of the values, equally likely) -> distribution."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return _checked(Fixed(float(value)), where)
    if not isinstance(value, dict) or "dist" not in value:
        raise ValueError(f"{where}: expected a number or a table with 'dist' ({', '.join(DISTRIBUTIONS)}), "
                         f"got {value!r}")
    kind = DISTRIBUTIONS.get(value["dist"])
    if kind is None:
        raise ValueError(f"{where}: unknown distribution {value['dist']!r}; choose one of {', '.join(DISTRIBUTIONS)}")
    params = {k: v for k, v in value.items() if k != "dist"}
    names = [f.name for f in dataclasses.fields(kind)]
    if sorted(params) != sorted(names):
        raise ValueError(f"{where}: distribution {value['dist']!r} takes exactly {names}, got {sorted(params)}")
    if kind is Choice:
        values = params["values"]
        if (not isinstance(values, (list, tuple)) or not values
                or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in values)):
            raise ValueError(f"{where}.values must be a list of numbers, got {values!r}")
        return _checked(Choice(tuple(float(v) for v in values)), where)
    for name, v in params.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f"{where}.{name} must be a number, got {v!r}")  # noqa: TRY004
    return _checked(kind(**{k: float(v) for k, v in params.items()}), where)


# The largest |z| a standard normal variate takes: Box-Muller from u >= 2^-33 (:func:`draw_variates`).
Z_MAX = math.sqrt(-2.0 * math.log(0.5 / 2.0**32))


def _spread(dist: Distribution) -> float:
    """The largest magnitude the arithmetic of ``dist``'s draws reaches: a uniform's width, a
    normal's mean +- Z_MAX std, a lognormal's median exp(Z_MAX sigma) (inf beyond a float)."""
    try:
        return {Fixed: lambda d: abs(d.value), Uniform: lambda d: d.high - d.low,
                Normal: lambda d: abs(d.mean) + Z_MAX * d.std,
                LogNormal: lambda d: d.median * math.exp(Z_MAX * d.sigma),
                Choice: lambda d: max(map(abs, d.values))}[type(dist)](dist)
    except OverflowError:
        return math.inf


def _checked(dist: Distribution, where: str) -> Distribution:
    values = dist.values if isinstance(dist, Choice) else dataclasses.astuple(dist)
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{where}: parameters must be finite, got {dist}")
    if not math.isfinite(_spread(dist)):
        tails = f" (normal variates reach {Z_MAX:.3g})" if isinstance(dist, (Normal, LogNormal)) else ""
        raise ValueError(f"{where}: {describe(dist)} draws values beyond what a float holds{tails}: narrow it")
    if isinstance(dist, Uniform) and dist.low > dist.high:
        raise ValueError(f"{where}: uniform needs low <= high, got {dist}")
    if (isinstance(dist, Normal) and dist.std < 0
            or isinstance(dist, LogNormal) and (dist.sigma < 0 or dist.median <= 0)):
        raise ValueError(f"{where}: needs std / sigma >= 0 and median > 0, got {dist}")
    return dist


def check_domain(dist: Distribution, where: str, low: float = 0.0, strict: bool = True) -> Distribution:
    """ValueError unless ``dist`` draws values of its quantity's domain, x > low (x >= low
    where not ``strict``): a fixed value, or a uniform's whole range (its upper end above
    ``low`` where strict), in the domain; a normal's mean in it (its tails beyond ``low``
    are drawn again or, after max_draws, reject the sample, for the physical parameters);
    a lognormal for low <= 0 (it is positive)."""
    ok = {
        Fixed: lambda d: d.value > low if strict else d.value >= low,
        Uniform: lambda d: d.low >= low and (d.high > low if strict else True),
        Normal: lambda d: d.mean > low if strict else d.mean >= low,
        LogNormal: lambda d: low <= 0.0,
        Choice: lambda d: min(d.values) > low if strict else min(d.values) >= low,
    }[type(dist)](dist)
    if not ok:
        raise ValueError(f"{where} must be {'>' if strict else '>='} {low:g}: {describe(dist)} is outside that domain")
    return dist


def check_magnitude(dist: Distribution, where: str, limit: float, limit_name: str) -> Distribution:
    """ValueError unless ``dist`` draws values of magnitude at most ``limit`` by
    :func:`check_domain`'s rule: a fixed value, or a uniform's whole range, in [-limit,
    limit]; a normal's mean, or a lognormal's median, in it (their tails beyond are
    rejected, sample by sample). limit_name: what bounds it, for the message."""
    ok = {
        Fixed: lambda d: abs(d.value) <= limit,
        Uniform: lambda d: -limit <= d.low and d.high <= limit,
        Normal: lambda d: abs(d.mean) <= limit,
        LogNormal: lambda d: d.median <= limit,
        Choice: lambda d: max(map(abs, d.values)) <= limit,
    }[type(dist)](dist)
    if not ok:
        raise ValueError(f"{where} must not exceed {limit_name} = {limit:g} in magnitude: {describe(dist)} "
                         "draws beyond it")
    return dist


def least(dist: Distribution) -> float:
    """The least value :func:`check_domain`'s rule counts ``dist`` to draw: a fixed value,
    a uniform's low end, a normal's mean, a lognormal's median (a tail below is rejected,
    sample by sample, where a check needs it)."""
    return {Fixed: lambda d: d.value, Uniform: lambda d: d.low, Normal: lambda d: d.mean,
            LogNormal: lambda d: d.median, Choice: lambda d: min(d.values)}[type(dist)](dist)


def greatest(dist: Distribution) -> float:
    """The greatest value :func:`check_domain`'s rule counts ``dist`` to draw: a fixed value,
    a uniform's high end, a normal's mean, a lognormal's median (a tail above is rejected,
    sample by sample, where a check needs it)."""
    return {Fixed: lambda d: d.value, Uniform: lambda d: d.high, Normal: lambda d: d.mean,
            LogNormal: lambda d: d.median, Choice: lambda d: max(d.values)}[type(dist)](dist)


_BOUND_NAME = {Uniform: "the upper end", Normal: "the mean", LogNormal: "the median", Choice: "the largest value"}


def check_orbit(dist: Distribution, where: str = "orbit.n") -> Distribution:
    """ValueError unless ``dist`` draws the mean motions [rad/s] of orbits at least
    MIN_ALTITUDE above the Earth's equatorial radius (:mod:`so3jax.dynamics.orbit`) by
    :func:`check_domain`'s rule: a fixed value, or a uniform's whole range, at most
    MAX_MEAN_MOTION; a normal's mean, or a lognormal's median (their tails above are
    rejected, sample by sample: :func:`in_orbit_domain`)."""
    label = where if isinstance(dist, Fixed) else f"{where} ({_BOUND_NAME[type(dist)]} of {describe(dist)})"
    check_mean_motion(greatest(dist), label)
    return dist


def in_orbit_domain(n, strict: bool = False) -> np.ndarray:
    """Whether each mean motion n [rad/s] is an orbit's at least MIN_ALTITUDE high: 0 <= n
    <= MAX_MEAN_MOTION (0 < n where ``strict``: a mission that flies on its orbit)."""
    n = np.asarray(n, np.float64)
    return ((n > 0.0) if strict else (n >= 0.0)) & (n <= MAX_MEAN_MOTION)


# The domain of each dispersed quantity (Dispersions field: config name, low, strict); the
# orbital rate's upper end: :func:`check_orbit`.
DOMAINS = {
    "tau_J": ("deployment.tau_J [s]", 0.0, True),
    "n": ("orbit.n [rad/s]", 0.0, False),
    "noise_std": ("disturbance.noise_std [N m]", 0.0, False),
    "initial_rate": ("initial.rate [rad/s]", 0.0, False),
}
INERTIA_DOMAINS = {"scale": (0.0, True), "axis_scale": (0.0, True)}  # InertiaDispersion field: low, strict


def check(d: Dispersions, *, warn: bool = True) -> None:
    """Every dispersed quantity's distribution in its domain (:func:`check_domain`), and
    the nominal inertias (docs/model.md §6; an InertiaWarning for one that breaks the triangle
    inequality, if ``warn``), before anything is drawn or compiled."""
    for name, (where, low, strict) in DOMAINS.items():
        check_domain(getattr(d, name), where, low, strict)
    check_orbit(d.n)
    for J in ("J0", "J1", "J2"):
        check_inertia_dispersion(getattr(d, J), f"inertia.{J}", warn=warn)
    if not 0.0 <= d.initial_angle_deg <= 180.0:
        raise ValueError(f"initial.max_angle_deg must be in [0, 180], got {d.initial_angle_deg}")


def check_inertia_dispersion(inertia: InertiaDispersion, where: str, *, warn: bool = True) -> None:
    """ValueError unless ``inertia``'s distributions draw in their domains and its nominal is
    an inertia (an InertiaWarning where it breaks the triangle inequality, if ``warn``)."""
    for field, (low, strict) in INERTIA_DOMAINS.items():
        check_domain(getattr(inertia, field), f"{where}.{field}", low, strict)
    if not 0.0 <= inertia.rotation_deg <= 180.0:
        raise ValueError(f"{where}.rotation_deg must be in [0, 180], got {inertia.rotation_deg}")
    if inertia.nominal is not None:
        check_inertia(f"{where.rsplit('.', 1)[-1]} ({where}.nominal)", np.asarray(inertia.nominal, dtype=float),
                      warn=warn)
    if inertia.second_moments is not None:
        _check_second_moments(inertia, where)


def _check_second_moments(inertia: InertiaDispersion, where: str) -> None:
    """ValueError unless the principal form can draw only bodies: its factors >= 0 (a fixed
    value, a uniform or a lognormal: a normal's tail draws negative moments), no
    axis_scale or products beside it, and a nominal that is a body (within round-off)."""
    dist = inertia.second_moments
    if isinstance(dist, Normal):
        raise ValueError(f"{where}.second_moments: a normal can draw a negative second moment; "
                         "use a lognormal or a uniform on [0, ...]")
    check_domain(dist, f"{where}.second_moments", 0.0, strict=False)
    if inertia.axis_scale != Fixed(1.0) or inertia.products != Fixed(0.0):
        raise ValueError(f"{where}: second_moments (a body by construction) replaces axis_scale and products; "
                         "give one form or the other")
    if inertia.nominal is not None:
        principal = np.linalg.eigvalsh(np.asarray(inertia.nominal, float))
        s = second_moments(principal)
        if np.any(s < -1e-9 * np.sum(principal)):
            raise ValueError(f"{where}.second_moments needs a nominal inertia that a rigid body has: its principal "
                             f"moments {np.round(principal, 6).tolist()} break the triangle inequality (give the "
                             "nominal a rigid body's, or disperse it with axis_scale and products)")


def describe(dist: Distribution) -> Any:
    """The TOML form of a distribution (a number when fixed)."""
    if isinstance(dist, Fixed):
        return dist.value
    name = next(k for k, v in DISTRIBUTIONS.items() if isinstance(dist, v))
    if isinstance(dist, Choice):
        return {"dist": name, "values": list(dist.values)}
    return {"dist": name, **dataclasses.asdict(dist)}


# --- what is dispersed ------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class InertiaDispersion:
    """J = scale * Q (D J_nom D) Q^T + P  [kg m^2], or, with ``second_moments``, a rigid
    body by construction: J = scale * Q V (tr(S) I - S) V^T Q^T.

    scale: overall factor; axis_scale: a_i (three independent draws) on the moment about
    body axis i, D = diag(sqrt(a)) (so J_ij -> sqrt(a_i a_j) J_ij; a_i <= 0 is redrawn);
    rotation_deg: Q uniform on SO(3) up to this angle [deg], the principal axes rotated;
    products: P symmetric, zero diagonal, its xy, xz, yz entries three independent draws.
    second_moments: factors f_i (three independent draws, >= 0) on the nominal's second
    moments of mass about its principal axes V, s_i = tr(J_nom) / 2 - lambda_i >= 0 [kg m^2]
    (J_nom = V diag(lambda) V^T); S = diag(f_i s_i). Every draw is then a body's inertia:
    its principal moments s_j + s_k meet the triangle inequality. It takes the variates of
    axis_scale, which it replaces with products.
    nominal: J_nom (3x3); None for J1, whose nominal is the sample's J0 (so scale is the
    deployment growth J1/J0, 2 in the paper).
    """

    nominal: tuple | None = None
    scale: Distribution = Fixed(1.0)
    axis_scale: Distribution = Fixed(1.0)
    rotation_deg: float = 0.0
    products: Distribution = Fixed(0.0)
    second_moments: Distribution | None = None

    def apply(self, variates: _Variates, J_nom):
        """(J, scale) from 11 variates, vectorized over leading axes."""
        s = self.scale.sample(*variates.take(1))[..., 0]
        if self.second_moments is not None:
            f = self.second_moments.sample(*variates.take(3))
            Q = rotation_matrix(rotation_vector(*variates.take(4), math.radians(self.rotation_deg)))
            variates.take(3)  # the products' variates: unused, so that the layout stays
            moments, V = np.linalg.eigh(np.asarray(J_nom, float))
            S = f * np.maximum(second_moments(moments), 0.0)  # a nominal on the triangle's edge: s_i = 0
            body = np.sum(S, axis=-1, keepdims=True) - S  # principal moments s_j + s_k
            QV = Q @ V
            J = s[..., None, None] * ((QV * body[..., None, :]) @ np.swapaxes(QV, -1, -2))
            return 0.5 * (J + np.swapaxes(J, -1, -2)), s
        root = np.sqrt(self.axis_scale.sample(*variates.take(3)))
        Q = rotation_matrix(rotation_vector(*variates.take(4), math.radians(self.rotation_deg)))
        p = self.products.sample(*variates.take(3))
        P = np.zeros(p.shape[:-1] + (3, 3))
        P[..., [0, 1, 0, 2, 1, 2], [1, 0, 2, 0, 2, 1]] = p[..., [0, 0, 1, 1, 2, 2]]
        J = s[..., None, None] * (Q @ (root[..., :, None] * J_nom * root[..., None, :]) @ np.swapaxes(Q, -1, -2)) + P
        return 0.5 * (J + np.swapaxes(J, -1, -2)), s


def second_moments(principal):
    """s_i = (lambda_1 + lambda_2 + lambda_3) / 2 - lambda_i [kg m^2], the second moments of
    mass about the principal axes from the principal moments lambda (..., 3): all >= 0
    exactly where the moments meet the triangle inequality (a rigid body)."""
    principal = np.asarray(principal, float)
    return 0.5 * np.sum(principal, axis=-1, keepdims=True) - principal


@dataclasses.dataclass(frozen=True)
class Dispersions:
    """Every dispersed quantity of the mission; defaults are the paper's fixed values.

    tau_J [s] deployment time constant; n [rad/s] orbital rate; disturbance_seed: None
    (a random seed per sample) or one seed for all; amplitude [N m], frequency [rad/s],
    noise_std [N m] of the disturbance; initial attitude error uniform on SO(3) up to
    initial_angle_deg [deg]; initial rate: magnitude initial_rate [rad/s], direction
    uniform on the sphere.
    """

    J0: InertiaDispersion = InertiaDispersion(nominal=PAPER_J0)
    J1: InertiaDispersion = InertiaDispersion(scale=Fixed(2.0))
    J2: InertiaDispersion = InertiaDispersion(nominal=PAPER_J2)
    tau_J: Distribution = Fixed(300.0)
    n: Distribution = Fixed(orbital_rate())
    disturbance_seed: int | None = None
    amplitude: Distribution = Fixed(0.1)
    frequency: Distribution = Fixed(1e-3)
    noise_std: Distribution = Fixed(0.025)
    initial_angle_deg: float = 0.0
    initial_rate: Distribution = Fixed(0.0)


class RolloutParams(NamedTuple):
    """What the rollout of one sample needs (numpy, with a leading batch axis)."""

    J0: np.ndarray  # (3, 3) kg m^2
    J1: np.ndarray  # (3, 3) kg m^2
    J2: np.ndarray  # (3, 3) kg m^2
    tau_J: np.ndarray  # s
    n: np.ndarray  # rad/s
    amplitude: np.ndarray  # N m
    frequency: np.ndarray  # rad/s
    noise_std: np.ndarray  # N m
    R0: np.ndarray  # (3, 3)
    Omega0: np.ndarray  # (3,) rad/s
    seed: np.ndarray  # int32, disturbance noise seed


# One sample's shape of each RolloutParams field (reals in the run's dtype, seed int32).
PARAM_SHAPES = RolloutParams((3, 3), (3, 3), (3, 3), (), (), (), (), (), (3, 3), (3,), ())


class Samples(NamedTuple):
    """The drawn samples (numpy, leading axis N): rollout parameters and how they came about."""

    params: RolloutParams
    valid: np.ndarray  # bool: positive definite within max_draws; the others are never simulated
    draws: np.ndarray  # draws used (max_draws for a rejected sample, whose values are its last draw)
    scale: np.ndarray  # (N, 3) overall scale factors drawn for J0, J1, J2
    attitude_error: np.ndarray  # (N, 3) rotation vector of R0 (R_d(0) = I), rad
    leaves: dict = {}  # dispersed component parameters {key: (N, *shape)} (so3jax.missions.dispersed)
    outside: np.ndarray | None = None  # bool: rejected for a component value outside its domain or limit
    reason: np.ndarray | None = None  # str: why each sample is rejected, "" where valid (so3jax.missions.dispersed)


# --- sampling ---------------------------------------------------------------------------


class _Variates:
    """Hands out consecutive variates (u, z) along the last axis."""

    def __init__(self, u, z):
        self.u, self.z, self.used = u, z, 0

    def take(self, n: int):
        if self.used + n > self.u.shape[-1]:
            raise IndexError("more variates taken than drawn")
        self.used += n
        return self.u[..., self.used - n : self.used], self.z[..., self.used - n : self.used]


def draw_variates(words) -> _Variates:
    """Two uint32 words per variate -> u uniform on (0, 1) and z standard normal (Box-Muller)."""
    u, v = ((words[..., i::2].astype(np.float64) + 0.5) / 2.0**32 for i in range(2))
    return _Variates(u, np.sqrt(-2.0 * np.log(u)) * np.cos(2.0 * np.pi * v))


def _angle_cdf(theta):
    """theta - sin(theta) (the Haar angle CDF on SO(3), unnormalized), by series where it cancels."""
    t2 = theta * theta
    series = theta * t2 / 6.0 * (1.0 - t2 / 20.0 * (1.0 - t2 / 42.0 * (1.0 - t2 / 72.0 * (1.0 - t2 / 110.0))))
    return np.where(theta < 0.1, series, theta - np.sin(theta))


def rotation_vector(u, z, max_angle: float):
    """Rotation vectors (..., 3) of rotations uniform (Haar) on SO(3) up to angle max_angle [rad].

    From 4 variates: the axis is the direction of 3 normals; the angle theta, with density
    proportional to 1 - cos(theta) on [0, max_angle], inverts theta - sin(theta) = c by
    Newton steps from (6 c)^(1/3), which lies below the root (convex side).
    """
    if max_angle <= 0.0:
        return np.zeros(u.shape[:-1] + (3,))
    max_angle = min(max_angle, math.pi)
    axis = z[..., :3] / np.linalg.norm(z[..., :3], axis=-1, keepdims=True)
    c = u[..., 3] * _angle_cdf(max_angle)
    theta = np.cbrt(6.0 * c)
    for _ in range(8):
        slope = 2.0 * np.sin(0.5 * theta) ** 2
        theta = theta - (_angle_cdf(theta) - c) / np.where(slope > 0, slope, 1.0)
    return np.clip(theta, 0.0, max_angle)[..., None] * axis


def rotation_matrix(v):
    """exp(hat(v)) for rotation vectors (..., 3) (Rodrigues)."""
    theta = np.linalg.norm(v, axis=-1)[..., None, None]
    axis = v / np.where(theta[..., 0] > 0, theta[..., 0], 1.0)
    K = np.zeros(v.shape[:-1] + (3, 3))
    K[..., [2, 0, 1], [1, 2, 0]] = axis
    K = K - np.swapaxes(K, -1, -2)
    return np.eye(3) + np.sin(theta) * K + (1.0 - np.cos(theta)) * (K @ K)


def is_positive_definite(J):
    """Sylvester's criterion on symmetric (..., 3, 3) matrices (False for non-finite entries)."""
    minor2 = J[..., 0, 0] * J[..., 1, 1] - J[..., 0, 1] ** 2
    return (J[..., 0, 0] > 0) & (minor2 > 0) & (np.linalg.det(J) > 0)


@functools.partial(jax.jit, static_argnames="n_words")
def _words(seed, indices, n_words: int):
    base = jax.random.key(seed)
    return jax.vmap(lambda k: jax.random.bits(jax.random.fold_in(base, k), (n_words,), jnp.uint32))(indices)


def _draw_block(d: Dispersions, words, max_draws: int):
    """Parameters of a block of samples from their words (B, L)."""
    other = draw_variates(words[:, 1 : 1 + 2 * OTHER_VARIATES])
    attempts = draw_variates(words[:, 1 + 2 * OTHER_VARIATES :].reshape(len(words), max_draws, 2 * PHYSICAL_VARIATES))
    J0, s0 = d.J0.apply(attempts, np.asarray(d.J0.nominal))
    J1, s1 = d.J1.apply(attempts, J0)
    J2, s2 = d.J2.apply(attempts, np.asarray(d.J2.nominal))
    tau_J = d.tau_J.sample(*attempts.take(1))[..., 0]
    ok = is_positive_definite(J0) & is_positive_definite(J1) & is_positive_definite(J2) & (tau_J > 0)
    valid = ok.any(axis=1)
    first = np.where(valid, ok.argmax(axis=1), max_draws - 1)

    def pick(x):
        return x[np.arange(len(x)), first]

    n, amplitude, frequency, noise_std = (dist.sample(*other.take(1))[:, 0]
                                          for dist in (d.n, d.amplitude, d.frequency, d.noise_std))
    attitude_error = rotation_vector(*other.take(4), math.radians(d.initial_angle_deg))
    R0 = rotation_matrix(attitude_error)
    rate_u, rate_z = other.take(4)
    norm = np.linalg.norm(rate_z[:, 1:], axis=-1, keepdims=True)
    Omega0 = d.initial_rate.sample(rate_u[:, :1], rate_z[:, :1]) * rate_z[:, 1:] / norm
    if d.disturbance_seed is None:
        seed = (words[:, 0] >> 1).astype(np.int32)
    else:
        seed = np.full(len(words), d.disturbance_seed, np.int32)
    params = RolloutParams(pick(J0), pick(J1), pick(J2), pick(tau_J), n, amplitude, frequency, noise_std, R0, Omega0,
                           seed)
    scale = np.stack([pick(s0), pick(s1), pick(s2)], -1)
    return Samples(params, valid, (first + 1).astype(np.int32), scale, attitude_error)


def draw_samples(dispersions: Dispersions, seed: int, n_samples: int, max_draws: int, first: int = 0) -> Samples:
    """Samples first .. first + n_samples - 1, in float64. Sample k depends only on (seed, k)."""
    check(dispersions, warn=False)
    if isinstance(n_samples, bool) or not isinstance(n_samples, int) or n_samples < 1:
        raise ValueError(f"n_samples must be a positive integer, got {n_samples!r}")
    if isinstance(max_draws, bool) or not isinstance(max_draws, int) or max_draws < 1:
        raise ValueError(f"max_draws must be a positive integer, got {max_draws!r}")
    n_words = 1 + 2 * (OTHER_VARIATES + max_draws * PHYSICAL_VARIATES)
    blocks = []
    for start in range(0, n_samples, BLOCK):
        indices = np.arange(first + start, first + start + BLOCK, dtype=np.uint32)
        words = np.asarray(_words(np.uint32(seed), indices, n_words))
        blocks.append(_draw_block(dispersions, words[: n_samples - start], max_draws))
    return jax.tree.map(lambda *xs: np.concatenate(xs), *blocks)
