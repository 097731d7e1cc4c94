"""A mission flown by the closed loop of docs/model.md §8 (sensors, estimator, sampled-data
control, actuators), each controller on the same mission and seed: the job ``so3jax fly``
(:mod:`so3jax.commands.fly`) runs, its report, trajectory, telemetry and figures."""

from __future__ import annotations

import dataclasses
import functools
import time
import warnings
from pathlib import Path

import jax
import numpy as np

from so3jax.components import registry as components
from so3jax.dynamics.inertia import InertiaWarning
from so3jax.dynamics.scenario import steps_for_horizon
from so3jax.jobs.identify import telemetry
from so3jax.missions.mission import Mission
from so3jax.parallel import devices
from so3jax.results import io, units
from so3jax.results.io import save_npz, to_builtin
from so3jax.sim import memory, pointing
from so3jax.sim.metrics import cell, reached_phases, reported
from so3jax.sim.rollout import simulate as simulate_rollout

METRICS = ("rmse", "rmse_unrotated", "effort", "rmse_phase", "effort_phase", "rms_angle_phase", "max_angle_phase",
           "max_torque", "orthogonality_error")
FLIGHT_METRICS = ("attitude_estimation_rms", "attitude_estimation_max", "bias_estimation_rms", "bias_estimation_max",
                  "command_effort", "actuator_effort", "time_at_torque_limit", "time_at_speed_limit",
                  "max_wheel_speed_ratio")
TRAJECTORY = ("t", "R", "Omega", "R_hat", "Omega_hat", "bias", "bias_hat", "tau_cmd", "tau_applied", "wheel_speed")


def fly(mission, dtype: str = "float64") -> tuple[dict, float]:
    """Every controller of the mission, side by side on the CPU devices
    (:func:`so3jax.parallel.devices.side_by_side`: compilations in parallel). Returns {name:
    Result with NumPy leaves} and the wall time [s], compile included."""
    scenario, loop = mission.scenario(dtype), mission.loop(dtype)

    def simulate(name):
        controller, gains = mission.controller(name)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", InertiaWarning)  # reported once, when the mission was read
            result = simulate_rollout(scenario, controller, gains, mission.seed, loop=loop,
                                 record_every=mission.record_every)
            return jax.tree.map(np.asarray, result)

    start = time.perf_counter()
    results = devices.side_by_side({name: functools.partial(simulate, name) for name in mission.controllers})
    return results, time.perf_counter() - start


def memory_needed(mission, dtype: str = "float64") -> int:
    """The memory [bytes] every controller's rollout needs (:mod:`so3jax.sim.memory`), each
    traced as :func:`fly` runs it (on its device, side by side): the flight reuses the traces."""
    scenario, loop = mission.scenario(dtype), mission.loop(dtype)

    def needed(name):
        return memory.simulate_bytes(scenario, *mission.controller(name), mission.seed, loop, mission.record_every)

    return sum(devices.side_by_side({name: functools.partial(needed, name) for name in mission.controllers}).values())


def check_memory(mission, dtype: str = "float64", max_memory: int | None = None) -> dict:
    """Refuse (one-line ValueError) a flight whose rollouts need more than ``max_memory``
    [bytes] (None: the memory available), before anything compiles; returns
    {'estimate_bytes', 'limit_bytes'}."""
    return memory.check(memory_needed(mission, dtype), max_memory,
                        f"T = {mission.T:g} s at record_every = {mission.record_every}",
                        "raise --record-every or shorten --T")


@dataclasses.dataclass(frozen=True)
class Flight:
    """A mission flown by each of its controllers: what ``so3jax fly`` computes, before any file.

    results: {controller: :class:`so3jax.sim.rollout.Result`, NumPy leaves} (metrics, history,
    final state, flight metrics); reports: {controller: :func:`report`} (metrics.json's entry:
    the metrics in SI units, the flight metrics, ``pointing`` [arcsec] and ``requirements``
    with their verdicts); wall_s: the wall time [s], compilation included."""

    mission: Mission
    results: dict
    reports: dict
    wall_s: float

    @property
    def trajectory(self) -> dict:
        """trajectory.npz's arrays: {controller/quantity: array} (:func:`trajectory_arrays`)."""
        return trajectory_arrays(self.results, steps_for_horizon(self.mission.T, self.mission.dt) * self.mission.dt)

    @property
    def diverged(self) -> list:
        """The controllers whose run diverged."""
        return [n for n in self.mission.controllers if self.reports[n]["diverged"]]

    @property
    def failed(self) -> list:
        """The controllers that failed a pointing requirement."""
        return [n for n in self.mission.controllers if not all(q["passed"] for q in self.reports[n]["requirements"])]

    def telemetry(self, name: str) -> dict:
        """Controller ``name``'s telemetry arrays (OUT/telemetry/NAME.npz's fields,
        :func:`so3jax.jobs.identify.telemetry.from_run`): the flight needs a gyro and a star tracker."""
        return telemetry.from_run(self.mission, self.results[name].history, self.mission.seed)

    def table(self) -> str:
        """The command's table: one column per controller (:func:`format_table`)."""
        return format_table(self.mission, {n: self.reports[n] for n in self.mission.controllers})

    def requirements_table(self) -> str:
        """A line per controller and requirement (:func:`format_requirements`)."""
        return format_requirements({n: self.reports[n] for n in self.mission.controllers})


