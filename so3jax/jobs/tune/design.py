"""A design campaign (``[[tune.goals]]``, docs/model.md §16.6): the law's gains tuned until
the hard goals hold with the soft ones as low as they go, over one fixed training batch of
dispersed missions, from several starts at once; then the held-out verdict.

Method, per start (all starts one vmapped batch of rollouts). With c_i = log g_i:

    L(p) = tau log sum_soft exp(c_s / tau)                                (the soft goals' smooth max)
         + sum_hard (max(0, lambda_h + rho c_h)^2 - lambda_h^2) / (2 rho)  (augmented Lagrangian, PHR)

(with no soft goal, the first term is the hard goals' smooth max: the design with the most
margin). Adam steps on the free log-gains along dL/dp, its norm clipped to ``clip_norm``
per start, the gains kept within their bounds. Every ``update_every`` iterations
lambda_h <- max(0, lambda_h + rho c_h), and rho *= growth where the hard goals' largest
violation max(0, c_h) did not fall below a quarter of its previous value. A start whose
goals are not finite (a diverged sample) returns to its previous gains with a quarter of
its step. Each start's best design is its evaluated iterate that meets every hard goal
(g <= 1) with the least largest soft goal, else the one with the least largest hard goal;
the campaign's is the best of the starts'.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from so3jax.jobs.sweep import margins as sweep_margins
from so3jax.jobs.tune import design_report
from so3jax.jobs.tune import goals as goal_specs
from so3jax.jobs.tune.config import TuneConfig, describe, make_optimizer
from so3jax.jobs.tune.gains import gain_columns, resolve_gains, tables, to_gains, to_params
from so3jax.jobs.tune.goal_values import GoalValues
from so3jax.jobs.tune.problem import MAX_DRAWS, Sampler
from so3jax.jobs.tune.storage import write_history
from so3jax.missions import batched, draw
from so3jax.results import io, runfolder
from so3jax.sim import pointing

CHECKPOINT = "checkpoint.npz"
DECADE = 10.0  # default bounds: a gain within a decade either side of its initial value
FEASIBLE = 1.0  # a hard goal holds where g <= FEASIBLE


# --- the batches -------------------------------------------------------------------------------


def draw_inputs(sampler: Sampler, seed: int, samples: int, dtype) -> tuple:
    """(sample_metrics' inputs of the valid samples among samples 0 .. samples - 1 of sampling
    seed ``seed``, their indices)."""
    drawn = draw.draw(sampler.dispersions, sampler.leaves, seed, samples, MAX_DRAWS, 0, sampler.mission)
    keep = np.flatnonzero(np.asarray(drawn.valid))
    if not len(keep):
        raise ValueError(f"every dispersed mission of sampling seed {seed} is rejected: narrow the dispersions")
    inputs = batched.inputs(drawn, dtype)
    return jax.tree.map(lambda x: jnp.asarray(x[keep]), inputs), keep


def chunks(inputs, size: int):
    """The batch in chunks of ``size`` samples, the last padded with its first sample:
    [(chunk, number of real samples)]."""
    n = len(np.asarray(inputs[0].J0))
    out = []
    for start in range(0, n, size):
        index = np.arange(start, min(start + size, n))
        padded = np.concatenate([index, np.full(size - len(index), index[0])])
        out.append((jax.tree.map(lambda x: x[padded], inputs), len(index)))
    return out


# --- the parameters ----------------------------------------------------------------------------


class Parameters:
    """The tuned log-gains as flat vectors (P,): ravel, bounds, the free mask, the starts."""

    def __init__(self, config: TuneConfig, initial):
        self.initial = initial
        flat, self.unravel = ravel_pytree(to_params(initial))
        self.p0 = np.asarray(flat, np.float64)
        dtype = flat.dtype
        lows, highs, free = {}, {}, {}
        for name, value in initial._asdict().items():
            low, high = config.bounds.get(name, (None, None))
            lows[name] = jnp.broadcast_to(jnp.asarray(low if low is not None else value / DECADE, dtype),
                                          jnp.shape(value))
            highs[name] = jnp.broadcast_to(jnp.asarray(high if high is not None else value * DECADE, dtype),
                                           jnp.shape(value))
            free[name] = jnp.full(jnp.shape(value), name not in config.fixed, dtype)
        kind = type(initial)
        self.low = np.asarray(ravel_pytree(to_params(kind(**lows)))[0], np.float64)
        self.high = np.asarray(ravel_pytree(to_params(kind(**highs)))[0], np.float64)
        self.free = np.asarray(ravel_pytree(kind(**free))[0]) > 0
        self.dtype = dtype

    def starts(self, n: int, seed: int) -> np.ndarray:
        """(n, P): the initial gains, then n - 1 draws uniform in p (log-uniform in a positive
        gain) within the bounds; fixed gains at their initial values."""
        rng = np.random.default_rng(seed)
        drawn = self.low + (self.high - self.low) * rng.random((n - 1, len(self.p0)))
        drawn = np.where(self.free, drawn, self.p0)
        return np.concatenate([self.clip(self.p0)[None], drawn])

    def clip(self, p):
        return np.clip(p, np.minimum(self.low, self.p0), np.maximum(self.high, self.p0))

    def gains(self, p):
        return to_gains(self.unravel(jnp.asarray(p, self.dtype)))

    def columns(self, p) -> dict:
        return gain_columns(self.gains(p))


# --- the method ---------------------------------------------------------------------------------


def logs(g):
    """c = log g, g clipped to [1e-300, inf]."""
    return np.log(np.maximum(g, 1e-300))


def smooth_max(c, tau: float):
    """(tau log sum exp(c / tau), its weights d/dc) along the last axis."""
    top = np.max(c, axis=-1, keepdims=True)
    e = np.exp((c - top) / tau)
    total = np.sum(e, axis=-1, keepdims=True)
    return (top + tau * np.log(total))[..., 0], e / total


def lagrangian(g, soft, hard, lam, rho, tau):
    """(L (N,), dL/dg (N, G)) of the module's L at goals g (N, G)."""
    c = logs(g)
    objective = soft if soft.any() else hard
    L, w = smooth_max(c[:, objective], tau)
    weights = np.zeros_like(g)
    weights[:, objective] = w
    shifted = np.maximum(0.0, lam + rho * c[:, hard])
    L = L + np.sum((shifted**2 - lam**2) / (2.0 * rho), axis=-1)
    weights[:, hard] += shifted
    return L, weights / np.maximum(g, 1e-300)  # d/dg = d/dc / g


