"""The gradient of a cost through the whole flight loop (gyro and star tracker noise, MEKF,
four reaction wheels with torque limits, Delta_c = 0.1 s; missions/flight.toml) with
respect to the PD's gains, by reverse-mode jax.grad, checked against central finite
differences of the same cost.

    cost(p) = RMSE / 1e-3 rad/s + effort / 100 N^2 m^2 s,   gains (k_R, k_Omega) = exp(p)

(docs/model.md §6's metrics). The rollout is checkpointed one control period at a time, as
`so3jax tune` does in reverse mode (so3jax.checkpoint_steps).

Run: python examples/gradient_through_flight.py [--T 400] [--set KEY=VALUE ...]   (horizon
T [s]; default $SO3JAX_EXAMPLE_T, else 400; --set: a mission entry, as for `so3jax fly`)
"""

import argparse
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import so3jax as sj

FLIGHT = Path(__file__).resolve().parents[1] / "missions" / "flight.toml"


def main(T: float, overrides=(), h: float = 1e-5) -> dict:
    """{"cost", "grad", "central", "relative_difference"}; overrides: the mission's KEY=VALUE entries
    (as `so3jax fly --set` takes them); h: the finite-difference step in log-gains."""
    mission = sj.load_mission(FLIGHT, [f"T={T}", 'controllers=["pd"]', *overrides])
    scenario, loop = mission.scenario(), mission.loop()
    law, gains = mission.controller("pd")  # the paper's gains, [gains.pd] of the mission
    record_every = sj.checkpoint_steps(loop, "reverse")

    def cost(log_gains):
        g = sj.PDGains(*jnp.exp(log_gains))
        m = sj.rollout(scenario, law, g, mission.seed, loop=loop, record_every=record_every).metrics
        return m.rmse / 1e-3 + m.effort / 100.0

    value_and_grad = jax.jit(jax.value_and_grad(cost))  # one compiled program for all the evaluations
    p = jnp.log(jnp.asarray([gains.k_R, gains.k_Omega], dtype=scenario.R0.dtype))
    value, grad = value_and_grad(p)
    central = np.array([(value_and_grad(p.at[i].add(h))[0] - value_and_grad(p.at[i].add(-h))[0]) / (2 * h)
                        for i in range(2)])
    grad = np.asarray(grad)
    rel = float(np.max(np.abs(grad - central)) / np.max(np.abs(central)))
    print(f"cost at the paper's gains (k_R, k_Omega) = ({gains.k_R}, {gains.k_Omega}): {float(value):.6f}")
    print(f"d cost / d log(k_R, k_Omega), jax.grad:        [{grad[0]: .8e}, {grad[1]: .8e}]")
    print(f"d cost / d log(k_R, k_Omega), central (h={h:g}): [{central[0]: .8e}, {central[1]: .8e}]")
    print(f"max relative difference: {rel:.2e}")
    return {"cost": float(value), "grad": grad, "central": central, "relative_difference": rel}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--T", type=float, default=float(os.environ.get("SO3JAX_EXAMPLE_T", 400.0)))
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a mission entry")
    args = parser.parse_args()
    sj.configure_xla()  # the so3jax command's XLA:CPU settings, before the first computation
    jax.config.update("jax_enable_x64", True)
    results = main(args.T, args.set)
