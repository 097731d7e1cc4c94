"""Mass-property identification from telemetry (``so3jax identify``).

Two methods estimate the inertia J (and the gyro bias and a body-fixed disturbance torque
polynomial in time) from a telemetry file (:mod:`so3jax.jobs.identify.telemetry`):
``regression`` (:mod:`~so3jax.jobs.identify.regression`, equation error in momentum-integral
form, instrumental variables) and ``simulation`` (:mod:`~so3jax.jobs.identify.simulation`,
output error through the simulated plant, multiple shooting). Both fit the log-Cholesky
parameters of J (:mod:`~so3jax.jobs.identify.inertia`), so every estimate is a physical inertia.
Each method's ``check`` takes its options and refuses, before the fit, what the fit would
refuse: options the record cannot hold, and telemetry that does not determine J
(:func:`so3jax.jobs.identify.fit.spread`).
"""

from so3jax.jobs.identify import inertia, regression, simulation, telemetry

METHODS = {"regression": regression.identify, "simulation": simulation.identify}
CHECKS = {"regression": regression.check, "simulation": simulation.check}

__all__ = ["CHECKS", "METHODS", "inertia", "regression", "simulation", "telemetry"]
