"""Identify the inertia from simulated telemetry: the identification manoeuvre of
missions/identify.toml (the docked spacecraft, J = the paper's J2, driven by an open-loop
square-wave torque through four reaction wheels, read by a gyro and a star tracker) is
flown, its telemetry regenerated from the flight (the readings the filter saw, the wheel
speeds), and the inertia fitted by the equation-error regression of so3jax.identify
(docs/model.md §17.3; log-Cholesky parameters, §17.2: the estimate is always a physical
inertia). Prints the estimate beside the truth with its 1-sigma.

Run: python examples/identify_inertia.py [--T 600] [--set KEY=VALUE ...]   (horizon T [s];
default $SO3JAX_EXAMPLE_T, else 600; --set: a mission entry, as for `so3jax fly`)
"""

import argparse
import os
from pathlib import Path

import jax
import numpy as np

import so3jax as sj

MISSION = Path(__file__).resolve().parents[1] / "missions" / "identify.toml"
ENTRIES = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))  # J's entries xx, yy, zz, xy, xz, yz


def main(T: float, overrides=()) -> dict:
    """{"J": estimate, "J_true", "sigma": 1-sigma of the entries (xx, yy, zz, xy, xz, yz), "relative_error"}."""
    flight = sj.fly(MISSION, overrides=overrides, T=T)  # one history sample per control tick
    data = flight.telemetry("open_loop")  # what `so3jax fly` writes to OUT/telemetry/open_loop.npz
    fit = sj.identify(data)  # the regression: J, gyro bias and a linear disturbance torque
    J, J_true = np.asarray(fit["J"]), np.asarray(flight.mission.J0)
    sigma = np.asarray(fit["J_entries_std"])
    rel = float(np.linalg.norm(J - J_true) / np.linalg.norm(J_true))
    print(f"{len(data['t'])} telemetry samples over {T:g} s; fit converged: {fit['converged']}")
    print("entry   truth [kg m^2]   estimate +- 1 sigma")
    for name, (i, j), s in zip(fit["J_entries"], ENTRIES, sigma):
        print(f"{name}  {J_true[i, j]:12.2f}   {J[i, j]:10.2f} +- {s:.2f}")
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
