"""The figures of ``so3jax fly``: with continuous control the attitude error and the
torque; with sampled control the attitude, the gyro bias, the torque, the actuator's
figures and the momentum manager's (:mod:`so3jax.viz.flight`)."""

from __future__ import annotations

from so3jax.viz import flight as flight_plots
from so3jax.viz import plots


def figures(mission, histories: dict) -> dict:
    """{file name: Figure} of the controllers' histories ({name: History}) over the mission."""
    phases = plots.Phases(mission.scenario().phase_times, mission.phase_names)
    if mission.period_steps is None:
        return {"attitude_error.png": plots.attitude_error_figure(histories, phases, mission.T),
                "torque.png": plots.torque_figure(histories, phases, mission.T)}
    figures = {
        "attitude.png": flight_plots.attitude_figure(histories, phases, mission.T),
        "bias.png": flight_plots.bias_figure(histories, phases, mission.T),
        "torque.png": flight_plots.torque_figure(histories, phases, mission.T),
    }
    kind = mission.actuator["kind"]
    figures.update(flight_plots.actuator_figures(kind, histories, phases, mission.T, mission.actuator[kind]))
    if mission.momentum["kind"] != "none":
        figures["momentum_management.png"] = flight_plots.momentum_management_figure(
            mission.momentum["kind"], histories, phases, mission.T)
    return figures
