"""A small Monte Carlo sweep from Python: the paper's mission (docs/model.md §4) with
dispersed inertias (J0 and J2 scaled by U(0.8, 1.2), J0's principal moments by U(0.9, 1.1)
and its axes rotated up to 10 deg; J1 = 2 J0; docs/model.md §15.3) and a disturbance seed
per sample, drawn by so3jax.draw_samples and flown by jax.vmap over so3jax.rollout, one
compiled program per control law. Prints each law's mean and worst RMSE over the samples.

`so3jax sweep` does the same at scale (chunks, resume, several devices);
`sj.rollout_batch` is the natively batched alternative to vmap.

Run: python examples/vmapped_sweep.py [--T 4000] [--samples 16]   (horizon T [s]; default
$SO3JAX_EXAMPLE_T, else 4000)
"""

import argparse
import dataclasses
import os

import jax
import numpy as np

import so3jax as sj


def main(T: float, samples: int, seed: int = 0) -> dict:
    """{law: RMSE of every sample [rad/s]}."""
    dispersions = sj.Dispersions(
        J0=sj.InertiaDispersion(nominal=sj.PAPER_J0, scale=sj.Uniform(0.8, 1.2), axis_scale=sj.Uniform(0.9, 1.1),
                                rotation_deg=10.0),
        J2=sj.InertiaDispersion(nominal=sj.PAPER_J2, scale=sj.Uniform(0.8, 1.2)),
    )
    drawn = sj.draw_samples(dispersions, seed, samples, max_draws=10)  # NumPy, leading axis = sample
    p = drawn.params
    base = sj.paper_scenario(T)

    def metrics(law, gains):
        def one(J0, J1, J2, seed):  # one sample's scenario: the paper's with its inertias
            scenario = dataclasses.replace(base, inertia=dataclasses.replace(base.inertia, J0=J0, J1=J1, J2=J2))
            return sj.rollout(scenario, law, gains, seed).metrics

        return jax.jit(jax.vmap(one))(p.J0, p.J1, p.J2, p.seed)

    print(f"{samples} samples, T = {T:g} s; J0 scale {drawn.scale[:, 0].min():.3f} .. {drawn.scale[:, 0].max():.3f}")
    out = {}
    for name, law, gains in (("pd", sj.geometric_pd(), sj.PAPER_PD_GAINS),
                             ("adaptive", sj.adaptive_backstepping(), sj.PAPER_ADAPTIVE_GAINS)):
        m = metrics(law, gains)
        rmse = np.asarray(m.rmse)
        out[name] = rmse
        print(f"{name:>8}: mean RMSE {rmse.mean():.4e} rad/s, worst {rmse.max():.4e} (sample {rmse.argmax()}), "
              f"diverged {int(np.sum(m.diverged))}")
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--T", type=float, default=float(os.environ.get("SO3JAX_EXAMPLE_T", 4000.0)))
    parser.add_argument("--samples", type=int, default=16)
    args = parser.parse_args()
    sj.configure_xla()  # the so3jax command's XLA:CPU settings, before the first computation
    jax.config.update("jax_enable_x64", True)
    results = main(args.T, args.samples)
