"""Sweep configuration: a mission, a ``[sweep]`` table and a ``[dispersions]`` table on the
mission's leaves (:mod:`so3jax.missions.draw`); the defaults are sweeps/default.toml."""

from __future__ import annotations

import copy
import dataclasses
from pathlib import Path

from so3jax.core import checks
from so3jax.jobs import margins
from so3jax.missions import config as cfg
from so3jax.missions import draw, keys
from so3jax.missions import mission as missions

# The default sweep (sweeps/default.toml): the paper's mission on a rigid body's J0
# (keys.BODY_J0), its inertias dispersed as rigid bodies.
DEFAULT = {
    "inertia": {"J0": {"nominal": keys.matrix(keys.BODY_J0)}},
    "sweep": {"samples": 1024, "seed": 0, "chunk": 128, "max_draws": 20, "divergence_angle_deg": 150.0,
              "limit_share": 0.05, "pointing": False, "margins_at": []},
    "dispersions": {
        "inertia": {
            "J0": {"scale": {"dist": "lognormal", "median": 1.0, "sigma": 0.1},
                   "second_moments": {"dist": "lognormal", "median": 1.0, "sigma": 0.1}, "rotation_deg": 10.0},
            "J1": {"scale": {"dist": "uniform", "low": 1.8, "high": 2.2}},
            "J2": {"scale": {"dist": "lognormal", "median": 1.0, "sigma": 0.1},
                   "second_moments": {"dist": "lognormal", "median": 1.0, "sigma": 0.1}, "rotation_deg": 10.0},
        },
        "seed": "random",
        "deployment": {"tau_J": {"dist": "uniform", "low": 200.0, "high": 400.0}},
        "orbit": {"n": {"dist": "uniform", "low": 1.0381e-3, "high": 1.1314e-3}},
        "disturbance": {"amplitude": {"dist": "uniform", "low": 0.05, "high": 0.15},
                        "noise_std": {"dist": "uniform", "low": 0.0125, "high": 0.0375}},
        "initial": {"attitude": {"max_angle_deg": 30.0},
                    "rate": {"norm": {"dist": "uniform", "low": 0.0, "high": 0.005}}},
    },
}
SWEEP_KEYS = tuple(DEFAULT["sweep"])


@dataclasses.dataclass(frozen=True)
class SweepConfig:
    """A sweep: samples 0 .. samples-1 (sampling seed ``seed``) of the mission with its
    ``dispersions`` (and dispersed component ``leaves``), each flown with every controller
    of the mission at its gains, so results pair sample by sample.

    chunk: samples per batch on the host (at least 8 per device, a multiple of the device count;
    an accelerator runs the largest batch its memory holds);
    max_draws: attempts at a positive definite sample before it is rejected; a sample
    diverged when its state is non-finite or its attitude error exceeds
    divergence_angle_deg [deg]; in a loop with limits, a sample is flagged where a
    controller spends more than limit_share of the horizon with a torque or speed limit
    binding. pointing: record each sample's attitude errors every ``record_every`` steps
    of the mission and report its pointing indices and requirements over the samples
    (temporal, ensemble and mixed, docs/model.md §18.2); on wherever the mission declares
    requirements. margins_at: times [s] (each a control tick) at which each sample's loop
    is linearized and its stability margins taken (docs/model.md §19; () for none).
    table: the [dispersions] table as given.
    """

    mission: missions.Mission
    dispersions: draw.Dispersions
    leaves: tuple
    table: dict
    samples: int = 1024
    seed: int = 0
    chunk: int = 128
    max_draws: int = 20
    divergence_angle_deg: float = 150.0
    limit_share: float = 0.05
    pointing: bool = False
    margins_at: tuple = ()

    @property
    def T(self) -> float:
        return self.mission.T

    @property
    def dt(self) -> float:
        return self.mission.dt

    @property
    def controllers(self) -> tuple:
        return self.mission.controllers

    @property
    def gains(self) -> dict:
        return self.mission.gains


