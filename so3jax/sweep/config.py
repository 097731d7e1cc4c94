"""Sweep configuration: SweepConfig, its defaults (sweeps/default.toml) and the TOML
structure it is read from and written to."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from so3jax import config as cfg
from so3jax import dispersions as disp
from so3jax.controllers import registry
from so3jax.scenario import PAPER_J0, PAPER_J2, check_gains, steps_for_horizon

CONTROLLERS = {n: (registry.get(n).factory, registry.get(n).gains_type) for n in registry.names(tunable=True)}
PAPER_GAINS = {n: registry.get(n).defaults for n in CONTROLLERS}


# The default sweep (sweeps/default.toml); a config file's missing entries take these values.
DEFAULT_DISPERSIONS = disp.Dispersions(
    J0=disp.InertiaDispersion(
        nominal=PAPER_J0,
        scale=disp.LogNormal(1.0, 0.1),
        axis_scale=disp.Uniform(0.9, 1.1),
        rotation_deg=10.0,
        products=disp.Normal(0.0, 10.0),
    ),
    J1=disp.InertiaDispersion(scale=disp.Uniform(1.8, 2.2), products=disp.Normal(0.0, 10.0)),
    J2=disp.InertiaDispersion(
        nominal=PAPER_J2,
        scale=disp.LogNormal(1.0, 0.1),
        axis_scale=disp.Uniform(0.9, 1.1),
        rotation_deg=10.0,
        products=disp.Normal(0.0, 20.0),
    ),
    tau_J=disp.Uniform(200.0, 400.0),
    n=disp.Uniform(1.0381e-3, 1.1314e-3),
    amplitude=disp.Uniform(0.05, 0.15),
    noise_std=disp.Uniform(0.0125, 0.0375),
    initial_angle_deg=30.0,
    initial_rate=disp.Uniform(0.0, 0.005),
)


@dataclasses.dataclass(frozen=True)
class SweepConfig:
    """A sweep: samples 0 .. samples-1 of ``dispersions`` (seed ``seed``), horizon T [s],
    step dt [s], with each of ``controllers`` at ``gains``. Defaults: sweeps/default.toml.

    chunk: samples per batch (at least 8 per device, a multiple of the device count);
    max_draws: attempts at a positive definite sample before it is rejected; a sample
    diverged when its state is non-finite or its attitude error exceeds
    divergence_angle_deg [deg].
    """

    samples: int = 1024
    seed: int = 0
    T: float = 4000.0
    dt: float = 0.01
    controllers: tuple = ("pd", "adaptive")
    chunk: int = 128
    max_draws: int = 20
    divergence_angle_deg: float = 150.0
    gains: dict = dataclasses.field(default_factory=lambda: dict(PAPER_GAINS))
    dispersions: disp.Dispersions = DEFAULT_DISPERSIONS


_TOP_KEYS = ("samples", "seed", "T", "dt", "controllers", "chunk", "max_draws", "divergence_angle_deg")
_TABLES = ("inertia", "deployment", "orbit", "disturbance", "initial", "gains")


def _inertia(t: dict, where: str, default: disp.InertiaDispersion) -> disp.InertiaDispersion:
    fields = {}
    if "nominal" in t:
        if default.nominal is None:
            raise ValueError(f"[{where}] takes no nominal: J1's nominal is the sample's J0 (scale is the growth J1/J0)")
        nominal = cfg.array(t["nominal"], f"{where}.nominal (a 3x3 matrix)", (3, 3))
        fields["nominal"] = tuple(map(tuple, nominal.tolist()))
    for name in ("scale", "axis_scale", "products"):
        if name in t:
            fields[name] = _distribution(t[name], f"{where}.{name}")
    if "rotation_deg" in t:
        fields["rotation_deg"] = cfg.number(t["rotation_deg"], f"{where}.rotation_deg", low=0.0, high=180.0)
    return dataclasses.replace(default, **fields)


def _distribution(value, where: str) -> disp.Distribution:
    """disp.parse_distribution, after checking that a table's ``dist`` is a name (a string)."""
    if isinstance(value, dict) and "dist" in value and not isinstance(value["dist"], str):
        cfg.choice(value["dist"], f"{where}.dist", tuple(disp.DISTRIBUTIONS))
    return disp.parse_distribution(value, where)


