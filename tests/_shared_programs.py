"""Compiled programs for tests whose property is the values a program computes (derivatives
against central differences, transformed calls against plain ones), not how XLA optimizes it."""

import jax

# XLA's backend optimizations, its expensive LLVM passes and its fusion emitters off: about
# a third of the compile time of a rollout's derivative, the same values to round-off (what
# the comparisons allow between differently fused programs).
FAST_COMPILE = {"xla_backend_optimization_level": 0, "xla_llvm_disable_expensive_passes": True,
                "xla_cpu_use_fusion_emitters": False}


def fast_jit(fn, *args):
    """jax.jit(fn) compiled with FAST_COMPILE for arguments shaped as ``args``."""
    return jax.jit(fn).lower(*args).compile(FAST_COMPILE)


def compiled(fn):
    """fn, jitted and compiled with FAST_COMPILE once per argument structure, shapes and
    dtypes: calls of other values share the program."""
    jitted, programs = jax.jit(fn), {}

    def call(*args):
        leaves, tree = jax.tree.flatten(args)
        key = (tree, tuple((x.shape, x.dtype, getattr(x, "weak_type", False)) for x in leaves))
        if key not in programs:
            programs[key] = jitted.lower(*args).compile(FAST_COMPILE)
        return programs[key](*args)

    return call