def flight(mission, dtype: str = "float64") -> Flight:
    """Every controller of the mission flown (:func:`fly`) and reported (:func:`report`)."""
    results, wall = fly(mission, dtype)
    reports = {name: report(mission, r) for name, r in results.items()}
    return Flight(mission, results, reports, wall)


def report(mission, result) -> dict:
    """The metrics of docs/model.md §6 (phases the horizon never reached omitted) and the flight metrics, as
    JSON-ready data: every metric of a diverged run None (null), the run flagged diverged."""
    m = result.metrics._asdict()
    diverged = bool(m["diverged"])
    reached = sum(reached_phases(mission.scenario().steps_per_phase))
    out = {k: to_builtin(reported(m[k], diverged)[..., :reached] if k.endswith("_phase") else reported(m[k], diverged))
           for k in METRICS}
    out["diverged"] = diverged
    if mission.period_steps is not None:
        f = result.flight._asdict()
        out.update({k: to_builtin(reported(f[k], diverged)) for k in FLIGHT_METRICS})
    out.update(pointing_report(mission, result.history))
    return out


def pointing_report(mission, history) -> dict:
    """:func:`pointing_errors` at the mission's window, levels, phases and requirements."""
    return pointing_errors(history, mission.scenario(), window=mission.pointing["window"],
                           levels=mission.pointing["levels"], requirements=mission.requirements,
                           phase_names=mission.phase_names)


def pointing_errors(history, scenario, *, window: float, levels=(0.95, 0.9973), requirements=(),
                    phase_names=None) -> dict:
    """The ECSS pointing indices of one run's recorded history (:func:`so3jax.sim.pointing.report`:
    APE, MPE, RPE and, with an estimate, AKE, MKE, RKE [arcsec], per phase the horizon reaches, at
    each confidence level, windowed indices over ``window`` [s]) and the requirements
    (:class:`so3jax.sim.pointing.Requirement`) checked over the scenario's phases
    (:func:`so3jax.sim.pointing.check`), JSON-ready: {"pointing": ..., "requirements": [...]}."""
    t, performance, knowledge = pointing.signals(history)
    phases = pointing.phase_bounds_of(scenario)
    reached = sum(reached_phases(scenario.steps_per_phase))
    names = None if phase_names is None else tuple(phase_names)[:reached]
    report = pointing.report(t, performance, knowledge, phases[:reached], window=window, levels=levels,
                             phase_names=names, indices=pointing.reported(knowledge))
    return {"pointing": to_builtin(report),
            "requirements": to_builtin(pointing.check(requirements, t, performance, knowledge, phases))}


def _cell(x, fmt):
    """None here is a diverged run's metric (phases never reached are left out); a string
    says why there is no value."""
    return "diverged" if x is None else x if isinstance(x, str) else cell(x, fmt)


def format_table(mission, reports: dict) -> str:
    """One column per controller."""
    names = list(reports)
    width = max(14, *(len(n) + 2 for n in names))
    lines = [f"{'':34s}" + "".join(f"{n:>{width}s}" for n in names)]

    def row(label, fn, fmt):
        lines.append(f"{label:34s}" + "".join(f"{_cell(fn(reports[n]), fmt):>{width}s}" for n in names))

    def metric(label, name, fmt, phase=None):
        """A metric's row in the unit tables show it in (:mod:`so3jax.results.units`)."""
        value = (lambda r: r[name]) if phase is None else (lambda r: r[name][phase])
        row(f"{label} [{units.shown_unit(name)}]", lambda r: units.shown(name, value(r)), fmt)

    metric("RMSE", "rmse", ".4e")
    metric("effort (delivered)", "effort", ".2f")
    for p in range(len(reports[names[0]]["rmse_phase"])):
        label = mission.phase_names[p]
        metric(f"  RMSE {label}", "rmse_phase", ".4e", p)
        metric(f"  max attitude error {label}", "max_angle_phase", ".3f", p)
    metric("max |tau| delivered", "max_torque", ".4f")
    if mission.period_steps is not None:
        metric("command effort", "command_effort", ".2f")
        metric(components.get("actuator", mission.actuator["kind"]).effort_label, "actuator_effort", ".2f")
        metric("attitude estimation RMS", "attitude_estimation_rms", ".2f")
        metric("attitude estimation max", "attitude_estimation_max", ".2f")
        metric("bias estimation RMS", "bias_estimation_rms", ".4f")
        metric("bias estimation max", "bias_estimation_max", ".4f")
        row("max wheel speed / limit", lambda r: r["max_wheel_speed_ratio"], ".3f")
        metric("time at a torque limit", "time_at_torque_limit", ".1f")
        metric("time at a speed limit", "time_at_speed_limit", ".1f")
    level = reports[names[0]]["pointing"]["levels"][0]
    for p, phase in enumerate(reports[names[0]]["pointing"]["phases"]):
        for index in [r["index"] for r in phase["rows"] if r["level"] == level]:
            row(f"  {index} {level:.4g} {phase['name']} [arcsec]", lambda r, p=p, i=index: _pointing(r, p, i, level),
                ".2f")
    lines.append(f"{'diverged':34s}" + "".join(f"{str(reports[n]['diverged']):>{width}s}" for n in names))
    return "\n".join(lines)


