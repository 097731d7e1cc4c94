"""Scenarios (plant + reference + disturbance + horizon), the paper's defaults (docs/model.md §4),
and input validation (docs/model.md §6)."""

from __future__ import annotations

import math
import warnings
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.core.pytree import pytree_dataclass, static_field
from so3jax.dynamics.disturbance import SinusoidPlusNoise
from so3jax.dynamics.plant import PaperInertia
from so3jax.dynamics.reference import piecewise_constant_rate

MU_EARTH = 3.986004418e14  # m^3/s^2
EARTH_RADIUS = 6378.137e3  # m
PAPER_ALTITUDE = 500e3  # m
PAPER_J0 = ((625.0, 5.5, 3.0), (5.5, 350.0, 4.0), (3.0, 4.0, 1000.0))
PAPER_J2 = ((3945.4, 66.7, 12.8), (66.7, 3663.5, 160.0), (12.8, 160.0, 2011.8))
PAPER_DEPLOY_TIME = 500.0  # s
PAPER_DOCK_TIME = 2600.0  # s


class InertiaWarning(UserWarning):
    """A positive definite inertia that no rigid body can have (triangle inequality):
    accepted (docs/model.md §4 and §6: the paper's J0 is one), with this warning."""


@pytree_dataclass
class Scenario:
    """Everything but the controller: a pytree, so it can be vmapped over (inertias,
    disturbances, initial states); dt, n_steps and the phase switch times are static.

    phase_times: start times [s] of the phases after the first; each is moved to the
    step boundary round(t / dt) (docs/model.md §5).
    """

    inertia: Any  # profile, see so3jax.dynamics.plant
    reference: Any  # see so3jax.dynamics.reference
    disturbance: Any  # see so3jax.dynamics.disturbance
    R0: jax.Array  # (3, 3)
    Omega0: jax.Array  # (3,) rad/s
    dt: float = static_field()
    n_steps: int = static_field()
    phase_times: tuple = static_field(default=())
    variable_inertia_term: bool = static_field(default=False)

    @property
    def phase_steps(self) -> tuple:
        return tuple(int(round(t / self.dt)) for t in self.phase_times)

    @property
    def steps_per_phase(self) -> tuple:
        bounds = (0,) + tuple(min(max(k, 0), self.n_steps) for k in self.phase_steps) + (self.n_steps,)
        return tuple(b - a for a, b in zip(bounds[:-1], bounds[1:]))

    @property
    def horizon(self) -> float:
        return self.n_steps * self.dt


def steps_for_horizon(T: float, dt: float) -> int:
    """N = T / dt, which must be a whole number (docs/model.md §6)."""
    if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive finite number of seconds, got {dt!r}")
    if not (isinstance(T, (int, float)) and math.isfinite(T) and T > 0):
        raise ValueError(f"T (horizon) must be a positive finite number of seconds, got {T!r}")
    ratio = T / dt
    if abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise ValueError(f"T (horizon) = {T} s is not a multiple of dt = {dt} s")
    return int(round(ratio))


def orbital_rate(altitude: float = PAPER_ALTITUDE) -> float:
    """Mean motion n = sqrt(mu / a^3) of a circular orbit [rad/s]."""
    return math.sqrt(MU_EARTH / (EARTH_RADIUS + altitude) ** 3)


