"""Stability margins of each dispersed sample's sampled loop (docs/model.md §19), per time.

Each sample's loop (its scenario :func:`so3jax.missions.build.scenario` with its reference and
inertia values :func:`so3jax.missions.batched.scenario_values`, its components
:func:`so3jax.missions.batched.loop`) is flown noise-free and disturbance-free from its
initial state to each time asked, as :func:`so3jax.sim.margins.nominal_state` flies one
mission, the samples together (:func:`fly`, a vmap: one program per chunk size and number
of times). There its one-period map is linearized (19.2), broken at the actuator input
(:func:`linearize`: :func:`so3jax.sim.margins.linearize_traced` vmapped, one program per
chunk size), and each sample's closed loop judged on the host, as ``so3jax margins`` judges
the sample's mission flown alone (:func:`so3jax.jobs.margins.at`): stable or not
(:func:`~so3jax.sim.margins.closed_loop_modes`), loop-at-a-time gain, phase and delay
margins (:func:`~so3jax.sim.margins.loop_at_a_time`) and the exact multi-loop disk margin
(19.4) (:func:`~so3jax.sim.margins.disk_margin`: the peak of sigma_max(S - I/2) on its
2000-point grid refined by bounded Brent; the grid's :func:`~so3jax.sim.margins.disk_alpha`
is at least it). The host's part costs a point of the flight loop some 10 ms (its PD,
n = 60, and its adaptive law, n = 87, on a 2-core CPU); the flights to the times cost about
as much as the sweep's own.

The loop is linearized as time-invariant at each time (docs/model.md §19.1): during a
transient (a deployment) a mode that the loop barely moves may sit a little outside the
unit circle (|z| - 1 ~ 1e-8 to 1e-6 per period, the wheels' momentum), and the sample is
then reported unstable there; at a relative equilibrium (the end of a phase held long
enough) the verdict is exact.
"""

from __future__ import annotations

import functools
import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.jobs import margins as jobs_margins
from so3jax.missions import batched, build
from so3jax.missions.mission import Mission
from so3jax.results.io import to_builtin
from so3jax.sim import margins
from so3jax.sim.loop import initial_state, tick

AXES = 3  # the broken loop's inputs: body torque (3,) [N m]
SCALARS = ("stable", "at_limit", "spectral_radius", "disk_alpha", "disk_db", "disk_phase_deg")
PER_AXIS = ("gain_margin_lower_db", "gain_margin_upper_db", "phase_margin_deg", "delay_margin_s", "disk_axis_alpha")
QUANTILES = (0.01, 0.05, 0.5)  # of the disk margin [dB] over the stable samples (summarize)


def _cast(tree, dtype):
    return jax.tree.map(lambda x: jnp.asarray(x, dtype), tree)


def _sample(mission: Mission, p, values, dtype):
    """(scenario, noise-free loop) of one sample: its RolloutParams p and dispersed values
    (reference, inertia and component leaves)."""
    own, components = batched.split(values)
    scenario = build.scenario(batched.scenario_values(mission, own), p)
    return scenario, margins.noise_free(batched.loop(mission, components, dtype))


@functools.partial(jax.jit, static_argnames=("controller", "mission"))
def fly(inputs, gains, ticks, *, controller, mission: Mission):
    """Each sample's state before each tick of ``ticks`` (K,) int32 ascending (leading axes
    S, K): its loop flown noise-free (:func:`so3jax.sim.margins.noise_free`) with d = 0 from
    its initial state, tick by tick (each tick followed by its m plant steps), a
    ``fori_loop`` from one tick to the next: one program for every set of K ticks."""
    params, leaves = inputs
    dtype = params.J0.dtype
    gains, key = _cast(gains, dtype), jax.random.key(0)

    def one(p, values):
        scenario, loop = _sample(mission, p, values, dtype)
        state = initial_state(scenario, controller, gains, (), loop)
        advance = lambda j, s: margins.advance_tick(scenario, loop, controller, gains, key, s, j)[0]
        states, start = [], jnp.zeros((), jnp.int32)
        for k in range(ticks.shape[0]):
            state = jax.lax.fori_loop(start, ticks[k], advance, state)
            states.append(state)
            start = ticks[k]
        return jax.tree.map(lambda *x: jnp.stack(x), *states)

    return jax.vmap(one)(params, leaves)


