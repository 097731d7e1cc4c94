"""One unit convention (so3jax.results.units): every metric has its SI unit, and the tables a
person reads (fly's, a sweep's summary.md) show a metric in one unit, converted from the SI
value the JSON holds. No compile: synthetic reports."""

import dataclasses
import math

import pytest

from so3jax.jobs import fly
from so3jax.jobs.sweep import summary as sweep_summary
from so3jax.missions import mission as missions
from so3jax.results import units
from so3jax.sim.flight_metrics import FlightMetrics
from so3jax.sim.metrics import Metrics

ARCSEC = 180.0 / math.pi * 3600.0
DEG_PER_HOUR = 180.0 / math.pi * 3600.0


def test_every_metric_has_its_si_unit():
    assert set(Metrics.units) == set(Metrics._fields)
    assert set(FlightMetrics.units) == set(FlightMetrics._fields)
    assert units.METRICS["rmse"] == "rad/s" and units.METRICS["attitude_estimation_rms"] == "rad"
    assert units.table(["rmse", "unknown", "bias_estimation_max"]) == {"rmse": "rad/s", "bias_estimation_max": "rad/s"}


def test_a_metric_is_shown_converted_from_its_si_value():
    assert units.shown("attitude_estimation_rms", 1e-5) == pytest.approx(1e-5 * ARCSEC, rel=1e-15)
    assert units.shown("bias_estimation_rms", 1e-6) == pytest.approx(1e-6 * DEG_PER_HOUR, rel=1e-15)
    assert units.shown("max_angle_phase", math.pi) == pytest.approx(180.0, rel=1e-15)
    assert units.shown("rmse", 0.25) == 0.25 and units.shown("bias_estimation_rms", None) is None
    assert [units.shown_unit(m) for m in ("attitude_estimation_max", "bias_estimation_max", "rms_angle_phase",
                                          "effort")] == ["arcsec", "deg/h", "deg", "N^2 m^2 s"]


REPORT = {"rmse": 1e-3, "rmse_unrotated": 1e-3, "effort": 2.0, "rmse_phase": [1e-3] * 3, "effort_phase": [2.0] * 3,
          "rms_angle_phase": [0.01] * 3, "max_angle_phase": [0.02] * 3, "max_torque": 0.1, "orthogonality_error": 1e-15,
          "diverged": False, "attitude_estimation_rms": 2e-5, "attitude_estimation_max": 5e-5,
          "bias_estimation_rms": 3e-7, "bias_estimation_max": 9e-7, "command_effort": 2.0, "actuator_effort": 1.5,
          "time_at_torque_limit": 0.0, "time_at_speed_limit": 0.0, "max_wheel_speed_ratio": 0.1,
          "pointing": {"levels": [0.95], "phases": []}}


def _row(text: str, label: str) -> str:
    return next(line for line in text.splitlines() if line.lstrip().startswith(label))


def test_fly_s_table_shows_each_metric_in_its_shown_unit():
    text = fly.format_table(missions.load(), {"pd": REPORT})
    estimation = _row(text, "attitude estimation RMS")
    assert "[arcsec]" in estimation and float(estimation.split()[-1]) == pytest.approx(2e-5 * ARCSEC, abs=0.01)
    bias = _row(text, "bias estimation max")
    assert "[deg/h]" in bias and float(bias.split()[-1]) == pytest.approx(9e-7 * DEG_PER_HOUR, abs=1e-4)
    angle = _row(text, "max attitude error capture")
    assert "[deg]" in angle and float(angle.split()[-1]) == pytest.approx(math.degrees(0.02), abs=1e-3)


def _stats(x):
    return {"mean": x, "std": 0.0, "p50": x, "p95": x, "p99": x, "max": x, "samples": 1}


def test_a_sweep_summary_shows_the_flight_metrics_in_fly_s_units():
    flight = {m: _stats(REPORT[m]) for m in sweep_summary.FLIGHT}
    entry = {"simulated": 1, "diverged": 0, "nonfinite": 0, "rmse": {"mission": _stats(1e-3)},
             "effort": {"mission": _stats(2.0)}, "flight": flight, "at_limit": {"share": 0.05, "samples": 0}}
    summary = {"samples": {"requested": 1, "simulated": 1, "rejected": 0, "rejected_component": 0, "redraws": 0,
                           "nonphysical_inertia": 0},
               "config": {"sweep": {"max_draws": 4}}, "controllers": {"pd": entry}, "paired": {}}
    text = sweep_summary.format_summary(summary)
    table = fly.format_table(missions.load(), {"pd": REPORT})
    for metric, label in (("attitude_estimation_rms", "attitude estimation RMS"),
                          ("bias_estimation_rms", "bias estimation RMS")):
        row = _row(text, f"| {metric}")
        unit = units.shown_unit(metric)
        assert f"[{unit}]" in row and f"[{unit}]" in _row(table, label)
        assert float(row.split("|")[3]) == pytest.approx(units.shown(metric, REPORT[metric]), rel=1e-3)


def test_every_margin_written_has_its_unit():
    from so3jax.sim import margins

    written = {f.name for cls in (margins.AxisMargins, margins.Disk, margins.LoopMargins, margins.DiskMargins)
               for f in dataclasses.fields(cls)} | {"t"}
    assert written - set(margins.UNITS) == {"axis", "stable", "at_limit", "axes", "multiloop"}  # labels, flags


def test_fly_s_table_says_no_whole_window_where_a_phase_is_shorter_than_the_window():
    """A windowed index (MPE, RPE) of a phase shorter than the window has no value: the table
    says so and names the window, beside a run that did not diverge (metrics.json: null)."""
    import numpy as np

    from so3jax.sim import pointing

    t = np.arange(0.0, 20.0, 0.5)
    e = np.full((len(t), 3), 1e-5)
    report = pointing.report(t, e, None, [(0.0, 20.0)], window=60.0, levels=(0.95,), phase_names=["capture"],
                             indices=("APE", "MPE", "RPE"))
    text = fly.format_table(missions.load(), {"pd": {**REPORT, "pointing": report}})
    for index in ("MPE", "RPE"):
        assert _row(text, f"{index} 0.95 capture").endswith("no whole window (window 60 s)")
    assert float(_row(text, "APE 0.95 capture").split()[-1]) == pytest.approx(math.sqrt(3) * 1e-5 * ARCSEC, rel=1e-3)
    assert "diverged" not in text.replace(_row(text, "diverged"), "")
