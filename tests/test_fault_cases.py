"""A fault sweep's cases (so3jax.jobs.sweep.fault_cases) on sweeps/faults.toml's drawn
samples: each sample's periods and case from its own draws, its APE and RPE over its own
period against direct NumPy, and the cases' counts (errors made up: nothing is flown)."""

import math
from pathlib import Path

import numpy as np
import pytest

from so3jax.jobs import sweep
from so3jax.jobs.sweep import fault_cases
from so3jax.jobs.sweep import pointing as sweep_pointing
from so3jax.missions import draw
from so3jax.sim import pointing

ROOT = Path(__file__).resolve().parents[1]
N = 64


@pytest.fixture(scope="module")
def drawn():
    config = sweep.load_config(ROOT / "sweeps" / "faults.toml", (f"sweep.samples={N}",))
    samples = draw.draw(config.dispersions, config.leaves, config.seed, N, config.max_draws,
                        mission=config.mission)
    return config, samples


def made_up_results(config, samples, seed=0):
    """Each controller's recorded errors e_P, e_K (N, M, 3) [rad] on the sweep's record grid."""
    m = config.mission
    records = int(round(m.T / sweep_pointing.times(config, 2)[1])) + 1
    rng = np.random.default_rng(seed)
    return {c: {"done": samples.valid.copy(),
                "pointing_performance": rng.normal(0.0, 1e-3, (N, records, 3)),
                "pointing_knowledge": rng.normal(0.0, 1e-5, (N, records, 3))} for c in config.controllers}


def test_each_sample_s_periods_and_case_are_its_own_draws(drawn):
    config, samples = drawn
    wheel_time = samples.leaves["faults.0.time"]
    starts = fault_cases.period_starts(config, samples)
    np.testing.assert_array_equal(starts["after_fault"], np.minimum(wheel_time, 1500.0))  # the outage at 1500 s
    np.testing.assert_array_equal(starts["after_detection"], wheel_time + 10.0)
    case = fault_cases.cases(config, samples)
    np.testing.assert_array_equal(case, [f"wheel {int(k)}" for k in samples.leaves["faults.0.wheel"]])
    assert set(case) == {"wheel 1", "wheel 2", "wheel 3", "wheel 4"}


def direct(index, t, e, start, end, level, window):
    """A sample's temporal APE / RPE angle [arcsec] over [start, end), written out."""
    keep = (t >= start) & (t < end)
    if index == "RPE":
        j = np.floor((t - start) / window).astype(int)
        keep &= j < math.floor((end - start) / window)
        means = {k: e[keep & (j == k)].mean(axis=0) for k in np.unique(j[keep])}
        x = np.array([e[i] - means[j[i]] for i in np.flatnonzero(keep)])
    else:
        x = e[keep]
    angles = np.sort(np.linalg.norm(x, axis=1))
    return angles[math.ceil(level * len(angles)) - 1] * 180 / math.pi * 3600


def test_each_sample_s_indices_over_its_own_period_match_numpy(drawn):
    config, samples = drawn
    results = made_up_results(config, samples)
    cols = fault_cases.columns(config, samples, results)
    t = sweep_pointing.times(config, results["pd"]["pointing_performance"].shape[1])
    starts = fault_cases.period_starts(config, samples)
    level, window = config.mission.pointing["levels"][0], config.mission.pointing["window"]
    for c in config.controllers:
        for name, start in starts.items():
            for index in pointing.SAMPLE_COLUMNS:
                x = cols[pointing.column(c, index, level, name)]
                assert np.all(np.isnan(x[~samples.valid]))
                for i in np.flatnonzero(samples.valid)[:6]:
                    expected = direct(index, t, results[c]["pointing_performance"][i], start[i], config.mission.T,
                                      level, window)
                    np.testing.assert_allclose(x[i], expected, rtol=1e-12, err_msg=f"{c} {name} {index} {i}")


def test_cases_count_their_samples_and_lost_missions_and_check_the_requirements(drawn):
    config, samples = drawn
    results = made_up_results(config, samples, seed=1)
    cols = fault_cases.columns(config, samples, results)
    simulated = {c: samples.valid for c in config.controllers}
    lost = {c: samples.valid & (np.arange(N) % (3 + k) == 0) for k, c in enumerate(config.controllers)}
    summary = fault_cases.summarize(config, samples, results, cols, simulated, lost)
    case = fault_cases.cases(config, samples)
    assert sorted(summary["cases"]) == ["wheel 1", "wheel 2", "wheel 3", "wheel 4"]
    for label, entry in summary["cases"].items():
        for c, row in entry.items():
            members = samples.valid & (case == label)
            assert row["samples"] == members.sum() and row["lost"] == (members & lost[c]).sum()
            ape = cols[pointing.column(c, "APE", 0.95, "after_detection")][members & ~lost[c]]
            assert row["after_detection"]["APE"]["max"] == ape.max()
            assert len(row["requirements"]) == len(config.mission.requirements)
            whole = pointing.check(config.mission.requirements, *sweep_pointing.signals(config, results[c], members),
                                   sweep_pointing.phases(config)[0], diverged_worst=True)
            assert [q["value"] for q in row["requirements"]] == [q["value"] for q in whole]
    lines = fault_cases.format_lines({"faults": summary})
    assert sum(line.startswith("| wheel ") for line in lines) == 4 * len(config.controllers)