def _pointing(report, phase, index, level):
    """The angle of ``index`` at ``level`` in ``phase`` [arcsec]; None where the run diverged;
    why not where the phase holds no whole window (a windowed index) or no sample."""
    entry = report["pointing"]["phases"][phase]
    row = next(r for r in entry["rows"] if r["index"] == index and r["level"] == level)
    if report["diverged"]:
        return None
    if row["angle"] is None:
        window = row["window"]
        short = window is not None and pointing.whole_windows((entry["t_start"], entry["t_end"]), window) < 1
        return f"no whole window (window {window:g} s)" if short else "no sample"
    return row["angle"]


def format_requirements(reports: dict) -> str:
    """A line per controller and requirement: its value against its limit, passed or FAILED."""
    lines = []
    for name, r in reports.items():
        lines += [f"{name}: {pointing.outcome(q)}" for q in r["requirements"]]
    return "\n".join(lines)


def recorded(x, otherwise):
    """A History field, or ``otherwise`` where the wiring does not record it (None)."""
    return otherwise if x is None else x


def trajectory_arrays(results: dict, t_final: float) -> dict:
    """{controller/quantity: array} of the recorded histories (t shared), and the state at
    the horizon's end t_final = N dt [s] (``final_t``, ``final_R``, ``final_Omega``,
    ``final_wheel_speed``): the records start a block of ``record_every`` steps, so the
    last is one block before the end. A wiring without
    an estimate (continuous: the law reads the true state) stores the truth as R_hat,
    Omega_hat and zero biases, and a zero covariance without a filter; wheel_speed is
    (M, 0) without wheels, wheel_momentum zeros; momentum_management: the momentum
    manager's held input, where one is flown; hinge_angle, hinge_rate (M, N) [rad, rad/s] and
    slosh_displacement, slosh_rate (M, N_slosh) [m, m/s] where the hub carries appendages or slosh."""
    arrays = {}
    for name, r in results.items():
        final = r.final
        arrays.update({f"{name}/final_t": np.asarray(t_final), f"{name}/final_R": np.asarray(final.R),
                       f"{name}/final_Omega": np.asarray(final.Omega),
                       f"{name}/final_wheel_speed": (np.asarray(final.actuator) if np.ndim(final.actuator) == 1
                                                     else np.zeros(0))})
        h = r.history
        values = {"t": h.t, "R": h.R, "Omega": h.Omega, "R_hat": recorded(h.R_hat, h.R),
                  "Omega_hat": recorded(h.Omega_hat, h.Omega), "bias": recorded(h.bias, np.zeros_like(h.Omega)),
                  "bias_hat": recorded(h.bias_hat, np.zeros_like(h.Omega)), "tau_cmd": h.tau_cmd, "tau_applied": h.tau,
                  "wheel_speed": h.actuator if np.ndim(h.actuator) == 2 else np.zeros((len(h.t), 0)),
                  "disturbance": h.disturbance, "covariance": recorded(h.covariance, np.zeros((len(h.t), 6, 6))),
                  "wheel_momentum": h.momentum}
        if h.managed is not None:  # a momentum manager's held input (thrusters: torque; magnetorquers: dipole)
            values["momentum_management"] = h.managed
        if h.flexible is not None:  # [[appendages]] and [[slosh]] (docs/model.md §8.9): (M, N) and (M, N_slosh)
            values.update(hinge_angle=h.flexible.theta, hinge_rate=h.flexible.theta_dot,
                          slosh_displacement=h.flexible.rho, slosh_rate=h.flexible.rho_dot)
        arrays.update({f"{name}/{k}": np.asarray(v) for k, v in values.items()})
    return arrays


def write_telemetry(out: Path, mission, results: dict) -> str:
    """OUT/telemetry/NAME.npz per controller (:mod:`so3jax.jobs.identify.telemetry`'s format),
    where the loop has a gyro and a star tracker; what the summary line lists."""
    if not telemetry.recorded(mission):
        return ""
    for name, r in results.items():
        save_npz(out / "telemetry" / f"{name}.npz", **telemetry.from_run(mission, r.history, mission.seed))
    return ", telemetry/"


def write_figures(out: Path, mission, results: dict) -> list[Path]:
    """The mission's figures (:func:`so3jax.viz.fly.figures`) into ``out``."""
    from so3jax.viz import fly as plots  # here: matplotlib only when drawing

    return io.save_figures(out, plots.figures(mission, {name: r.history for name, r in results.items()}))
