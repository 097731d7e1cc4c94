"""A design campaign's goals (``[[tune.goals]]``, docs/model.md §16.6): the mission's pointing
requirements, floors on the sampled loop's disk margin and budgets on the flight's metrics,
each normalized to g = value / limit (a floor: limit / value) over a batch of dispersed
missions, hard (g < 1 required) or soft (the largest minimized).

Each goal is a table of ``[[tune.goals]]`` with ``hard = true`` or ``false`` and one of

* ``requirement = "NAME"`` (or a 0-based index): a ``[[requirements]]`` entry of the mission,
  or the keys of one inline (``index``, ``axis``, ``level``, ``limit``, ``window``, ``phase``,
  ``interpretation``, ...): its value over the batch in its interpretation (the sweep's
  reading, :func:`so3jax.sim.pointing.statistic` with a diverged sample as +inf) [arcsec];
* a margin floor at ``at`` (times [s], whole control periods, or ``"phase ends"``: the last
  tick of each phase), on the 256-point grid of each sample at each time, g = alpha_req /
  alpha at its worst point: ``margin = "disk"`` with ``min_db`` > 0, the multi-loop disk
  margin (19.4), all axes varied at once; ``margin = "gain"`` with ``min_db`` or ``margin =
  "phase"`` with ``min_deg`` in (0, 180), each ``axis``'s loop (``"x"``, ``"y"``, ``"z"``,
  default ``"each"``: the worst of the three) with the others closed, by its disk margin
  (alpha_req = :func:`~so3jax.sim.margins.alpha_of_db` or 2 tan(min_deg / 2)): a gain and a
  phase margin it guarantees, each a lower bound on the classical one (§19.4);
* ``budget = METRIC`` with ``limit`` > 0 and ``statistic`` (``"mean"`` or ``"max"`` over
  the batch): ``effort`` [N^2 m^2 s], ``rmse`` [rad/s], or a flight metric
  (:data:`BUDGETS`).
"""

from __future__ import annotations

import dataclasses
import math
import numbers

import jax.numpy as jnp
import numpy as np

from so3jax.core import checks
from so3jax.sim import pointing
from so3jax.sim.margins import alpha_of_db, db_of_alpha, first_formed_tick

KINDS = ("requirement", "margin", "budget")
MARGINS = ("disk", "gain", "phase")
AXES = ("x", "y", "z", "each")
BUDGETS = {"effort": "N^2 m^2 s", "rmse": "rad/s", "command_effort": "N^2 m^2 s", "actuator_effort": "N^2 m^2 s",
           "time_at_torque_limit": "s", "time_at_speed_limit": "s", "max_wheel_speed_ratio": "-"}
STATISTICS = ("mean", "max")
PHASE_ENDS = "phase ends"
MAX_DB = 60.0  # the highest disk or gain margin floor: alpha_req = 1.996, at the edge of what alpha can reach (< 2)
MAX_DEG = 89.9  # the highest phase margin floor: alpha_req = 1.997
COMMON_KEYS = ("hard", "name")
# the keys of a margin goal beside margin (the floor first), by margin; of a budget goal beside budget
MARGIN_KEYS = {"disk": ("min_db", "at"), "gain": ("min_db", "at", "axis"), "phase": ("min_deg", "at", "axis")}
BUDGET_KEYS = ("limit", "statistic")


@dataclasses.dataclass(frozen=True)
class Goal:
    """One goal: g = value / limit (a margin floor: alpha_req / alpha), hard or soft."""

    kind: str  # "requirement", "margin" or "budget"
    hard: bool
    name: str
    requirement: pointing.Requirement | None = None
    min_db: float | None = None  # a disk or gain margin's floor [dB]
    min_deg: float | None = None  # a phase margin's floor [deg]
    axis: str = "each"  # a gain or phase margin's loop: "x", "y", "z" or the worst ("each")
    at: tuple = ()  # margin times [s]
    metric: str | None = None  # budget
    limit: float | None = None  # budget's limit (its metric's unit); a requirement's is its own [arcsec]
    statistic: str = "mean"  # budget: over the batch

    margin: str | None = None  # "disk", "gain" or "phase"

    @property
    def alpha_required(self) -> float:
        """The disk margin alpha the floor needs: alpha_of_db(min_db), 2 tan(min_deg / 2)."""
        return alpha_of_db(self.min_db) if self.min_deg is None else 2.0 * math.tan(math.radians(self.min_deg) / 2.0)

    @property
    def columns(self) -> tuple:
        """A margin goal's disk margins among (all axes at once, x, y, z)."""
        if self.margin == "disk":
            return (0,)
        return (1, 2, 3) if self.axis == "each" else (1 + "xyz".index(self.axis),)

    def margin_value(self, alpha: float) -> float:
        """What a disk margin alpha guarantees in the floor's unit: +-dB, or +-deg."""
        return math.degrees(2.0 * math.atan(alpha / 2.0)) if self.margin == "phase" else db_of_alpha(alpha)

    @property
    def unit(self) -> str:
        if self.kind == "margin":
            return "deg" if self.margin == "phase" else "dB"
        return "arcsec" if self.kind == "requirement" else BUDGETS[self.metric]

    @property
    def bound(self) -> float:
        """The value's limit in its unit (a margin's floor [dB] or [deg])."""
        if self.kind == "margin":
            return self.min_deg if self.margin == "phase" else self.min_db
        return self.requirement.limit if self.kind == "requirement" else self.limit

    def describe(self) -> str:
        if self.kind == "requirement":
            return self.requirement.describe()
        if self.kind == "margin":
            what = "disk margin, all axes" if self.margin == "disk" else (
                f"{self.margin} margin of {'each axis' if self.axis == 'each' else 'axis ' + self.axis}")
            return f"{what} >= {self.bound:g} {self.unit} at t = {', '.join(f'{t:g}' for t in self.at)} s"
        return f"{self.statistic} {self.metric} <= {self.limit:g} {self.unit}"


