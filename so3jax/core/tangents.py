"""A loop's carry given its forward-mode tangents at the start, so that JAX traces its
derivative once.

Under ``jax.jvp`` (and so ``jax.jacfwd``, ``jax.grad``), a ``lax.scan`` finds which carries
have tangents by a fixpoint: it differentiates its body, promotes the carries whose tangent
turned out non-zero and differentiates it again, and under ``jax.vmap`` it finds the batched
carries the same way. Each pass traces the whole body, nested scans included (each with its
own fixpoint), so a closed loop whose rate, attitude, estimate and metrics pick up a tangent
one after another is traced several times over. :func:`seed` gives a carry, before the loop,
the tangents the fixpoint would end with: the carries that depend, through the loop's body
applied again and again, on an input that has a tangent (:func:`dependence`, a boolean
dataflow over the body's jaxpr). The loop's derivative is then traced in one pass per scan.

The values are unchanged: a seeded tangent is the carry's own (zero where it had none),
selected by a constant predicate beside a term of the inputs' tangents that makes it
non-zero and batched like them. Where the dataflow over-approximates (a float that only a
comparison or a rounding reads from the inputs), a carry carries a zero tangent it need not.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax.custom_derivatives import SymbolicZero
from jax.extend import core as jex

_ZERO_DERIVATIVE = frozenset({"floor", "ceil", "round", "sign", "stop_gradient", "is_finite", "nextafter",
                              "random_bits", "random_seed", "random_wrap", "random_unwrap", "iota"})


def _inexact(var) -> bool:
    return jnp.issubdtype(var.aval.dtype, jnp.inexact)


def _jaxpr_dependence(jaxpr, consts, ins) -> list[bool]:
    """Which outputs of an open ``jaxpr`` depend on an input marked True (``consts`` for its
    constvars, ``ins`` for its invars), float outputs only."""
    marked = {}
    read = lambda v: False if isinstance(v, jex.Literal) else marked.get(v, False)
    for v, m in zip(jaxpr.constvars, consts):
        marked[v] = m
    for v, m in zip(jaxpr.invars, ins):
        marked[v] = m
    for eqn in jaxpr.eqns:
        outs = _eqn_dependence(eqn, [read(v) for v in eqn.invars])
        for v, m in zip(eqn.outvars, outs):
            marked[v] = m and _inexact(v)
    return [read(v) and not isinstance(v, jex.Literal) and _inexact(v) for v in jaxpr.outvars]


def dependence(closed, ins) -> list[bool]:
    """Which outputs of ``closed`` (a ``ClosedJaxpr``) depend on an input marked True in
    ``ins``: the derivative's non-zero tangents, loops to their fixpoint (an over-approximation
    where a primitive's derivative is zero but not known here as such)."""
    return _jaxpr_dependence(closed.jaxpr, [False] * len(closed.jaxpr.constvars), ins)


def _fixpoint(body, consts, carry, xs, num_carry):
    """(carry's final marks, the ys' marks) of a loop body ``(consts, carry, xs) -> (carry, ys)``
    applied until no carry is marked anew."""
    while True:
        out = body(consts + carry + xs)
        new = [a or b for a, b in zip(carry, out[:num_carry])]
        if new == carry:
            return carry, out[num_carry:]
        carry = new


def _eqn_dependence(eqn, ins) -> list[bool]:
    name, params = eqn.primitive.name, eqn.params
    if name == "scan":
        n_c, n_k = params["num_consts"], params["num_carry"]
        carry, ys = _fixpoint(lambda x: dependence(params["jaxpr"], x), ins[:n_c], ins[n_c:n_c + n_k],
                              ins[n_c + n_k:], n_k)
        return carry + ys
    if name == "while":
        n_cc, n_bc = params["cond_nconsts"], params["body_nconsts"]
        consts, carry = ins[n_cc:n_cc + n_bc], ins[n_cc + n_bc:]
        return _fixpoint(lambda x: dependence(params["body_jaxpr"], x), consts, carry, [], len(carry))[0]
    if name == "cond":
        outs = [dependence(branch, ins[1:]) for branch in params["branches"]]
        return [any(column) for column in zip(*outs)]
    for key in ("jaxpr", "call_jaxpr", "fun_jaxpr"):
        sub = params.get(key)
        if isinstance(sub, jex.ClosedJaxpr):
            return dependence(sub, ins)
        if isinstance(sub, jex.Jaxpr):
            return _jaxpr_dependence(sub, [False] * len(sub.constvars), ins)
    if name in _ZERO_DERIVATIVE:
        return [False] * len(eqn.outvars)
    return [any(ins)] * len(eqn.outvars)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def seed(body, carry, inputs):
    """``carry``, unchanged; under differentiation, each carry that ``body(carry, inputs) ->
    carry`` (one pass of the loop) makes depend on a differentiated input, or on such a carry,
    has a tangent from the start (its own, or zero)."""
    return carry


def _seed_jvp(body, primals, tangents):
    carry, inputs = primals
    t_carry, t_inputs = tangents
    leaves, treedef = jax.tree.flatten(carry)
    t_leaves = treedef.flatten_up_to(t_carry)
    t_ins = jax.tree.leaves(t_inputs, is_leaf=lambda t: isinstance(t, SymbolicZero))
    given = [not isinstance(t, SymbolicZero) for t in t_ins]
    aval = lambda x: jax.ShapeDtypeStruct(jnp.shape(x), jnp.result_type(x))
    closed = jax.make_jaxpr(body)(jax.tree.map(aval, carry), jax.tree.map(aval, inputs))
    marks = [not isinstance(t, SymbolicZero) for t in t_leaves]
    marks = _fixpoint(lambda x: dependence(closed, x), [], marks, given, len(marks))[0]
    sums = [jnp.sum(t) for t in t_leaves + t_ins
            if not isinstance(t, SymbolicZero) and jnp.issubdtype(t.dtype, jnp.inexact)]
    if not sums:
        return carry, t_carry
    term = functools.reduce(lambda a, b: a + b.astype(a.dtype), sums)  # of every tangent given

    def seeded(x, t, mark):
        if not mark or not jnp.issubdtype(jnp.result_type(x), jnp.inexact):
            return t
        own = jnp.zeros_like(x) if isinstance(t, SymbolicZero) else t
        return jax.lax.select(jnp.zeros(jnp.shape(x), bool), jnp.broadcast_to(term.astype(own.dtype), own.shape), own)

    return carry, treedef.unflatten([seeded(x, t, m) for x, t, m in zip(leaves, t_leaves, marks)])


seed.defjvp(_seed_jvp, symbolic_zeros=True)
