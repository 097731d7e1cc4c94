"""The space environment's physics (docs/model.md §4): a circular orbit, the geomagnetic field
(a tilted dipole turning with the Earth), an exponential atmosphere, the sun's direction and
the Earth's shadow, and the environmental torques on the body (gravity gradient, a residual
magnetic dipole, drag, solar radiation pressure). The registered torque models that the
loop flies are :mod:`so3jax.components.environment`'s.

Frames:

* N, the simulation's inertial frame: the orbit (LVLH) frame at t = 0 -- x along the
  velocity, z toward nadir (-r^), y = z x x (minus the orbit normal). The attitude R maps
  body -> N: a vector v_N has body components R^T v_N.
* ECI: Earth-centred inertial, x toward the vernal equinox, z the north pole, fixed
  (no precession or nutation). ECEF turns about z by theta_G(t) = theta_G0 + OMEGA_EARTH t:
  r_ECI = Rz(theta_G) r_ECEF.

The orbit is circular: mean motion n [rad/s], radius a = (MU_EARTH / n^2)^(1/3) [m],
inclination i, right ascension of the ascending node raan, argument of latitude u0 at
t = 0 [rad]; u = u0 + n t and

    r_ECI = a [cos raan cos u - sin raan sin u cos i, sin raan cos u + cos raan sin u cos i, sin u sin i],

v_ECI = dr_ECI/dt. In N, r_N = a [sin n t, 0, -cos n t], v_N = n a [cos n t, 0, sin n t].

Every function is pure and JAX-traceable (jit, vmap, grad) in t [s], the attitude, the
inertia and the parameters, and computes in the dtype of its inputs (the orbit's for orbit
quantities; t is cast to it). Vectors and matrices follow :mod:`so3jax.core.so3`: component
axes first, batch axes (if any) last -- (3,), (3, 3), or (3, *b), (3, 3, *b) with an orbit
whose scalars have the batch shape b. The only branches (the shadow, the atmosphere's band)
are selections whose derivatives are those of the selected piece: gradients stay finite.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.core import so3
from so3jax.core.pytree import pytree_dataclass
from so3jax.dynamics.orbit import EARTH_RADIUS, MU_EARTH, check_mean_motion

OMEGA_EARTH = 7.2921159e-5  # rad/s, the Earth's sidereal rotation rate
SIDEREAL_YEAR = 365.25636 * 86400.0  # s: the sun's period in a non-precessing inertial frame
OBLIQUITY = math.radians(23.4393)  # rad, the ecliptic's obliquity (J2000)
SOLAR_IRRADIANCE = 1361.0  # W/m^2 at 1 AU: the IAU 2015 Resolution B3 nominal total solar irradiance
SPEED_OF_LIGHT = 299_792_458.0  # m/s
P_SUN = SOLAR_IRRADIANCE / SPEED_OF_LIGHT  # N/m^2, the solar radiation pressure at 1 AU (fully absorbed): 4.540e-6

# IGRF-13's 2020 dipole (degree 1) coefficients [nT] and the IGRF reference radius [m], the
# radius they refer to (the mean radius, not EARTH_RADIUS: 0.3 % in the field at a given r).
IGRF_2020_DIPOLE = (-29404.8, -1450.9, 4652.5)  # (g10, g11, h11)
IGRF_REFERENCE_RADIUS = 6371.2e3  # m

# Vallado, Fundamentals of Astrodynamics and Applications (4th ed. 2013), Table 8-4, the
# exponential atmosphere: base altitude h0 [km], nominal density rho0 [kg/m^3], scale height H [km].
_ATMOSPHERE_KM = np.array([
    (0, 1.225, 7.249), (25, 3.899e-2, 6.349), (30, 1.774e-2, 6.682), (40, 3.972e-3, 7.554),
    (50, 1.057e-3, 8.382), (60, 3.206e-4, 7.714), (70, 8.770e-5, 6.549), (80, 1.905e-5, 5.799),
    (90, 3.396e-6, 5.382), (100, 5.297e-7, 5.877), (110, 9.661e-8, 7.263), (120, 2.438e-8, 9.473),
    (130, 8.484e-9, 12.636), (140, 3.845e-9, 16.149), (150, 2.070e-9, 22.523), (180, 5.464e-10, 29.740),
    (200, 2.789e-10, 37.105), (250, 7.248e-11, 45.546), (300, 2.418e-11, 53.628), (350, 9.518e-12, 53.298),
    (400, 3.725e-12, 58.515), (450, 1.585e-12, 60.828), (500, 6.967e-13, 63.822), (600, 1.454e-13, 71.835),
    (700, 3.614e-14, 88.667), (800, 1.170e-14, 124.64), (900, 5.245e-15, 181.05), (1000, 3.019e-15, 268.00),
])
ATMOSPHERE_BASE_ALTITUDE = _ATMOSPHERE_KM[:, 0] * 1e3  # m
ATMOSPHERE_DENSITY = _ATMOSPHERE_KM[:, 1]  # kg/m^3
ATMOSPHERE_SCALE_HEIGHT = _ATMOSPHERE_KM[:, 2] * 1e3  # m


def _float_dtype(x):
    """x's dtype where it is floating, else JAX's default float (float64 with x64)."""
    dtype = jnp.asarray(x).dtype
    return dtype if jnp.issubdtype(dtype, jnp.floating) else jnp.asarray(0.0).dtype


def _rotate_z(angle, v):
    """Rz(angle) v for v (3, ...) (or (3,) broadcast against angle's shape)."""
    c, s = jnp.cos(angle), jnp.sin(angle)
    return jnp.stack([c * v[0] - s * v[1], s * v[0] + c * v[1], v[2] + jnp.zeros_like(c)])


@pytree_dataclass
class CircularOrbit:
    """A circular orbit and the Earth's rotation angle at t = 0 (module docstring). Build with
    :func:`circular_orbit`. Each field is a scalar (or of one batch shape b)."""

    n: jax.Array  # mean motion [rad/s]
    inclination: jax.Array  # i [rad]
    raan: jax.Array  # right ascension of the ascending node [rad]
    argument_of_latitude: jax.Array  # u0 at t = 0 [rad]
    earth_angle: jax.Array  # theta_G0, Greenwich's right ascension at t = 0 [rad]

    def _t(self, t):
        return jnp.asarray(t, dtype=self.n.dtype)

    def radius(self):
        """a = (MU_EARTH / n^2)^(1/3) [m]."""
        return (MU_EARTH / (self.n * self.n)) ** (1.0 / 3.0)

    def altitude(self):
        """a - EARTH_RADIUS [m]."""
        return self.radius() - EARTH_RADIUS

    def _radial_along(self, u):
        """(r^, t^) (3, ...) in ECI at argument of latitude u: the radial and along-track units."""
        ci, si = jnp.cos(self.inclination), jnp.sin(self.inclination)
        co, so = jnp.cos(self.raan), jnp.sin(self.raan)
        cu, su = jnp.cos(u), jnp.sin(u)
        radial = jnp.stack([co * cu - so * su * ci, so * cu + co * su * ci, su * si])
        along = jnp.stack([-co * su - so * cu * ci, -so * su + co * cu * ci, cu * si])
        return radial, along

    def position_eci(self, t):
        """r_ECI(t) (3, ...) [m]."""
        t = self._t(t)
        return self.radius() * self._radial_along(self.argument_of_latitude + self.n * t)[0]

    def velocity_eci(self, t):
        """v_ECI(t) = n a t^(u) (3, ...) [m/s]."""
        t = self._t(t)
        return self.n * self.radius() * self._radial_along(self.argument_of_latitude + self.n * t)[1]

    def eci_from_n(self):
        """C (3, 3, ...): its columns are N's axes in ECI -- t^(u0), -h^, -r^(u0) (h^ = r^ x t^,
        the orbit normal [sin raan sin i, -cos raan sin i, cos i]); v_ECI = C v_N."""
        radial, along = self._radial_along(self.argument_of_latitude)
        ci, si = jnp.cos(self.inclination), jnp.sin(self.inclination)
        minus_normal = jnp.stack([-jnp.sin(self.raan) * si, jnp.cos(self.raan) * si, -ci])
        return jnp.stack([along, minus_normal, -radial], axis=1)

    def radial_n(self, t):
        """r^_N(t) = [sin n t, 0, -cos n t] (3, ...): the unit radius in N."""
        nt = self.n * self._t(t)
        return jnp.stack([jnp.sin(nt), jnp.zeros_like(nt), -jnp.cos(nt)])

    def position_n(self, t):
        """r_N(t) = C^T r_ECI(t) = a [sin n t, 0, -cos n t] (3, ...) [m]."""
        return self.radius() * self.radial_n(t)

    def velocity_n(self, t):
        """v_N(t) = C^T v_ECI(t) = n a [cos n t, 0, sin n t] (3, ...) [m/s]."""
        nt = self.n * self._t(t)
        return self.n * self.radius() * jnp.stack([jnp.cos(nt), jnp.zeros_like(nt), jnp.sin(nt)])

    def earth_rotation_angle(self, t):
        """theta_G(t) = theta_G0 + OMEGA_EARTH t [rad]: r_ECI = Rz(theta_G) r_ECEF."""
        return self.earth_angle + OMEGA_EARTH * self._t(t)


def circular_orbit(n, inclination=0.0, raan=0.0, argument_of_latitude=0.0, earth_angle=0.0, dtype=None):
    """A :class:`CircularOrbit` of mean motion n [rad/s] (:func:`so3jax.dynamics.orbit.orbital_rate`)
    and angles [rad], its fields arrays of ``dtype`` (default: n's floating dtype). One-line
    ValueError where a concrete n is not positive or is an orbit's below MIN_ALTITUDE
    (:func:`so3jax.dynamics.orbit.check_mean_motion`)."""
    dtype = _float_dtype(n) if dtype is None else jnp.dtype(dtype)
    try:
        concrete = np.asarray(n, np.float64)
    except jax.errors.TracerArrayConversionError:  # traced: not checked
        concrete = None
    if concrete is not None and not np.all(concrete > 0.0):
        raise ValueError(f"the mean motion n must be positive, not {n}")
    if concrete is not None:
        check_mean_motion(float(np.max(concrete)), "the mean motion n")
    as_array = lambda x: jnp.asarray(x, dtype=dtype)
    return CircularOrbit(as_array(n), as_array(inclination), as_array(raan), as_array(argument_of_latitude),
                         as_array(earth_angle))


# --- the geomagnetic field -------------------------------------------------------------


def dipole_field_ecef(r_ecef, coefficients=IGRF_2020_DIPOLE):
    """The degree-1 geomagnetic field B (3, ...) [T] at r_ecef (3, ...) [m], in the same axes.

    The degree-1 potential V = a^3 (g . r) / |r|^3, g = (g11, h11, g10) [nT], a the IGRF
    reference radius, gives B = -grad V = B0 (a / |r|)^3 [3 (m^ . r^) r^ - m^] with
    m^ = g / |g| and B0 = |g| (g10 < 0: m^ points south, B points down in the north).
    """
    g10, g11, h11 = coefficients
    b0 = math.sqrt(g10 * g10 + g11 * g11 + h11 * h11)
    m = (g11 / b0, h11 / b0, g10 / b0)
    r2 = so3.dot(r_ecef, r_ecef)
    m_dot_r = m[0] * r_ecef[0] + m[1] * r_ecef[1] + m[2] * r_ecef[2]
    scale = (b0 * 1e-9 * IGRF_REFERENCE_RADIUS**3) / (r2 * jnp.sqrt(r2))  # B0 a^3 / |r|^3
    return scale * jnp.stack([3.0 * m_dot_r * r_ecef[k] / r2 - m[k] for k in range(3)])


def magnetic_field_n(orbit: CircularOrbit, t, coefficients=IGRF_2020_DIPOLE):
    """The geomagnetic field at the spacecraft in N (3, ...) [T]: the tilted dipole
    (:func:`dipole_field_ecef`) turning with the Earth, B_N = C^T Rz(theta_G) B_ECEF(Rz(-theta_G) r_ECI);
    computed as the dipole of axis m^_N = C^T Rz(theta_G) m^_ECEF at r^_N."""
    g10, g11, h11 = coefficients
    b0 = math.sqrt(g10 * g10 + g11 * g11 + h11 * h11)
    m_ecef = jnp.asarray([g11 / b0, h11 / b0, g10 / b0], dtype=orbit.n.dtype)
    m_n = so3.rmatvec(orbit.eci_from_n(), _rotate_z(orbit.earth_rotation_angle(t), m_ecef))
    r_hat = orbit.radial_n(t)
    scale = b0 * 1e-9 * (IGRF_REFERENCE_RADIUS / orbit.radius()) ** 3
    return scale * (3.0 * so3.dot(m_n, r_hat) * r_hat - m_n)


# --- the atmosphere -------------------------------------------------------------------


def atmosphere_density(altitude):
    """rho(h) = rho0_k exp(-(h - h0_k) / H_k) [kg/m^3] at the altitude h [m] (any shape), band k
    the last with h0_k <= h (Vallado Table 8-4, 0 to 1000 km; below 0 km the first band's
    exponential, above 1000 km the last's)."""
    h = jnp.asarray(altitude)
    h = h.astype(_float_dtype(h))
    base = jnp.asarray(ATMOSPHERE_BASE_ALTITUDE, dtype=h.dtype)
    k = jnp.clip(jnp.searchsorted(base, h, side="right") - 1, 0, base.shape[0] - 1)
    rho0 = jnp.asarray(ATMOSPHERE_DENSITY, dtype=h.dtype)[k]
    scale_height = jnp.asarray(ATMOSPHERE_SCALE_HEIGHT, dtype=h.dtype)[k]
    return rho0 * jnp.exp(-(h - base[k]) / scale_height)


# --- the sun --------------------------------------------------------------------------


def sun_direction_eci(t, sun_longitude):
    """The unit vector s^ (3, ...) from the Earth to the sun in ECI: ecliptic longitude
    lambda = sun_longitude + 2 pi t / SIDEREAL_YEAR [rad] (a circular apparent orbit),
    s^ = [cos lambda, cos eps sin lambda, sin eps sin lambda], eps the obliquity. t [s] is cast
    to sun_longitude's floating dtype."""
    longitude = jnp.asarray(sun_longitude)
    longitude = longitude.astype(_float_dtype(longitude))
    lam = longitude + (2.0 * math.pi / SIDEREAL_YEAR) * jnp.asarray(t, dtype=longitude.dtype)
    sin = jnp.sin(lam)
    return jnp.stack([jnp.cos(lam), math.cos(OBLIQUITY) * sin, math.sin(OBLIQUITY) * sin])


def sunlit(r_eci, s_hat):
    """1 where r_eci (3, ...) [m] is in sunlight, 0 in the Earth's cylindrical shadow (behind the
    Earth, r . s^ < 0, within EARTH_RADIUS of the Earth-sun line), in r_eci's dtype."""
    along = so3.dot(r_eci, s_hat)
    perpendicular = r_eci - along * s_hat
    shadow = (along < 0.0) & (so3.dot(perpendicular, perpendicular) < EARTH_RADIUS**2)
    return jnp.where(shadow, 0.0, 1.0).astype(r_eci.dtype)


# --- the torques (body frame, N m) ---------------------------------------------------------


def gravity_gradient_torque(orbit: CircularOrbit, t, R, J):
    """tau = 3 n^2 r^_b x (J r^_b) [N m], r^_b = R^T r^_N the unit radius in body axes
    (docs/model.md eq. 4.3; 3 mu / a^3 = 3 n^2 on a circular orbit):
    minus the derivative of U = (3 n^2 / 2) r^_b^T J r^_b on SO(3)."""
    r_b = so3.rmatvec(R, orbit.radial_n(t).astype(R.dtype))
    n2 = (orbit.n * orbit.n).astype(R.dtype)
    return 3.0 * n2 * so3.cross(r_b, so3.matvec(J, r_b))


def magnetic_torque(dipole_body, B_body):
    """tau = m x B [N m] (docs/model.md eq. 4.4): a magnetic dipole m [A m^2] in the field B [T], both in
    body axes (B_b = R^T :func:`magnetic_field_n`)."""
    return so3.cross(dipole_body, B_body)


def aerodynamic_torque(orbit: CircularOrbit, t, R, area, drag_coefficient, centre_of_pressure):
    """tau = c_p x F_b [N m] (docs/model.md eq. 4.5), F_b = -1/2 rho(h) C_D A |v| v_b the drag on a
    constant area A [m^2] through the centre of pressure c_p (3,) [m] (body axes, from the centre
    of mass); v the orbit velocity, v_b = R^T v_N (the atmosphere not rotating), h = a - EARTH_RADIUS
    (:func:`atmosphere_density`)."""
    rho = atmosphere_density(orbit.altitude())
    speed = orbit.n * orbit.radius()
    v_b = so3.rmatvec(R, orbit.velocity_n(t).astype(R.dtype))
    force = (-0.5 * rho * speed).astype(R.dtype) * drag_coefficient * area * v_b
    return so3.cross(centre_of_pressure, force)


def solar_pressure_torque(orbit: CircularOrbit, t, R, area, reflectivity, centre_of_pressure, sun_longitude):
    """tau = c_p x F_b [N m] (docs/model.md eq. 4.6), F_b = -P_SUN A (1 + reflectivity) s^_b * sunlit: a flat plate of
    area A [m^2] facing the sun (normal incidence; the area is not projected), pushed away
    from it, through the centre of pressure c_p (3,) [m] (body axes); s^_b = R^T C^T s^_ECI,
    the sun's ecliptic longitude sun_longitude [rad] at t = 0 (:func:`sun_direction_eci`),
    none in the Earth's shadow (:func:`sunlit`)."""
    s_eci = sun_direction_eci(t, jnp.asarray(sun_longitude, dtype=orbit.n.dtype))
    lit = sunlit(orbit.position_eci(t), s_eci)
    s_b = so3.rmatvec(R, (so3.rmatvec(orbit.eci_from_n(), s_eci) * lit).astype(R.dtype))
    force = -P_SUN * area * (1.0 + reflectivity) * s_b
    return so3.cross(centre_of_pressure, force)
