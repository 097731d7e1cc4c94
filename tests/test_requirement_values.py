"""A requirement's value on traced signals (so3jax.sim.requirement_values): equal to
pointing.evaluate's (diverged_worst) for every index, interpretation, axis and level, in a phase
and over the whole run; its gradient against finite differences, finite at e = 0 and past a
diverged run; under jit and vmap."""

import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from so3jax.sim import pointing as pt
from so3jax.sim import requirement_values as rv

DT = 0.5
M = 60  # records, t = k DT in [0, 30) s
T = np.arange(M) * DT
PHASES = ((0.0, 12.0), (12.0, 30.0))  # 24 and 36 samples
S = 5
LEVELS = (0.6, 0.97)  # temporal: resolved over the whole run, not in phase 0; ensemble (S = 5): 0.97 is not
WINDOWS = (2.0, 1.25)  # 4 samples each (contiguous blocks); 3, 2, 3, 2, ... (segments)


def _requirement(index, axis="angle", level=0.6, interpretation="temporal", phase=None, window=2.0):
    windowed = index in pt.WINDOWED
    return pt.Requirement(index, axis, level, 1.0, window if windowed else None,
                          2 * window if index in pt.DRIFT else None, phase, interpretation)


def _signals():
    rng = np.random.default_rng(1)
    e = rng.normal(size=(S, M, 3)) * 1e-4 + rng.normal(size=(S, 1, 3)) * 1e-4
    diverged = e.copy()
    diverged[2, 40:] = np.nan  # run 2 diverges at t = 20 s
    diverged[4, 50:, 1] = np.inf
    diverged[3, 55, 0] = np.nan  # three of five runs at t = 27.5 s
    return e, diverged


