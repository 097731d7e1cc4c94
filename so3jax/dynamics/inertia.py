"""Inertia checks (docs/model.md §6): a matrix symmetric positive definite, the triangle
inequality of its principal moments (a warning), and every J(t) of a scenario's profile."""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.dynamics.paper import PAPER_J0, PAPER_J2


class InertiaWarning(UserWarning):
    """A positive definite inertia that no rigid body can have (triangle inequality):
    accepted (docs/model.md §4 and §6: the paper's J0 is one), with this warning."""


def check_real_dtype(x, what: str) -> None:
    """TypeError naming ``what`` unless x is a real numeric array (tracers included)."""
    try:
        dtype = x.dtype if hasattr(x, "dtype") else np.asarray(x).dtype
    except (TypeError, ValueError):
        dtype = None
    if dtype is None or dtype.kind not in "fiu":
        raise TypeError(f"{what} must be a real numeric array, got {x!r}"
                        + (f" of dtype {dtype}" if dtype is not None else ""))


def concrete_values(x) -> np.ndarray | None:
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
    check_real_dtype(J, f"inertia {name}")
    shape = np.shape(J)
    if len(shape) < 2 or shape[-2:] != (3, 3):
        raise ValueError(f"inertia {name} must be a (3, 3) matrix [kg m^2], got shape {shape}")
    J = concrete_values(J)
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


def _inertia_checks(scenario, batch_last: bool):
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


def check_inertia_profile(scenario, *, batch_last: bool = False) -> None:
    """Every inertia the run of ``scenario`` (a Scenario) will use, before it runs: the profile's own checks (e.g. a
    positive time constant), its matrices, and J(t) (see :func:`_inertia_checks`): one
    ValueError naming the phase; one InertiaWarning listing the inertias that break the
    triangle inequality."""
    profile = scenario.inertia
    if not callable(profile):
        raise TypeError("scenario.inertia must be an inertia profile J(t, phase) (see so3jax.dynamics.plant), "
                        f"got {profile!r}")
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
