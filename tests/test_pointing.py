"""ECSS-E-ST-60-10C pointing indices (so3jax.sim.pointing) on synthetic signals: the indices
against direct NumPy, closed forms, the three statistical interpretations, the error signals
from rotation matrices, requirements. NumPy only, but for one small so3.log call."""

import dataclasses
import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from so3jax.sim import pointing as pt
from so3jax.sim.rollout import History

ARCSEC = pt.ARCSEC
DT = 0.1


def _grid(n):
    return np.arange(n) * DT  # s, as the recorder's k dt


def _requirement(**item):
    return pt.parse_requirements([item])[0]


def test_windowed_indices_equal_direct_numpy():
    """e = bias + sine + noise; windows of 20 samples tiling [3, 17.5) s from its start (the
    last 1.5 s hold no whole window): MPE = the window means, RPE = e minus them (zero mean per
    window), the angle the vector norm."""
    k = np.arange(200)
    t = k * DT
    rng = np.random.default_rng(0)
    e = np.array([1e-5, -2e-5, 3e-6]) + 4e-6 * np.sin(0.7 * t)[:, None] * [1, 2, 3] + 1e-6 * rng.normal(size=(200, 3))
    bounds, window = (3.0, 17.5), 2.0
    first = 30  # sample of t = 3 s
    j = np.where((k >= first) & (k < first + 7 * 20), (k - first) // 20, -1)  # 7 whole windows
    np.testing.assert_array_equal(pt.window_of(t, bounds, window), j)
    means = np.stack([e[j == w].mean(axis=0) for w in range(7)])
    np.testing.assert_allclose(pt.mean(t, e, bounds, window), means, rtol=0, atol=1e-20)
    rpe = pt.relative(t, e, bounds, window)
    np.testing.assert_allclose(rpe, e[j >= 0] - means[j[j >= 0]], rtol=0, atol=1e-20)
    np.testing.assert_allclose(rpe.reshape(7, 20, 3).mean(axis=1), 0.0, atol=1e-20)
    np.testing.assert_array_equal(pt.absolute(t, e, bounds), e[(k >= 30) & (k < 175)])
    for index, vectors in (("APE", e[(k >= 30) & (k < 175)]), ("MPE", means), ("RPE", rpe)):
        x = pt.index_samples(index, t, e, bounds, window)
        np.testing.assert_array_equal(x[:, :3], np.abs(vectors))
        np.testing.assert_allclose(x[:, 3], np.sqrt((vectors**2).sum(axis=1)), rtol=1e-15)


def test_the_angle_of_a_windowed_index_is_the_norm_of_the_vector_index():
    """e_x = +-a alternating: each window's mean is 0 (MPE angle 0, not the mean angle a),
    and |e - mean| = a."""
    a, t = 5.0 / ARCSEC, _grid(40)
    e = np.zeros((40, 3))
    e[:, 0] = a * (-1.0) ** np.arange(40)
    mpe = pt.index_samples("MPE", t, e, (0.0, 4.0), 1.0)
    np.testing.assert_allclose(mpe[:, 3], 0.0, atol=1e-22)
    np.testing.assert_allclose(pt.index_samples("RPE", t, e, (0.0, 4.0), 1.0)[:, 3], a, rtol=1e-15)


def test_a_constant_error_gives_ape_equal_mpe_and_zero_rpe():
    t, c = _grid(100), np.array([3.0, -4.0, 12.0]) / ARCSEC  # |c| = 13 arcsec
    e = np.broadcast_to(c, (100, 3))
    bounds = [(0.0, 10.0)]
    for index, expected in (("APE", [3, 4, 12, 13]), ("MPE", [3, 4, 12, 13]), ("RPE", [0, 0, 0, 0])):
        window = None if index == "APE" else 2.0
        for axis, value in zip(("x", "y", "z", "angle"), expected):
            r = pt.evaluate(_requirement(index=index, axis=axis, level=0.9, limit=13, window=window), t, e, bounds)
            assert r.value == pytest.approx(value, abs=1e-9), (index, axis)
            assert r.passed


def test_a_sinusoid_over_whole_periods_has_zero_mpe_and_the_arcsine_quantile():
    """e_x = a sin(w t) sampled uniformly, N samples a period, windows of two periods: MPE = 0;
    |e_x| has the quantile a sin(pi p / 2) (P(|sin| <= y) = 2 arcsin(y) / pi), to the sampling's
    resolution a w dt."""
    n, periods, a = 200, 6, 7.0
    t = np.arange(n * periods) * DT
    w = 2 * math.pi / (n * DT)
    e = np.zeros((t.size, 3))
    e[:, 0] = a * np.sin(w * t) / ARCSEC
    bounds = [(0.0, t.size * DT)]
    mpe = _requirement(index="MPE", axis="x", level=0.99, limit=1e-9, window=2 * n * DT)
    assert pt.evaluate(mpe, t, e, bounds).value < 1e-12
    for p in (0.5, 0.9, 0.95, 0.99):
        ape = pt.evaluate(_requirement(index="APE", axis="x", level=p, limit=a), t, e, bounds)
        assert ape.value == pytest.approx(a * math.sin(math.pi * p / 2), abs=a * w * DT), p
        assert ape.samples == t.size and ape.resolved


def test_the_drift_of_a_ramp_is_its_slope_times_the_separation():
    t = _grid(100)
    e = np.outer(t, [2.0, 0.0, -1.0]) / ARCSEC  # arcsec/s
    r = _requirement(index="PDE", axis="each", level=0.5, limit=6.0, window=1.0, separation=3.0)
    out = pt.evaluate(r, t, e, [(0.0, 10.0)])
    assert out.samples == 7  # window pairs (0, 3) .. (6, 9)
    assert out.value == pytest.approx(6.0, rel=1e-12) and out.values["angle"] == pytest.approx(math.sqrt(45), rel=1e-12)
    np.testing.assert_allclose(pt.drift(t, e, (0.0, 10.0), 1.0, 3.0) * ARCSEC, np.tile([6.0, 0.0, -3.0], (7, 1)),
                               rtol=1e-12, atol=1e-12)


def test_the_quantile_is_the_smallest_sample_with_the_level_at_or_below_it():
    x = np.array([3.0, 1.0, 2.0, 5.0, 4.0])
    assert pt.quantile(x, 0.6) == 3.0  # k = ceil(3) = 3
    assert pt.quantile(x, 0.61) == 4.0  # k = ceil(3.05) = 4
    assert pt.quantile(x, 0.01) == 1.0
    rng = np.random.default_rng(1)
    y = rng.normal(size=(997, 2))
    for p in (0.5, 0.9, 0.95, 0.9973):
        np.testing.assert_array_equal(pt.quantile(y, p), np.quantile(y, p, axis=0, method="inverted_cdf"))
    assert np.isnan(pt.quantile([1.0, np.nan, 2.0], 0.5))


def test_temporal_ensemble_and_mixed_interpretations():
    """|e_x| of 4 runs (rows) at 4 times, level 0.75: a quantile over 4 is the 3rd smallest,
    over 16 the 12th. Temporal: the worst run's, run 0's 9; ensemble: the worst time's, t0's
    {10, 8, 2, 2} -> 8; mixed: of all 16 (10, 9, 8, then 2s) -> 2. Signs do not count."""
    x = np.array([[10, -9, 1, 1], [8, 2, -2, 2], [2, 2, 2, -2], [-2, 2, 2, 2]], float)
    e = np.zeros((4, 4, 3))
    e[..., 0] = x / ARCSEC
    t = _grid(4)
    for interpretation, expected in (("temporal", 9.0), ("ensemble", 8.0), ("mixed", 2.0)):
        for axis in ("x", "angle", "each"):
            r = _requirement(index="APE", axis=axis, level=0.75, limit=5.0, interpretation=interpretation)
            out = pt.evaluate(r, t, e, [(0.0, 0.4)])
            assert out.value == pytest.approx(expected, rel=1e-12), (interpretation, axis)
            assert out.passed == (expected <= 5.0)
            assert out.samples == {"temporal": 4, "ensemble": 4, "mixed": 16}[interpretation]


def test_a_diverged_run_counts_as_the_worst_sample_where_asked():
    """The runs of the test above with run 3 diverged (NaN from t1 on): by default every
    interpretation is NaN and fails; counted as +inf, the temporal value is infinite (the
    worst run's), the ensemble one the worst time's, t1's {9, 2, 2, inf} -> 9 (t0: 8, t2
    and t3: 2), and the mixed one the 12th smallest of 16, now 1, 1, eight 2s, 8, 9 -> 9."""
    x = np.array([[10, -9, 1, 1], [8, 2, -2, 2], [2, 2, 2, -2], [-2, np.nan, np.nan, np.nan]], float)
    e = np.zeros((4, 4, 3))
    e[..., 0] = x / ARCSEC
    e[3, 1:] = np.nan
    t, bounds = _grid(4), [(0.0, 0.4)]
    for interpretation, expected in (("temporal", math.inf), ("ensemble", 9.0), ("mixed", 9.0)):
        r = _requirement(index="APE", axis="x", level=0.75, limit=10.0, interpretation=interpretation)
        assert math.isnan(pt.evaluate(r, t, e, bounds).value)
        out = pt.evaluate(r, t, e, bounds, diverged_worst=True)
        assert out.value == pytest.approx(expected, rel=1e-12), interpretation
        assert out.passed == math.isfinite(expected)
        row = pt.report(t, e, None, bounds, window=0.2, levels=(0.75,), indices=("APE",),
                        interpretations=(interpretation,), diverged_worst=True)["phases"][0]["rows"][0]
        assert row["interpretation"] == interpretation and row["x"] == pytest.approx(expected, rel=1e-12)


def test_the_error_signals_are_the_rotation_vectors_between_the_attitudes():
    """R = R_d exp(hat(v)), R_hat = R exp(-hat(u)): e_P = v, e_K = u, up to near a half turn;
    batch axes after (M, 3, 3) come first in the result, as runs."""
    rng = np.random.default_rng(2)
    M = 24
    R_d = Rotation.random(M, random_state=3).as_matrix()
    v = rng.normal(size=(M, 3)) * np.r_[1e-7, 1e-3, 0.3, np.full(M - 3, 1.0)][:, None]
    v[-1] = [0.0, 0.0, 3.1]  # 178 degrees
    u = 1e-5 * rng.normal(size=(M, 3))
    R = R_d @ Rotation.from_rotvec(v).as_matrix()
    R_hat = R @ Rotation.from_rotvec(-u).as_matrix()
    history = History(_grid(M), R, None, R_d, None, None, None, None, None, None, R_hat=R_hat)
    s = pt.signals(history)
    np.testing.assert_allclose(s.performance, v, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(s.knowledge, u, rtol=1e-9, atol=1e-15)
    assert pt.signals(history._replace(R_hat=None)).knowledge is None
    batched = pt.attitude_error(R_d[..., None], np.stack([R, R_hat], axis=-1))  # (M, 3, 3, 2) -> (2, M, 3)
    np.testing.assert_allclose(batched[0], v, rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize("change, key, words", [
    ({"index": "XPE"}, "index", "unknown index"),
    ({"axis": "roll"}, "axis", "unknown axis"),
    ({"level": 1.0}, "level", "(0, 1)"),
    ({"level": 0}, "level", "(0, 1)"),
    ({"level": True}, "level", "(0, 1)"),
    ({"limit": -1.0}, "limit", ">= 0"),
    ({"limit": "5"}, "limit", ">= 0"),
    ({"window": None}, "window", "missing"),
    ({"window": 0.0}, "window", "positive"),
    ({"window": 200.0}, "window", "longer than"),
    ({"index": "APE"}, "window", "takes no window"),
    ({"index": "PDE"}, "separation", "missing"),
    ({"index": "PDE", "separation": 15.0}, "separation", "whole number"),
    ({"separation": 10.0}, "separation", "takes no separation"),
    ({"interpretation": "worst"}, "interpretation", "unknown"),
    ({"phase": 2}, "phase", "does not exist"),
    ({"phase": "slew"}, "phase", "unknown phase"),
    ({"phase": -1}, "phase", ">= 0"),
    ({"units": "deg"}, "", "unknown key 'units'"),
])
def test_a_bad_requirement_is_a_one_line_error_naming_entry_and_key(change, key, words):
    good = {"index": "RPE", "axis": "angle", "level": 0.95, "limit": 5.0, "window": 10.0}
    item = good | change
    with pytest.raises(ValueError) as error:
        pt.parse_requirements([good, item], phase_names=("capture", "pointing"), phase_bounds=[(0, 50), (50, 150)])
    message = str(error.value)
    assert "\n" not in message and f"requirements[1]{'.' + key if key else ''}:" in message and words in message


def test_a_missing_key_and_a_non_list_are_refused():
    with pytest.raises(ValueError, match=r"^requirements\[0\]\.limit: missing$"):
        pt.parse_requirements([{"index": "APE", "axis": "x", "level": 0.9}])
    with pytest.raises(ValueError, match="must be a list"):
        pt.parse_requirements({"index": "APE"})


def test_a_violated_requirement_fails_and_a_met_one_passes():
    """A 10 arcsec bias on x in phase 1 only; e_K 1 arcsec everywhere (check() reads each
    requirement's signal); "each" fails where one component does."""
    t = _grid(200)
    e_P = np.zeros((200, 3))
    e_P[100:, 0] = 10.0 / ARCSEC
    e_K = np.full((200, 3), 1.0 / ARCSEC)
    bounds = [(0.0, 10.0), (10.0, 20.0)]
    items = [
        {"index": "APE", "axis": "each", "level": 0.95, "limit": 5.0, "phase": "capture"},
        {"index": "APE", "axis": "each", "level": 0.95, "limit": 5.0, "phase": 1},
        {"index": "APE", "axis": "y", "level": 0.95, "limit": 5.0, "phase": 1},
        {"index": "MPE", "axis": "angle", "level": 0.95, "limit": 5.0, "window": 2.0},
        {"index": "AKE", "axis": "angle", "level": 0.95, "limit": 1.8},
        {"index": "AKE", "axis": "angle", "level": 0.95, "limit": 1.7, "name": "knowledge"},
    ]
    requirements = pt.parse_requirements(items, phase_names=("capture", "pointing"), phase_bounds=bounds)
    assert [r.phase for r in requirements] == [0, 1, 1, None, None, None]
    out = pt.check(requirements, t, e_P, e_K, bounds)
    assert [o["passed"] for o in out] == [True, False, True, False, True, False]
    assert out[1]["value"] == pytest.approx(10.0) and out[4]["value"] == pytest.approx(math.sqrt(3))
    assert out[5]["name"] == "knowledge" and "AKE angle at 0.95" in out[5]["requirement"]
    json.dumps(out, allow_nan=False)
    with pytest.raises(ValueError, match="knowledge error"):
        pt.check(requirements, t, e_P, None, bounds)
    diverged = e_P.copy()
    diverged[150, 2] = np.nan
    assert not pt.evaluate(requirements[2], t, diverged, bounds).passed  # NaN fails, on any axis of the run
    with pytest.raises(ValueError, match="longer than the evaluation period"):
        pt.evaluate(_requirement(index="RPE", axis="x", level=0.9, limit=1.0, window=30.0), t, e_P, bounds)


def test_fewer_samples_than_the_level_needs_are_flagged():
    """0.9973 needs 1 / 0.0027 = 371 samples: 100 are flagged (their quantile is their
    maximum); 0.95 needs 20; 10 runs are too few for an ensemble at 0.95."""
    t, e = _grid(100), np.random.default_rng(4).normal(size=(10, 100, 3)) / ARCSEC
    bounds = [(0.0, 10.0)]
    strict = pt.evaluate(_requirement(index="APE", axis="x", level=0.9973, limit=10.0), t, e[0], bounds)
    assert not strict.resolved and strict.value == pytest.approx(np.abs(e[0, :, 0]).max() * ARCSEC)
    assert pt.evaluate(_requirement(index="APE", axis="x", level=0.95, limit=10.0), t, e[0], bounds).resolved
    assert not pt.evaluate(_requirement(index="MPE", axis="x", level=0.95, limit=10.0, window=1.0), t, e[0],
                           bounds).resolved  # 10 windows
    ensemble = _requirement(index="APE", axis="x", level=0.95, limit=10.0, interpretation="ensemble")
    assert not pt.evaluate(ensemble, t, e, bounds).resolved
    assert pt.evaluate(dataclasses.replace(ensemble, level=0.9), t, e, bounds).resolved
    assert [pt.resolved(0.95, n) for n in (19, 20)] == [False, True]
    assert [pt.resolved(0.9973, n) for n in (370, 371)] == [False, True]


def test_the_report_gives_every_index_per_phase_and_level():
    t = _grid(100)
    e_P = np.full((100, 3), 2.0 / ARCSEC)
    bounds = pt.phase_bounds_of(SimpleNamespace(phase_steps=(60, 200), dt=DT, n_steps=100))
    assert bounds == ((0.0, 6.0), (6.0, 10.0), (10.0, 10.0))
    out = pt.report(t, e_P, None, bounds, window=5.0, levels=(0.95, 0.9973), phase_names=("a", "b", "c"))
    json.dumps(out, allow_nan=False)
    assert out["unit"] == "arcsec" and [p["samples"] for p in out["phases"]] == [60, 40, 0]
    rows = {(r["index"], r["level"]): r for r in out["phases"][0]["rows"]}
    assert set(rows) == {(i, p) for i in pt.REPORTED for p in (0.95, 0.9973)}
    assert pt.REPORTED == ("APE", "MPE", "RPE", "AKE", "MKE", "RKE") and pt.reported(None) == ("APE", "MPE", "RPE")
    assert rows["MPE", 0.95]["samples"] == 1 and rows["MPE", 0.95]["x"] == pytest.approx(2.0)  # one whole window
    assert rows["APE", 0.95]["x"] == pytest.approx(2.0) and rows["APE", 0.95]["angle"] == pytest.approx(2 * 3**0.5)
    assert rows["APE", 0.95]["resolved"] and not rows["APE", 0.9973]["resolved"]
    assert rows["RPE", 0.95]["samples"] == 50 and rows["RPE", 0.95]["x"] == pytest.approx(0.0, abs=1e-9)
    assert rows["AKE", 0.95]["angle"] is None  # no estimate recorded
    second = {(r["index"], r["level"]): r for r in out["phases"][1]["rows"]}
    assert second["RPE", 0.95]["x"] is None and second["APE", 0.95]["samples"] == 40  # 4 s < the 5 s window
    assert all(r["x"] is None for r in out["phases"][2]["rows"])  # a phase the horizon never reaches