def score(g, soft, hard) -> tuple:
    """The order of designs (lower is better): (0, largest soft g) where every hard goal holds,
    else (1, largest hard g); with no soft goal, the largest hard g either way."""
    worst_hard = float(np.max(g[hard])) if hard.any() else 0.0
    if not np.all(np.isfinite(g)):
        return (2, math.inf)
    if worst_hard <= FEASIBLE:
        return (0, float(np.max(g[soft])) if soft.any() else worst_hard)
    return (1, worst_hard)


def conflicts(g, jac, goals, hard, lam=None, rows=()) -> list:
    """Pairs [a, b] of hard goals that cannot be improved together at a design ``g``, a over
    its limit there, by either of two signs:

    * local: both active (over or within 5 % of their limit, or with a positive multiplier
      lam, one per hard goal: the constraint pushed back during the run) and their gradients
      dg/dp point against each other (cosine < -0.5);
    * traded: among the run's evaluated iterates ``rows`` (history rows, ``g[NAME]`` per
      goal), some have a below its value at the design, and every one of them has b over
      its limit, b within it at the design."""
    pushed = np.zeros(len(goals), bool)
    if lam is not None:
        pushed[np.flatnonzero(hard)] = np.asarray(lam) > 0
    active = [i for i in range(len(goals)) if hard[i] and (g[i] >= 0.95 or pushed[i])]
    out = []
    for a in active:
        for b in active:
            if b <= a or max(g[a], g[b]) <= FEASIBLE:
                continue
            na, nb = np.linalg.norm(jac[a]), np.linalg.norm(jac[b])
            if na > 0 and nb > 0 and float(jac[a] @ jac[b]) / (na * nb) < -0.5:
                out.append([goals[a].name, goals[b].name])
    table = np.array([[float(r[f"g[{goal.name}]"]) for goal in goals] for r in rows]).reshape(-1, len(goals))
    for a in np.flatnonzero(hard & (np.asarray(g) > FEASIBLE)):
        for b in np.flatnonzero(hard & (np.asarray(g) <= FEASIBLE)):
            better = table[table[:, a] < g[a]]
            pair = sorted([int(a), int(b)])
            if len(better) and np.all(better[:, b] > FEASIBLE) and [goals[i].name for i in pair] not in out:
                out.append([goals[i].name for i in pair])
    return out


