"""Independent reference implementations of the paper's closed loop, for speed and cross-checks.

``numpy_loop.simulate`` (NumPy, a Python loop over steps, vectorized over the batch) and
``numba_loop.simulate`` (Numba, scalar, prange over the batch; needs numba) share one
signature and result; ``numba_dispersed.simulate_dispersed`` (Numba) flies every
trajectory of a batch in its own scenario, as a sweep's samples; ``noise.paper_noise``
draws the disturbance noise of docs/model.md §4. Their loops do not call ``so3jax``'s
(``numba_noise`` takes the inverse error function's coefficients from
``so3jax.core._erfinv``).
"""