def config_from_dict(d: dict) -> SweepConfig:
    """A SweepConfig from the TOML structure (see sweeps/default.toml); ValueError on bad input."""
    if not isinstance(d, dict):
        raise ValueError(f"a sweep config must be a table, got {cfg.short(d)}")  # noqa: TRY004 (bad input)
    unknown = set(d) - set(_TOP_KEYS) - set(_TABLES)
    if unknown:
        raise ValueError(f"unknown config key(s): {', '.join(sorted(unknown))}")
    base = SweepConfig()
    top = {}
    for key in ("samples", "chunk", "max_draws"):
        if key in d:
            top[key] = cfg.number(d[key], key, low=1, integer=True)
    if "seed" in d:
        top["seed"] = cfg.number(d["seed"], "seed", low=0, high=2**32 - 1, integer=True)
    for key in ("T", "dt"):
        if key in d:
            top[key] = cfg.number(d[key], key, low=0.0)
    if "divergence_angle_deg" in d:
        top["divergence_angle_deg"] = cfg.number(d["divergence_angle_deg"], "divergence_angle_deg", 0.0, 180.0)
    if "controllers" in d:
        top["controllers"] = cfg.names(d["controllers"], "controllers", tuple(CONTROLLERS))
    config = dataclasses.replace(base, **top)
    steps_for_horizon(config.T, config.dt)

    inertia = cfg.table(d, "inertia", ("J0", "J1", "J2"), "")
    inertia_keys = ("nominal", "scale", "axis_scale", "rotation_deg", "products")
    base_d = base.dispersions
    fields = {
        name: _inertia(cfg.table(inertia, name, inertia_keys, "inertia."), f"inertia.{name}", getattr(base_d, name))
        for name in ("J0", "J1", "J2")
    }
    for table, keys in (("deployment", ("tau_J",)), ("orbit", ("n",)), ("disturbance", ("amplitude", "frequency", "noise_std"))):
        t = cfg.table(d, table, keys + (("seed",) if table == "disturbance" else ()), "")
        fields.update({k: _distribution(t[k], f"{table}.{k}") for k in keys if k in t})
    seed = cfg.table(d, "disturbance", ("seed", "amplitude", "frequency", "noise_std"), "").get("seed", "random")
    if seed != "random":
        fields["disturbance_seed"] = cfg.number(seed, "disturbance.seed ('random' or a seed)", 0, 2**31 - 1, integer=True)
    initial = cfg.table(d, "initial", ("max_angle_deg", "rate"), "")
    if "max_angle_deg" in initial:
        fields["initial_angle_deg"] = cfg.number(initial["max_angle_deg"], "initial.max_angle_deg", 0.0, 180.0)
    if "rate" in initial:
        fields["initial_rate"] = _distribution(initial["rate"], "initial.rate")
    dispersions = dataclasses.replace(base_d, **fields)
    if not dispersions.initial_angle_deg < config.divergence_angle_deg:
        raise ValueError(
            f"divergence_angle_deg ({config.divergence_angle_deg}) must exceed initial.max_angle_deg "
            f"({dispersions.initial_angle_deg}), or every large initial error would count as diverged"
        )

    gains = dict(base.gains)
    gain_tables = cfg.table(d, "gains", tuple(CONTROLLERS), "")
    for name, t in gain_tables.items():
        spec = registry.get(name)
        gains[name] = cfg.gains(t, gains[name], spec.gain_shapes(), f"gains.{name}")
    for name, g in gains.items():
        try:
            check_gains(g)
        except (TypeError, ValueError) as err:
            raise ValueError(f"[gains.{name}]: {err}") from None
    disp.check(dispersions)
    return dataclasses.replace(config, gains=gains, dispersions=dispersions)


def config_to_dict(config: SweepConfig) -> dict:
    """The TOML structure of a config (config_from_dict inverts it)."""
    d = {k: getattr(config, k) for k in _TOP_KEYS}
    d["controllers"] = list(config.controllers)
    ds = config.dispersions

    def inertia(x: disp.InertiaDispersion) -> dict:
        t = {} if x.nominal is None else {"nominal": [list(r) for r in x.nominal]}
        t.update(scale=disp.describe(x.scale), axis_scale=disp.describe(x.axis_scale), rotation_deg=x.rotation_deg)
        t["products"] = disp.describe(x.products)
        return t

    d["inertia"] = {name: inertia(getattr(ds, name)) for name in ("J0", "J1", "J2")}
    d["deployment"] = {"tau_J": disp.describe(ds.tau_J)}
    d["orbit"] = {"n": disp.describe(ds.n)}
    d["disturbance"] = {
        "seed": "random" if ds.disturbance_seed is None else ds.disturbance_seed,
        **{k: disp.describe(getattr(ds, k)) for k in ("amplitude", "frequency", "noise_std")},
    }
    d["initial"] = {"max_angle_deg": ds.initial_angle_deg, "rate": disp.describe(ds.initial_rate)}
    d["gains"] = {name: {k: np.asarray(v).tolist() for k, v in g._asdict().items()} for name, g in config.gains.items()}
    return d


def load_config(path: Path | None = None, overrides: tuple = ()) -> SweepConfig:
    """Config from a TOML file (or the defaults), then ``KEY=VALUE`` overrides (dotted keys)."""
    d = cfg.load(path, overrides)
    return config_from_dict(d)