def paper_scenario(
    T: float = 4000.0,
    dt: float = 0.01,
    *,
    tau_J: float = 300.0,
    n: float | None = None,
    J0=PAPER_J0,
    J1=None,
    J2=PAPER_J2,
    disturbance_amplitude: float = 0.1,
    disturbance_frequency: float = 1e-3,
    noise_std: float = 0.025,
    variable_inertia_term: bool = False,
    dtype=None,
) -> Scenario:
    """The capture-and-detumble mission of docs/model.md §4 (J1 = 2 J0 unless given)."""
    dtype = jnp.result_type(float) if dtype is None else jnp.dtype(dtype)
    n_steps = steps_for_horizon(T, dt)
    n = orbital_rate() if n is None else n
    as_array = lambda x: jnp.asarray(x, dtype)
    J0 = as_array(J0)
    J1 = 2.0 * J0 if J1 is None else as_array(J1)
    capture_rate = as_array([n, -10.0 * n, 2.0 * n])
    reference = piecewise_constant_rate(
        jnp.stack([capture_rate, capture_rate, jnp.zeros(3, dtype)]),
        as_array([0.0, PAPER_DEPLOY_TIME, PAPER_DOCK_TIME]),
    )
    scenario = Scenario(
        inertia=PaperInertia(J0, J1, as_array(J2), as_array(PAPER_DEPLOY_TIME), as_array(tau_J)),
        reference=reference,
        disturbance=SinusoidPlusNoise(as_array(disturbance_amplitude), as_array(disturbance_frequency), as_array(noise_std)),
        R0=jnp.eye(3, dtype=dtype),
        Omega0=jnp.zeros(3, dtype),
        dt=dt,
        n_steps=n_steps,
        phase_times=(PAPER_DEPLOY_TIME, PAPER_DOCK_TIME),
        variable_inertia_term=variable_inertia_term,
    )
    scenario.inertia.check()
    for name, J in scenario.inertia.matrices().items():
        check_inertia(name, J, warn=False)  # errors here; the warning comes with the run's checks
    return scenario


# --- validation (docs/model.md §6) -------------------------------------------------------------


def _real_dtype(x, what: str) -> None:
    """TypeError naming ``what`` unless x is a real numeric array (tracers included)."""
    try:
        dtype = x.dtype if hasattr(x, "dtype") else np.asarray(x).dtype
    except (TypeError, ValueError):
        dtype = None
    if dtype is None or dtype.kind not in "fiu":
        raise TypeError(f"{what} must be a real numeric array, got {x!r}" + (f" of dtype {dtype}" if dtype is not None else ""))


def _concrete(x) -> np.ndarray | None:
    """x as a numpy array, or None under tracing (values unknown before compilation)."""
    if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(x)):
        return None
    return np.asarray(x, dtype=np.float64)


TRIANGLE_ADVICE = "the run goes on; if it is meant to be a real body, check the matrix's entries and units"


def is_paper_inertia(J) -> bool:
    """Whether J (3, 3), or every matrix of a stack (..., 3, 3), is one the paper gives
    (docs/model.md §4: J0, J1 = 2 J0, J2), to 1e-12 relative. The paper's J0 and J1 break the
    triangle inequality; runs of the paper's mission use them as the paper does, without
    a warning."""
    J = np.asarray(J, dtype=np.float64)
    if J.ndim < 2 or J.shape[-2:] != (3, 3) or J.size == 0:
        return False
    paper = np.asarray((PAPER_J0, 2.0 * np.asarray(PAPER_J0), PAPER_J2))
    close = np.abs(J.reshape(-1, 1, 3, 3) - paper) <= 1e-12 * np.abs(paper)
    return bool(np.all(np.any(np.all(close, axis=(-2, -1)), axis=1)))


