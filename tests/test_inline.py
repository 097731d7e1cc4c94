"""so3jax.core.inline: a helper traced once per shapes and dtypes, inlined where it is called."""

import jax
import jax.numpy as jnp
import numpy as np

from so3jax.core import so3
from so3jax.core.inline import inline


def test_a_helper_runs_its_python_once_per_shape_and_leaves_the_callers_program_as_its_operations_make_it():
    runs = []

    def body(a, b, scale=1.0):
        runs.append(a.shape)
        return scale * (a * b + jnp.sin(a))

    helper = inline(body, static_argnames=("scale",))
    caller = lambda f: lambda x: f(x, 2.0 * x) + f(x + 1.0, x)
    x = jnp.linspace(0.0, 1.0, 5)
    jaxpr = jax.make_jaxpr(caller(helper))(x)
    assert runs == [(5,)]  # both calls: one trace
    jax.make_jaxpr(caller(helper))(jnp.ones(7))
    assert runs == [(5,), (7,)]
    assert all(eqn.primitive.name != "pjit" for eqn in jaxpr.jaxpr.eqns)  # inlined: no call left
    plain = jax.make_jaxpr(caller(body))(x)
    assert [e.primitive for e in jaxpr.jaxpr.eqns] == [e.primitive for e in plain.jaxpr.eqns]
    np.testing.assert_array_equal(jax.jit(caller(helper))(x), jax.jit(caller(body))(x))
    np.testing.assert_array_equal(helper(x, x, scale=3.0), body(x, x, scale=3.0))  # a static argument


def test_inlined_so3_helpers_keep_their_derivatives():
    v = jnp.array([0.3, -0.2, 0.1])
    jac = jax.jacfwd(lambda v: so3.exp(v).reshape(-1))(v)
    eps = 1e-6
    fd = np.stack([(np.asarray(so3.exp(v + eps * e)) - np.asarray(so3.exp(v - eps * e))).reshape(-1) / (2 * eps)
                   for e in np.eye(3)], axis=1)
    np.testing.assert_allclose(jac, fd, rtol=0, atol=1e-9)
