"""so3jax.core.tangents: the carries a loop's derivative reaches, found by a dataflow over its
jaxpr, against the tangents JAX's own differentiation leaves non-zero; a seeded loop's
derivative equal to the unseeded one's, with no carry given a tangent it would not have."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.extend import core as jex

import so3jax as sj
from so3jax.core import tangents
from so3jax.missions import mission as missions


def _body(carry, x):
    """A loop body whose carries reach the input x in one pass (a), two passes (b: through a,
    a nested scan), through a cond (c), a while loop (d); e: only through a comparison; f:
    never; k: an integer."""
    a, b, c, d, e, f, k = carry
    b = jax.lax.scan(lambda s, _: (s + 0.5 * a, None), b, None, length=2)[0]
    c = jax.lax.cond(k > 2, lambda u: u * b, lambda u: u + 1.0, c)
    d = jax.lax.while_loop(lambda s: s[1] < 2, lambda s: (s[0] + c, s[1] + 1), (d, 0))[0]
    e = jnp.where(x > 0.0, e + 1.0, e)
    return a + x, b, c, d, e, f * 2.0, k + 1


CARRY = tuple(jnp.asarray(v) for v in (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)) + (jnp.asarray(0, jnp.int32),)
X = jnp.asarray(0.3)


def _fixpoint(marks, given):
    closed = jax.make_jaxpr(_body)(CARRY, X)
    while True:
        out = tangents.dependence(closed, marks + given)
        new = [m or o for m, o in zip(marks, out)]
        if new == marks:
            return marks
        marks = new


def test_dependence_follows_each_pass_of_the_loop():
    closed = jax.make_jaxpr(_body)(CARRY, X)
    none = [False] * len(CARRY)
    assert tangents.dependence(closed, none + [True]) == [True, False, False, False, False, False, False]
    # through a, then the nested scan (b), the cond (c), the while loop (d); e, f and k never
    assert _fixpoint(none, [True]) == [True, True, True, True, False, False, False]
    assert _fixpoint([False, False, False, False, False, True, False], [False]) == \
        [False, False, False, False, False, True, False]
    assert tangents.dependence(closed, none + [False]) == [False] * len(CARRY)


def _loop(carry, x, seeded, length=5):
    if seeded:
        carry = tangents.seed(lambda c, x: _body(c, x), carry, x)
    return jax.lax.scan(lambda c, _: (_body(c, x), None), carry, None, length=length)[0]


def _scan_carries(closed) -> int:
    scans = [e for e in closed.jaxpr.eqns if e.primitive.name == "scan"]
    return scans[-1].params["num_carry"]


def test_a_seeded_loop_has_the_derivative_and_the_tangent_carries_of_the_unseeded_one():
    f = lambda x, seeded: _loop(CARRY, x, seeded)
    plain = jax.jvp(lambda x: f(x, False), (X,), (jnp.ones_like(X),))
    seeded = jax.jvp(lambda x: f(x, True), (X,), (jnp.ones_like(X),))
    for a, b in zip(jax.tree.leaves(plain), jax.tree.leaves(seeded)):
        np.testing.assert_array_equal(a, b)
    counts = [_scan_carries(jax.make_jaxpr(lambda x, s=s: jax.jvp(lambda y: f(y, s), (x,), (x,)))(X))
              for s in (False, True)]
    assert counts[0] == counts[1] == len(CARRY) + 4  # a, b, c and d carry tangents, e, f and k do not
    # differentiated through the initial carry alone: f's chain
    g = lambda f0, seeded: _loop(CARRY[:5] + (f0, CARRY[6]), X, seeded)
    counts = [_scan_carries(jax.make_jaxpr(lambda y, s=s: jax.jvp(lambda z: g(z, s), (y,), (y,)))(CARRY[5]))
              for s in (False, True)]
    assert counts[0] == counts[1] == len(CARRY) + 1


def test_an_undifferentiated_loop_is_unchanged():
    np.testing.assert_array_equal(jax.jit(lambda x: _loop(CARRY, x, True))(X)[3],
                                  jax.jit(lambda x: _loop(CARRY, x, False))(X)[3])


def _all_scan_carries(closed) -> int:
    """The carries of every scan in a jaxpr, nested ones included."""
    count = 0
    for eqn in closed.jaxpr.eqns:
        count += eqn.params["num_carry"] if eqn.primitive.name == "scan" else 0
        for value in eqn.params.values():
            for sub in value if isinstance(value, tuple) else (value,):
                if isinstance(sub, jex.ClosedJaxpr):
                    count += _all_scan_carries(sub)
                elif isinstance(sub, jex.Jaxpr):
                    count += _all_scan_carries(jex.ClosedJaxpr(sub, []))
    return count


def test_the_rollout_s_derivative_carries_the_tangents_jax_s_fixpoint_finds(monkeypatch):
    """The rollout seeds its carry (so3jax.sim.rollout): its derivative along the gains carries
    as many tangents, in every scan, as JAX's fixpoint finds for the unseeded loop (the flight
    loop, whose sensors' biases, momentum manager and limit counters take none)."""
    m = missions.load(None, ["T=0.3", "dt=0.05", "record_every=6", "control.period=0.1", 'estimator.kind="mekf"',
                             'actuator.kind="wheels"'])
    scenario, flown = m.scenario(), m.loop()
    controller, gains = m.controller("pd")
    gains = jax.tree.map(lambda g: jnp.asarray(g, jnp.float64), gains)
    rmse = lambda g: sj.rollout(scenario, controller, g, 0, loop=flown, record_every=6).metrics.rmse
    seeded = jax.make_jaxpr(lambda g: jax.jvp(rmse, (g,), (g,)))(gains)
    monkeypatch.setattr(tangents, "seed", lambda body, carry, inputs: carry)
    unseeded = jax.make_jaxpr(lambda g: jax.jvp(rmse, (g,), (g,)))(gains)  # a function of its own: traced anew
    assert _all_scan_carries(seeded) == _all_scan_carries(unseeded) > 0
