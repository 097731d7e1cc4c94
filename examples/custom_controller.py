"""A new control law: a PD without feedforward whose torque saturates per body axis,

    tau_i = clip(-k_R e_R - k_Omega Omega_e, -max_torque, max_torque)_i    [N m]

(e_R, Omega_e: the attitude and rate errors of docs/model.md §2), written as a subclass of
``so3jax.Controller`` (a frozen dataclass of its options, ``init`` and ``torque``),
registered by name with a plot style, and flown on the paper's mission
(missions/paper.toml) beside the built-in geometric PD with the same gains.

Run: python examples/custom_controller.py [--T 4000] [--set KEY=VALUE ...]   (horizon T [s];
default $SO3JAX_EXAMPLE_T, else 4000; --set: a mission entry, as for `so3jax fly`, e.g.
--set controller.example_saturated_pd.max_torque=0.1)
"""

import argparse
import dataclasses
import os
from pathlib import Path

import jax
import jax.numpy as jnp

import so3jax as sj

NAME = "example_saturated_pd"  # the registry's name: what a mission's `controllers` lists
PAPER = Path(__file__).resolve().parents[1] / "missions" / "paper.toml"


@dataclasses.dataclass(frozen=True)
class SaturatedPD(sj.Controller):
    """The law above; max_torque [N m], per axis. A static law: its state is (). Its
    options are hashable fields: two equal instances share one compiled rollout."""

    max_torque: float = 0.25

    gains_type = sj.PDGains

    def init(self, gains):
        return ()

    def torque(self, gains, state, feedback, desired, t):
        err = sj.tracking_error(feedback, desired)
        e_R = sj.so3.skew_vee(err.R_e)  # vee of the skew part of R_e (docs/model.md §3.1)
        tau = -gains.k_R * e_R - gains.k_Omega * err.Omega_e
        return jnp.clip(tau, -self.max_torque, self.max_torque), ()


def check(gains):
    if any(float(g) < 0 for g in gains):
        raise ValueError(f"gains must be non-negative, got {gains}")


sj.register_controller(sj.ControllerSpec(
    name=NAME, label="saturated PD", factory=SaturatedPD, gains_type=sj.PDGains, defaults=sj.PAPER_PD_GAINS,
    check=check, options=(sj.Param("max_torque", 0.25, "N m", low=0.0, doc="torque limit per body axis"),),
))
sj.register_style(NAME, color="tab:olive", label="saturated PD")  # its lines in the figures


def main(T: float, overrides=()) -> dict:
    """{controller: (RMSE [rad/s], effort [N^2 m^2 s])} on the paper's mission (docs/model.md §6)."""
    mission = sj.load_mission(PAPER, [f"T={T}", f'controllers=["pd", "{NAME}"]', *overrides])
    flight = sj.fly(mission)  # every controller of the mission, compiled and flown side by side
    out = {}
    for name, r in flight.results.items():
        out[name] = (float(r.metrics.rmse), float(r.metrics.effort))
        print(f"{name:>22}: RMSE {out[name][0]:.4e} rad/s   effort {out[name][1]:8.3f} N^2 m^2 s")
    print(f"({flight.wall_s:.1f} s, compilation included)")
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--T", type=float, default=float(os.environ.get("SO3JAX_EXAMPLE_T", 4000.0)))
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a mission entry")
    args = parser.parse_args()
    sj.configure_xla()  # the so3jax command's XLA:CPU settings, before the first computation
    jax.config.update("jax_enable_x64", True)
    results = main(args.T, args.set)
