"""Inertia dispersions that draw rigid bodies by construction (``second_moments``,
docs/model.md §15): the second moments of mass against a box's closed form, every draw's
principal moments within the triangle inequality, the factors' statistics, the variate
layout, and one-line refusals. Draws only: nothing compiles."""

from __future__ import annotations

import numpy as np
import pytest

from so3jax.missions import draw, mission

IMAGING_J0 = [[900.0, 6.0, -4.0], [6.0, 800.0, 5.0], [-4.0, 5.0, 600.0]]
LOGNORMAL = {"dist": "lognormal", "median": 1.0, "sigma": 0.05}


@pytest.fixture(scope="module")
def body():
    """A mission whose J0 is a rigid body's (the imaging mission's) and J2 = J0."""
    return mission.load(None, ["T=1.0", f"inertia.J0.nominal={IMAGING_J0}", "inertia.J1.scale=1.4",
                               f"inertia.J2.nominal={IMAGING_J0}"])


def drawn(m, J0: dict, n: int, seed: int = 0, **other):
    d, _ = draw.parse({"inertia": {"J0": J0}, **other}, m)
    return draw.draw_samples(d, seed, n, 20)


def principal(J):
    return np.linalg.eigvalsh(J)


def test_second_moments_of_a_box_are_its_squared_half_sides():
    """A solid box of mass 12 and sides 2a, 2b, 2c: J = 4 diag(b^2 + c^2, a^2 + c^2, a^2 + b^2),
    so s = 4 (a^2, b^2, c^2); a rod (c -> 0 ...) sits on the triangle's edge, s_z = 0."""
    a, b, c = 1.5, 0.7, 0.2
    J = 4.0 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])
    np.testing.assert_allclose(draw.second_moments(J), 4.0 * np.array([a * a, b * b, c * c]), rtol=1e-14)
    assert draw.second_moments([1.0, 1.0, 2.0])[2] == 0.0  # a flat plate: J_z = J_x + J_y
    assert draw.second_moments([625.0, 350.0, 1000.0])[2] < 0  # the paper's J0: no rigid body has it


def test_every_draw_is_a_rigid_body(body):
    """Wide factors (lognormal sigma 1: a factor e^-3 to e^3 within 3 sigma), 90 deg of
    rotation and a scale: every J0 drawn is positive definite with principal moments within
    the triangle inequality; the matrix form with products of the same spread breaks it."""
    wide = {"scale": {"dist": "lognormal", "median": 1.0, "sigma": 0.2}, "rotation_deg": 90.0,
            "second_moments": {"dist": "lognormal", "median": 1.0, "sigma": 1.0}}
    s = drawn(body, wide, 4000)
    lam = principal(s.params.J0)
    assert np.all(lam > 0) and np.all(s.draws == 1)
    assert np.all(2.0 * lam.max(axis=-1) <= lam.sum(axis=-1) * (1 + 1e-12))  # lambda_max <= the other two
    matrix = drawn(body, {"axis_scale": {"dist": "lognormal", "median": 1.0, "sigma": 1.0},
                          "products": {"dist": "normal", "mean": 0.0, "std": 200.0}}, 4000)
    lam = principal(matrix.params.J0)
    assert np.mean(2.0 * lam.max(axis=-1) > lam.sum(axis=-1)) > 0.05


def test_fixed_factors_and_no_rotation_give_the_nominal(body):
    s = drawn(body, {"second_moments": 1.0, "rotation_deg": 0.0}, 8)
    np.testing.assert_allclose(s.params.J0, np.broadcast_to(IMAGING_J0, (8, 3, 3)), rtol=1e-12, atol=1e-10)
    np.testing.assert_allclose(s.params.J1, 1.4 * s.params.J0, rtol=1e-12)


def test_the_factors_follow_their_distribution(body):
    """Without rotation the drawn second moments over the nominal's, per principal axis (well
    separated: the order stays), are the lognormal factors: log-mean 0 within 4 standard
    errors, log-std 0.05 within 5 %, independent across axes."""
    n = 4000
    s = drawn(body, {"second_moments": LOGNORMAL}, n)
    nominal = draw.second_moments(principal(np.asarray(IMAGING_J0)))
    logs = np.log(draw.second_moments(principal(s.params.J0)) / nominal)
    assert np.all(np.abs(logs.mean(axis=0)) < 4 * 0.05 / np.sqrt(n))
    assert np.all(np.abs(logs.std(axis=0) / 0.05 - 1) < 0.05)
    assert np.max(np.abs(np.corrcoef(logs.T) - np.eye(3))) < 4 / np.sqrt(n)


def test_the_form_takes_the_variates_of_the_matrix_form(body):
    """The other quantities' draws do not move with the form, and the rotation draws
    the same principal axes: Q V is the same where the factors are 1."""
    other = {"deployment": {"tau_J": {"dist": "uniform", "low": 200.0, "high": 400.0}}}
    rotated = {"rotation_deg": 30.0}
    a = drawn(body, {**rotated, "second_moments": 1.0}, 64, **other)
    b = drawn(body, {**rotated, "axis_scale": 1.0}, 64, **other)
    np.testing.assert_array_equal(a.params.tau_J, b.params.tau_J)
    np.testing.assert_allclose(a.params.J0, b.params.J0, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("J0, nominal, message", [
    ({"second_moments": {"dist": "normal", "mean": 1.0, "std": 0.1}}, IMAGING_J0, "a normal can draw a negative"),
    ({"second_moments": {"dist": "uniform", "low": -0.1, "high": 1.0}}, IMAGING_J0, "must be >= 0"),
    ({"second_moments": LOGNORMAL, "products": 1.0}, IMAGING_J0, "replaces axis_scale and products"),
    ({"second_moments": LOGNORMAL}, [[625.0, 5.5, 3.0], [5.5, 350.0, 4.0], [3.0, 4.0, 1000.0]],
     "break the triangle inequality"),
])
def test_bad_physical_dispersions_are_one_line_errors(J0, nominal, message):
    m = mission.load(None, ["T=1.0", f"inertia.J0.nominal={nominal}"])
    with pytest.raises(ValueError, match=message):
        draw.parse({"inertia": {"J0": J0}}, m)
