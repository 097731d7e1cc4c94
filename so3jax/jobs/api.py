"""What the commands compute, as library calls (re-exported by :mod:`so3jax`).

Each is a thin wrapper over its job, so a call and its command share one code path:
:func:`fly` (``so3jax fly``), :func:`margins` (``so3jax margins``) and
:func:`pointing_errors` (the pointing report of ``fly``) return objects and write nothing;
:func:`sweep` and :func:`tune` write, checkpoint and resume their run folder ``out`` as their
commands do and return its report; :func:`identify` (``so3jax identify``) returns the
estimate. A mission is a :class:`~so3jax.missions.mission.Mission` or the path of a mission
file (None: the flight mission), with ``overrides`` as the commands' ``--set KEY=VALUE``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from so3jax.dynamics.inertia import InertiaWarning
from so3jax.dynamics.scenario import Scenario
from so3jax.jobs import fly as fly_job
from so3jax.jobs import margins as margins_job
from so3jax.jobs.identify import CHECKS, METHODS, telemetry
from so3jax.jobs.identify import report as identify_report
from so3jax.missions import mission as missions
from so3jax.sim import pointing

# the body-fixed disturbance torque an identification fits: its polynomial degree in time by name
DISTURBANCE = {"none": -1, "constant": 0, "linear": 1, "quadratic": 2, "cubic": 3}
DEFAULT_DISTURBANCE = {"regression": "linear", "simulation": "cubic"}


def _names(controllers) -> list:
    """A sequence of controller names, or one comma-separated string."""
    if isinstance(controllers, str):
        return [c.strip() for c in controllers.split(",") if c.strip()]
    return [str(c) for c in controllers]


def _mission(mission=None, overrides: Sequence[str] = (), *, controllers=None, T=None, seed=None,
                 record_every=None) -> missions.Mission:
    """A Mission as given, or read from a mission file (None: the flight mission) with
    ``overrides`` (``KEY=VALUE`` strings, as ``--set``) and the commands' options: T [s], seed,
    record_every [steps], controllers (names, or one comma-separated string). A Mission object
    takes only ``controllers``, a subset of its own."""
    names = None if controllers is None else _names(controllers)
    if isinstance(mission, missions.Mission):
        given = [key for key, value in (("overrides", tuple(overrides)), ("T", T), ("seed", seed),
                                        ("record_every", record_every)) if value not in (None, ())]
        if given:
            raise ValueError(f"{', '.join(given)} apply to a mission file; a Mission object is taken as it is "
                             "(read its file with them, or build the Mission wanted)")
        if names is None:
            return mission
        unknown = [n for n in names if n not in mission.controllers]
        if unknown or not names:
            raise ValueError(f"controllers must be among the mission's ({', '.join(mission.controllers)}), "
                             f"got {', '.join(names) or 'none'}")
        return dataclasses.replace(mission, controllers=tuple(names))
    items = list(overrides)
    for key, value, kind in (("T", T, float), ("seed", seed, int), ("record_every", record_every, int)):
        if value is not None:
            items.append(f"{key}={kind(value)!r}")
    if names is not None:
        items.append("controllers=" + json.dumps(names))
    return missions.load(mission, items)


def fly(mission=None, controllers=None, *, overrides: Sequence[str] = (), T=None, seed=None, record_every=None,
        precision: str = "float64", max_memory: int | None = None) -> fly_job.Flight:
    """Each controller of the mission flown as ``so3jax fly`` flies it, nothing written: a
    :class:`~so3jax.jobs.fly.Flight`.

    Its ``results`` {controller: Result} (metrics, history, final state, flight metrics; NumPy,
    SI units), ``reports`` {controller: metrics.json's entry} (the metrics, ``pointing``
    [arcsec], ``requirements`` with ``passed``), ``trajectory`` (trajectory.npz's arrays),
    ``telemetry(controller)``, ``wall_s`` [s], ``diverged``, ``failed`` and ``table()``.

    mission: a Mission, or a mission file (None: the flight mission) read with ``overrides``
    (``KEY=VALUE`` strings, as ``--set``), T [s], seed, record_every [steps] and controllers
    (names, or one comma-separated string; of a Mission object, a subset of its own);
    precision: "float64" or "float32"; max_memory [bytes]: refuse (ValueError) a flight whose
    rollouts need more (None: the memory available)."""
    m = _mission(mission, overrides, controllers=controllers, T=T, seed=seed, record_every=record_every)
    fly_job.check_memory(m, precision, max_memory)
    return fly_job.flight(m, precision)


def pointing_errors(history, mission, *, window: float | None = None, levels=None, requirements=None,
                    phase_names=None) -> dict:
    """The ECSS pointing errors of one run (a History, or a Result's) as ``so3jax fly`` reports
    them: {"pointing": ..., "requirements": [...]}, in arcsec.

    "pointing": APE, MPE, RPE (and AKE, MKE, RKE with an estimate) per phase, level and axis;
    "requirements": each requirement's value and verdict (``passed``).

    mission: a Mission (its scenario's phases, its pointing window [s], levels and
    requirements, each of which the keywords replace) or a Scenario (``window`` [s] then
    required; levels default 0.95 and 0.9973; no requirement). requirements:
    :class:`~so3jax.sim.pointing.Requirement` or dicts as a mission's ``[[requirements]]``."""
    history = getattr(history, "history", history)
    if isinstance(mission, missions.Mission):
        scenario = mission.scenario()
        window = mission.pointing["window"] if window is None else window
        levels = mission.pointing["levels"] if levels is None else levels
        requirements = mission.requirements if requirements is None else requirements
        phase_names = mission.phase_names if phase_names is None else phase_names
    elif isinstance(mission, Scenario):
        scenario = mission
        if window is None:
            raise ValueError("pointing_errors: a Scenario needs the window [s] of the windowed indices")
        levels = (0.95, 0.9973) if levels is None else levels
    else:
        raise ValueError(f"pointing_errors: mission must be a Mission or a Scenario, got {type(mission).__name__}")
    bounds = pointing.phase_bounds_of(scenario)
    names = None if phase_names is None else tuple(phase_names)
    parsed = tuple(r if isinstance(r, pointing.Requirement) else
                   pointing.parse_requirement(r, f"requirements[{i}]", names, bounds)
                   for i, r in enumerate(requirements or ()))
    return fly_job.pointing_errors(history, scenario, window=window, levels=tuple(levels), requirements=parsed,
                                   phase_names=names)


def margins(mission=None, controller: str | None = None, at=None, *, overrides: Sequence[str] = (), T=None,
            precision: str = "float64"):
    """The stability margins of a controller's sampled loop at ``at`` [s], as ``so3jax margins``
    takes them: a :class:`~so3jax.jobs.margins.Margins`; {t: Margins} for several times.

    Margins: ``linearization``, ``loop_at_a_time`` (per-axis gain [dB], phase [deg] and delay
    [s] margins), ``disk`` (disk margins), the loop broken at the actuator input. at: a whole
    number of control periods, a sequence of them, or None (the last tick of each phase the
    horizon reaches).

    mission: a Mission, or a mission file (None: the flight mission) read with ``overrides``
    (``KEY=VALUE``, as ``--set``) and T [s]; controller: None, the mission's first."""
    m = _mission(mission, overrides, T=T)
    name = m.controllers[0] if controller is None else controller
    if name not in m.controllers:
        raise ValueError(f"controller {name!r} is not flown by the mission (its controllers: "
                         f"{', '.join(m.controllers)})")
    single = at is not None and np.ndim(at) == 0
    times = margins_job.check_times(m, (at,) if single else None if at is None else tuple(at))
    found = {t: margins_job.at(m, name, t, precision) for t in times}
    return found[times[0]] if single else found


def sweep(config, out, *, overrides: Sequence[str] = (), samples=None, T=None,
          controllers=None, chunk=None, seed=None, resume: bool = False, max_memory: int | None = None,
          layout: str = "chunks", progress: bool | None = None) -> dict:
    """A Monte Carlo sweep run (or finished, with ``resume``) into the folder ``out`` as
    ``so3jax sweep`` runs it: summary.json's content.

    The summary: statistics per controller and metric, diverged samples, the paired comparison,
    the run; the folder: the command's files and checkpointed chunks.

    config: a sweep file (None: the built-in sweep) with ``overrides`` (``KEY=VALUE``: a
    mission key, ``sweep.KEY`` or ``dispersions.LEAF``) and samples, T [s], controllers, chunk,
    seed (the sampling seed); or a sweep configuration already read. max_memory [bytes]: refuse
    a run that needs more (None: the memory available); layout: "chunks" or "mesh" over
    several processes."""
    from so3jax.jobs.sweep.config import SweepConfig, load_config
    from so3jax.jobs.sweep.engine import run_sweep

    if not isinstance(config, SweepConfig):
        items = list(overrides)
        for key, where, value in (("samples", "sweep.samples", samples), ("T", "T", T), ("chunk", "sweep.chunk", chunk),
                                  ("seed", "sweep.seed", seed)):
            if value is not None:
                items.append(f"{where}={float(value) if key == 'T' else value}")
        if controllers is not None:
            names = controllers.split(",") if isinstance(controllers, str) else controllers
            items.append("controllers=" + json.dumps([str(c).strip() for c in names]))
        with warnings.catch_warnings():
            warnings.simplefilter("once", InertiaWarning)
            config = load_config(None if config is None else Path(config), tuple(items))
    elif overrides or any(v is not None for v in (samples, T, controllers, chunk, seed)):
        raise ValueError("overrides apply to a sweep file; a sweep configuration is taken as it is")
    return run_sweep(config, Path(out), resume=resume, progress=progress, max_memory=max_memory, layout=layout)


def tune(campaign, out, *, overrides: Sequence[str] = (), iterations=None, T=None, resume: bool = False,
         progress: bool = True) -> dict:
    """A tuning campaign run (or resumed) into the folder ``out`` as ``so3jax tune`` runs it,
    checkpointed every iteration: validation.json's content (the tuned gains, the held-out
    validation), or a design campaign's report (its goals and verdict).

    campaign: a campaign file with ``overrides`` (``KEY=VALUE``: a mission key or a
    ``tune.*`` key), iterations and T [s]; or a campaign configuration already read. A cost or
    gradient that is not finite raises NonFiniteGradientError, after saving."""
    from so3jax.jobs.tune.campaign import tune as run_tune
    from so3jax.jobs.tune.config import TuneConfig, load_config
    from so3jax.missions import config as cfg

    if not isinstance(campaign, TuneConfig):
        items = [cfg.parse_override(text) for text in overrides]
        if iterations is not None:
            items.append(("tune.iterations", iterations))
        if T is not None:
            items.append(("T", float(T)))
        campaign = load_config(campaign, items)
    elif overrides or iterations is not None or T is not None:
        raise ValueError("overrides apply to a campaign file; a campaign configuration is taken as it is")
    return run_tune(campaign, Path(out), resume=resume, progress=progress)


def identification_options(method: str = "regression", *, bias: bool = True, disturbance: str | None = None,
                           interval: float = 5.0, window: float = 10.0, initial=None) -> dict:
    """The keyword arguments of an identification method (``so3jax identify``'s options);
    one-line ValueError for a method, disturbance, interval [s] or window [s] it does not take."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    disturbance = DEFAULT_DISTURBANCE[method] if disturbance is None else disturbance
    if disturbance not in DISTURBANCE:
        raise ValueError(f"disturbance must be one of {', '.join(DISTURBANCE)}, got {disturbance!r}")
    options = dict(bias=bool(bias), degree=DISTURBANCE[disturbance])
    if method == "regression":
        if initial is not None:
            raise ValueError("initial is the simulation method's first guess; the regression needs none")
        value, name = interval, "interval"
        options["interval"] = interval
    else:
        value, name = window, "window"
        if initial is not None:
            initial = np.asarray(initial, float)
            initial = initial * np.eye(3) if initial.shape == () else initial
        options.update(window=window, initial=initial)
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive number of seconds, got {value!r}")
    return options


def identify(data, method: str = "regression", *, mission=None, bias: bool = True, disturbance: str | None = None,
             interval: float = 5.0, window: float = 10.0, initial=None) -> dict:
    """The inertia J [kg m^2], gyro bias [rad/s] and disturbance torque [N m / s^k] estimated
    from telemetry as ``so3jax identify`` estimates them: identification.json's content
    without its config.

    The content: J, its entries' 1 sigma and covariance, principal moments and axes, bias,
    disturbance, residual RMS, ``converged``, ``units``.

    data: a telemetry file (.npz), a :class:`~so3jax.jobs.identify.telemetry.Telemetry`, or its
    arrays as a dict (``Flight.telemetry``); mission: the mission file or Mission whose wheels
    the telemetry uses where it names none (None: the flight mission). method: "regression"
    (equation error; ``interval`` [s]) or "simulation" (output error; ``window`` [s],
    ``initial``: a first guess of J, a number or 3x3 [kg m^2]); disturbance: "none",
    "constant", "linear", "quadratic" or "cubic" (None: linear for regression, cubic for
    simulation); bias: fit the gyro bias."""
    options = identification_options(method, bias=bias, disturbance=disturbance, interval=interval, window=window,
                                      initial=initial)
    if not isinstance(data, telemetry.Telemetry):
        m = mission if isinstance(mission, missions.Mission) else missions.load(mission)
        wheels = m.actuator.get("wheels")
        geometry = None if wheels is None else (np.asarray(wheels["axes"], float).T, wheels["spin_inertia"])
        data = telemetry.check(data, "telemetry", geometry) if isinstance(data, dict) else telemetry.load(data,
                                                                                                          geometry)
    CHECKS[method](data, **options)
    return identify_report.summary(METHODS[method](data, **options))
