"""The Numba draw of the paper's disturbance noise (benchmarks/baselines/numba_noise.py) is
JAX's, bit for bit: Threefry-2x32, the key words of a seed, the inverse error function,
eta_k = normal(fold_in(key(seed), k), (3,), float64), and the Numba baseline's loop
with the noise drawn in the kernel (noise="draw") against the same loop fed
paper_noise_batch."""

import jax
import jax.extend.random
import jax.numpy as jnp
import numpy as np
import pytest

pytest.importorskip("numba")

from benchmarks.baselines import numba_loop, numba_noise, numpy_loop
from benchmarks.baselines.noise import paper_noise_batch
from tests.test_baselines_agree import assert_results_close

SEEDS = [0, 1, 5, 2**31 - 1]
STEPS = [0, 1, 7, 2**20, 2**31 - 1, 2**32 - 1]


def jax_eta(seed, k):
    """docs/model.md §4's eta_k, drawn as benchmarks/baselines/noise.py draws it."""
    with jax.enable_x64(True):
        key = jax.random.fold_in(jax.random.key(seed), np.uint32(k))
        return np.asarray(jax.random.normal(key, (3,), np.float64))


def assert_ulp_close(got, expected, maxulp=2):
    """Equal to an ulp or two: bit for bit on an x86-64 CPU with FMA (numba_noise's docstring),
    within an ulp where XLA rounds its polynomials otherwise (another CPU, another XLA)."""
    got, expected = np.asarray(got), np.asarray(expected)
    finite = np.isfinite(expected)
    np.testing.assert_array_equal(got[~finite], expected[~finite])
    np.testing.assert_array_max_ulp(got[finite], expected[finite], maxulp=maxulp)


def test_threefry2x32_matches_jax():
    rng = np.random.default_rng(0)
    words = rng.integers(0, 2**32, (400, 4), dtype=np.uint64).astype(np.uint32)
    words[:4] = [[0, 0, 0, 0], [2**32 - 1] * 4, [0, 5, 0, 7], [0x1BD11BDA, 0, 2**31, 1]]
    y0, y1 = jax.extend.random.threefry2x32_p.bind(*(jnp.asarray(words[:, i]) for i in range(4)))
    got = np.array([numba_noise.threefry2x32(*w) for w in words], dtype=np.uint64)
    np.testing.assert_array_equal(got[:, 0], np.asarray(y0))
    np.testing.assert_array_equal(got[:, 1], np.asarray(y1))


def test_key_words_match_jax():
    for seed in SEEDS + [12345, np.int64(7)]:
        for x64 in (False, True):
            with jax.enable_x64(x64):
                expected = tuple(int(v) for v in np.asarray(jax.random.key_data(jax.random.key(seed))))
            assert numba_noise.key_words(seed) == expected, (seed, x64)
    np.testing.assert_array_equal(numba_noise.key_array([3, 9]), np.array([[0, 3], [0, 9]], np.uint32))
    for seed in (-1, 2**31, 2**40):  # JAX's key data for these depends on jax_enable_x64
        with pytest.raises(ValueError, match="seed"):
            numba_noise.key_words(seed)
    with pytest.raises(TypeError):
        numba_noise.key_words(1.0)


def erfinv_inputs():
    """Uniform on (-1, 1); near +-1 (1 - 10^-u, u in [1, 16]); tiny (10^-u, u in [0, 320], subnormals
    included); the branch points w = 6.25, w = 16 and other special values."""
    rng = np.random.default_rng(1)
    n = 100_000
    sign = rng.choice([-1.0, 1.0], n)
    tiny = np.finfo(np.float64).tiny
    specials = [0.0, -0.0, 1.0, -1.0, 0.5, -0.5, numba_noise.LO, np.nextafter(1.0, 0.0), np.nextafter(-1.0, 0.0),
                0.999, 0.99903, 0.999031, np.sqrt(1 - np.exp(-6.25)), np.sqrt(1 - np.exp(-16.0)), 2**-53, -(2**-52),
                1e-300, -1.1e-300, tiny, -tiny, 2.5e-308, -2.6e-308, 5e-324, -1e-310]  # fmt: skip
    return np.concatenate([rng.uniform(-1, 1, n), sign * (1 - 10.0 ** -rng.uniform(1, 16, n)),
                           sign * 10.0 ** -rng.uniform(0, 320, n), specials])  # fmt: skip


@pytest.mark.optimized  # XLA's erf_inv as a user's program computes it
def test_erfinv_matches_xla():
    x = erfinv_inputs()
    expected = np.asarray(jax.jit(jax.lax.erf_inv)(x))
    got = np.array([numba_noise.erfinv(v) for v in x])
    assert_ulp_close(got, expected)  # also +-inf at +-1
    assert np.isinf(got[np.abs(x) == 1]).all()


@pytest.mark.optimized  # XLA's erf_inv as a user's program computes it
def test_chunked_erfinv_matches_xla():
    """The vectorized passes fill_eta uses give the same values, the rare branches included."""
    x = erfinv_inputs()
    expected = np.asarray(jax.jit(lambda u: np.sqrt(2.0) * jax.lax.erf_inv(u))(x))
    got = np.full_like(x, 42.0)
    numba_noise._sqrt2_erfinv(x, x.size, got)
    assert_ulp_close(got, expected)


@pytest.mark.parametrize("seed", SEEDS)
def test_paper_eta_matches_jax(seed):
    kw = numba_noise.key_words(seed)
    for k in STEPS:
        assert_ulp_close(np.array(numba_noise.paper_eta(*kw, k)), jax_eta(seed, k))
    eta = paper_noise_batch([seed], 8)[0]
    got = np.array([numba_noise.paper_eta(*kw, k) for k in range(8)])
    assert_ulp_close(got, eta)


@pytest.mark.optimized  # XLA's erf_inv as a user's program computes it
def test_fill_eta_matches_paper_noise_batch():
    """Chunks of 256 steps and a ragged last one; 3 x 6000 draws, about 18 of them |u| > 0.999."""
    seeds, n, chunk = [0, 3], 3000, 256
    expected = paper_noise_batch(seeds, n)
    got = np.full((len(seeds), n, 3), np.nan)
    out, scratch = np.empty((chunk, 3)), np.empty(3 * chunk)
    for b, kw in enumerate(numba_noise.key_array(seeds)):
        for k0 in range(0, n, chunk):
            nk = min(chunk, n - k0)
            numba_noise.fill_eta(kw[0], kw[1], k0, nk, out, scratch)
            got[b, k0 : k0 + nk] = out[:nk]
    assert_ulp_close(got, expected)


@pytest.mark.parametrize("controller", ["pd", "adaptive"])
def test_numba_loop_draws_the_noise_it_is_given(controller):
    seeds, n_steps = [0, 5], 600  # 600 steps: three chunks of the kernel, the last one ragged
    drawn = numba_loop.simulate(controller, n_steps, seeds, noise="draw")
    given = numba_loop.simulate(controller, n_steps, seeds, noise=paper_noise_batch(seeds, n_steps))
    assert_results_close(drawn, given, rtol=1e-12)
    assert (drawn["Theta"] is None) == (controller == "pd")


def test_draw_argument_checks():
    with pytest.raises(ValueError, match="noise"):
        numba_loop.simulate("pd", 10, [0], noise="drawn")
    with pytest.raises(ValueError, match="noise"):
        numpy_loop.simulate("pd", 10, [0], noise="draw")  # the NumPy baseline takes arrays only
    with pytest.raises(ValueError, match="seed"):
        numba_loop.simulate("pd", 10, [-1], noise="draw")
