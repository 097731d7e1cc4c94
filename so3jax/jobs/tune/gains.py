"""Tunable controllers and their gains: reading gains ("mission", "paper", a table, a
best_gains.json through the missions' reader), the tuned parameters (p = log g; g / scale
for a nonnegative gain), and gains as tables and columns."""

from __future__ import annotations

import collections
import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from so3jax.controllers import registry
from so3jax.controllers.gains import Nonnegative, gain_domain
from so3jax.core import checks
from so3jax.missions import schedule as schedules
from so3jax.missions.mission import gains_file

# One instance per controller with its default options, so that jit caches hit across runs.
CONTROLLERS = {n: registry.get(n).factory() for n in registry.names(tunable=True)}
GAIN_TYPES = {n: registry.get(n).gains_type for n in CONTROLLERS}
PAPER_GAINS = {n: registry.get(n).defaults for n in CONTROLLERS}

def diagonals(controller: str) -> dict:
    """{gain: (n,)} of the gains that may be a diagonal of n entries (the adaptive law's Gamma)."""
    spec = registry.get(controller)
    return {f: s for f, shapes in spec.gain_shapes().items() for s in shapes if len(s) == 1}


def resolve_gains(controller: str, spec, dtype, diagonal_gamma=False, mission=None):
    """Gains from "mission" (the mission's [gains.NAME]), "paper" (the registered defaults),
    a table {name: value}, or a best_gains.json path; checked by the registration. Each
    gain a number or a diagonal (no matrix); ``diagonal_gamma``: every gain that may be a
    diagonal broadcast to one. A law the mission schedules (``[schedule]``) gets its gains
    per phase or breakpoint (a leading axis), each given as a list or one number for all."""
    registered = registry.get(controller)
    cls = registered.gains_type
    schedule = mission.schedule.get(controller) if mission is not None else None
    if spec == "mission":
        if mission is None or controller not in mission.gains:
            flown = ", ".join(mission.controllers) if mission is not None else "none"
            raise ValueError(f"'mission' gains: the mission flies no {controller!r} controller (controllers: {flown}); "
                             f"add it to the mission's controllers or give the gains")
        table = {k: np.asarray(v).tolist() for k, v in mission.gains[controller]._asdict().items()}
    elif spec == "paper":
        table = registered.defaults._asdict()
    elif isinstance(spec, str):
        table = {k: np.asarray(v).tolist() for k, v in gains_file(spec, controller, schedule, mission.phases
                                                                  if schedule else None)._asdict().items()}
    elif isinstance(spec, dict):
        table = spec
    else:
        raise ValueError(f"gains must be 'mission', 'paper', a table or a .json path, got {checks.short(spec)}")
    for name in table:
        if name not in cls._fields:
            raise ValueError(f"unknown gain {name!r} for the {controller} controller ({', '.join(cls._fields)})")
    missing = [name for name in cls._fields if name not in table]
    if missing:
        raise ValueError(f"missing gain {missing[0]!r} for the {controller} controller")
    if schedule is not None:
        gains = schedules.scheduled_gains(controller, table, schedule, mission.phases, "gains")
        if diagonal_gamma:
            n = len(schedules.knots(schedule, mission.phases))
            gains = gains._replace(**{f: np.broadcast_to(np.reshape(getattr(gains, f), (n,) + (1,) * len(s)), (n, *s))
                                      for f, s in diagonals(controller).items()})
        return cls(**{name: jnp.asarray(value, dtype) for name, value in gains._asdict().items()})
    shapes = {name: tuple(s for s in allowed if len(s) < 2) for name, allowed in registered.gain_shapes().items()}
    table = checks.gains(table, registered.defaults, shapes, "gains")._asdict()
    gains = cls(**{name: jnp.asarray(table[name], dtype) for name in cls._fields})
    if diagonal_gamma:
        gains = gains._replace(**{f: jnp.broadcast_to(getattr(gains, f), s) for f, s in diagonals(controller).items()})
    try:
        registered.check(gains)
    except TypeError as err:
        raise ValueError(str(err)) from None
    return gains


@dataclasses.dataclass(frozen=True)
class Below:
    """The domain of a positive parameter held below ``high`` (a tuned filter's frequency
    below the Nyquist frequency of the control period): p = log g, clipped at log high."""

    high: float


def _fieldwise(gains, positive, nonnegative, below):
    """nonnegative(value, scale) on each gain its type declares Nonnegative(scale)
    (controllers.gains.gain_domain), below(value, log high) on one it declares Below(high),
    positive(value) on every other (a positive gain)."""
    def one(name, value):
        domain = gain_domain(gains, name)
        if isinstance(domain, Below):
            return below(value, math.log(domain.high))
        return nonnegative(value, domain.scale) if isinstance(domain, Nonnegative) else positive(value)

    return type(gains)(**{name: one(name, value) for name, value in gains._asdict().items()})


def to_params(gains):
    """The tuned parameters: p = log g of a positive gain, p = g / scale of a nonnegative one."""
    return _fieldwise(gains, jnp.log, lambda g, scale: g / scale, lambda g, _: jnp.log(g))