# --- the run ------------------------------------------------------------------------------------


def run(config: TuneConfig, out: Path, resume: bool, progress: bool) -> dict:
    """Run (or resume) a design campaign into ``out``; returns design.json's content."""
    from tqdm import tqdm  # here: only a run that shows progress needs it

    goals = goal_specs.parse_goals(list(config.goals), config.mission)
    soft, hard = goal_specs.soft_and_hard(goals)
    dtype = jnp.result_type(float)
    controller = config.mission.controller(config.controller)[0]
    initial = resolve_gains(config.controller, config.initial_gains, dtype, config.diagonal_gamma, config.mission)
    parameters = Parameters(config, initial)
    parsed, leaves = draw.parse(config.dispersions, config.mission)
    sampler = Sampler(parsed, leaves, config.mission)
    train, train_index = draw_inputs(sampler, config.train.seeds[0], config.train.samples, dtype)
    values = GoalValues(goals, config.mission, controller, parameters.unravel)
    lagrangian_config = config.lagrangian
    tx = make_optimizer(config.optimizer, clip=False)  # each start's gradient clipped on its own

    fingerprint = campaign_fingerprint(config)
    checkpoint = out / CHECKPOINT
    if checkpoint.exists() and not resume:
        raise ValueError(f"{checkpoint} exists: pass --resume to continue that run, or choose another --out")
    P = parameters.starts(config.starts, config.es.seed)
    state = {"P": P, "previous": P.copy(), "step": np.ones(len(P)), "lam": np.zeros((len(P), int(hard.sum()))),
             "rho": np.full(len(P), lagrangian_config.penalty), "violation": np.full(len(P), np.inf),
             "iteration": 0, "rows": [], "best": [None] * len(P)}
    opt_state = tx.init(jnp.asarray(P))
    start = time.perf_counter()
    if resume and checkpoint.exists():
        state, opt_state = load(checkpoint, fingerprint, state, opt_state)
        start -= state["rows"][-1]["wall_s"] if state["rows"] else 0.0

    bar = tqdm(total=config.iterations, initial=state["iteration"], desc=f"design {config.controller}",
               disable=not progress)
    try:
        while state["iteration"] < config.iterations:
            opt_state = _iterate(config, goals, soft, hard, values, parameters, tx, train, state, opt_state, start)
            save(checkpoint, fingerprint, state, opt_state)
            write_history(out, state["rows"])
            best = pick(state["best"])
            bar.set_postfix(best=f"{best['score'][1]:.4g}", feasible=best["score"][0] == 0)
            bar.update(1)
    finally:
        bar.close()

    report = _report(config, goals, soft, hard, values, parameters, state, train_index, sampler, dtype)
    design_report.write(out, config, report, state["rows"])
    return report


def campaign_fingerprint(config: TuneConfig) -> str:
    """What a checkpoint belongs to: the campaign's description but its iteration count (a
    resumed run may be extended)."""
    description = io.to_builtin(describe(config))
    return runfolder.fingerprint({**description, "tune": {**description["tune"], "iterations": 0}})