def check_inertia(name: str, J, *, warn: bool = True) -> bool:
    """J (3, 3), or a stack (..., 3, 3): symmetric positive definite, else ValueError
    naming ``name``. Returns whether its principal moments satisfy the triangle inequality
    (J_i <= J_j + J_k, a rigid body); where they do not, warns (InertiaWarning) if
    ``warn``. Shapes are checked under tracing too; values only when concrete."""
    _real_dtype(J, f"inertia {name}")
    shape = np.shape(J)
    if len(shape) < 2 or shape[-2:] != (3, 3):
        raise ValueError(f"inertia {name} must be a (3, 3) matrix [kg m^2], got shape {shape}")
    J = _concrete(J)
    if J is None:
        return True
    if not np.all(np.isfinite(J)):
        raise ValueError(f"inertia {name} has non-finite entries")
    if not np.allclose(J, np.swapaxes(J, -1, -2), rtol=1e-12, atol=1e-12 * np.max(np.abs(J))):
        raise ValueError(f"inertia {name} is not symmetric")
    moments = np.linalg.eigvalsh(J)
    if np.any(moments <= 0):
        raise ValueError(f"inertia {name} is not positive definite (principal moments {moments.min():.6g} <= 0)")
    slack = moments[..., 0] + moments[..., 1] - moments[..., 2]
    physical = not np.any(slack < -1e-9 * moments[..., 2])
    if not physical and warn and not is_paper_inertia(J):
        i = np.unravel_index(np.argmin(slack), slack.shape)
        a, b, c = moments[i]
        warnings.warn(
            f"inertia {name} breaks the triangle inequality of principal moments ({a:.1f} + {b:.1f} < {c:.1f} "
            f"kg m^2): positive definite, but no rigid body has it; {TRIANGLE_ADVICE}",
            InertiaWarning,
            stacklevel=3,
        )
    return physical


INERTIA_SAMPLES = 16  # sample times per phase where a profile is checked as a black box


def _inertia_checks(scenario: Scenario, batch_last: bool):
    """(name, J) of every inertia to check, in turn: the profile's matrices and J(t) at the start
    of every phase (unless the profile's parameters are traced); a profile that does not
    declare ``convex_phases`` (a user's J(t)) also at INERTIA_SAMPLES + 1 times spread over
    each phase. batch_last: the leaves carry a trailing batch axis (a natively batched
    rollout), moved to the front here."""
    profile = scenario.inertia
    front = (lambda J: jnp.moveaxis(J, -1, 0) if jnp.ndim(J) > 2 else J) if batch_last else (lambda J: J)
    for name, J in getattr(profile, "matrices", dict)().items():
        yield name, front(J)  # checked (shapes first) before J(t) is evaluated from them
    if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(profile)):
        return  # traced: values unknown, and nothing added to the trace
    bounds = (0,) + tuple(min(max(k, 0), scenario.n_steps) for k in scenario.phase_steps) + (scenario.n_steps,)
    n_phases = len(bounds) - 1
    dtype = scenario.R0.dtype
    for p, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
        if b <= a:
            continue  # the horizon never reaches this phase
        if getattr(profile, "convex_phases", False):
            ts = np.asarray([a * scenario.dt])
        else:
            ts = np.linspace(a * scenario.dt, b * scenario.dt, INERTIA_SAMPLES + 1)
        Js = jax.vmap(lambda t, p=p: profile(t, p))(jnp.asarray(ts, dtype))
        where = f"J(t) of phase {p + 1} of {n_phases} (from t = {a * scenario.dt:g} s)"
        if batch_last and jnp.ndim(Js) > 3:
            Js = jnp.moveaxis(Js, -1, 1)
        yield where, Js


def check_inertia_profile(scenario: Scenario, *, batch_last: bool = False) -> None:
    """Every inertia the run will use, before it runs: the profile's own checks (e.g. a
    positive time constant), its matrices, and J(t) (see :func:`_inertia_checks`): one
    ValueError naming the phase; one InertiaWarning listing the inertias that break the
    triangle inequality."""
    profile = scenario.inertia
    if not callable(profile):
        raise TypeError(f"scenario.inertia must be an inertia profile J(t, phase) (see so3jax.dynamics.plant), got {profile!r}")
    check = getattr(profile, "check", None)
    if check is not None:
        check()
    unphysical = [name for name, J in _inertia_checks(scenario, batch_last)
                  if not check_inertia(name, J, warn=False) and not is_paper_inertia(J)]
    named = [name for name in unphysical if not name.startswith("J(t)")] or unphysical  # J(t) only beyond them
    if unphysical:
        warnings.warn(
            f"inertia {', '.join(named)} {'breaks' if len(named) == 1 else 'break'} the triangle inequality of "
            f"principal moments: positive definite, but no rigid body has it; {TRIANGLE_ADVICE}",
            InertiaWarning,
            stacklevel=3,
        )


