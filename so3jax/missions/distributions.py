"""The distributions of a ``[dispersions]`` value (docs/model.md §15): fixed, uniform, normal,
lognormal and a choice, each mapping a variate (u uniform on (0, 1), z standard normal) to a
value, their TOML form, and the checks that a distribution draws within a quantity's domain or
a magnitude limit.

Which quantities are dispersed, the variates and the sampler are
:mod:`so3jax.missions.draw`'s; a distribution that cannot draw its quantity's domain (a fixed
tau_J <= 0, a uniform scale reaching 0, ...) is a ValueError (:func:`check_domain`), before
anything is drawn.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

# --- distributions ----------------------------------------------------------------------
# Each maps a variate (u uniform on (0, 1), z standard normal) to a value.


@dataclasses.dataclass(frozen=True)
class Fixed:
    """Always ``value``."""

    value: float

    def sample(self, u, z):
        return np.full_like(u, self.value)


@dataclasses.dataclass(frozen=True)
class Uniform:
    """Uniform on [low, high]."""

    low: float
    high: float

    def sample(self, u, z):
        return self.low + (self.high - self.low) * u


@dataclasses.dataclass(frozen=True)
class Normal:
    """Gaussian with mean ``mean`` and standard deviation ``std``."""

    mean: float
    std: float

    def sample(self, u, z):
        return self.mean + self.std * z


@dataclasses.dataclass(frozen=True)
class LogNormal:
    """exp(N(log median, sigma^2)): positive, median ``median``, log-space std ``sigma``."""

    median: float
    sigma: float

    def sample(self, u, z):
        return self.median * np.exp(self.sigma * z)


@dataclasses.dataclass(frozen=True)
class Choice:
    """One of ``values``, each with probability 1 / len(values): value floor(u len(values))."""

    values: tuple

    def sample(self, u, z):
        values = np.asarray(self.values, float)
        return values[np.minimum((np.asarray(u) * len(values)).astype(np.int64), len(values) - 1)]


DISTRIBUTIONS = {"fixed": Fixed, "uniform": Uniform, "normal": Normal, "lognormal": LogNormal, "choice": Choice}
Distribution = Fixed | Uniform | Normal | LogNormal | Choice


def parse_distribution(value, where: str) -> Distribution:
    """A number (fixed) or a table ``{dist = "uniform", low = .., high = ..}`` (``{dist =
    "choice", values = [..]}``: one of the values, equally likely) -> distribution."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return _checked(Fixed(float(value)), where)
    if not isinstance(value, dict) or "dist" not in value:
        raise ValueError(f"{where}: expected a number or a table with 'dist' ({', '.join(DISTRIBUTIONS)}), "
                         f"got {value!r}")
    kind = DISTRIBUTIONS.get(value["dist"])
    if kind is None:
        raise ValueError(f"{where}: unknown distribution {value['dist']!r}; choose one of {', '.join(DISTRIBUTIONS)}")
    params = {k: v for k, v in value.items() if k != "dist"}
    names = [f.name for f in dataclasses.fields(kind)]
    if sorted(params) != sorted(names):
        raise ValueError(f"{where}: distribution {value['dist']!r} takes exactly {names}, got {sorted(params)}")
    if kind is Choice:
        values = params["values"]
        if (not isinstance(values, (list, tuple)) or not values
                or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in values)):
            raise ValueError(f"{where}.values must be a list of numbers, got {values!r}")
        return _checked(Choice(tuple(float(v) for v in values)), where)
    for name, v in params.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f"{where}.{name} must be a number, got {v!r}")  # noqa: TRY004
    return _checked(kind(**{k: float(v) for k, v in params.items()}), where)


# The largest |z| a standard normal variate takes: Box-Muller from u >= 2^-33 (so3jax.missions.draw.draw_variates).
Z_MAX = math.sqrt(-2.0 * math.log(0.5 / 2.0**32))


def _spread(dist: Distribution) -> float:
    """The largest magnitude the arithmetic of ``dist``'s draws reaches: a uniform's width, a
    normal's mean +- Z_MAX std, a lognormal's median exp(Z_MAX sigma) (inf beyond a float)."""
    try:
        return {Fixed: lambda d: abs(d.value), Uniform: lambda d: d.high - d.low,
                Normal: lambda d: abs(d.mean) + Z_MAX * d.std,
                LogNormal: lambda d: d.median * math.exp(Z_MAX * d.sigma),
                Choice: lambda d: max(map(abs, d.values))}[type(dist)](dist)
    except OverflowError:
        return math.inf