def _iterate(config, goals, soft, hard, values, parameters, tx, train, state, opt_state, start):
    """One iteration of every start: evaluate, record, keep the best, step, update the multipliers."""
    it, P = state["iteration"], state["P"]
    g, jac, units = values(P, train)
    lam, rho = state["lam"], state["rho"]
    tau = config.lagrangian.temperature
    finite = np.all(np.isfinite(g), axis=1) & np.all(np.isfinite(jac), axis=(1, 2))
    safe_g = np.where(np.isfinite(g), g, 1.0)
    L, dL_dg = lagrangian(safe_g, soft, hard, lam, rho[:, None], tau)
    grad = np.einsum("ng,ngp->np", dL_dg, np.where(np.isfinite(jac), jac, 0.0)) * parameters.free
    norm = np.linalg.norm(grad, axis=1, keepdims=True)
    grad = grad * np.minimum(1.0, config.optimizer.clip_norm / np.maximum(norm, 1e-300))
    wall = time.perf_counter() - start
    for n in range(len(P)):
        s = score(g[n], soft, hard)
        row = {"iteration": it, "start": n, "lagrangian": float(L[n]) if finite[n] else math.nan,
               "feasible": s[0] == 0, "rho": float(rho[n]),
               **{f"g[{goal.name}]": float(g[n, i]) for i, goal in enumerate(goals)},
               "wall_s": round(wall, 3), **parameters.columns(P[n])}
        state["rows"].append(row)
        if state["best"][n] is None or s < tuple(state["best"][n]["score"]):
            state["best"][n] = {"score": list(s), "iteration": it, "start": n, "p": P[n].tolist(),
                                "g": g[n].tolist(), "values": units[n].tolist(), "jacobian": jac[n].tolist()}
    with jax.numpy_dtype_promotion("standard"):  # optax mixes int32 step counts with floats
        updates, opt_state = tx.update(jnp.asarray(grad), opt_state)
    step = np.asarray(updates) * state["step"][:, None]
    stepped = parameters.clip(P + step)
    new = np.where(finite[:, None], stepped, state["previous"])
    state["step"] = np.where(finite, state["step"], state["step"] / 4.0)
    state["previous"] = np.where(finite[:, None], P, state["previous"])
    state["P"] = new
    state["iteration"] = it + 1
    if hard.any() and (it + 1) % config.lagrangian.update_every == 0:
        c = logs(safe_g[:, hard])
        violation = np.max(np.maximum(c, 0.0), axis=1)
        state["lam"] = np.maximum(0.0, lam + rho[:, None] * c)
        grow = violation > 0.25 * state["violation"]
        state["rho"] = np.where(grow & (violation > 0), rho * config.lagrangian.growth, rho)
        state["violation"] = violation
    return opt_state


def pick(best: list) -> dict:
    """The best of the starts' best designs (:func:`score`)."""
    return min((b for b in best if b is not None), key=lambda b: tuple(b["score"]))


# --- checkpoint ----------------------------------------------------------------------------------


def save(path: Path, fingerprint: str, state: dict, opt_state) -> None:
    arrays = {k: np.asarray(state[k]) for k in ("P", "previous", "step", "lam", "rho", "violation")}
    io.save_npz(path, fingerprint=np.array(fingerprint), iteration=np.array(state["iteration"]),
                rows=np.array(json.dumps(io.to_builtin(state["rows"]))),
                best=np.array(json.dumps(io.to_builtin(state["best"]))), **arrays,
                **{f"opt_{i}": np.asarray(leaf) for i, leaf in enumerate(jax.tree.leaves(opt_state))})


