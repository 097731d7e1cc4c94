"""A diverged rollout never reads as a number, and a phase the horizon never reached never
reads as 0: JSON null (with the diverged flag), "diverged" / "—" in tables, figures that
end at the horizon."""

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

import so3jax as sj
from so3jax.jobs import paper
from so3jax.results import io
from so3jax.sim import metrics
from so3jax.sim.rollout import History
from tests.test_cli import run_cli


def strict_json(text):
    """json.loads that refuses NaN and Infinity (not JSON)."""
    return json.loads(text, parse_constant=lambda name: pytest.fail(f"{name} in JSON"))


def test_json_has_null_for_non_finite_values(tmp_path):
    obj = {"a": np.array([1.5, np.nan, np.inf]), "b": float("-inf"), "c": np.float64(np.nan), "d": [2, True, None]}
    assert io.to_builtin(obj) == {"a": [1.5, None, None], "b": None, "c": None, "d": [2, True, None]}
    io.write_json(tmp_path / "x.json", obj)
    assert strict_json((tmp_path / "x.json").read_text())["a"] == [1.5, None, None]


def test_reported_values_and_cells():
    assert np.isnan(metrics.reported([1.0, 2.0], True)).all()  # a maximum taken before the blow-up
    np.testing.assert_array_equal(metrics.reported([[1.0, 2.0], [3.0, 4.0]], [False, True])[0], [1.0, 2.0])
    assert np.isnan(metrics.reported([[1.0, 2.0], [3.0, 4.0]], [False, True])[1]).all()
    assert metrics.phase_values([0.5, 0.0, 0.0], (10, 0, 0)) == [0.5, None, None]
    assert metrics.cell(float("nan"), ".2f") == "diverged" and metrics.cell(None, ".2f") == "—"
    assert metrics.cell(1.234, ".2f") == "1.23"


def test_paper_diverged_controller_is_null_in_json_and_diverged_in_the_table(tmp_path):
    """dt = 20 s: the adaptive law (Gamma = 1e8) blows up in 5 steps, the PD does not. The
    100 s horizon reaches only phase 1."""
    args = ("paper", "--T", "100", "--dt", "20", "--no-figures")
    proc = run_cli(*args, "--json", "--out", str(tmp_path / "j"), cwd=tmp_path)
    assert proc.returncode == 1 and "diverged rollout(s): adaptive" in proc.stderr
    report = strict_json(proc.stdout.strip().splitlines()[-1])
    assert strict_json((tmp_path / "j" / "metrics.json").read_text())["adaptive"] == report["adaptive"]
    ad, pd = report["adaptive"], report["pd"]
    assert ad["diverged"] is True and pd["diverged"] is False
    for key in paper.METRIC_NAMES:
        if key != "diverged":
            assert ad[key] is None or ad[key] == [None, None, None], key  # no number, not even max |tau|
    assert pd["rmse"] > 0 and pd["rmse_phase"][0] == pd["rmse"]
    for key in ("rmse_phase", "effort_phase", "rms_angle_phase", "max_angle_phase"):
        assert pd[key][1:] == [None, None], key  # never reached: null, not 0
    assert report["config"]["steps_per_phase"] == [5, 0, 0]

    table = run_cli(*args, "--out", str(tmp_path / "t"), cwd=tmp_path)
    assert table.returncode == 1
    lines = table.stdout.splitlines()
    rmse = next(line for line in lines if line.startswith("RMSE [rad/s]")).split()
    assert rmse[2:] == [f"{pd['rmse']:.4e}", "4.0240e-03", "diverged", "2.7760e-03"]
    assert next(line for line in lines if line.startswith("max |tau|")).split()[-1] == "diverged"
    assert next(line for line in lines if "RMSE phase 2" in line).split()[-2:] == ["—", "—"]
    assert next(line for line in lines if "effort phase 3" in line).split()[-2:] == ["—", "—"]
    comparison = lines.index("adaptive vs PD            ours        paper")
    assert lines[comparison + 1].split() == ["RMSE", "—", "-31.0", "%"]  # no "ours" against a diverged side
    assert lines[comparison + 4].split()[-1] == "—"  # ours vs paper: the adaptive column
    assert "nan" not in table.stdout.lower()


def _history(T, dt=0.5):
    t = np.arange(0.0, T, dt)
    m = len(t)
    eye = np.broadcast_to(np.eye(3), (m, 3, 3))
    vec = np.full((m, 3), 1e-3)
    return History(t=t, R=eye, Omega=vec, R_d=eye, Omega_d=0 * vec, Omega_e=vec, tau=vec, angle=np.full(m, 0.01),
                   J=500.0 * eye, controller=None)


def _spans(ax):
    """(start, end) [s] of the shaded phase spans of an axes."""
    out = []
    for patch in ax.patches:
        if hasattr(patch, "get_width"):
            out.append((patch.get_x(), patch.get_x() + patch.get_width()))
        else:
            x = np.asarray(patch.get_xy())[:, 0]
            out.append((x.min(), x.max()))
    return out


@pytest.mark.parametrize("T", [20.0, 1000.0])
def test_paper_figures_end_at_the_horizon(monkeypatch, T):
    """T = 20 s (phase 1 only) and 1000 s (phases 1 and 2): x axis [0, T], the phases shaded
    up to T and no further, no label of a phase never reached."""
    scenario = sj.paper_scenario(T, 0.5)
    reached = sum(metrics.reached_phases(scenario.steps_per_phase))
    assert reached == (1 if T == 20.0 else 2)
    captured = {}
    monkeypatch.setattr(io, "save_figures", lambda out, figures: captured.update(figures) or [])
    results = {name: SimpleNamespace(history=_history(T)) for name in paper.CONTROLLERS}
    paper.write_figures(None, results, scenario)
    assert len(captured) == 6
    for name, fig in captured.items():
        for ax in fig.axes:
            assert ax.get_xlim() == (0.0, T), name
            spans = _spans(ax)
            assert len(spans) == reached and max(end for _, end in spans) == pytest.approx(T), name
            labels = {t.get_text() for t in ax.texts}
            assert labels == {f"phase {p + 1}" for p in range(reached)}, name
        fig.clf()


def test_fly_continuous_figures_end_at_the_horizon():
    from so3jax.viz import plots

    phases = sj.paper_scenario(20.0, 0.5).phase_times
    histories = {"pd": _history(20.0)}
    for fig in (plots.attitude_error_figure(histories, phases, 20.0), plots.torque_figure(histories, phases, 20.0)):
        for ax in fig.axes:
            assert ax.get_xlim() == (0.0, 20.0) and len(_spans(ax)) == 1
    assert math.isclose(max(e for _, e in _spans(fig.axes[0])), 20.0)