@functools.partial(jax.jit, static_argnames=("controller", "mission", "kinds"))
def linearize(inputs, gains, states, j, *, controller, mission: Mission, kinds):
    """(A (S, n, n), B (S, n, 3), C (S, 3, n), at_limit (S,)) of (19.2) at tick j about each
    sample's state (leading axis S): :func:`so3jax.sim.margins.linearize_traced` vmapped, and
    whether an actuator limit binds there (:func:`so3jax.sim.margins.linearize`'s ``at_limit``)."""
    params, leaves = inputs
    dtype = params.J0.dtype
    gains, key = _cast(gains, dtype), jax.random.key(0)

    def one(p, values, state):
        scenario, loop = _sample(mission, p, values, dtype)
        A, B, C = margins.linearize_traced(scenario, loop, controller, gains, state, j, kinds, key)
        new, out = tick(scenario, loop, controller, gains, key, state, j)  # held: as over the period
        return A, B, C, jnp.any(jnp.stack(loop.actuator.limits(state.actuator, new.held, out.tau_cmd)))

    return jax.vmap(one)(params, leaves, states)


def _judge(lin: margins.Linearization, omegas=None) -> dict:
    """One point's margins (NaN where the closed loop is unstable or not finite) on the
    frequency grid ``omegas`` [rad/s] (None: :func:`so3jax.sim.margins.default_omegas`)."""
    nan3 = np.full(AXES, np.nan)
    out = {"stable": False, "at_limit": lin.at_limit, "spectral_radius": np.nan, "disk_alpha": np.nan,
           "disk_db": np.nan, "disk_phase_deg": np.nan, **{name: nan3 for name in PER_AXIS}}
    if not all(np.isfinite(x).all() for x in (lin.A, lin.B, lin.C)):
        return out  # a flight gone non-finite: no linearization
    classical = margins.loop_at_a_time(lin, omegas)
    out["stable"], out["spectral_radius"] = classical.stable, classical.spectral_radius
    if not classical.stable:
        return out
    disks = margins.disk_margin(lin, omegas)
    disk = disks.multiloop
    out.update(disk_alpha=disk.alpha, disk_db=disk.gain_margin_upper_db, disk_phase_deg=disk.phase_margin_deg)
    for name in PER_AXIS[:-1]:
        out[name] = np.array([getattr(axis, name) for axis in classical.axes])
    out["disk_axis_alpha"] = np.array([axis.alpha for axis in disks.axes])
    return out


def _resolving(mission: Mission, inputs, i: int, t: float) -> np.ndarray:
    """Sample i's frequency grid at t [s]: the default grid with points about each of its
    structural modes (its own J(t), k and c; :func:`so3jax.sim.margins.resolving_omegas`)."""
    params, values = jax.tree.map(lambda x: x[i], inputs)
    scenario, _ = _sample(mission, params, values, params.J0.dtype)
    return margins.resolving_omegas(float(mission.period), margins.structural_modes(scenario, t))


def shared_kinds(states, n_samples: int, t: float) -> tuple:
    """:func:`so3jax.sim.margins.state_kinds` shared by the samples' states (leading axis S)
    with finite values (a diverged sample's margins are NaN whatever its coordinates);
    ValueError where two of them differ (a leaf a rotation in one and not in another)."""
    one = lambda i: jax.tree.map(lambda x: x[i], states)
    finite = [i for i in range(n_samples) if all(np.isfinite(x).all() for x in jax.tree.leaves(one(i)))]
    kinds = margins.state_kinds(one(finite[0] if finite else 0))
    for i in finite[1:]:
        if margins.state_kinds(one(i)) != kinds:
            raise ValueError(f"margins: at t = {t:g} s sample {i}'s state has a rotation where sample {finite[0]}'s "
                             "has none (or the reverse): their linearizations cannot share coordinates")
    return kinds


