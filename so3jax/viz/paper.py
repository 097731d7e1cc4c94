"""The figures of ``so3jax paper``: the paper's Figs. 1-5 and the attitude error."""

from __future__ import annotations

from so3jax.viz import plots


def figures(histories: dict, scenario) -> dict:
    """{file name: Figure} of the controllers' histories ({name: History}, the pd's
    inertia shown) over the scenario's phases and horizon."""
    h = histories["pd"]
    phases, T = scenario.phase_times, scenario.horizon
    t_last = phases[-1] if phases else T  # the last phase's start (the paper's: docking)
    return {
        "fig1_inertia.png": plots.inertia_figure(h.t, h.J, phases, T),
        "fig2_angular_velocity.png": plots.rate_figure(histories, phases, T),
        "fig3_tracking_error.png": plots.rate_error_figure(histories, phases, t_last, T),
        "fig4_torque.png": plots.torque_figure(histories, phases, T),
        "fig5_torque_norm.png": plots.torque_norm_figure(histories, phases, T),
        "fig6_attitude_error.png": plots.attitude_error_figure(histories, phases, T),
    }