def _number(value, where: str, low: float = 0.0, high: float = math.inf) -> float:
    """A finite number in (low, high]."""
    if not isinstance(value, numbers.Real) or isinstance(value, bool) or not math.isfinite(value) or not (
            low < value <= high):
        raise ValueError(f"{where}: must be a number in ({low:g}, {high:g}], got {checks.short(value)}")
    return float(value)


def phase_ends(mission) -> tuple:
    """The last tick [s] of each phase the horizon reaches: t_end - Delta_c."""
    bounds = pointing.phase_bounds_of(mission.scenario())
    return tuple(round(b - mission.period, 12) for a, b in bounds if b > a)


def _requirement(item: dict, where: str, mission) -> pointing.Requirement:
    bounds = pointing.phase_bounds_of(mission.scenario())
    reference = item.get("requirement")
    inline = {k: v for k, v in item.items() if k not in COMMON_KEYS + ("requirement",)}
    if reference is None:
        return pointing.parse_requirement(inline, where, mission.phase_names, bounds, mission.recording)
    if inline:
        raise ValueError(f"{where}: names the mission's requirement {reference!r} and gives keys of its own "
                         f"({', '.join(inline)}): one or the other")
    names = [r.name for r in mission.requirements]
    if isinstance(reference, str):
        if reference not in names:
            known = ", ".join(repr(n) for n in names if n) or "none named"
            raise ValueError(f"{where}.requirement: the mission has no requirement {reference!r} ({known})")
        return mission.requirements[names.index(reference)]
    if isinstance(reference, bool) or not isinstance(reference, int) or not 0 <= reference < len(names):
        raise ValueError(f"{where}.requirement: a requirement's name or index 0..{len(names) - 1}, "
                         f"got {checks.short(reference)}")
    return mission.requirements[reference]


def _margin(item: dict, where: str, mission) -> dict:
    margin = checks.choice(item["margin"], f"{where}.margin", MARGINS)
    floor = MARGIN_KEYS[margin][0]
    checks.table({"": item}, "", COMMON_KEYS + ("margin",) + MARGIN_KEYS[margin], where)
    if floor not in item:
        raise ValueError(f"{where}.{floor}: missing (the floor on the {margin} margin "
                         f"[{'deg' if margin == 'phase' else 'dB'}], > 0)")
    fields = {"margin": margin, "axis": checks.choice(item.get("axis", "each"), f"{where}.axis", AXES)}
    if margin == "phase":
        fields["min_deg"] = _number(item[floor], f"{where}.min_deg", 0.0, MAX_DEG)
    else:
        fields["min_db"] = _number(item[floor], f"{where}.min_db", 0.0, MAX_DB)
    if mission.period_steps is None:
        raise ValueError(f"{where}: a margin needs a sampled loop (control.mode = \"sampled\")")
    at = item.get("at", PHASE_ENDS)
    if at == PHASE_ENDS:
        at = phase_ends(mission)
    elif not isinstance(at, list) or not at:
        raise ValueError(f"{where}.at: a list of times [s] or \"{PHASE_ENDS}\", got {checks.short(at)}")
    times = []
    for t in at:
        if isinstance(t, bool) or not isinstance(t, numbers.Real) or not math.isfinite(t) or not 0 <= t < mission.T:
            raise ValueError(f"{where}.at: t = {checks.short(t)} s is outside the horizon [0, {mission.T:g}) s")
        if abs(t - round(t / mission.period) * mission.period) > 1e-9 * max(mission.period, abs(t)):
            raise ValueError(f"{where}.at: t = {t:g} s is not a whole number of control periods "
                             f"({mission.period:g} s)")
        formed_before(mission, t, f"{where}.at")
        times.append(float(t))
    return {**fields, "at": tuple(times)}