def to_gains(params):
    """g = exp p, or scale max(p, 0) for a nonnegative gain, or exp min(p, log high) below high."""
    return _fieldwise(params, jnp.exp, lambda p, scale: scale * jnp.maximum(p, 0.0),
                      lambda p, log_high: jnp.exp(jnp.minimum(p, log_high)))


def project(params):
    """Parameters on their domain: a nonnegative gain's p clipped at 0 after each step
    (projected gradient), so that a gain at 0 keeps a derivative that can move it; a
    parameter below high clipped at log high."""
    return _fieldwise(params, lambda p: p, lambda p, scale: jnp.maximum(p, 0.0),
                      lambda p, log_high: jnp.minimum(p, log_high))


# --- loop parameters tuned beside the gains: the estimator's assumed noise levels, the filter's -----------

ESTIMATOR = "estimator_"  # the prefix of an estimator parameter among the tuned ones
FILTER = "filter_"  # the prefix of a structural filter's parameter among the tuned ones
PARTS = {"estimator": ESTIMATOR, "filter": FILTER}  # the loop's tuned components and their prefixes
NYQUIST_SHARE = 0.99  # a tuned filter frequency is held below this share of the Nyquist frequency
_TUNED: dict = {}  # (gains type, tuned field names, their domains) -> the NamedTuple type of all


def with_estimator(gains, values: dict, filter: dict | None = None, nyquist: float | None = None):  # noqa: A002
    """The tuned parameters: the law's gains, the estimator's parameters {name: value}
    (each positive, e.g. the noise levels the filter assumes) and the structural filter's
    ``filter`` {name: value} (frequency [Hz], zeta_zero, zeta_pole; each positive, one value
    per phase where the mission gives them per phase) as one NamedTuple, fields
    ``estimator_NAME`` then ``filter_NAME`` after the gains', so that the optimizer, the
    history and the checkpoints treat them as gains (in log space); the gains themselves
    where there are none. nyquist: the Nyquist frequency 1 / (2 Delta_c) [Hz] of the control
    period, below whose NYQUIST_SHARE a tuned frequency is held (:class:`Below`)."""
    filter = filter or {}  # noqa: A001
    if not values and not filter:
        return gains
    base = type(gains)
    names = tuple(ESTIMATOR + n for n in values) + tuple(FILTER + n for n in filter)
    domains = dict(getattr(base, "domains", {}))
    if "frequency" in filter:
        if nyquist is None:
            raise ValueError("a tuned filter frequency needs the Nyquist frequency of the control period")
        domains[FILTER + "frequency"] = Below(NYQUIST_SHARE * float(nyquist))
    key = (base, names, tuple(sorted(domains.items(), key=lambda kv: kv[0])))
    if key not in _TUNED:
        suffix = "And".join(part.capitalize() for part, prefix in PARTS.items()
                            if any(n.startswith(prefix) for n in names))
        tuned = collections.namedtuple(f"{base.__name__}And{suffix}", base._fields + names)
        tuned.domains, tuned.law_gains = domains, base
        _TUNED[key] = tuned
    return _TUNED[key](*gains, *values.values(), *filter.values())


def parts(tuned) -> tuple:
    """(the law's gains, {component: {parameter: value}}) of tuned parameters: the
    estimator's and the filter's (:data:`PARTS`), each {} where none is tuned."""
    base = getattr(type(tuned), "law_gains", None)
    if base is None:
        return tuned, {part: {} for part in PARTS}
    n = len(base._fields)
    out = {part: {} for part in PARTS}
    for field, value in zip(tuned._fields[n:], tuned[n:]):
        part = next(p for p, prefix in PARTS.items() if field.startswith(prefix))
        out[part][field[len(PARTS[part]):]] = value
    return base(*tuned[:n]), out


def split(tuned) -> tuple:
    """(the law's gains, {estimator parameter: value}) of tuned parameters."""
    gains, tuned_parts = parts(tuned)
    return gains, tuned_parts["estimator"]


def gains_table(gains) -> dict:
    """{gain: value} of the law's gains (an estimator's or filter's tuned parameters left out)."""
    return {name: np.asarray(value).tolist() for name, value in parts(gains)[0]._asdict().items()}


def tables(tuned) -> dict:
    """{"gains": the law's gains, "estimator": its tuned parameters, "filter": the structural
    filter's (each where any; a filter parameter given per phase a list)}."""
    tuned_parts = parts(tuned)[1]
    estimator = {"estimator": {k: float(v) for k, v in tuned_parts["estimator"].items()}}
    structural = {"filter": {k: np.asarray(v).tolist() for k, v in tuned_parts["filter"].items()}}
    return {"gains": gains_table(tuned), **(estimator if tuned_parts["estimator"] else {}),
            **(structural if tuned_parts["filter"] else {})}


def gain_columns(gains) -> dict:
    """Flat {column: value}: Gamma_0 .. Gamma_8 for a diagonal Gamma; k_R_0 .. k_R_2 for a
    gain scheduled over three phases (Gamma_0_0 .. Gamma_2_8 for a scheduled diagonal)."""
    columns = {}
    for name, value in gains._asdict().items():
        value = np.asarray(value)
        if value.ndim == 0:
            columns[name] = float(value)
        else:
            columns.update({"_".join([name, *map(str, i)]): float(value[i]) for i in np.ndindex(value.shape)})
    return columns
