"""Drawing a mission's dispersed samples (docs/model.md §4, §15): the ``[dispersions]`` table
parsed and checked against the mission (:func:`parse`: the dispersed quantities,
:class:`Dispersions`, and leaves, :class:`Leaf`), and each sample's values drawn from their
distributions (:func:`draw`), with every check that rejects a sample and its reason
(:data:`REJECTED`). The distributions are :mod:`so3jax.missions.distributions`'; the drawn
values become each sample's scenario and loop, a batch of rollouts, in
:mod:`so3jax.missions.batched`, which this module never imports.

Keys are the mission's leaves (``deployment.tau_J``, ``sensors.gyro.arw``,
``actuator.wheels.max_torque``, ...), values a number (fixed) or a distribution
(:func:`so3jax.missions.distributions.parse_distribution`). A few leaves take structured
distributions and keep the variate layout of the sampler below:

* ``inertia.J0``, ``inertia.J1``, ``inertia.J2``: ``{scale, axis_scale, rotation_deg,
  products}``, or ``{scale, second_moments, rotation_deg}`` (a rigid body by construction)
  (:class:`InertiaDispersion`; J1's is applied to the
  sample's J0 when the mission gives J1 as a scale of J0);
* ``initial.attitude``: ``{max_angle_deg}``, R(0) = R_mission(0) exp(hat(v)), v uniform
  on SO(3) up to that angle; ``initial.rate``: ``{norm}``, |Omega(0)| drawn from the
  distribution ``norm`` [rad/s], its direction uniform on the sphere;
* ``seed``: ``"random"``, a disturbance and sensor-noise seed per sample, or ``"mission"``
  (the default), the mission's seed for every sample.

Every other leaf is a parameter of a flown sensor, estimator or actuator, or of the
mission's reference or inertia kind (:data:`SCENARIO_LEAVES`: slew times and attitudes,
inertia-event times, ...; an inertia matrix by an inertia.J0-style table, each matrix from
11 variates of its own): each element of its value is drawn independently from its own
variates, ``fold_in(fold_in(key(seed), k), crc32(leaf))``, so adding or removing a
dispersion moves no other; a distribution with ``relative = "offset"`` (``"scale"``) draws
what is added to (multiplies) the mission's value. Each sample's reference and inertia are
built from its values (:func:`so3jax.missions.batched.scenario_values`); a sample whose values the kind's checks
refuse (slews that overlap) is rejected. A sample with a
value outside the parameter's declared domain is rejected (never simulated), and so is
one that breaks a bound a component's own check sets between two of its parameters
(:data:`MAGNITUDE_LIMITS`: a wheel's initial speed within its speed limit, as ``fly``
checks it): a sample's mission passes the checks of a flown one. A distribution that
cannot keep within such a bound, by :func:`~so3jax.missions.distributions.check_domain`'s
rule against the least limit drawn (:func:`~so3jax.missions.distributions.least`), is
refused before anything is drawn; its tails are rejected sample by sample. The
estimator keeps the noise levels the mission's nominal sensors report: the hardware is
dispersed, not what the filter assumes. A fault's values (``faults.I.time``, ``.end``,
``.factor``, ``.wheel``, ``.step``, I the 0-based ``[[faults]]`` entry: :data:`FAULT_LEAVES`)
are leaves of each sample's loop as a component's parameters are; a sample whose
star-tracker outage ends at or before its time is rejected, and so is one whose wheels
failed off leave the others spanning less than 3-D where the loop drops them. The springs
and dampers of the mission's hinged panels and slosh particles (``appendages.I.k``, ``.c``,
``slosh.J.k``, ``.c``: :data:`FLEXIBLE_LEAVES`, docs/model.md §8.9) are leaves of each
sample's scenario; one given per phase draws each phase's value on its own.

The dispersed quantities' sampler (:func:`draw_samples`): sample k's values depend only on
(seed, k): its random words are ``jax.random.bits(fold_in(key(seed), k), (L,), uint32)``
(threefry, partitionable, so word i depends only on the key and i). Word 0 is its
disturbance seed; then two words per variate, first those of the quantities drawn once per
sample, then those of each attempt at the physical parameters (inertias, tau_J). Each
quantity reads its own variates, so adding a dispersion (appended last) moves no other. The
words become uniform and normal variates and then parameters on the host, in float64 NumPy.

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
import zlib
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.components import registry as components
from so3jax.core import checks
from so3jax.dynamics import attitude_profiles as profiles
from so3jax.dynamics.inertia import check_inertia
from so3jax.dynamics.orbit import MAX_MEAN_MOTION, MIN_ALTITUDE, check_mean_motion, orbital_rate
from so3jax.dynamics.paper import PAPER_J0, PAPER_J2
from so3jax.missions import build
from so3jax.missions import faults as fault_list
from so3jax.missions.distributions import (
    DISTRIBUTIONS,
    Choice,
    Distribution,
    Fixed,
    LogNormal,
    Normal,
    Uniform,
    check_domain,
    check_magnitude,
    describe,
    greatest,
    least,
    parse_distribution,
)
from so3jax.missions.mission import Mission
from so3jax.sim.pointing import AFTER_FAULT

BLOCK = 512  # samples per call of the (compiled) word generator
MAX_SAMPLES = 2**32  # samples 0 .. 2^32 - 1: sample k's words are keyed by k as a 32-bit integer
OTHER_VARIATES = 12  # n, amplitude, frequency, noise_std, initial attitude (4) and rate (4)
PHYSICAL_VARIATES = 3 * 11 + 1  # per attempt: J0, J1, J2 (11 each), tau_J
STRUCTURED = {
    ("deployment", "tau_J"): "tau_J",
    ("orbit", "n"): "n",
    ("disturbance", "amplitude"): "amplitude",
    ("disturbance", "frequency"): "frequency",
    ("disturbance", "noise_std"): "noise_std",
}
INERTIA_KEYS = ("scale", "axis_scale", "rotation_deg", "products", "second_moments")
LOOP_TABLES = ("sensors", "estimator", "actuator", "momentum", "filter")
SCENARIO_TABLES = ("reference", "inertia")
# A component parameter whose magnitude its component's check bounds by another of its
# parameters, element by element: {parameter: limit} (Wheels.check: |Omega_w(0)| <= Omega_max).
MAGNITUDE_LIMITS = {"actuator.wheels.initial_speed": "actuator.wheels.max_speed"}
INERTIA = "inertia"  # an inertia matrix [kg m^2], dispersed as inertia.J0 is (an InertiaDispersion)
# The scenario's dispersible parameters, by reference and inertia kind: {(table, kind):
# {parameter: (low, strict) or INERTIA}}. Each sample's reference or inertia is built from its values
# (:func:`so3jax.missions.batched.scenario_values`); one its kind's checks refuse is rejected (:func:`draw_leaves`).
SCENARIO_LEAVES = {
    ("reference", "inertial"): {"attitude": (-math.inf, False)},
    ("reference", "lvlh"): {"offset": (-math.inf, False)},
    ("reference", "table"): {"times": (-math.inf, False)},
    ("reference", "slews"): {"start": (-math.inf, False), "attitudes": (-math.inf, False), "times": (0.0, False),
                             "max_rate": (0.0, True), "max_acceleration": (0.0, True)},
    ("inertia", "events"): {"initial": INERTIA, "times": (0.0, False), "time_constants": (0.0, False),
                            "targets": (0.0, True)},
    ("inertia", "linear"): {"start": INERTIA, "end": INERTIA, "times": (0.0, False)},
    ("inertia", "table"): {"inertias": INERTIA, "times": (-math.inf, False)},
}
# A fault's dispersible values ([[faults]] entry i: faults.i.PARAMETER), by its target:
# {target: {parameter: (low, high, high excluded)}}; a wheel's factor is a degraded one's.
FAULT_LEAVES = {"wheel": {"time": (0.0, math.inf, False), "factor": (0.0, 1.0, True), "wheel": (1.0, math.inf, False)},
                "star_tracker": {"time": (0.0, math.inf, False), "end": (0.0, math.inf, False)},
                "gyro": {"time": (0.0, math.inf, False), "step": (-math.inf, math.inf, False)},
                "thruster": {"time": (0.0, math.inf, False)}}
FRICTION_FACTOR = {"friction": (0.0, math.inf, False)}  # a friction fault's factor: >= 0 (8.23)
FAULT_UNITS = {"time": "s", "end": "s", "factor": "-", "step": "rad/s", "wheel": "-"}  # samples.csv's units
# The flexible body's dispersible values (docs/model.md §8.9): an [[appendages]] entry's or a
# [[slosh]] entry's spring and damper, appendages.I.k or slosh.J.c (I, J 0-based), each sample's
# scenario built with its values (so3jax.missions.batched.scenario_values): {table: {parameter: unit}}.
FLEXIBLE_LEAVES = {"appendages": {"k": "N m/rad", "c": "N m s/rad"}, "slosh": {"k": "N/m", "c": "N s/m"}}
FLEXIBLE_TABLES = tuple(FLEXIBLE_LEAVES)
# Why a sample is rejected (never simulated), in the order its checks are read: {check: reason}.
REJECTED = {
    "draws": "no positive definite inertia and positive tau_J within sweep.max_draws draws",
    "orbit": f"an orbit below the least altitude ({MIN_ALTITUDE / 1e3:g} km: orbit.n above "
             f"{MAX_MEAN_MOTION:.6g} rad/s) or no orbit (orbit.n < 0, or 0 where the mission flies on its orbit)",
    "domain": "a dispersed value outside its parameter's domain",
    "bound": "a dispersed value beyond its limit (|actuator.wheels.initial_speed| > max_speed)",
    "outage": "a star-tracker outage that ends at or before its time (faults: [time, end))",
    "wheels": "wheels failed off that leave the others spanning less than 3-D, with detection on (fdir)",
    "overlap": "slews that overlap (reference.slews: a slew ends after the next starts)",
    "order": "times that do not increase (reference or inertia table, inertia events)",
    "inertia_table": "an inertia of the inertia kind (events, linear, table) not positive definite",
}
# A distribution's ``relative`` key: "offset", the mission's value plus the draw; "scale", times it.
RELATIVE = ("offset", "scale")
INERTIA_VARIATES = 11  # per inertia matrix drawn (InertiaDispersion.apply)


# --- what is dispersed, and its checks ---------------------------------------------------


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
    leaves: dict = {}  # dispersed component parameters {key: (N, *shape)} (draw)
    outside: np.ndarray | None = None  # bool: rejected for a component value outside its domain or limit
    reason: np.ndarray | None = None  # str: why each sample is rejected, "" where valid (draw)



# --- the [dispersions] table: the dispersed quantities and leaves of a mission --------------


@dataclasses.dataclass(frozen=True)
class Leaf:
    """A dispersed component or scenario parameter: its dotted key, distribution (of the value,
    or of its offset from or scale of the mission's value, element by element), the shape of
    the mission's value, and the parameter's domain [low, high]. bound: (parameter, its
    mission value, limit, its mission value), flattened, of a :data:`MAGNITUDE_LIMITS`
    pair this leaf is either side of (each sample's |parameter| <= limit, element by
    element, the dispersed side's drawn values in place of the mission's)."""

    key: str
    dist: Distribution
    shape: tuple
    low: float
    high: float
    bound: tuple | None = None
    order: tuple | None = None  # (time key, its mission value, end key, its value): end > time (an outage's)
    relative: str | None = None  # "offset" or "scale" of the mission's value (:data:`RELATIVE`)
    nominal: tuple = ()  # the mission's value, flattened (a relative leaf's)
    inertia: InertiaDispersion | None = None  # inertia matrices (..., 3, 3) drawn as inertia.J0 is


def _flatten(table: dict, prefix: str = "") -> dict:
    """{dotted key: value} down to numbers, strings and distribution tables (with 'dist',
    or an inertia / initial-state table)."""
    out = {}
    for key, value in table.items():
        path = f"{prefix}{key}"
        structured = (path in ("inertia.J0", "inertia.J1", "inertia.J2", "initial.attitude", "initial.rate")
                      or path.split(".")[0] in ("reference", "inertia") and path.count(".") == 2)
        if isinstance(value, dict) and "dist" not in value and not structured:
            out.update(_flatten(value, path + "."))
        else:
            out[path] = value
    return out


def parse(table: dict, mission: Mission) -> tuple[Dispersions, tuple[Leaf, ...]]:
    """(structured dispersions, component leaves) of a ``[dispersions]`` table on ``mission``;
    one-line ValueErrors naming the key."""
    if not isinstance(table, dict):
        raise ValueError(f"[dispersions] must be a table, got {checks.short(table)}")  # noqa: TRY004 (bad input)
    fields = {
        "J0": InertiaDispersion(nominal=_matrix(mission.J0)),
        "J1": InertiaDispersion(nominal=None if mission.J1_scale is not None else _matrix(mission.J1),
                                scale=Fixed(1.0 if mission.J1_scale is None else mission.J1_scale)),
        "J2": InertiaDispersion(nominal=_matrix(mission.J2)),
        "tau_J": Fixed(mission.tau_J),
        "n": Fixed(mission.n),
        **{name: Fixed(mission.disturbance[name]) for name in ("amplitude", "frequency", "noise_std")},
        "disturbance_seed": mission.seed,
    }
    leaves = []
    for key, value in _flatten(table).items():
        path = tuple(key.split("."))
        where = f"dispersions.{key}"
        if key == "seed":
            choice = checks.choice(value, f"{where} (random: a seed per sample; mission: the mission's seed for all)",
                                ("random", "mission"))
            fields["disturbance_seed"] = None if choice == "random" else mission.seed
        elif path[0] == "inertia" and len(path) == 2 and path[1] in ("J0", "J1", "J2"):
            if mission.inertia["kind"] != "paper":
                raise ValueError(f"{where}: the mission's inertia is of kind {mission.inertia['kind']!r}; "
                                 "inertia.J0/J1/J2 disperse the paper's profile (inertia.kind = \"paper\")")
            if mission.constant_inertia and path[1] != "J0":
                raise ValueError(f"{where}: a constant inertia ([inertia] J) is dispersed as inertia.J0")
            fields[path[1]] = _inertia(value, where, fields[path[1]])
        elif key == "initial.attitude":
            t = checks.table({"": value}, "", ("max_angle_deg",), where)
            fields["initial_angle_deg"] = checks.number(t.get("max_angle_deg", 0.0), f"{where}.max_angle_deg",
                                                        0.0, 180.0)
        elif key == "initial.rate":
            t = checks.table({"": value}, "", ("norm",), where)
            fields["initial_rate"] = _distribution(t.get("norm", 0.0), f"{where}.norm")
        elif path in STRUCTURED:
            fields[STRUCTURED[path]] = _distribution(value, where)
        elif path[0] in LOOP_TABLES:
            leaves.append(_leaf(path, value, where, mission))
        elif path[0] in ("reference", "inertia") and len(path) == 3:
            leaves.append(_scenario_leaf(path, value, where, mission))
        elif path[0] == "faults":
            leaves.append(_fault_leaf(path, value, where, mission))
        elif path[0] in FLEXIBLE_TABLES:
            leaves.append(_flexible_leaf(path, value, where, mission))
        else:
            raise ValueError(f"{where} cannot be dispersed: dispersible are inertia.J0/J1/J2, deployment.tau_J, "
                             f"orbit.n, {_scenario_parameters(mission)}, disturbance.amplitude/frequency/noise_std, "
                             "initial.attitude/rate, seed, the numeric parameters of the mission's sensors, "
                             "estimator, actuator and momentum management, its faults' "
                             "(faults.I.time/end/factor/wheel/step, I the 0-based [[faults]] entry) and its "
                             "appendages' and slosh particles' springs and dampers (appendages.I.k/c, slosh.J.k/c)")
    if mission.constant_inertia:  # J(t) = J0 throughout; J1, J2 follow it undispersed
        fields["J1"] = InertiaDispersion(nominal=None, scale=Fixed(1.0))
        fields["J2"] = InertiaDispersion(nominal=_matrix(mission.J0))
    dispersions = Dispersions(**fields)
    check_orbit(dispersions.n, "dispersions.orbit.n")
    check(dispersions, warn=False)
    users = build.orbit_users(mission)
    if users:  # no orbit (n = 0) is refused, n > 0 drawn: the mission flies on its orbit
        check_domain(dispersions.n, f"dispersions.orbit.n ({', '.join(users)} fly on the orbit)", 0.0, strict=True)
    timed = [leaf.key for leaf in leaves if leaf.key.startswith("faults.") and leaf.key.endswith(".time")]
    if timed and any(r.after is not None for r in mission.requirements):
        raise ValueError(f"requirements: phase = {AFTER_FAULT!r} starts at the mission's first fault, and "
                         f"{', '.join(timed)} is dispersed: each sample's starts elsewhere (a sweep's fault cases "
                         "give each sample's APE and RPE after its own fault)")
    return dispersions, _ordered(_bounded(tuple(leaves), mission), mission)


def _bounded(leaves: tuple, mission: Mission) -> tuple:
    """The leaves, each side of a :data:`MAGNITUDE_LIMITS` pair given its bound; ValueError
    where a distribution cannot keep within it (against the least limit drawn)."""
    by_key = {leaf.key: leaf for leaf in leaves}
    for key, limit_key in MAGNITUDE_LIMITS.items():
        value, limit = by_key.get(key), by_key.get(limit_key)
        if value is None and limit is None:
            continue
        nominal, nominal_limit = _flown(mission, key), _flown(mission, limit_key)
        if value is not None:
            lowest = least(limit.dist) if limit is not None else float(np.min(nominal_limit))
            check_magnitude(value.dist, f"dispersions.{key}", lowest,
                            f"the least {limit_key}{' drawn' if limit is not None else ''}")
        else:
            check_domain(limit.dist, f"dispersions.{limit_key} (the limit of {key})",
                         float(np.max(np.abs(nominal))), strict=False)
        bound = (key, _flat(nominal), limit_key, _flat(nominal_limit))
        for leaf in (value, limit):
            if leaf is not None:
                by_key[leaf.key] = dataclasses.replace(leaf, bound=bound)
    return tuple(by_key[leaf.key] for leaf in leaves)


def _ordered(leaves: tuple, mission: Mission) -> tuple:
    """The leaves, each side of a dispersed star-tracker outage given its order (end > time,
    per sample: the mission's value of the side not dispersed)."""
    by_key = {leaf.key: leaf for leaf in leaves}
    for i, fault in enumerate(mission.faults):
        time, end = f"faults.{i}.time", f"faults.{i}.end"
        if "star_tracker" not in fault or (time not in by_key and end not in by_key):
            continue
        order = (time, (float(fault["time"]),), end, (float(fault["end"]),))
        for key in (time, end):
            if key in by_key:
                by_key[key] = dataclasses.replace(by_key[key], order=order)
    return tuple(by_key[leaf.key] for leaf in leaves)


def _fault_leaf(path: tuple, value, where: str, mission: Mission) -> Leaf:
    """A numeric value of one of the mission's ``[[faults]]`` (:data:`FAULT_LEAVES`):
    ``faults.I.PARAMETER``, I the entry's 0-based index."""
    if len(path) != 3:
        raise ValueError(f"{where} must name a fault's value, e.g. dispersions.faults.0.time "
                         "(the 0-based [[faults]] entry)")
    n = len(mission.faults)
    if not path[1].isdigit() or int(path[1]) >= n:
        raise ValueError(f"{where}: the mission has no fault {path[1]!r} "
                         + (f"(its [[faults]] entries are 0 to {n - 1})" if n else "(it states no [[faults]])"))
    fault, param = mission.faults[int(path[1])], path[2]
    target = next(t for t in FAULT_LEAVES if t in fault)
    if param not in FAULT_LEAVES[target]:
        raise ValueError(f"{where}: a {target.replace('_', ' ')} fault disperses "
                         f"{', '.join(FAULT_LEAVES[target])}, not {param!r}")
    if param == "factor" and fault["mode"] not in FRICTION_FACTOR and fault["mode"] != "degraded":
        raise ValueError(f"{where}: wheel {fault['wheel']} {'fails off' if fault['mode'] == 'off' else 'sticks'} "
                         "(no factor); a degraded wheel's factor, or its friction's, is dispersed")
    low, high, high_excluded = FAULT_LEAVES[target][param] if param != "factor" else FRICTION_FACTOR.get(
        fault["mode"], FAULT_LEAVES[target][param])
    if param == "wheel":  # which wheel fails: one of the mission's, 1-based
        high = float(len(mission.actuator["wheels"]["axes"]))
        dist = _distribution(value, where)
        drawn = dist.values if isinstance(dist, Choice) else (dist.value,) if isinstance(dist, Fixed) else ()
        if not drawn or not all(v == int(v) and low <= v <= high for v in drawn):
            raise ValueError(f"{where} draws a wheel's index, 1 to {high:g} (the mission's wheels): a number or "
                             f"{{dist = \"choice\", values = [...]}} of those, got {checks.short(value)}")
    leaf = _checked_leaf(f"faults.{int(path[1])}.{param}", value, where, np.asarray(fault[param], np.float64),
                         low, high, strict=False)
    return dataclasses.replace(leaf, high=float(np.nextafter(high, -np.inf))) if high_excluded else leaf


def _flexible_leaf(path: tuple, value, where: str, mission: Mission) -> Leaf:
    """A spring or damper of one of the mission's ``[[appendages]]`` or ``[[slosh]]`` entries
    (:data:`FLEXIBLE_LEAVES`): ``appendages.I.k``, I the entry's 0-based index; one value, or one
    per phase as the mission gives it (each element drawn on its own), >= 0."""
    table = path[0]
    if len(path) != 3:
        raise ValueError(f"{where} must name an entry's value, e.g. dispersions.{table}.0.k "
                         f"(the 0-based [[{table}]] entry)")
    entries = getattr(mission, table)
    n = len(entries)
    if not path[1].isdigit() or int(path[1]) >= n:
        raise ValueError(f"{where}: the mission has no {table} entry {path[1]!r} "
                         + (f"(its [[{table}]] entries are 0 to {n - 1})" if n else f"(it states no [[{table}]])"))
    param = path[2]
    if param not in FLEXIBLE_LEAVES[table]:
        raise ValueError(f"{where}: an entry of [[{table}]] disperses {', '.join(FLEXIBLE_LEAVES[table])}, "
                         f"not {param!r}")
    current = np.asarray(entries[int(path[1])][param], np.float64)
    return _checked_leaf(f"{table}.{int(path[1])}.{param}", value, where, current, 0.0, math.inf, strict=False)


def _flown(mission: Mission, key: str):
    """The mission's value of a flown component's parameter (a dotted key)."""
    table, name, param = key.split(".")
    return (mission.sensors if table == "sensors" else getattr(mission, table))[name][param]


def _flat(x) -> tuple:
    return tuple(np.asarray(x, float).ravel().tolist())


def _matrix(J) -> tuple:
    return tuple(map(tuple, np.asarray(J, float).tolist()))


def _distribution(value, where: str) -> Distribution:
    if isinstance(value, dict) and "dist" in value and not isinstance(value["dist"], str):
        checks.choice(value["dist"], f"{where}.dist", tuple(DISTRIBUTIONS))
    return parse_distribution(value, where)


def _inertia(value, where: str, default: InertiaDispersion) -> InertiaDispersion:
    t = checks.table({"": value}, "", INERTIA_KEYS, where)
    changes = {name: _distribution(t[name], f"{where}.{name}")
               for name in ("scale", "axis_scale", "products", "second_moments") if name in t}
    if "rotation_deg" in t:
        changes["rotation_deg"] = checks.number(t["rotation_deg"], f"{where}.rotation_deg", low=0.0, high=180.0)
    return dataclasses.replace(default, **changes)


def _leaf(path: tuple, value, where: str, mission: Mission) -> Leaf:
    """A component parameter of the mission: flown, numeric, not an integer."""
    table, name, param = path[0], path[1] if len(path) > 1 else "", path[2] if len(path) > 2 else ""
    if len(path) != 3:
        raise ValueError(f"{where} must name a component parameter, e.g. dispersions.{table}.NAME.PARAMETER")
    if table == "sensors":
        flown = mission.sensors
    else:
        chosen = getattr(mission, table)  # {"kind": name, name: values}
        flown = {chosen["kind"]: chosen[chosen["kind"]]}
    if name not in flown:
        raise ValueError(f"{where}: the mission flies no {table} {name!r} (flown: {', '.join(flown) or 'none'})")
    kind = "sensor" if table == "sensors" else table
    spec = next((p for p in components.get(kind, name).params if p.name == param), None)
    if spec is None:
        raise ValueError(f"{where}: {table} {name!r} has no parameter {param!r}")
    current = flown[name][param]
    if spec.integer or spec.boolean or spec.choices or current is None:
        raise ValueError(f"{where}: only real-valued parameters are dispersed ({param} is "
                         f"{'not set in the mission' if current is None else 'not a real number'})")
    return _checked_leaf(".".join(path), value, where, current, spec.low, spec.high, strict=spec.low_excluded)


def _checked_leaf(key: str, value, where: str, current, low: float, high: float, strict: bool) -> Leaf:
    """A leaf of the mission's value ``current`` in [low, high] (low excluded where strict): a
    distribution of the value or, with ``relative = "offset"`` ("scale") in its table, of
    what is added to (multiplies) the mission's value, element by element; ValueError where
    it cannot draw into the domain (an offset: for no element; the elements drawn outside it
    reject their samples)."""
    relative = None
    if isinstance(value, dict) and "relative" in value:
        relative = checks.choice(value["relative"], f"{where}.relative", RELATIVE)
        value = {k: v for k, v in value.items() if k != "relative"}
    dist = _distribution(value, where)
    nominal = np.asarray(current, np.float64)
    if relative == "offset" and math.isfinite(low) and isinstance(dist, (Fixed, Uniform)):
        largest = float(nominal.max()) + (dist.value if isinstance(dist, Fixed) else dist.high)
        if not largest > low:
            raise ValueError(f"{where}: the mission's value plus {describe(dist)} never exceeds {low:g}")
    elif relative == "scale" and low >= 0.0:
        check_domain(dist, f"{where} (a scale)", 0.0, strict)
    elif relative is None:
        check_domain(dist, where, low, strict)
    low = float(np.nextafter(low, np.inf)) if strict else low
    return Leaf(key, dist, np.shape(current), low, high, relative=relative,
                nominal=_flat(nominal) if relative else ())


def _scenario_keys(mission: Mission, table: str | None = None) -> list[str]:
    """The dispersible parameters of the mission's reference and inertia kinds (``table``'s
    alone where given), as a dispersions table names them: "reference.slews.times", ..."""
    return [f"{t}.{kind}.{param}" for (t, kind), params in SCENARIO_LEAVES.items()
            if (table is None or t == table) and getattr(mission, t)["kind"] == kind for param in params]


def _scenario_parameters(mission: Mission) -> str:
    """The dispersible parameters of the mission's reference and inertia kinds, in words."""
    keys = _scenario_keys(mission)
    if keys:
        return f"the parameters of the mission's reference and inertia kinds ({', '.join(keys)})"
    kinds = " and ".join(f"{table}.kind = {getattr(mission, table)['kind']!r}" for table in SCENARIO_TABLES)
    return f"the parameters of the reference and inertia kinds (the mission's, {kinds}, have none)"


def _scenario_leaf(path: tuple, value, where: str, mission: Mission) -> Leaf:
    """A parameter of the mission's reference or inertia kind (:data:`SCENARIO_LEAVES`); an
    inertia event's targets when every one is a scale of the inertia at its event."""
    table, kind, param = path
    flown = getattr(mission, table)["kind"]
    if kind != flown:
        raise ValueError(f"{where}: the mission's {table} is of kind {flown!r}, not {kind!r}")
    params = SCENARIO_LEAVES.get((table, kind))
    if params is None or param not in params:
        keys = _scenario_keys(mission, table)
        raise ValueError(f"{where} cannot be dispersed: "
                         + (f"dispersible are {', '.join(keys)}" if keys else
                            f"{table}.kind = {kind!r} has no dispersible parameter"))
    values = getattr(mission, table)[kind]
    current, domain = values[param], params[param]
    if (kind, param) == ("events", "targets"):
        scales = values["scales"] > 0
        if scales.any() and not scales.all():
            raise ValueError(f"{where}: the targets are dispersed where all are scales of the inertia at their "
                             "event, or all inertias")
        current, domain = (values["scales"], domain) if scales.all() else (values["matrices"], INERTIA)
    if domain == INERTIA:
        matrices = np.asarray(current, np.float64)
        inertia = _inertia(value, where, InertiaDispersion(nominal=None))
        for J in matrices.reshape(-1, 3, 3):
            check_inertia_dispersion(dataclasses.replace(inertia, nominal=_matrix(J)), where, warn=False)
        return Leaf(".".join(path), Fixed(0.0), matrices.shape, -math.inf, math.inf, inertia=inertia,
                    nominal=_flat(matrices))
    low, strict = domain
    return _checked_leaf(".".join(path), value, where, current, low, math.inf, strict)


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


# --- drawing ---------------------------------------------------------------------------------


@functools.partial(jax.jit, static_argnames="n_words")
def _leaf_words(seed, indices, salt, n_words: int):
    base = jax.random.key(seed)
    draw = lambda k: jax.random.bits(jax.random.fold_in(jax.random.fold_in(base, k), salt), (n_words,), jnp.uint32)
    return jax.vmap(draw)(indices)


def draw_leaves(leaves: tuple, seed: int, n_samples: int, first: int = 0) -> tuple[dict, np.ndarray]:
    """({key: values (N, *shape)}, valid (N,)): each leaf's values for samples first ..
    first + N - 1, in float64, and whether every value lies in its parameter's domain and
    within its bound."""
    values, passed = _drawn_leaves(leaves, seed, n_samples, first)
    return values, np.logical_and.reduce(list(passed.values()))


def _drawn_leaves(leaves: tuple, seed: int, n_samples: int, first: int) -> tuple[dict, dict]:
    """(:func:`draw_leaves`' values, {reason: (N,) whether each sample passes}: every value in
    its parameter's domain, every bound kept, every dispersed outage ending after its time
    (:data:`REJECTED`))."""
    values, domain, bound = {}, np.ones(n_samples, bool), np.ones(n_samples, bool)
    order = np.ones(n_samples, bool)
    for leaf in leaves:
        size = int(np.prod(leaf.shape))
        n_words = 2 * INERTIA_VARIATES * (size // 9) if leaf.inertia is not None else 2 * max(size, 1)
        words = np.asarray(_leaf_words(np.uint32(seed), np.arange(first, first + n_samples, dtype=np.uint32),
                                       np.uint32(zlib.crc32(leaf.key.encode())), n_words))
        if leaf.inertia is not None:  # each matrix from its own 11 variates, as inertia.J0's
            nominal = np.reshape(leaf.nominal, (-1, 3, 3))
            variates = draw_variates(words.reshape(n_samples, len(nominal), 2 * INERTIA_VARIATES))
            values[leaf.key] = leaf.inertia.apply(variates, nominal)[0].reshape((n_samples, *leaf.shape))
            continue
        v = draw_variates(words)
        u, z = v.take(max(size, 1))
        x = leaf.dist.sample(u, z)[:, :size].reshape((n_samples, *leaf.shape))
        if leaf.relative is not None:
            nominal = np.reshape(leaf.nominal, leaf.shape)
            x = nominal + x if leaf.relative == "offset" else nominal * x
        values[leaf.key] = x
        domain &= np.all((x >= leaf.low) & (x <= leaf.high), axis=tuple(range(1, x.ndim)))
    for leaf in leaves:
        if leaf.bound is not None:
            bound &= within_bound(leaf.bound, values, n_samples)
        if leaf.order is not None:
            time, nominal_time, end, nominal_end = leaf.order
            order &= (values[end] if end in values else nominal_end[0]) > (
                values[time] if time in values else nominal_time[0])
    return values, {REJECTED["domain"]: domain, REJECTED["bound"]: bound, REJECTED["outage"]: order}


def within_bound(bound: tuple, values: dict, n_samples: int) -> np.ndarray:
    """(N,) whether each sample keeps |parameter| <= limit, element by element (a leaf's
    bound; ``values``: the drawn leaves, the mission's value of the side not drawn)."""
    key, nominal, limit_key, nominal_limit = bound
    x = np.reshape(values[key], (n_samples, -1)) if key in values else np.asarray(nominal)
    limit = np.reshape(values[limit_key], (n_samples, -1)) if limit_key in values else np.asarray(nominal_limit)
    return np.all(np.reshape(np.abs(x) <= limit, (n_samples, -1)), axis=1)


def _scenario_checks(mission: Mission, values: dict, n_samples: int) -> dict:
    """{reason: (N,) whether each sample passes} of the checks a mission file's reference and
    inertia pass (:data:`REJECTED`): slews that do not overlap, times that increase,
    inertias positive definite (the other dispersible parameters' domains are their leaves')."""
    passed = {}
    if any(k.startswith("reference.slews.") for k in values):
        given = mission.reference["slews"]
        drawn = {name: values.get(f"reference.slews.{name}", np.asarray(given[name], np.float64))
                 for name in ("start", "attitudes", "times", "max_rate", "max_acceleration")}
        times = np.broadcast_to(drawn["times"], (n_samples, len(given["times"])))
        passed[REJECTED["overlap"]] = ~profiles.overlapping(
            rotation_matrix(drawn["start"]), rotation_matrix(drawn["attitudes"]), times, drawn["max_rate"],
            drawn["max_acceleration"])
    order = np.ones(n_samples, bool)
    for key in ("inertia.events.times", "inertia.linear.times", "inertia.table.times", "reference.table.times"):
        if key in values:
            order &= np.all(np.diff(values[key], axis=1) > 0, axis=1)
    definite = np.ones(n_samples, bool)
    for key, x in values.items():
        if key.startswith("inertia.") and np.shape(x)[-2:] == (3, 3):
            definite &= np.all(is_positive_definite(x), axis=tuple(range(1, np.ndim(x) - 2)))
    return {**passed, REJECTED["order"]: order, REJECTED["inertia_table"]: definite}


def _wheels_span(mission: Mission, values: dict, n_samples: int) -> np.ndarray:
    """(N,) whether each sample's wheels left after those failed off or stuck (``values``' drawn
    wheels, the mission's where not drawn) span 3-D, or the loop never drops them (fdir
    detection "never", which flies the sample unaware, as ``fly`` does)."""
    if mission.fdir["detection"] == "never":
        return np.ones(n_samples, bool)
    axes = np.asarray(mission.actuator["wheels"]["axes"], float)
    off = np.zeros((n_samples, len(axes)), bool)
    for i, fault in enumerate(mission.faults):
        if fault_list.lost(fault):
            wheel = np.broadcast_to(values.get(f"faults.{i}.wheel", fault["wheel"]), (n_samples,)).astype(int)
            off[np.arange(n_samples), wheel - 1] = True
    return fault_list.spanning(axes, off)


def draw(dispersions: Dispersions, leaves: tuple, seed: int, n_samples: int, max_draws: int,
         first: int = 0, mission: Mission | None = None) -> Samples:
    """Samples first .. first + n_samples - 1 with their dispersed component and scenario
    values (``leaves``); valid: a positive definite inertia within max_draws, an orbit at
    least MIN_ALTITUDE high (:func:`in_orbit_domain`), every value in
    its domain and, with dispersed reference or inertia parameters, the sample's reference
    and inertia passing their kind's checks (``mission``: the mission the leaves disperse);
    outside: the samples rejected for a component or scenario value alone; reason: why each
    sample is rejected, the first of :data:`REJECTED` in order it fails ("" where valid)."""
    samples = draw_samples(dispersions, seed, n_samples, max_draws, first)
    values, passed = _drawn_leaves(leaves, seed, n_samples, first)
    strict = mission is not None and bool(build.orbit_users(mission))
    passed = {REJECTED["orbit"]: in_orbit_domain(samples.params.n, strict), **passed}
    if any(leaf.key.split(".")[0] in SCENARIO_TABLES for leaf in leaves):
        if mission is None:
            raise TypeError("draw: dispersed reference or inertia parameters need the mission (mission=)")
        passed.update(_scenario_checks(mission, values, n_samples))
    if any(leaf.key.startswith("faults.") and leaf.key.endswith(".wheel") for leaf in leaves):
        if mission is None:
            raise TypeError("draw: a dispersed failed wheel needs the mission (mission=)")
        passed[REJECTED["wheels"]] = _wheels_span(mission, values, n_samples)
    reason = np.where(samples.valid, "", REJECTED["draws"]).astype(object)
    for why, ok in passed.items():
        reason[(reason == "") & ~ok] = why
    in_domain = np.logical_and.reduce([np.ones(n_samples, bool), *passed.values()])
    return samples._replace(valid=samples.valid & in_domain, leaves=values, outside=samples.valid & ~in_domain,
                            reason=reason)


def rejections(samples: Samples) -> dict:
    """{reason: samples rejected for it} of the rejected samples (:func:`draw`'s ``reason``;
    without one, their draws), in :data:`REJECTED`'s order."""
    reason = samples.reason if samples.reason is not None else np.where(samples.valid, "", REJECTED["draws"])
    return {why: int(np.sum(reason == why)) for why in REJECTED.values() if np.any(reason == why)}