def _cases():
    """(index, interpretation, axis, level, phase, window): per index and interpretation, "each"
    over the whole run, the angle in a phase (windows of unequal sample counts for the windowed
    indices), and one of x, y, z in turn."""
    for i, (index, interpretation) in enumerate(itertools.product(pt.INDICES, pt.INTERPRETATIONS)):
        yield index, interpretation, "each", LEVELS[i % 2], None, WINDOWS[0]
        yield index, interpretation, "angle", LEVELS[1 - i % 2], 0, WINDOWS[index in pt.WINDOWED]
        yield index, interpretation, "xyz"[(i + i // 3) % 3], LEVELS[1], (None, 1)[i % 2], WINDOWS[0]


def test_values_equal_pointing_evaluate():
    """Every index, interpretation, axis, level (resolved and not), a phase and the whole run,
    windows in blocks and not, on clean signals and with diverged runs (NaN, +inf):
    pointing.evaluate(..., diverged_worst=True)'s. All the plans' values in one jit (plans of a
    P and a K index are equal)."""
    requirements = [_requirement(index, axis, level, interpretation, phase, window)
                    for index, interpretation, axis, level, phase, window in _cases()]
    plans = [rv.plan(r, T, PHASES, runs=S) for r in requirements]
    distinct = list(dict.fromkeys(plans))
    values = jax.jit(lambda e: jnp.stack([rv.value(p, e) for p in distinct]))
    seen = set()
    for e in _signals():
        got = np.asarray(values(jnp.asarray(e)))
        for r, p in zip(requirements, plans):
            expected = pt.evaluate(r, T, e, PHASES, diverged_worst=True)
            np.testing.assert_allclose(got[distinct.index(p)], expected.value, rtol=1e-12, atol=0,
                                       err_msg=r.describe())
            assert rv.resolved(p) == expected.resolved and rv.count(p) == expected.samples, r.describe()
            seen.add((r.interpretation, expected.resolved, bool(np.isinf(expected.value))))
    for interpretation in pt.INTERPRETATIONS:
        assert {(interpretation, True, False), (interpretation, True, True)} <= seen
    assert ("temporal", False, False) in seen and ("ensemble", False, True) in seen


def test_one_run_and_a_shuffled_grid():
    """(M, 3) for one run; a time grid out of order (the samples gathered, not sliced)."""
    e = _signals()[0]
    order = np.random.default_rng(2).permutation(M)
    requirements = [_requirement(index, "each", 0.9, "temporal", 1, window)
                    for index, window in (("APE", 2.0), ("RPE", 1.25), ("PDE", 2.0))]
    plans = [rv.plan(r, T, PHASES) for r in requirements]
    shuffled = [rv.plan(r, T[order], PHASES) for r in requirements]
    assert all(p.take is not None for p in shuffled) and shuffled[1].segments is not None
    values = jax.jit(lambda one, runs: jnp.stack([rv.value(p, one) for p in plans]
                                                 + [rv.value(p, runs) for p in shuffled]))
    got = np.asarray(values(e[0], e[:, order])).reshape(2, -1)
    for r, one, runs in zip(requirements, *got):
        np.testing.assert_allclose(one, pt.evaluate(r, T, e[0], PHASES).value, rtol=1e-12)
        np.testing.assert_allclose(runs, pt.evaluate(r, T, e, PHASES).value, rtol=1e-12)


def test_a_window_that_does_not_fit_is_refused():
    with pytest.raises(ValueError, match=r"^window 15 s is longer than the evaluation period \[0, 12\) s$"):
        rv.plan(_requirement("RPE", window=15.0, phase=0), T, PHASES)
    with pytest.raises(ValueError, match=r"^window 5 s \+ separation 10 s is longer"):
        rv.plan(_requirement("PDE", window=5.0, phase=0), T, PHASES)
    with pytest.raises(ValueError, match="holds no sample"):
        rv.plan(_requirement("APE", phase=0), T, ((0.1, 0.3), (0.3, 30.0)))
    with pytest.raises(ValueError, match="number of runs"):
        rv.resolved(rv.plan(_requirement("APE", interpretation="mixed"), T, PHASES))


H = 1e-6  # the parameter's step of central differences
GRADIENT_CASES = tuple(_requirement(index, axis, level, interpretation, window=window)
                       for interpretation in pt.INTERPRETATIONS
                       for index, axis, level, window in (("APE", "angle", 0.6, 2.0), ("RPE", "each", 0.9, 1.25)))
GRADIENT_CASES += (_requirement("MPE", "angle", 0.6, "temporal"), _requirement("PDE", "angle", 0.6, "mixed"),
                   _requirement("RPE", "angle", 0.6, "ensemble"), _requirement("MPE", "x", 0.6, "ensemble"))


@functools.cache
def _probe():
    """(e0, e1) -> (cases, 4): value, d value / d a (reverse mode), value at a = +-H, of
    e(a) = e0 + a e1 at a = 0, for each of GRADIENT_CASES, in one jit."""
    plans = [rv.plan(r, T, PHASES) for r in GRADIENT_CASES]

    def probe(e0, e1):
        out = []
        for p in plans:
            f = lambda a, p=p: rv.value(p, e0 + a * e1)
            v, g = jax.value_and_grad(f)(0.0)
            out.append(jnp.stack([v, g, f(H), f(-H)]))
        return jnp.stack(out)

    return jax.jit(probe)


def test_gradient_equals_finite_differences():
    """d value / d a at a = 0 against central differences, each interpretation, absolute and
    windowed indices, on clean signals and past a diverged run (+inf where the statistic
    selects it, with a zero derivative)."""
    rng = np.random.default_rng(3)
    e0, e1 = rng.normal(size=(2, S, M, 3)) * 1e-4
    diverged = e0.copy()
    diverged[1, 30:] = np.nan
    infinite = 0
    for e in (e0, diverged):
        for r, (v, grad, up, down) in zip(GRADIENT_CASES, np.asarray(_probe()(e, e1))):
            if np.isinf(v):
                infinite += 1
                assert grad == 0.0, r.describe()
                continue
            assert np.isfinite(grad) and grad != 0.0, r.describe()
            np.testing.assert_allclose(grad, (up - down) / (2 * H), rtol=1e-6, err_msg=r.describe())
    assert 0 < infinite < len(GRADIENT_CASES)


def test_gradient_is_finite_at_zero():
    """At e = 0 (every angle 0): the value 0, the gradient finite (the safe norm's)."""
    e1 = np.random.default_rng(4).normal(size=(S, M, 3))
    out = np.asarray(_probe()(np.zeros((S, M, 3)), e1))
    assert np.all(out[:, 0] == 0.0) and np.all(np.isfinite(out[:, 1]))


def test_jit_and_vmap_compose():
    """A batch of B signals (gain sets) through jit(vmap(value)) and jit(vmap(grad)); the plan a
    static argument of jit."""
    rng = np.random.default_rng(5)
    e = jnp.asarray(rng.normal(size=(3, S, M, 3)) * 1e-4)
    requirements = (_requirement("RPE", "each", 0.9, "ensemble"), _requirement("PDE", "angle", 0.6, "mixed", 1, 1.25))
    plans = [rv.plan(r, T, PHASES, runs=S) for r in requirements]
    expected = [[pt.evaluate(r, T, np.asarray(x), PHASES).value for x in e] for r in requirements]

    def batched(e):
        values = [jax.vmap(lambda x, p=p: rv.value(p, x))(e) for p in plans]
        # the value is homogeneous of degree 1 in e: d value(a e) / d a at a = 1 is the value
        grads = [jax.vmap(jax.grad(lambda a, x, p=p: rv.value(p, a * x)))(jnp.ones(e.shape[0]), e) for p in plans]
        return jnp.stack(values), jnp.stack(grads)

    values, grads = jax.jit(batched)(e)
    np.testing.assert_allclose(np.asarray(values), expected, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(grads), expected, rtol=1e-12)
    static = jax.jit(rv.value, static_argnums=0)
    np.testing.assert_allclose(float(static(plans[0], e[1])), expected[0][1], rtol=1e-12)