def _checked(dist: Distribution, where: str) -> Distribution:
    values = dist.values if isinstance(dist, Choice) else dataclasses.astuple(dist)
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{where}: parameters must be finite, got {dist}")
    if not math.isfinite(_spread(dist)):
        tails = f" (normal variates reach {Z_MAX:.3g})" if isinstance(dist, (Normal, LogNormal)) else ""
        raise ValueError(f"{where}: {describe(dist)} draws values beyond what a float holds{tails}: narrow it")
    if isinstance(dist, Uniform) and dist.low > dist.high:
        raise ValueError(f"{where}: uniform needs low <= high, got {dist}")
    if (isinstance(dist, Normal) and dist.std < 0
            or isinstance(dist, LogNormal) and (dist.sigma < 0 or dist.median <= 0)):
        raise ValueError(f"{where}: needs std / sigma >= 0 and median > 0, got {dist}")
    return dist


def check_domain(dist: Distribution, where: str, low: float = 0.0, strict: bool = True) -> Distribution:
    """ValueError unless ``dist`` draws values of its quantity's domain, x > low (x >= low
    where not ``strict``): a fixed value, or a uniform's whole range (its upper end above
    ``low`` where strict), in the domain; a normal's mean in it (its tails beyond ``low``
    are drawn again or, after max_draws, reject the sample, for the physical parameters);
    a lognormal for low <= 0 (it is positive)."""
    ok = {
        Fixed: lambda d: d.value > low if strict else d.value >= low,
        Uniform: lambda d: d.low >= low and (d.high > low if strict else True),
        Normal: lambda d: d.mean > low if strict else d.mean >= low,
        LogNormal: lambda d: low <= 0.0,
        Choice: lambda d: min(d.values) > low if strict else min(d.values) >= low,
    }[type(dist)](dist)
    if not ok:
        raise ValueError(f"{where} must be {'>' if strict else '>='} {low:g}: {describe(dist)} is outside that domain")
    return dist


def check_magnitude(dist: Distribution, where: str, limit: float, limit_name: str) -> Distribution:
    """ValueError unless ``dist`` draws values of magnitude at most ``limit`` by
    :func:`check_domain`'s rule: a fixed value, or a uniform's whole range, in [-limit,
    limit]; a normal's mean, or a lognormal's median, in it (their tails beyond are
    rejected, sample by sample). limit_name: what bounds it, for the message."""
    ok = {
        Fixed: lambda d: abs(d.value) <= limit,
        Uniform: lambda d: -limit <= d.low and d.high <= limit,
        Normal: lambda d: abs(d.mean) <= limit,
        LogNormal: lambda d: d.median <= limit,
        Choice: lambda d: max(map(abs, d.values)) <= limit,
    }[type(dist)](dist)
    if not ok:
        raise ValueError(f"{where} must not exceed {limit_name} = {limit:g} in magnitude: {describe(dist)} "
                         "draws beyond it")
    return dist


def least(dist: Distribution) -> float:
    """The least value :func:`check_domain`'s rule counts ``dist`` to draw: a fixed value,
    a uniform's low end, a normal's mean, a lognormal's median (a tail below is rejected,
    sample by sample, where a check needs it)."""
    return {Fixed: lambda d: d.value, Uniform: lambda d: d.low, Normal: lambda d: d.mean,
            LogNormal: lambda d: d.median, Choice: lambda d: min(d.values)}[type(dist)](dist)


def greatest(dist: Distribution) -> float:
    """The greatest value :func:`check_domain`'s rule counts ``dist`` to draw: a fixed value,
    a uniform's high end, a normal's mean, a lognormal's median (a tail above is rejected,
    sample by sample, where a check needs it)."""
    return {Fixed: lambda d: d.value, Uniform: lambda d: d.high, Normal: lambda d: d.mean,
            LogNormal: lambda d: d.median, Choice: lambda d: max(d.values)}[type(dist)](dist)



def describe(dist: Distribution) -> Any:
    """The TOML form of a distribution (a number when fixed)."""
    if isinstance(dist, Fixed):
        return dist.value
    name = next(k for k, v in DISTRIBUTIONS.items() if isinstance(dist, v))
    if isinstance(dist, Choice):
        return {"dist": name, "values": list(dist.values)}
    return {"dist": name, **dataclasses.asdict(dist)}