class Nonnegative(NamedTuple):
    """The domain g >= 0 of a gain (0 turns a term off), declared in its gains type's class
    attribute ``domains`` ({field: Nonnegative(scale)}); every other gain is positive.
    scale: the gain's typical size, in its unit: the tuner's parameter is g / scale."""

    scale: float


def gain_domain(gains, name: str):
    """Nonnegative(scale) where the gains type declares it, else None (a positive gain)."""
    return getattr(type(gains), "domains", {}).get(name)


def check_gains(gains, *, batch_axes: int = 0) -> None:
    """Every gain finite and positive (>= 0 where its type declares it :class:`Nonnegative`);
    a matrix Gamma symmetric positive definite. batch_axes: leading batch axes of every
    gain (a batch of gains)."""
    for path, value in jax.tree_util.tree_flatten_with_path(gains)[0]:
        name = jax.tree_util.keystr(path, simple=True, separator=".")
        nonnegative = isinstance(gain_domain(gains, name), Nonnegative)
        _real_dtype(value, f"gain {name}")
        value = _concrete(value)
        if value is None:
            continue
        if not np.all(np.isfinite(value)):
            raise ValueError(f"gain {name} must be finite, got {value}")
        if name == "Gamma" and value.ndim >= 2 + batch_axes:
            if value.shape[-2:] != (9, 9):
                raise ValueError(f"gain Gamma must be a scalar, a (9,) diagonal or a (9, 9) matrix, got {value.shape}")
            if not np.allclose(value, np.swapaxes(value, -1, -2), rtol=1e-12, atol=0):
                raise ValueError("gain Gamma is not symmetric")
            if np.any(np.linalg.eigvalsh(value) <= 0):
                raise ValueError("gain Gamma is not positive definite")
        elif nonnegative and np.any(value < 0):
            raise ValueError(f"gain {name} must be >= 0, got {value}")
        elif not nonnegative and np.any(value <= 0):
            raise ValueError(f"gain {name} must be positive, got {value}")


def check_scenario(scenario: Scenario, *, batch_last: bool = False) -> None:
    """The checks of docs/model.md §6 that concern the scenario (shapes always, values where
    concrete). batch_last: the leaves carry a trailing batch axis (B or 1)."""
    if not isinstance(scenario, Scenario):
        raise TypeError(f"scenario must be a so3jax.Scenario, got {type(scenario).__name__}")
    if not (math.isfinite(scenario.dt) and scenario.dt > 0):
        raise ValueError(f"dt must be positive, got {scenario.dt}")
    if scenario.n_steps < 1:
        raise ValueError(f"n_steps must be at least 1, got {scenario.n_steps}")
    for name, shape in (("R0", (3, 3)), ("Omega0", (3,))):
        got = np.shape(getattr(scenario, name))
        n = len(shape)
        if got[:n] != shape or len(got) > n + batch_last:
            expected = f"{shape} or {shape[:-1] + (shape[-1], 'B')}" if batch_last else f"{shape}"
            raise ValueError(f"scenario.{name} must have shape {expected}, got {got}")
    check_inertia_profile(scenario, batch_last=batch_last)
    front = (lambda x: np.moveaxis(x, -1, 0)) if batch_last else (lambda x: x)
    R0 = _concrete(scenario.R0)
    if R0 is not None:
        R0 = front(R0) if R0.ndim > 2 else R0
        if not np.allclose(np.swapaxes(R0, -1, -2) @ R0, np.eye(3), atol=1e-6):
            raise ValueError("R0 is not a rotation matrix (R0^T R0 != I)")
    for name in ("R0", "Omega0"):
        value = _concrete(getattr(scenario, name))
        if value is not None and not np.all(np.isfinite(value)):
            raise ValueError(f"{name} has non-finite entries")
