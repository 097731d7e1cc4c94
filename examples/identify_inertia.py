"""Identify the inertia from simulated telemetry: the identification manoeuvre of
missions/identify.toml (the docked spacecraft, J = the paper's J2, driven by an open-loop
square-wave torque through four reaction wheels, read by a gyro and a star tracker) is
flown, its telemetry regenerated from the flight (the readings the filter saw, the wheel
speeds), and the inertia fitted by the equation-error regression of so3jax.jobs.identify
(docs/model.md §17.3; log-Cholesky parameters, §17.2: the estimate is always a physical
inertia). Prints the estimate beside the truth with its 1-sigma.

Run: python examples/identify_inertia.py [--T 600] [--set KEY=VALUE ...]   (horizon T [s];
default $SO3JAX_EXAMPLE_T, else 600; --set: a mission entry, as for `so3jax fly`)
"""

import argparse
import os
import warnings
from pathlib import Path

import jax
import numpy as np

import so3jax as sj
from so3jax.jobs.identify import inertia, regression, telemetry

MISSION = Path(__file__).resolve().parents[1] / "missions" / "identify.toml"


def main(T: float, overrides=()) -> dict:
    """{"J": estimate, "J_true", "sigma": 1-sigma of the entries (xx, yy, zz, xy, xz, yz), "relative_error"}."""
    mission = sj.load_mission(MISSION, [f"T={T}", *overrides])
    law, gains = mission.controller("open_loop")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sj.InertiaWarning)
        flight = sj.simulate(mission.scenario(), law, gains, mission.seed, loop=mission.loop(),
                             record_every=mission.record_every)  # one history sample per control tick
    history = jax.tree.map(np.asarray, flight.history)
    tm = telemetry.check(telemetry.from_run(mission, history, mission.seed))  # what `so3jax fly` writes
    fit = regression.identify(tm)  # J, gyro bias and a linear disturbance torque
    J, J_true = np.asarray(fit["J"]), np.asarray(mission.J0)
    sigma = np.sqrt(np.diag(fit["theta_cov"]))
    rel = float(np.linalg.norm(J - J_true) / np.linalg.norm(J_true))
    print(f"{len(tm.t)} telemetry samples over {T:g} s; fit converged: {fit['converged']}")
    print("entry   truth [kg m^2]   estimate +- 1 sigma")
    for name, true, est, s in zip(("xx", "yy", "zz", "xy", "xz", "yz"), inertia.entries(J_true),
                                  inertia.entries(J), sigma):
        print(f"J_{name}  {float(true):12.2f}   {float(est):10.2f} +- {s:.2f}")
    print(f"relative error |J - J_true| / |J_true| = {rel:.2e}")
    return {"J": J, "J_true": J_true, "sigma": sigma, "relative_error": rel}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--T", type=float, default=float(os.environ.get("SO3JAX_EXAMPLE_T", 600.0)))
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a mission entry")
    args = parser.parse_args()
    sj.configure_xla()  # the so3jax command's XLA:CPU settings, before the first computation
    jax.config.update("jax_enable_x64", True)
    results = main(args.T, args.set)
