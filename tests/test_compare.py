"""so3jax compare: the paired statistics against direct computations, the comparison
file's checks, the report from a sweep's columns, the nested run folders, and (slow: a
few minutes of compilation) one tiny comparison end to end."""

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from so3jax.jobs import compare
from so3jax.results import io, runfolder
from so3jax.viz import compare as compare_plots
from tests.test_cli import run_cli

ROOT = Path(__file__).parents[1]


def test_paired_statistics():
    """The mean relative change, the win share and the tails against NumPy; a constant
    change has a zero-width interval; a noisy one's interval holds its mean and narrows as
    1/sqrt(n)."""
    rng = np.random.default_rng(0)
    x = rng.lognormal(0.0, 0.3, 400)
    y = x * (1.0 - 0.1)
    out = compare.paired(x, y, 500, np.random.default_rng(1))
    assert out["samples"] == 400 and out["wins"]["share"] == 1.0 and out["wins"]["ci95"] == [1.0, 1.0]
    np.testing.assert_allclose([out["relative_change"]["mean"], *out["relative_change"]["ci95"]], -0.1, rtol=1e-12)
    np.testing.assert_allclose(out["tails"]["difference"], np.percentile(y, 95) - np.percentile(x, 95), rtol=1e-12)

    widths = []
    for n in (400, 6400):
        x = rng.lognormal(0.0, 0.3, n)
        y = x * (1.0 + rng.normal(0.02, 0.1, n))
        out = compare.paired(x, y, 2000, np.random.default_rng(2))
        change = (y - x) / x
        low, high = out["relative_change"]["ci95"]
        assert low < np.mean(change) < high
        assert out["relative_change"]["mean"] == pytest.approx(np.mean(change), rel=1e-12)
        assert out["wins"]["share"] == pytest.approx(np.mean(y < x), rel=1e-12)
        assert out["wins"]["ci95"][0] < out["wins"]["share"] < out["wins"]["ci95"][1]
        widths.append(high - low)
        # the percentile interval of a mean: about 2 x 1.96 standard errors
        np.testing.assert_allclose(high - low, 2 * 1.96 * np.std(change) / np.sqrt(n), rtol=0.15)
    assert widths[1] == pytest.approx(widths[0] / 4, rel=0.2)
    assert compare.paired([], [], 10, np.random.default_rng(0)) == {"samples": 0}


@pytest.mark.parametrize(("change", "message"), [
    ({"tune": None}, "needs a \\[tune\\] table"),
    ({"tune": {"controller": "pd"}}, "tunes each of the mission's controllers"),
    ({"controllers": ["pd", "open_loop"]}, "has no gains to tune"),
    ({"controllers": ["pd"]}, "at least two laws"),
    ({"compare": {"reference": "sliding_mode"}}, "compare.reference must be one of"),
    ({"compare": {"bootstrap": 5}}, "compare.bootstrap"),
    ({"sweep": {"samples": 0}}, "sweep.samples"),
])
def test_bad_comparisons_are_refused_in_one_line(change, message):
    table = {"mission": "../missions/paper.toml", "controllers": ["pd", "adaptive"],
             "tune": {"iterations": 1, "train": {"seeds": [0]}, "validation": {"seeds": [1]}}}
    table.update(change)
    table = {k: v for k, v in table.items() if v is not None}
    with pytest.raises(ValueError, match=message):
        compare.parse(table, ROOT / "comparisons")


