"""Structural filters at the control tick (docs/model.md §8.8): the second-order section's
coefficients against scipy's bilinear transform, its response to a sinusoid against the
continuous filter at Tustin's warped frequency (a notch's depth zeta_z / zeta_p), and the
loop broken at the actuator input with the filter in it: its transfer the filter's times
the loop's without."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import signal

import so3jax as sj
from so3jax.components.filters import SecondOrder
from so3jax.missions import mission as missions
from so3jax.sim import margins

PERIOD = 0.1  # [s]


def analog(f: SecondOrder):
    """(b, a) of H(s), numerator and denominator in descending powers of s."""
    w = 2 * np.pi * float(f.frequency)
    a = [1.0, 2 * float(f.zeta_pole) * w, w * w]
    return ([0.0, 0.0, w * w] if f.lowpass else [1.0, 2 * float(f.zeta_zero) * w, w * w]), a


FILTERS = [SecondOrder(jnp.asarray(1.3), jnp.asarray(0.02), jnp.asarray(0.5), PERIOD),
           SecondOrder(jnp.asarray(0.4), jnp.asarray(0.0), jnp.asarray(0.2), PERIOD),
           SecondOrder(jnp.asarray(2.0), jnp.asarray(1.0), jnp.asarray(0.7071067811865476), PERIOD, lowpass=True)]


@pytest.mark.parametrize("f", FILTERS, ids=["notch", "deep-notch", "lowpass"])
def test_the_coefficients_are_tustin_s_prewarped_at_the_frequency(f):
    """scipy's bilinear transform s = 2 f_s (z - 1)/(z + 1) at f_s = K / 2, K = omega / tan(omega Delta_c / 2)."""
    w = 2 * np.pi * float(f.frequency)
    b, a = signal.bilinear(*analog(f), fs=w / np.tan(w * PERIOD / 2) / 2)
    n0, n1, n2, d1, d2 = (float(c) for c in f.coefficients(jnp.float64))
    np.testing.assert_allclose([n0, n1, n2], b / a[0], rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose([1.0, d1, d2], a / a[0], rtol=1e-13, atol=1e-15)


def steady_response(f: SecondOrder, omega: float, ticks: int = 3000) -> complex:
    """The filter's gain and phase on x_j = sin(omega t_j), from a least-squares fit of its
    output's last third (the transient decayed) to sin and cos."""
    t = PERIOD * np.arange(ticks)
    x = jnp.asarray(np.stack([np.sin(omega * t)] * 3, axis=1))  # (ticks, 3): one per axis

    def one(state, xj):
        return f.apply(state, xj)

    y = np.asarray(jax.lax.scan(one, f.init((), jnp.float64), x)[1])[:, 0]
    tail = slice(2 * ticks // 3, None)
    basis = np.stack([np.sin(omega * t[tail]), np.cos(omega * t[tail])], axis=1)
    (s, c), *_ = np.linalg.lstsq(basis, y[tail], rcond=None)
    return complex(s, c)  # y = Im((s + i c) e^{i omega t}) for x = Im(e^{i omega t})


@pytest.mark.parametrize("f", FILTERS, ids=["notch", "deep-notch", "lowpass"])
def test_a_sinusoid_comes_out_as_the_continuous_filter_at_the_warped_frequency(f):
    """H_d(e^{i omega Delta_c}) = H(i K tan(omega Delta_c / 2)); at omega = the filter's own, H(i omega)."""
    w = 2 * np.pi * float(f.frequency)
    K = w / np.tan(w * PERIOD / 2)
    b, a = analog(f)
    for omega in (0.3 * w, w, 1.7 * w):
        if omega >= np.pi / PERIOD:
            continue
        s = 1j * K * np.tan(omega * PERIOD / 2)
        expected = np.polyval(b, s) / np.polyval(a, s)
        np.testing.assert_allclose(steady_response(f, omega), expected, rtol=0, atol=1e-9)
    if not f.lowpass:
        assert abs(abs(steady_response(f, w)) - float(f.zeta_zero) / float(f.zeta_pole)) < 1e-9


BASE = {"T": 20.0, "controllers": ["pd"], "sensors": {"gyro": False, "star_tracker": False},
        "estimator": {"kind": "truth"}, "actuator": {"kind": "ideal"}, "momentum": {"kind": "none"},
        "disturbance": {"amplitude": 0.0, "noise_std": 0.0}, "reference": {"kind": "inertial"},
        "initial": {"attitude": [0.0, 0.0, 0.0], "rate": [0.0, 0.0, 0.0]}}


def test_the_loop_broken_at_the_actuator_input_carries_the_filter():
    """L(z) of the loop with a torque notch equals H_d(z) L(z) of the loop without, about the
    same equilibrium (at rest on an inertial reference, the filter at rest): the margins see
    the filter, its states among the loop's."""
    notch = {"kind": "notch", "notch": {"frequency": 0.8, "zeta_zero": 0.05, "zeta_pole": 0.4}}
    plain, filtered = (missions.from_dict(d) for d in (BASE, {**BASE, "filter": notch}))
    lin = [sj.margins(m, "pd", at=0.0).linearization for m in (plain, filtered)]
    assert lin[1].A.shape[0] == lin[0].A.shape[0] + 6  # two delays per axis
    omegas = np.array([0.5, 2 * np.pi * 0.8, 12.0])
    H = np.array([steady_response(filtered.loop(jnp.float64).filter, w) for w in omegas])
    L0, L1 = (margins.frequency_response(x, omegas) for x in lin)
    np.testing.assert_allclose(L1, H[:, None, None] * L0, rtol=0, atol=1e-8 * np.abs(L0).max())


@pytest.mark.parametrize(("table", "message"), [
    ({"kind": "notch", "notch": {"frequency": 5.0}}, "below the Nyquist frequency 5 Hz"),
    ({"kind": "notch", "notch": {"frequency": -1.0}}, "filter.notch.frequency"),
    ({"kind": "lowpass", "lowpass": {"zeta_pole": 0.0}}, "filter.lowpass.zeta_pole"),
    ({"kind": "notch", "notch": {"signal": "attitude"}}, "filter.notch.signal"),
    ({"kind": "bandstop"}, "filter.kind"),
])
def test_bad_filters_are_refused_in_one_line(table, message):
    with pytest.raises(ValueError, match=message):
        m = missions.from_dict({**BASE, "filter": table})
        m.loop()


def test_a_filter_needs_the_sampled_loop():
    with pytest.raises(ValueError, match="sampled loop"):
        missions.from_dict({**BASE, "control": {"mode": "continuous"},
                            "filter": {"kind": "lowpass", "lowpass": {"frequency": 1.0}}})


def test_a_mission_without_a_filter_describes_none():
    assert "filter" not in missions.from_dict(BASE).describe()
    assert missions.from_dict(BASE).loop().filter is None