def load(path: Path, fingerprint: str, state: dict, opt_state) -> tuple:
    """(state, optimizer state) saved in a checkpoint of this campaign; a one-line ValueError else."""
    try:
        with np.load(path) as data:
            found = str(data["fingerprint"])
            if found != fingerprint:
                raise ValueError(f"{path} was written for another design campaign; resume it with its own settings, "
                                 "or use a new --out folder")
            loaded = {k: np.array(data[k]) for k in ("P", "previous", "step", "lam", "rho", "violation")}
            loaded.update(iteration=int(data["iteration"]), rows=json.loads(str(data["rows"])),
                          best=json.loads(str(data["best"])))
            leaves, treedef = jax.tree.flatten(opt_state)
            opt_leaves = [jnp.asarray(data[f"opt_{i}"], np.asarray(t).dtype) for i, t in enumerate(leaves)]
    except ValueError:
        raise
    except Exception as err:  # a truncated or foreign file
        raise runfolder.corrupt(path, err, "delete it to start the run over, or choose another --out") from None
    if loaded["P"].shape != state["P"].shape:
        raise ValueError(f"{path} holds {loaded['P'].shape[0]} starts of {loaded['P'].shape[1]} parameters, "
                         f"this campaign {state['P'].shape[0]} of {state['P'].shape[1]}")
    for key in ("rows", "best"):
        loaded[key] = [_infinite(x) for x in loaded[key]]
    return loaded, jax.tree.unflatten(treedef, opt_leaves)


