"""A new actuator: a first-order lag between the commanded and the applied torque,

    d tau_a / dt = (tau_c - tau_a) / time_constant,   the body receives tau_a    [N m]

(tau_a: the actuator's state, integrated by RK4 with the plant), registered as a mission
component and flown with the PD through the flight mission (missions/flight.toml: gyro,
star tracker, MEKF, Delta_c = 0.1 s) beside the ideal actuator. The interface is
so3jax.Actuator (docs/model.md §11.1): `command` is required, the base
gives the rest's defaults (no stored momentum, no limits).

Run: python examples/custom_actuator.py [--T 4000] [--set KEY=VALUE ...]   (horizon T [s];
default $SO3JAX_EXAMPLE_T, else 4000; --set: a mission entry, as for `so3jax fly`)
"""

import argparse
import dataclasses
import os
from pathlib import Path

import jax
import jax.numpy as jnp

import so3jax as sj

NAME = "example_lag"  # the mission's actuator.kind
FLIGHT = Path(__file__).resolve().parents[1] / "missions" / "flight.toml"


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class FirstOrderLag(sj.Actuator):
    time_constant: jax.Array  # s

    def init(self, batch_shape, dtype):  # tau_a(0) = 0, components first, batch axes last
        return jnp.zeros((3, *batch_shape), dtype)

    def command(self, state, tau_c, Omega_hat):  # the input held over a control period
        return tau_c

    def body_torque(self, state, held, Omega):
        return state

    def derivative(self, state, held, Omega, Omega_dot):
        return (held - state) / self.time_constant


sj.register_component(sj.ComponentSpec(  # the Param declares the domain, checked when a mission is read
    kind="actuator", name=NAME, component=FirstOrderLag, doc="tau_a' = (tau_c - tau_a) / time_constant",
    params=(sj.Param("time_constant", 0.5, "s", low=1e-6, doc="lag time constant"),),
    build=lambda values, ctx: FirstOrderLag(ctx.as_array(values["time_constant"])),
))


def main(T: float, overrides=()) -> dict:
    """{actuator: (RMSE [rad/s], effort [N^2 m^2 s])} of the PD on the flight mission (docs/model.md §6);
    overrides: the mission's KEY=VALUE entries, as `so3jax fly --set` takes them."""
    law = None
    out = {}
    for label, actuator in (("ideal", ["actuator.kind=ideal"]),
                            ("lag 0.5 s", [f"actuator.kind={NAME}"]),
                            ("lag 5 s", [f"actuator.kind={NAME}", f"actuator.{NAME}.time_constant=5.0"])):
        mission = sj.load_mission(FLIGHT, [f"T={T}", 'controllers=["pd"]', *overrides, *actuator])
        if law is None:  # one Controller object for every run: jit compiles once per actuator kind
            law, gains = mission.controller("pd")
        r = sj.simulate(mission.scenario(), law, gains, mission.seed, loop=mission.loop())
        out[label] = (float(r.metrics.rmse), float(r.metrics.effort))
        print(f"PD, {label:>9}: RMSE {out[label][0]:.4e} rad/s   effort {out[label][1]:8.3f} N^2 m^2 s")
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--T", type=float, default=float(os.environ.get("SO3JAX_EXAMPLE_T", 4000.0)))
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a mission entry")
    args = parser.parse_args()
    sj.configure_xla()  # the so3jax command's XLA:CPU settings, before the first computation
    jax.config.update("jax_enable_x64", True)
    results = main(args.T, args.set)