def sample_margins(inputs, gains, *, controller, mission: Mission, times) -> dict[str, np.ndarray]:
    """Each sample's margins at each time [s] of ``times`` (whole control periods within the
    horizon, :func:`so3jax.jobs.margins.check_times`; None: the last tick of each phase the
    horizon reaches, :func:`so3jax.jobs.margins.default_times`), its loop broken at the actuator input
    (docs/model.md §19). inputs = (RolloutParams, {dispersed component parameter: values}),
    leading batch axis S, as :func:`so3jax.missions.batched.sample_metrics` takes them;
    ``controller`` a :class:`~so3jax.controllers.Controller` (``mission.controller(name)[0]``).

    Returns numpy arrays, (S, K) for K times:

    - ``stable`` (bool): every mode the loop moves inside the unit circle (:class:`~so3jax.sim.margins.Modes`);
    - ``at_limit`` (bool): an actuator limit binds at the point (its channel open in (19.2));
    - ``spectral_radius`` [-] of those modes;
    - ``disk_alpha`` [-], ``disk_db`` [dB], ``disk_phase_deg`` [deg]: the exact multi-loop
      balanced disk margin (19.4) (the sigma_max lower bound, refined,
      :func:`~so3jax.sim.margins.disk_margin`), the gain +-dB and phase +-deg it covers;

    and (S, K, 3), per axis, the other axes closed (:func:`~so3jax.sim.margins.loop_at_a_time`):

    - ``gain_margin_lower_db`` (< 0; -inf: no lower crossover), ``gain_margin_upper_db``
      (> 0; inf: none) [dB], ``phase_margin_deg`` [deg] and ``delay_margin_s`` [s] (inf: no
      gain crossover);
    - ``disk_axis_alpha`` [-]: the axis's balanced disk margin (its gain and phase guarantees).

    Every margin is NaN where the closed loop is unstable (or its flight not finite)."""
    params, _ = inputs
    times = jobs_margins.check_times(mission, times)
    scenario, loop = mission.scenario(), mission.loop()
    ticks = np.array([margins.tick_index(scenario, loop, t) for t in times], np.int32)
    order = np.argsort(ticks, kind="stable")
    states = fly(inputs, gains, jnp.asarray(ticks[order]), controller=controller, mission=mission)
    states = jax.tree.map(np.asarray, states)
    n_samples = len(params.J0)
    rows = [[None] * len(times) for _ in range(n_samples)]
    for at, k in enumerate(order):
        here = jax.tree.map(lambda x: x[:, at], states)
        kinds = shared_kinds(here, n_samples, times[k])
        A, B, C, at_limit = map(np.asarray, linearize(inputs, gains, here, jnp.asarray(ticks[k], jnp.int32),
                                                      controller=controller, mission=mission, kinds=kinds))
        for i in range(n_samples):
            omegas = _resolving(mission, inputs, i, times[k]) if mission.flexible else None
            lin = margins.Linearization(np.asarray(A[i], np.float64), np.asarray(B[i], np.float64),
                                        np.asarray(C[i], np.float64), float(mission.period), (), bool(at_limit[i]))
            rows[i][k] = _judge(lin, omegas)
    return {name: np.array([[row[name] for row in sample] for sample in rows], bool if name in ("stable", "at_limit")
                           else np.float64) for name in SCALARS + PER_AXIS}


# --- summary ----------------------------------------------------------------------------