def _infinite(x):
    """JSON's null back to NaN in a row or best record (io.to_builtin writes NaN/inf as null)."""
    if isinstance(x, dict):
        return {k: _infinite(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_infinite(v) for v in x]
    return math.nan if x is None else x


# --- the verdict ---------------------------------------------------------------------------------


def held_out(config, goals, values: GoalValues, parameters: Parameters, sampler, gains_sets: dict, size: int,
             dtype) -> dict:
    """{label: goal values (G,) in their units and g (G,)} of each gains' design on the held-out
    batch (validation: ``validation.samples`` dispersed missions of sampling seed
    ``validation.seeds[0]``), read as ``sweep`` reads them: the requirements by
    :func:`so3jax.sim.pointing.evaluate` with a diverged sample as +inf, each margin the worst
    sample's at its times (unstable anywhere: infinite g)."""
    inputs, index = draw_inputs(sampler, config.validation.seeds[0], config.validation.samples, dtype)
    controller = values.controller
    out = {"samples": int(len(index)), "drawn": config.validation.samples}
    for label, p in gains_sets.items():
        gains = parameters.gains(p)
        parts = []
        for chunk, n in chunks(inputs, size):
            r = batched.sample_metrics(chunk, gains, controller=controller, mission=config.mission,
                                       record_every=config.mission.record_every, pointing=True)
            parts.append({k: np.asarray(v)[:n] for k, v in r.items()})
        results = {k: np.concatenate([p_[k] for p_ in parts]) for k in parts[0]}
        t = np.arange(results["pointing_performance"].shape[1]) * (values.block * config.mission.dt)
        value, g, disks = np.zeros(len(goals)), np.zeros(len(goals)), {}
        for i, goal in enumerate(goals):
            if goal.kind == "requirement":
                e = results["pointing_performance" if goal.requirement.signal == "performance"
                            else "pointing_knowledge"]
                checked = pointing.evaluate(goal.requirement, t, e, values.bounds, diverged_worst=True)
                value[i] = math.inf if checked.value is None else checked.value
                g[i] = value[i] / goal.bound
            elif goal.kind == "budget":
                x = np.where(np.isnan(results[goal.metric]), np.inf, results[goal.metric])
                value[i] = float(np.mean(x) if goal.statistic == "mean" else np.max(x))
                g[i] = value[i] / goal.bound
            else:
                if goal.at not in disks:
                    disks[goal.at] = _disks(inputs, gains, controller, config.mission, goal.at)
                alpha = disks[goal.at]
                worst = float(np.min(alpha[..., list(goal.columns)]))  # NaN where a point is unstable
                value[i] = math.nan if math.isnan(worst) else goal.margin_value(worst)
                g[i] = math.inf if math.isnan(worst) else goal.alpha_required / worst
        out[label] = {"values": value.tolist(), "g": g.tolist()}
    return out


def _disks(inputs, gains, controller, mission, times) -> np.ndarray:
    """Each sample's disk margins (all axes at once, x, y, z) at each time (S, K, 4), refined
    (:func:`so3jax.jobs.sweep.margins.sample_margins`); NaN where the closed loop is unstable."""
    m = sweep_margins.sample_margins(inputs, gains, controller=controller, mission=mission, times=times)
    return np.concatenate([m["disk_alpha"][..., None], m["disk_axis_alpha"]], axis=-1)


def _report(config, goals, soft, hard, values, parameters, state, train_index, sampler, dtype) -> dict:
    best = pick(state["best"])
    first = next(r for r in state["rows"] if r["iteration"] == 0 and r["start"] == 0)
    g0 = np.array([first[f"g[{goal.name}]"] for goal in goals])
    g_best = np.array(best["g"])
    start = time.perf_counter()
    checked = held_out(config, goals, values, parameters, sampler,
                       {"initial": parameters.p0, "best": np.array(best["p"])}, len(train_index), dtype)
    held_wall = time.perf_counter() - start
    meets = bool(np.all(np.array(checked["best"]["g"])[hard] <= FEASIBLE))
    feasible_training = best["score"][0] == 0
    rows = []
    for i, goal in enumerate(goals):
        rows.append({"name": goal.name, "kind": goal.kind, "hard": goal.hard, "goal": goal.describe(),
                     "unit": goal.unit, "limit": goal.bound,
                     "training": {"initial": float(g0[i]), "best": float(g_best[i]),
                                  "best_value": best["values"][i]},
                     "held_out": {"initial": checked["initial"]["g"][i], "best": checked["best"]["g"][i],
                                  "initial_value": checked["initial"]["values"][i],
                                  "best_value": checked["best"]["values"][i]}})
    binding = _binding(g_best, soft, hard, goals)
    return io.to_builtin({
        "controller": config.controller,
        "schedule": config.mission.schedule.get(config.controller),  # None: one set of gains
        "verdict": "met" if meets else "not met",
        "met_on_training": feasible_training,
        "goals": rows,
        "binding": binding,
        "conflicts": [] if feasible_training else conflicts(g_best, np.array(best["jacobian"]), goals, hard,
                                                            state["lam"][best["start"]], state["rows"]),
        "unmet_hard": [goals[i].name for i in range(len(goals))
                       if hard[i] and checked["best"]["g"][i] > FEASIBLE],
        "gains": {"initial": tables(parameters.initial)["gains"], "best": tables(parameters.gains(best["p"]))["gains"]},
        "best": {"start": best["start"], "iteration": best["iteration"]},
        "starts": [{"start": b["start"], "iteration": b["iteration"], "feasible": b["score"][0] == 0,
                    "score": b["score"][1], **parameters.columns(b["p"])} for b in state["best"] if b is not None],
        "training": {"samples": int(len(train_index)), "drawn": config.train.samples,
                     "sampling_seed": config.train.seeds[0], "iterations": state["iteration"],
                     "starts": config.starts},
        "held_out": {"samples": checked["samples"], "drawn": checked["drawn"],
                     "sampling_seed": config.validation.seeds[0], "wall_s": held_wall},
        "method": {"lagrangian": dataclasses.asdict(config.lagrangian),
                   "learning_rate": config.optimizer.learning_rate, "clip_norm": config.optimizer.clip_norm},
        "wall_s": {"design": state["rows"][-1]["wall_s"] if state["rows"] else 0.0, "held_out": held_wall},
        "T": config.mission.T,
    })


def _binding(g, soft, hard, goals) -> list:
    """The goals that bind at the best design: the hard ones within 2 % of their limit, and
    the largest soft one."""
    out = [goals[i].name for i in range(len(goals)) if hard[i] and g[i] >= 0.98]
    if soft.any():
        i = int(np.flatnonzero(soft)[np.argmax(g[soft])])
        out.append(goals[i].name)
    return out
