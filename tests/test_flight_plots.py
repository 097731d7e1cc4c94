"""Flight figures at the edges of what a run records: one sample, non-finite values."""

from types import SimpleNamespace

import numpy as np

from so3jax.viz import flight as flight_plots


def _history(t, value):
    n = len(t)
    return SimpleNamespace(t=np.asarray(t), bias=np.full((n, 3), value), bias_hat=np.full((n, 3), value),
                           std=np.full((n, 6), 1e-6))


def test_bias_figure_with_no_sample_past_the_first_two_percent():
    """A horizon of one recorded sample (t = 0): the figure is drawn on matplotlib's own range."""
    fig = flight_plots.bias_figure({"pd": _history([0.0], 1e-4)}, (500.0, 2600.0), 1.0)
    assert len(fig.axes) == 3


def test_bias_figure_range_follows_the_late_values_and_skips_non_finite():
    t = np.linspace(0.0, 100.0, 11)
    h = _history(t, 1e-4)
    h.bias_hat[-1] = np.nan  # a diverged run's last sample
    fig = flight_plots.bias_figure({"pd": h}, (500.0, 2600.0), 100.0)
    low, high = fig.axes[0].get_ylim()
    value = 1e-4 * np.degrees(1.0) * 3600.0
    assert np.isfinite(low) and np.isfinite(high) and low < value < high
