"""Scenarios (plant + reference + disturbance + horizon), the paper's mission (docs/model.md §4),
and the scenario's checks (docs/model.md §6)."""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.core.pytree import pytree_dataclass, static_field
from so3jax.dynamics import flexible
from so3jax.dynamics.disturbance import SinusoidPlusNoise
from so3jax.dynamics.inertia import check_inertia, check_inertia_profile, concrete_values
from so3jax.dynamics.orbit import orbital_rate
from so3jax.dynamics.paper import PAPER_DEPLOY_TIME, PAPER_DOCK_TIME, PAPER_J0, PAPER_J2
from so3jax.dynamics.plant import PaperInertia
from so3jax.dynamics.reference import piecewise_constant_rate


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
    environment: Any = None  # so3jax.dynamics.environment.Environment: the orbit and its torques, or None
    # so3jax.dynamics.flexible.FlexibleBody: hinged panels and slosh particles on the hub, or None (a rigid
    # body); its hub's inertia is J(t) less the wheels' at each stage (so3jax.dynamics.plant.flexible_derivative)
    flexible: Any = None
    flexible_initial: Any = None  # (theta(0) (N,) [rad], rho(0) (M,) [m]) of the flexible body, or None: at rest

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
        disturbance=SinusoidPlusNoise(as_array(disturbance_amplitude), as_array(disturbance_frequency),
                                      as_array(noise_std)),
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


def check_flexible(body) -> None:
    """One-line ValueErrors for a flexible body's parameters (:func:`so3jax.dynamics.flexible.check`),
    where concrete; its hub's inertia is the scenario's J(t), checked with the profile."""
    if not isinstance(body, flexible.FlexibleBody):
        raise TypeError(f"scenario.flexible must be a so3jax.dynamics.flexible.FlexibleBody or None, "
                        f"got {type(body).__name__}")
    flexible.check(body)


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
    if scenario.flexible is not None and not batch_last:  # a batch's: the mission's, checked when parsed
        check_flexible(scenario.flexible)
    front = (lambda x: np.moveaxis(x, -1, 0)) if batch_last else (lambda x: x)
    R0 = concrete_values(scenario.R0)
    if R0 is not None:
        R0 = front(R0) if R0.ndim > 2 else R0
        if not np.allclose(np.swapaxes(R0, -1, -2) @ R0, np.eye(3), atol=1e-6):
            raise ValueError("R0 is not a rotation matrix (R0^T R0 != I)")
    for name in ("R0", "Omega0"):
        value = concrete_values(getattr(scenario, name))
        if value is not None and not np.all(np.isfinite(value)):
            raise ValueError(f"{name} has non-finite entries")
