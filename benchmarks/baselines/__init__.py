"""Independent reference implementations of the paper's closed loop, for speed and cross-checks.

``numpy_loop.simulate`` (NumPy, a Python loop over steps, vectorized over the batch) and
``numba_loop.simulate`` (Numba, scalar, prange over the batch; needs numba) share one
signature and result; ``noise.paper_noise`` draws the disturbance noise of SPEC §4.
Neither imports ``so3jax``.
"""