# Per-axis margins: the worst case is the smallest, but for the lower gain margin (< 0 dB)
# the largest, the one nearest 0 dB.
_WORST = {"disk_db": np.nanargmin, "gain_margin_lower_db": np.nanargmax, "gain_margin_upper_db": np.nanargmin,
          "phase_margin_deg": np.nanargmin, "delay_margin_s": np.nanargmin}
_LABELS = {"disk_db": "disk, all axes [+-dB]", "gain_margin_lower_db": "lower GM [dB]",
           "gain_margin_upper_db": "upper GM [dB]", "phase_margin_deg": "PM [deg]", "delay_margin_s": "delay [s]"}


def _worst(x, stable, index, pick) -> dict:
    """The worst value of x (S,) or (S, 3) over the stable samples: its value, sample index
    (``index``'s) and axis (None for a scalar); all None without a stable sample."""
    x = np.asarray(x, float)
    rows = np.flatnonzero(stable)
    if not len(rows):
        return {"value": None, "sample": None, "axis": None}
    flat = x[rows].reshape(len(rows), -1)
    at = int(pick(flat))
    row, axis = divmod(at, flat.shape[1])
    return {"value": float(flat[row, axis]), "sample": int(index[rows[row]]), "axis": axis if x.ndim > 1 else None}


def summarize(values: dict, times, phase_names, index=None) -> dict:
    """Per time of ``values`` (:func:`sample_margins`' arrays, S samples): its time [s] and
    phase (``phase_names``, one per time: :func:`so3jax.jobs.margins.phase_of`); the samples
    stable, unstable (their indices) and with an actuator limit binding; over the stable
    samples, the worst case of each margin (the smallest disk margin, upper gain margin,
    phase margin and delay margin, the lower gain margin nearest 0 dB: its value, sample
    and axis) and the disk margin's quantiles [dB] (QUANTILES). ``index``: each row's
    sample number (default 0 .. S-1). No stable sample: every statistic None."""
    stable_all = np.asarray(values["stable"], bool)
    n_samples = stable_all.shape[0]
    index = np.arange(n_samples) if index is None else np.asarray(index)
    out = []
    for k, (t, phase) in enumerate(zip(times, phase_names, strict=True)):
        stable = stable_all[:, k]
        disk = np.asarray(values["disk_db"], float)[stable, k]
        entry = {"t": float(t), "phase": phase, "samples": n_samples, "stable": int(stable.sum()),
                 "stable_share": float(stable.mean()) if n_samples else None,
                 "unstable_samples": index[~stable].tolist(),
                 "at_limit": int(np.asarray(values["at_limit"], bool)[:, k].sum()),
                 "worst": {name: _worst(np.asarray(values[name])[:, k], stable, index, pick)
                           for name, pick in _WORST.items()},
                 "disk_db_quantiles": {f"p{100 * q:g}": (float(np.quantile(disk, q)) if len(disk) else None)
                                       for q in QUANTILES}}
        out.append(entry)
    return {"quantiles": list(QUANTILES), "times": out}


def _number(x, fmt: str) -> str:
    if x is None:
        return "—"
    return format(x, fmt) if math.isfinite(x) else ("inf" if x > 0 else "-inf")


def format_lines(summary: dict) -> list[str]:
    """Markdown lines of :func:`summarize`'s summary: a table of the stable share and the
    disk margin's quantiles per time, and one of each margin's worst case (sample, axis)."""
    quantiles = [f"p{100 * q:g}" for q in summary["quantiles"]]
    lines = ["| t [s] | phase | stable | at a limit | " + " | ".join(f"disk {q} [dB]" for q in quantiles) + " |",
             "|---:|---|---:|---:|" + "---:|" * len(quantiles)]
    for e in summary["times"]:
        cells = [f"{e['t']:g}", e["phase"], f"{e['stable']}/{e['samples']}", str(e["at_limit"])]
        cells += [_number(e["disk_db_quantiles"][q], ".2f") for q in quantiles]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "| t [s] | " + " | ".join(f"worst {_LABELS[name]} (sample, axis)" for name in _WORST) + " |",
              "|---:|" + "---|" * len(_WORST)]
    for e in summary["times"]:
        cells = [f"{e['t']:g}"]
        for name in _WORST:
            w = e["worst"][name]
            where = "" if w["sample"] is None else f" (#{w['sample']}" + (
                "" if w["axis"] is None else f", {'xyz'[w['axis']]}") + ")"
            cells.append(_number(w["value"], ".3g" if name == "delay_margin_s" else ".2f") + where)
        lines.append("| " + " | ".join(cells) + " |")
    unstable = [f"t = {e['t']:g} s: {', '.join(map(str, e['unstable_samples']))}"
                for e in summary["times"] if e["unstable_samples"]]
    if unstable:
        lines += ["", "Unstable samples (no margins): " + "; ".join(unstable)]
    return lines