def formed_before(mission, t: float, where: str) -> None:
    """A one-line ValueError where t [s] is before the first tick at which the mission's
    sampled loop is formed (:func:`so3jax.sim.margins.first_formed_tick`)."""
    formed = first_formed_tick(mission.loop())
    if t < formed * mission.period - 1e-9 * mission.period:
        raise ValueError(f"{where}: t = {t:g} s is before t = {formed * mission.period:g} s, the first tick at which "
                         "the loop is formed (the rate-integrating gyro has no reading before it)")


def _budget(item: dict, where: str) -> dict:
    checks.table({"": item}, "", COMMON_KEYS + ("budget",) + BUDGET_KEYS, where)
    metric = checks.choice(item["budget"], f"{where}.budget", tuple(BUDGETS))
    if "limit" not in item:
        raise ValueError(f"{where}.limit: missing (the budget [{BUDGETS[metric]}], > 0)")
    statistic = checks.choice(item.get("statistic", "mean"), f"{where}.statistic", STATISTICS)
    return {"metric": metric, "limit": _number(item["limit"], f"{where}.limit", 0.0, 1e300), "statistic": statistic}


def parse_goal(item, where: str, mission) -> Goal:
    """One ``[[tune.goals]]`` entry (module docstring); a one-line ValueError naming its key."""
    if not isinstance(item, dict):
        raise ValueError(f"{where}: must be a table, got {checks.short(item)}")  # noqa: TRY004
    kinds = [k for k in ("requirement", "margin", "budget") if k in item]
    if "index" in item and not kinds:
        kinds = ["requirement"]
    if len(kinds) != 1:
        raise ValueError(f"{where}: give exactly one of requirement (or an inline requirement's index, axis, "
                         f"level, limit), margin, budget; got {', '.join(kinds) or 'none'}")
    if "hard" not in item:
        raise ValueError(f"{where}.hard: missing (true: a hard goal, g < 1 required; false: a soft goal, minimized)")
    hard = checks.boolean(item["hard"], f"{where}.hard")
    name = item.get("name")
    if name is not None and not isinstance(name, str):
        raise ValueError(f"{where}.name: must be a string, got {checks.short(name)}")
    kind = kinds[0]
    if kind == "requirement":
        requirement = _requirement(item, where, mission)
        if requirement.limit <= 0:
            raise ValueError(f"{where}: the requirement's limit is 0 arcsec: a goal normalizes by it (> 0)")
        pointing.check_signal(requirement, where, mission.no_estimate)
        label = name or requirement.name or requirement.describe()
        return Goal("requirement", hard, label, requirement=requirement)
    if kind == "margin":
        goal = Goal("margin", hard, "", **_margin(item, where, mission))
        label = f"{goal.margin} margin" + ("" if goal.margin == "disk" or goal.axis == "each" else f" {goal.axis}")
        return dataclasses.replace(goal, name=name or f"{label} >= {goal.bound:g} {goal.unit}")
    fields = _budget(item, where)
    return Goal("budget", hard, name or f"{fields['statistic']} {fields['metric']}", **fields)


def parse_goals(items, mission) -> tuple[Goal, ...]:
    """The goals of ``[[tune.goals]]``; at least one, names distinct."""
    where = "tune.goals"
    if not isinstance(items, (list, tuple)) or not items:
        raise ValueError(f"{where}: must be a non-empty list of tables ([[tune.goals]]), got {checks.short(items)}")
    goals = tuple(parse_goal(item, f"{where}[{i}]", mission) for i, item in enumerate(items))
    names = [g.name for g in goals]
    for i, n in enumerate(names):
        if n in names[:i]:
            raise ValueError(f"{where}[{i}].name: {n!r} names another goal too: give each a distinct name")
    return goals


# --- values ---------------------------------------------------------------------------------


def budget_value(goal: Goal, results: dict):
    """A budget's statistic over the batch of ``results`` (sample_metrics' dict), traced."""
    x = results[goal.metric]
    x = jnp.where(jnp.isnan(x), jnp.inf, x)  # a diverged sample is the worst
    return jnp.mean(x) if goal.statistic == "mean" else jnp.max(x)


def normalized(goal: Goal, value):
    """g of a goal's value: value / limit; a margin's (its alpha): alpha_req / alpha."""
    if goal.kind == "margin":
        return goal.alpha_required / value
    return value / goal.bound


def soft_and_hard(goals) -> tuple[np.ndarray, np.ndarray]:
    """Boolean masks (G,) of the soft and the hard goals."""
    hard = np.array([g.hard for g in goals])
    return ~hard, hard
