"""The orbit: Earth's constants, the mean motion of a circular orbit and its domain
(docs/model.md §4)."""

from __future__ import annotations

import math

MU_EARTH = 3.986004418e14  # m^3/s^2
EARTH_RADIUS = 6378.137e3  # m
PAPER_ALTITUDE = 500e3  # m
# The least altitude of an orbit [m] above EARTH_RADIUS (the Karman line): no circular orbit
# lasts below it, and none can lie below the surface.
MIN_ALTITUDE = 100e3


def orbital_rate(altitude: float = PAPER_ALTITUDE) -> float:
    """Mean motion n = sqrt(mu / a^3) of a circular orbit [rad/s]."""
    return math.sqrt(MU_EARTH / (EARTH_RADIUS + altitude) ** 3)


# The greatest mean motion [rad/s]: that of a circular orbit MIN_ALTITUDE above EARTH_RADIUS.
MAX_MEAN_MOTION = orbital_rate(MIN_ALTITUDE)


def orbit_radius(n: float) -> float:
    """a = (mu / n^2)^(1/3) [m] of the circular orbit of mean motion n > 0 [rad/s]."""
    return (MU_EARTH / (n * n)) ** (1.0 / 3.0)


def check_mean_motion(n: float, where: str = "orbit.n") -> float:
    """n [rad/s] unless it is the mean motion of a circular orbit below MIN_ALTITUDE (above
    MAX_MEAN_MOTION); one-line ValueError naming ``where``, the orbit's radius and altitude
    and the least altitude otherwise. n = 0 (no orbital motion) passes."""
    if n > MAX_MEAN_MOTION:
        a = orbit_radius(n)
        raise ValueError(
            f"{where} = {n:g} rad/s is a circular orbit of radius {a / 1e3:.0f} km, altitude "
            f"{(a - EARTH_RADIUS) / 1e3:.0f} km: below the least altitude, {MIN_ALTITUDE / 1e3:g} km above the "
            f"Earth's equatorial radius {EARTH_RADIUS / 1e3:.3f} km ({where} <= {MAX_MEAN_MOTION:.6g} rad/s)")
    return n