# --- a sweep's margins (sweep.margins_at) ---------------------------------------------------

PREFIX = "margins_"  # a chunk's margins fields: PREFIX + a name of SCALARS or PER_AXIS
COLUMNS = {"disk_db": "disk_db", "gain_margin_upper_db": "gm_upper_db", "gain_margin_lower_db": "gm_lower_db",
           "phase_margin_deg": "pm_deg", "delay_margin_s": "delay_s"}  # samples.csv: each, worst axis


def _values(results: dict, controller: str) -> dict:
    """The controller's margins fields of the loaded chunks, without PREFIX."""
    r = results.get(controller, {})
    return {k[len(PREFIX):]: v for k, v in r.items() if k.startswith(PREFIX)}


def columns(config, results: dict, n: int) -> dict:
    """Each controller's per-sample margins at each time of ``sweep.margins_at``: whether its
    loop is stable there (1, 0; NaN where not simulated) and the disk margin [dB] and the
    worst axis's gain margins [dB], phase margin [deg] and delay margin [s] (NaN where
    unstable), ``<controller>_<margin>_at_<t>s``."""
    cols = {}
    for c in config.controllers:
        values = _values(results, c)
        for k, t in enumerate(config.margins_at):
            suffix = f"_at_{t:g}s"
            stable = values.get("stable", np.full((n, len(config.margins_at)), np.nan))[:, k]
            cols[f"{c}_loop_stable{suffix}"] = stable
            for name, column in COLUMNS.items():
                x = np.asarray(values.get(name, np.full((n, len(config.margins_at)), np.nan)), float)[:, k]
                if x.ndim > 1:  # per axis: the worst (the lower gain margin's nearest 0 dB); NaN: unstable
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN row
                        x = np.nanmax(x, axis=-1) if name == "gain_margin_lower_db" else np.nanmin(x, axis=-1)
                cols[f"{c}_{column}{suffix}"] = x
    return cols


def summary_of(config, results: dict, simulated: dict) -> dict:
    """{controller: :func:`summarize` over its simulated samples} (``simulated``: bool per
    sample), JSON-ready; {} without ``sweep.margins_at``."""
    if not config.margins_at:
        return {}
    phases = [jobs_margins.phase_of(config.mission, t) for t in config.margins_at]
    out = {}
    for c in config.controllers:
        values = _values(results, c)
        if not values or not simulated[c].any():
            continue
        rows = np.flatnonzero(simulated[c])
        picked = {k: np.asarray(v)[rows] for k, v in values.items()}
        picked["stable"], picked["at_limit"] = (picked[k] == 1 for k in ("stable", "at_limit"))
        out[c] = to_builtin(summarize(picked, config.margins_at, phases, rows))
    return out


def format_summary(summary: dict) -> list[str]:
    """Markdown: each controller's :func:`format_lines`."""
    lines = []
    for c, entry in summary.get("margins", {}).items():
        lines += ["", f"Stability margins of {c}'s loop, broken at the actuator (each sample linearized at each time; "
                  "worst cases over its stable samples):", ""] + format_lines(entry)
    return lines
