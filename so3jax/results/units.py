"""The units of every number a result holds (docs/model.md, "Units of the results").

Machine-read results (JSON, CSV, NPZ) hold SI values: angles in rad, rates in rad/s, torques
in N m, momenta in N m s, inertias in kg m^2, times in s, efforts in N^2 m^2 s. Pointing
errors are the exception: arcsec, the unit of the requirements they are checked against,
and their key or column names it (``"unit": "arcsec"``, ``..._arcsec``); margins name
theirs (``_db``, ``_deg``, ``_s``). Each JSON result carries a ``units`` table, {key: unit}
for its metrics (a statistic of a metric, mean, p95, ..., has the metric's unit), and a
sweep's ``summary.json`` gives the unit of each column of ``samples.csv``.

Tables printed for a person show each metric in the unit a GNC engineer reads it in
(:data:`SHOWN`: attitude errors in deg, estimation errors in arcsec, gyro bias errors in
deg/h), the unit in the row's label; every command shows a metric in the same unit.
"""

from __future__ import annotations

import math

from so3jax.sim.flight_metrics import FlightMetrics
from so3jax.sim.metrics import Metrics
from so3jax.sim.pointing import ARCSEC  # arcsec per rad

DEG_PER_HOUR = math.degrees(1.0) * 3600.0  # deg/h per rad/s

# SI unit of each metric ("-": dimensionless, or a flag).
METRICS = {**Metrics.units, **FlightMetrics.units}

# Each metric a table shows in another unit: (unit, factor from the SI value).
SHOWN = {
    "rms_angle_phase": ("deg", math.degrees(1.0)),
    "max_angle_phase": ("deg", math.degrees(1.0)),
    "attitude_estimation_rms": ("arcsec", ARCSEC),
    "attitude_estimation_max": ("arcsec", ARCSEC),
    "bias_estimation_rms": ("deg/h", DEG_PER_HOUR),
    "bias_estimation_max": ("deg/h", DEG_PER_HOUR),
}


def shown_unit(metric: str) -> str:
    """The unit a table shows ``metric`` in."""
    return SHOWN[metric][0] if metric in SHOWN else METRICS[metric]


def shown(metric: str, value):
    """``metric``'s SI value in :func:`shown_unit` (None stays None: a diverged run's)."""
    if value is None or metric not in SHOWN:
        return value
    return value * SHOWN[metric][1]


def table(metrics) -> dict:
    """{name: SI unit} of the metrics named (an iterable of names; unknown names left out)."""
    return {name: METRICS[name] for name in metrics if name in METRICS}
