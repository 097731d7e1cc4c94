"""What the figures say about themselves: titles, legends, line styles and ticks, on small
synthetic histories (no simulation)."""

from types import SimpleNamespace

import numpy as np
import pytest

from so3jax.viz import flight as flight_plots
from so3jax.viz import plots
from so3jax.viz import sweep as sweep_plots
from so3jax.viz import tune as tune_plots

PHASES = (5.0, 10.0)  # phase starts [s]
T = 20.0  # horizon [s]


def _rotation_z(angle):
    """(M, 3, 3) rotations about z by angle (M,) [rad]."""
    c, s = np.cos(angle), np.sin(angle)
    R = np.zeros((len(angle), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    return R


def _flight_history(n=21):
    t = np.linspace(0.0, T, n)
    angle = np.linspace(0.5, 0.01, n)
    return SimpleNamespace(t=t, angle=angle, R=_rotation_z(angle), R_d=_rotation_z(np.zeros(n)),
                           R_hat=_rotation_z(angle + 1e-3), momentum=np.full((n, 3), 0.1),
                           actuator=np.full((n, 4), 10.0))


def _legend_texts(ax):
    return [text.get_text() for text in ax.get_legend().get_texts()]


def _line(ax, label):
    (line,) = [line for line in ax.get_lines() if line.get_label() == label]
    return line


def test_attitude_figure_title_and_legend_match_the_line_styles():
    """PD is drawn dashed: nothing may call the truth solid; the legend tells truth from estimate."""
    fig = flight_plots.attitude_figure({"pd": _flight_history(), "adaptive": _flight_history()}, PHASES, T)
    top = fig.axes[0]
    assert "solid" not in top.get_title() and "dotted" not in top.get_title()
    assert set(_legend_texts(top)) == {"PD (true)", "PD (estimated)", "adaptive (true)", "adaptive (estimated)"}
    assert _line(top, "PD (true)").get_linestyle() == "--"
    assert _line(top, "adaptive (true)").get_linestyle() == "-"


def test_attitude_figure_draws_the_estimate_wide_under_a_thin_truth():
    """The estimate, close to the truth, shows around it: wider and below it."""
    fig = flight_plots.attitude_figure({"pd": _flight_history()}, PHASES, T)
    top = fig.axes[0]
    true, estimated = _line(top, "PD (true)"), _line(top, "PD (estimated)")
    assert estimated.get_linewidth() >= 3 * true.get_linewidth()
    assert estimated.get_zorder() < true.get_zorder()
    assert estimated.get_alpha() < 1.0
    assert "thin" in top.get_title() and "wide" in top.get_title()


def _sweep_columns(n=5):
    """Sweep columns of n samples of one controller (a small sweep: a handful of counts per bin)."""
    rng = np.random.default_rng(0)
    return {"index": np.arange(n), "pd_diverged": np.zeros(n), "pd_rmse": rng.uniform(1e-3, 2e-3, n),
            "pd_effort": rng.uniform(90.0, 110.0, n), "pd_rmse_detumble": rng.uniform(1e-3, 2e-3, n),
            "J0_trace_ratio": rng.uniform(0.9, 1.1, n), "J2_trace_ratio": rng.uniform(0.9, 1.1, n)}


def test_sweep_histograms_count_in_whole_samples():
    config = SimpleNamespace(controllers=["pd"], T=T, pointing=False, margins_at=())
    hist = sweep_plots.figures(config, _sweep_columns(), [(0, "capture")])["histograms.png"]
    for ax in hist.axes:
        ticks = ax.get_yticks()
        assert ax.get_ylabel() == "samples"
        assert np.all(ticks == np.round(ticks)), ticks


def _tune_rows(n=4):
    return [{"iteration": i, "cost": 1.0 - 0.1 * i, "rmse": 1e-3, "effort": 100.0 + i, "k_R": 0.5 + i,
             "k_Omega": 25.0} for i in range(n)]


def test_tune_history_iterations_are_whole():
    fig = tune_plots.history_figure(_tune_rows(), ["k_R", "k_Omega"])
    for ax in fig.axes:
        ticks = [tick for tick in ax.get_xticks() if 0 <= tick <= 3]
        assert ticks and np.all(np.equal(ticks, np.round(ticks))), ticks


@pytest.mark.parametrize("budget, label", [(104.0, "effort budget"),
                                           (np.array([100.0, 108.0]), "effort budget (mean over scenarios)")])
def test_tune_history_draws_the_effort_budget(budget, label):
    fig = tune_plots.history_figure(_tune_rows(), ["k_R", "k_Omega"], budget=budget)
    effort = fig.axes[2]
    assert effort.get_ylabel().startswith("effort")
    assert label in _legend_texts(effort)
    line = _line(effort, label)
    assert list(line.get_ydata()) == [104.0, 104.0]
    low, high = effort.get_ylim()
    assert low < 104.0 < high


def test_tune_history_without_a_budget_draws_no_budget_line():
    fig = tune_plots.history_figure(_tune_rows(), ["k_R", "k_Omega"])
    assert all("budget" not in line.get_label() for ax in fig.axes for line in ax.get_lines())


def test_inertia_figure_plots_the_principal_moments():
    """An inertia with products: the principal moments are its eigenvalues, not its diagonal."""
    J0 = np.array([[625.0, 5.5, 3.0], [5.5, 350.0, 4.0], [3.0, 4.0, 1000.0]])
    J0[0, 1] = J0[1, 0] = 200.0  # far from diagonal
    t = np.linspace(0.0, T, 3)
    J = np.stack([J0, 2 * J0, 2 * J0])
    fig = plots.inertia_figure(t, J, PHASES, T)
    moments = fig.axes[0]
    assert moments.get_title().startswith("principal moments")
    drawn = np.sort([line.get_ydata()[0] for line in moments.get_lines()])
    np.testing.assert_allclose(drawn, np.linalg.eigvalsh(J0))
    assert not np.allclose(drawn, np.sort(np.diag(J0)))


def test_principal_moments_of_a_non_finite_inertia_are_nan():
    J = np.stack([np.diag([1.0, 2.0, 3.0]), np.full((3, 3), np.nan)])
    moments = plots.principal_moments(J)
    np.testing.assert_allclose(moments[0], [1.0, 2.0, 3.0])
    assert np.all(np.isnan(moments[1]))


def _rate_history():
    t = np.linspace(0.0, T, 21)
    return SimpleNamespace(t=t, Omega=np.zeros((21, 3)), Omega_d=np.full((21, 3), 1e-3))


def test_rate_error_figure_names_the_phases_it_shows():
    """Up to the third phase's start: phases 1-2 (capture and deployment), not "before capture"."""
    fig = plots.rate_error_figure({"pd": _rate_history()}, PHASES, PHASES[-1], T)
    title = fig.get_suptitle()
    assert "capture" not in title
    assert "phases 1–2" in title and "t < 10 s" in title
    assert {text.get_text() for text in fig.axes[0].texts} == {"phase 1", "phase 2"}


def test_a_mission_s_phase_names_label_its_figures():
    fig = flight_plots.wheel_speed_figure({"pd": _flight_history()}, plots.Phases(PHASES, ("acquire", "image", "dump")),
                                          T, np.full(4, 600.0))
    shown = [text.get_text() for text in fig.axes[0].texts]
    assert shown == ["acquire", "image", "dump"][: len(shown)] and len(shown) == sum(p < T for p in PHASES) + 1


def test_wheel_speed_limits_are_in_the_legend():
    fig = flight_plots.wheel_speed_figure({"pd": _flight_history()}, PHASES, T, np.full(4, 600.0))
    ax = fig.axes[0]
    assert _legend_texts(ax).count("speed limit ±Ω_max") == 1
    assert sorted(_line(ax, "speed limit ±Ω_max").get_ydata()) == [600.0, 600.0]


def test_momentum_capacity_is_in_the_legend():
    fig = flight_plots.momentum_figure({"pd": _flight_history()}, PHASES, T, np.array([1.0, 2.0, 3.0]))
    ax = fig.axes[0]
    assert "capacity ±h_max" in _legend_texts(ax)
    assert list(_line(ax, "capacity ±h_max").get_ydata()) == [1.0, 1.0]
