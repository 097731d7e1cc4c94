"""The orbit: Earth's constants and the mean motion of a circular orbit (docs/model.md §4)."""

from __future__ import annotations

import math

MU_EARTH = 3.986004418e14  # m^3/s^2
EARTH_RADIUS = 6378.137e3  # m
PAPER_ALTITUDE = 500e3  # m


def orbital_rate(altitude: float = PAPER_ALTITUDE) -> float:
    """Mean motion n = sqrt(mu / a^3) of a circular orbit [rad/s]."""
    return math.sqrt(MU_EARTH / (EARTH_RADIUS + altitude) ** 3)