def config_from_dict(d: dict, base_dir: Path = Path(".")) -> SweepConfig:
    """A SweepConfig from a sweep file's tables (see sweeps/default.toml): ``mission`` (a
    file, relative to ``base_dir``) and/or mission tables inline, ``[sweep]``,
    ``[dispersions]``; missing entries take the default sweep's. ValueError on bad input."""
    if not isinstance(d, dict):
        raise ValueError(f"a sweep config must be a table, got {checks.short(d)}")  # noqa: TRY004 (bad input)
    mission, jobs = missions.load_job(d, base_dir, ("sweep", "dispersions"), missions.PAPER)
    sweep = checks.table(jobs, "sweep", SWEEP_KEYS)
    values = dict(DEFAULT["sweep"], **sweep)
    top = {key: checks.number(values[key], f"sweep.{key}", low=1, integer=True)
           for key in ("samples", "chunk", "max_draws")}
    top["seed"] = checks.number(values["seed"], "sweep.seed", low=0, high=2**32 - 1, integer=True)
    top["divergence_angle_deg"] = checks.number(values["divergence_angle_deg"], "sweep.divergence_angle_deg",
                                                0.0, 180.0)
    top["limit_share"] = checks.number(values["limit_share"], "sweep.limit_share", 0.0, 1.0)
    if not isinstance(values["pointing"], bool):
        raise ValueError(f"sweep.pointing must be true or false, got {checks.short(values['pointing'])}")
    top["pointing"] = values["pointing"] or bool(mission.requirements)
    top["margins_at"] = _margins_at(values["margins_at"], mission)
    table = jobs.get("dispersions", DEFAULT["dispersions"])
    dispersions, leaves = draw.parse(table, mission)
    if not dispersions.initial_angle_deg < top["divergence_angle_deg"]:
        raise ValueError(
            f"sweep.divergence_angle_deg ({top['divergence_angle_deg']}) must exceed dispersions.initial.attitude's "
            f"max_angle_deg ({dispersions.initial_angle_deg}), or every large initial error would count as diverged"
        )
    draw.check(dispersions)  # the nominal inertias' warnings, once
    return SweepConfig(mission, dispersions, leaves, table, **top)


def _margins_at(value, mission) -> tuple:
    """sweep.margins_at: a list of times [s], each a control tick within the horizon of a
    sampled loop (:func:`so3jax.jobs.margins.check_times`)."""
    if not isinstance(value, (list, tuple)) or not all(isinstance(t, (int, float)) and not isinstance(t, bool)
                                                       for t in value):
        raise ValueError(f"sweep.margins_at must be a list of times [s], got {checks.short(value)}")
    if not value:
        return ()
    try:
        return margins.check_times(mission, [float(t) for t in value])
    except ValueError as error:
        raise ValueError(f"sweep.margins_at: {error}") from None


def config_to_dict(config: SweepConfig) -> dict:
    """The sweep's own tables ([sweep], [dispersions]) as TOML data; the mission is
    ``config.mission.describe()``. ``pointing`` and ``margins_at`` only where set."""
    sweep = {k: getattr(config, k) for k in SWEEP_KEYS if k not in ("pointing", "margins_at")}
    sweep.update({k: getattr(config, k) for k in ("pointing", "margins_at") if getattr(config, k)})
    return {"sweep": sweep, "dispersions": config.table}


def load_config(path: Path | None = None, overrides: tuple = ()) -> SweepConfig:
    """Config from a TOML file (or the default sweep), then ``KEY=VALUE`` overrides (dotted keys)."""
    d = cfg.read_toml(path) if path is not None else copy.deepcopy(DEFAULT)
    for item in overrides:
        cfg.set_dotted(d, *cfg.parse_override(item))
    return config_from_dict(d, Path(path).parent if path is not None else Path("."))