@pytest.mark.slow
def test_a_tiny_comparison_end_to_end(tmp_path):
    """Two laws tuned to the PD's budget and swept: the report pairs them on every sample
    the sweep wrote, and a resumed run computes nothing again and reports the same."""
    args = ("compare", str(ROOT / "comparisons" / "paper.toml"), "--out", str(tmp_path / "c"), "--set", "T=1.0",
            "--set", 'controllers=["pd", "mrp_feedback"]', "--set", 'compare.reference="pd"',
            "--set", "tune.iterations=1", "--set", "tune.optimizer.schedule_options.decay_steps=1",
            "--set", "tune.validation.seeds=[100]", "--set", "tune.validation.inertia_scales=[1.0]",
            "--set", "sweep.samples=8", "--set", "sweep.chunk=8", "--set", "compare.bootstrap=200")
    proc = run_cli(*args, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = tmp_path / "c"
    result = json.loads((out / "compare.json").read_text())
    columns = np.load(out / "sweep" / "samples.npz")
    pair = result["laws"]["mrp_feedback"]["against_reference"]
    x, y = columns["pd_rmse"], columns["mrp_feedback_rmse"]
    assert pair["samples"] == 8 and pair["relative_change"]["mean"] == pytest.approx(np.mean((y - x) / x), rel=1e-12)
    for law in ("pd", "mrp_feedback"):
        tuned = json.loads((out / "tune" / law / "validation.json").read_text())["tuned"]["gains"]
        assert result["laws"][law]["gains"] == tuned
    assert (out / "compare.png").stat().st_size > 0 and "| mrp_feedback |" in (out / "compare.md").read_text()
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["complete"] and {"tune/", "sweep/", "compare.json"} <= set(manifest["files"])
    again = run_cli(*args, "--resume", cwd=tmp_path)
    assert again.returncode == 0, again.stderr[-3000:]
    assert json.loads((out / "compare.json").read_text()) == result


def test_the_report_pairs_the_sweep_s_columns():
    """judge, markdown and the figure from a sweep's columns: a diverged sample leaves the
    pairs it is in; the paired change is the mean over the rest."""
    rng = np.random.default_rng(3)
    x = rng.lognormal(-6.0, 0.2, 50)
    y = x * 0.8
    columns = {"pd_rmse": x, "pd_effort": x * 1e4, "pd_diverged": np.zeros(50),
               "sliding_mode_rmse": y, "sliding_mode_effort": y * 1e4, "sliding_mode_diverged": np.zeros(50)}
    columns["sliding_mode_diverged"][7] = 1.0
    columns["sliding_mode_rmse"][7] = np.nan
    reports = {law: {"tuned": {"gains": {"g": 1.0}, "mean_rmse": 1e-3, "mean_effort": 10.0, "diverged_count": 0},
                     "budget": {"mean_effort": 10.0}} for law in ("pd", "sliding_mode")}
    config = SimpleNamespace(laws=("pd", "sliding_mode"), reference="pd", bootstrap=200, seed=0)
    result = compare.judge(config, reports, columns)
    pair = result["laws"]["sliding_mode"]["against_reference"]
    assert pair["samples"] == 49 and pair["relative_change"]["mean"] == pytest.approx(-0.2, rel=1e-12)
    assert result["laws"]["sliding_mode"]["sweep"]["diverged"] == 1 and "against_reference" not in result["laws"]["pd"]
    measured = {k for law in result["laws"].values() for part in ("held_out", "sweep") for k in law[part]}
    measured |= set(pair["tails"]) | {"budget_effort", "relative_change"}
    assert measured - set(result["units"]) == {"diverged_count", "samples", "diverged", "ci95"}  # counts, intervals
    assert result["units"]["rmse_median"] == "rad/s" and result["units"]["budget_effort"] == "N^2 m^2 s"
    table = compare.markdown(io.to_builtin(result))
    assert "| sliding_mode | g = 1 |" in table and "-20.0 % [-20.0, -20.0]" in table and "1 of 50" in table
    assert compare_plots.figure(config, columns, compare.pairs(config)).axes[1].get_ylabel() == "RMSE change vs PD [%]"


def test_a_run_inside_another_s_folder_lists_its_own_files(tmp_path):
    """Nested claims (compare's campaigns and sweep): the inner run lists its files, the
    outer one the inner folder; a fresh outer run removes the previous one's parts."""
    out = tmp_path / "c"
    for _ in range(2):
        with runfolder.claim(out, "compare", {"a": 1}) as outer:
            outer.start()
            assert not (out / "part").exists()  # the previous run's part is gone
            with runfolder.claim(out / "part", "sweep", {"b": 2}):
                io.write_text(out / "part" / "x.txt", "x")
            io.write_text(out / "top.txt", "t")
    assert json.loads((out / "manifest.json").read_text())["files"] == ["part/", "top.txt"]
    assert json.loads((out / "part" / "manifest.json").read_text())["files"] == ["x.txt"]


def test_candidates_name_what_is_compared():
    """[compare.candidates]: one law tuned two ways or at fixed gains, each paired with its
    own ``against``; candidates of one law go to separate sweeps of the same samples; the
    campaigns tune over the comparison's dispersions where tune.dispersions = "sweep"."""
    cvar = compare.load_config(ROOT / "comparisons" / "flight_cvar.toml")
    assert cvar.laws == ("pd_mean", "adaptive_mean", "pd_cvar", "adaptive_cvar")
    assert cvar.sweeps() == [["pd_mean", "adaptive_mean"], ["pd_cvar", "adaptive_cvar"]]
    assert [compare.sweep_folder(i) for i in range(2)] == ["sweep", "sweep_2"]
    assert [c.campaign.objective for c in cvar.candidates.values()] == ["mean", "mean", "cvar", "cvar"]
    assert cvar.candidates["pd_cvar"].campaign.dispersions == cvar.sweep_table["dispersions"]
    assert [compare.paired_with(cvar, n) for n in cvar.laws] == ["adaptive_mean", None, "pd_mean", "adaptive_mean"]
    flown = compare.load_config(ROOT / "comparisons" / "paper_gains_in_flight.toml")
    fixed = flown.candidates["pd_paper_tuned"]
    saved = json.loads((ROOT / "tuning" / "pd_equal_effort" / "best_gains.json").read_text())["gains"]
    assert fixed.controller == "pd" and fixed.gains._asdict() == pytest.approx(saved, rel=1e-12)
    assert flown.candidates["pd"].gains is None and "candidates" in compare.describe(flown)
    assert "candidates" not in compare.describe(compare.load_config(ROOT / "comparisons" / "flight.toml"))


@pytest.mark.parametrize(("candidates", "message"), [
    ({"a": {"controller": "pd"}}, "at least two"),
    ({"a": {"controller": "open_loop"}, "b": {"controller": "pd"}}, "controller must be one of"),
    ({"a": {"controller": "pd", "gains": "paper", "tune": {}}, "b": {"controller": "pd"}}, "not both"),
    ({"a": {"controller": "pd", "against": "a"}, "b": {"controller": "pd"}}, "paired with another"),
    ({"a": {"controller": "pd", "against": "c"}, "b": {"controller": "pd"}}, "against must be one of"),
    ({"a": {"controller": "pd", "gains": {"k_R": 1.0}}, "b": {"controller": "pd"}}, "missing gain"),
    ({"a": {"controller": "pd", "colour": 1}, "b": {"controller": "pd"}}, "unknown key"),
    ({"a": {"controller": "pd", "tune": {"controller": "pd"}}, "b": {"controller": "pd"}}, "a table of \\[tune\\]"),
])
def test_bad_candidates_are_refused_in_one_line(candidates, message):
    table = {"mission": "../missions/paper.toml", "compare": {"candidates": candidates},
             "tune": {"iterations": 1, "train": {"seeds": [0]}, "validation": {"seeds": [1]}}}
    with pytest.raises(ValueError, match=message):
        compare.parse(table, ROOT / "comparisons")


def test_tuning_over_the_sweep_s_dispersions_keeps_its_samples_out():
    table = {"mission": "../missions/flight.toml", "sweep": {"seed": 1},
                         "tune": {"iterations": 1, "dispersions": "sweep", "train": {"seeds": [1], "samples": 4},
                                  "validation": {"seeds": [2], "samples": 4}}}
    with pytest.raises(ValueError, match="would tune pd on the missions that judge it"):
        compare.parse(table, ROOT / "comparisons")
    table["sweep"]["seed"] = 0
    from so3jax.jobs.sweep.config import DEFAULT

    assert compare.parse(table, ROOT / "comparisons").campaigns["pd"].dispersions == DEFAULT["dispersions"]


def test_a_candidate_paired_with_another_than_the_reference():
    rng = np.random.default_rng(4)
    x = rng.lognormal(-6.0, 0.2, 40)
    columns = {f"{n}_{k}": v for n, f in (("a", 1.0), ("b", 0.9), ("c", 1.2)) for k, v in
               (("rmse", x * f), ("effort", x * 1e4), ("diverged", np.zeros(40)))}
    candidates = {"a": compare.Candidate("pd", None), "b": compare.Candidate("adaptive", None),
                  "c": compare.Candidate("pd", None, against="b")}
    config = SimpleNamespace(laws=("a", "b", "c"), candidates=candidates, reference="a", bootstrap=200, seed=0)
    reports = {n: {"tuned": {"gains": {"g": 1.0}, "mean_rmse": 1e-3, "mean_effort": 10.0, "diverged_count": 0}}
               for n in "abc"}
    result = compare.judge(config, reports, columns)
    assert result["laws"]["c"]["paired_with"] == "b" and "paired_with" not in result["laws"]["b"]
    assert result["laws"]["c"]["against_reference"]["relative_change"]["mean"] == pytest.approx(1.2 / 0.9 - 1)
    assert "vs b: +33.3 %" in compare.markdown(io.to_builtin(result))
    figure = compare_plots.figure(config, columns, compare.pairs(config))
    labels = [t.get_text() for t in figure.axes[1].get_xticklabels()]
    assert labels == ["b", "c\nvs b"]  # named after the candidate where it is not its law
