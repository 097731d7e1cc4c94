"""The environment's torque models (``[environment.NAME]``, docs/model.md §4): registrations
of :mod:`so3jax.dynamics.environment`'s torques on the mission's orbit, each flown where the
mission gives its table (an empty table: its defaults).

* ``gravity_gradient``: 3 n^2 r^_b x J r^_b, with the true, time-varying J;
* ``magnetic``: a residual magnetic dipole m_res in the tilted, rotating geomagnetic
  dipole field, m_res x B;
* ``aerodynamic``: drag on a flat area through a centre of pressure offset from the centre
  of mass, in an exponential atmosphere;
* ``solar_pressure``: sunlight on a flat area facing the sun through a centre of pressure,
  none in the Earth's shadow.
"""

from __future__ import annotations

import jax

from so3jax.components import registry as components
from so3jax.core.params import Param
from so3jax.core.pytree import pytree_dataclass
from so3jax.dynamics import environment as env
from so3jax.dynamics.space import EnvironmentTorque


@pytree_dataclass
class GravityGradient(EnvironmentTorque):
    """3 mu / r^3 r^_b x J r^_b [N m] (a circular orbit: mu / r^3 = n^2)."""

    def torque(self, orbit, t, R, J):
        return env.gravity_gradient_torque(orbit, t, R, J)


@pytree_dataclass
class ResidualDipole(EnvironmentTorque):
    """m_res x B_b [N m]: dipole (3,) [A m^2], body frame."""

    dipole: jax.Array

    def torque(self, orbit, t, R, J):
        return env.magnetic_torque(self.dipole, R.T @ env.magnetic_field_n(orbit, t))


@pytree_dataclass
class Aerodynamic(EnvironmentTorque):
    """c_p x F_drag [N m]: area [m^2], drag_coefficient, centre_of_pressure (3,) [m], body frame."""

    area: jax.Array
    drag_coefficient: jax.Array
    centre_of_pressure: jax.Array

    def torque(self, orbit, t, R, J):
        return env.aerodynamic_torque(orbit, t, R, self.area, self.drag_coefficient, self.centre_of_pressure)


@pytree_dataclass
class SolarPressure(EnvironmentTorque):
    """c_p x F_sun [N m]: area [m^2], reflectivity, centre_of_pressure (3,) [m], sun_longitude [rad] at t = 0."""

    area: jax.Array
    reflectivity: jax.Array
    centre_of_pressure: jax.Array
    sun_longitude: jax.Array

    def torque(self, orbit, t, R, J):
        return env.solar_pressure_torque(orbit, t, R, self.area, self.reflectivity, self.centre_of_pressure,
                                         self.sun_longitude)


_OFFSET = Param("centre_of_pressure", [0.05, 0.02, 0.0], "m", shapes=((3,),),
                doc="the centre of pressure from the centre of mass, body frame")

components.register(components.ComponentSpec(
    kind="environment", name="gravity_gradient", component=GravityGradient, params=(),
    build=lambda v, ctx: GravityGradient(),
    doc="the gravity gradient 3 n^2 r_b x J r_b of the true inertia (r_b: the unit radius, Earth to spacecraft, "
        "in body axes)",
))
components.register(components.ComponentSpec(
    kind="environment", name="magnetic", component=ResidualDipole,
    params=(Param("dipole", [0.1, 0.1, 0.1], "A m^2", shapes=((3,),), doc="the residual dipole, body frame"),),
    build=lambda v, ctx: ResidualDipole(ctx.as_array(v["dipole"])),
    doc="a residual magnetic dipole in the tilted dipole field rotating with the Earth: m_res x B",
))
components.register(components.ComponentSpec(
    kind="environment", name="aerodynamic", component=Aerodynamic,
    params=(Param("area", 2.0, "m^2", low=0.0, doc="the area facing the flow"),
            Param("drag_coefficient", 2.2, low=0.0, doc="C_D"), _OFFSET),
    build=lambda v, ctx: Aerodynamic(*(ctx.as_array(v[k]) for k in ("area", "drag_coefficient",
                                                                     "centre_of_pressure"))),
    doc="drag in an exponential atmosphere (not rotating) through the centre of pressure",
))
components.register(components.ComponentSpec(
    kind="environment", name="solar_pressure", component=SolarPressure,
    params=(Param("area", 2.0, "m^2", low=0.0, doc="the area facing the sun"),
            Param("reflectivity", 0.3, low=0.0, high=1.0, doc="the force is P A (1 + reflectivity)"), _OFFSET,
            Param("sun_longitude", 0.0, "deg", doc="the sun's ecliptic longitude at t = 0")),
    build=lambda v, ctx: SolarPressure(*(ctx.as_array(v[k]) for k in ("area", "reflectivity", "centre_of_pressure")),
                                       ctx.as_array(v["sun_longitude"] * 3.141592653589793 / 180.0)),
    doc="sunlight on an area facing the sun through the centre of pressure, none in the Earth's shadow",
))
