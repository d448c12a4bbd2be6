"""Kameleon: kernel gradients, the proposal, exactness on a banana (and failure without the
reverse proposal term), adaptation, no retracing, differentiability."""

import importlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import multivariate_normal

import jaxgrasp as jg
from jaxgrasp.mcmc.kameleon import (
    default_nu,
    gaussian_kernel,
    kameleon_proposal_covariance,
    kameleon_proposal_logdensity,
    kameleon_proposal_sample,
    kernel_gradients,
    median_heuristic,
)

KAMELEON = importlib.import_module("jaxgrasp.mcmc.kameleon")  # the module; mcmc exports kameleon()

# ---------------------------------------------------------------- banana target (Haario et al.)
S1, B = 10.0, 0.1  # strongly curved: x2 + B (x1² − S1²) ~ N(0, 1), x1 ~ N(0, S1²)


def banana_logdensity(x):
    return -0.5 * (x[0] / S1) ** 2 - 0.5 * (x[1] + B * (x[0] ** 2 - S1**2)) ** 2


def banana_exact(key, n):
    z = jax.random.normal(key, (n, 2))
    x1 = S1 * z[:, 0]
    return jnp.stack([x1, z[:, 1] - B * (x1**2 - S1**2)], axis=1)


# ---------------------------------------------------------------- proposal pieces


def test_kernel_gradients_match_closed_form():
    key = jax.random.key(0)
    Z = 2.0 * jax.random.normal(key, (50, 3))
    y = jnp.array([0.3, -0.2, 1.0])
    sigma = 1.7
    y_np, Z_np = np.asarray(y, np.float64), np.asarray(Z, np.float64)
    k = np.exp(-np.sum((Z_np - y_np) ** 2, axis=1) / (2 * sigma**2))
    closed = (2.0 / sigma**2) * k[None, :] * (Z_np - y_np).T
    M = jax.jit(kernel_gradients)(y, Z, sigma)
    np.testing.assert_allclose(M, closed, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(jax.jit(gaussian_kernel)(y, Z, sigma), k, rtol=1e-5)


@pytest.mark.compile_bound
def test_proposal_logdensity_and_samples_match_covariance():
    key = jax.random.key(1)
    Z = 2.0 * jax.random.normal(key, (100, 2))
    y = jnp.array([0.5, -0.3])
    sigma, gamma, nu = 1.5, 1e-4, 1.0
    cov = np.asarray(jax.jit(kameleon_proposal_covariance)(y, Z, sigma, gamma, nu), np.float64)
    # explicit formula γ²I + ν² M H Mᵀ with H = I − 11ᵀ/n
    M = np.asarray(jax.jit(kernel_gradients)(y, Z, sigma), np.float64)
    H = np.eye(100) - 1.0 / 100
    np.testing.assert_allclose(cov, gamma**2 * np.eye(2) + nu**2 * M @ H @ M.T, rtol=1e-4)
    logq = jax.jit(kameleon_proposal_logdensity)
    for dx in ([0.1, 0.05], [0.0, 1e-4], [-0.3, 0.2]):
        x = y + jnp.array(dx)
        ref = multivariate_normal(np.asarray(y, np.float64), cov).logpdf(np.asarray(x, np.float64))
        got = float(logq(x, y, Z, sigma, gamma, nu))
        assert got == pytest.approx(ref, rel=2e-4, abs=2e-3)
    keys = jax.random.split(jax.random.key(2), 40000)
    draws = jax.jit(jax.vmap(lambda k: kameleon_proposal_sample(k, y, Z, sigma, 0.1, nu)))(keys)
    emp = np.cov(np.asarray(draws, np.float64).T)
    expected = np.asarray(jax.jit(kameleon_proposal_covariance)(y, Z, sigma, 0.1, nu))
    np.testing.assert_allclose(emp, expected, rtol=0.05, atol=0.05 * np.abs(expected).max())


@pytest.mark.compile_bound
def test_logq_of_grasp_size_matches_float64():
    """d = 7, n = 100 as in a grasp run, γ = 1e-4 next to O(1) kernel directions (a covariance
    of condition ~1e8, hopeless for a float32 Cholesky): the Householder factor in float32
    gives log q within 5e-4 relative of a float64 reference, on rank-deficient A too (the
    float32 LAPACK QR it replaced erred by up to 1.3e-4 on these, the Householder 0.9e-4)."""
    from jaxgrasp.mcmc.kameleon import _logq

    rng = np.random.default_rng(4)
    logq = jax.jit(jax.vmap(_logq, in_axes=(0, 0, 0, None, None)))
    for rank in (7, 2):
        A = rng.standard_normal((16, 7, rank)) @ rng.standard_normal((16, rank, 100)) * 0.05
        y = rng.standard_normal((16, 7))
        # x from the proposal itself: y + γ ξ₁ + ν A ξ₂
        x = (y + 1e-4 * rng.standard_normal((16, 7))
             + 0.9 * np.einsum("bij,bj->bi", A, rng.standard_normal((16, 100))))
        got = np.asarray(logq(*(jnp.asarray(a, jnp.float32) for a in (x, y, A)), 1e-4, 0.9))
        ref = [multivariate_normal(y[i], 1e-8 * np.eye(7) + 0.81 * A[i] @ A[i].T).logpdf(x[i])
               for i in range(16)]
        np.testing.assert_allclose(got, ref, rtol=5e-4)


_TWO_SAMPLERS = """
import importlib
import jax, jax.numpy as jnp, numpy as np
K = importlib.import_module("jaxgrasp.mcmc.kameleon")
rng = np.random.default_rng(0)
A = jnp.asarray(rng.standard_normal((256, 7, 100)), jnp.float32)
y = jnp.asarray(rng.standard_normal((256, 7)), jnp.float32)
f = jax.jit(jax.vmap(lambda x, y, A: K._logq(x, y, A, 0.1, 0.5)))
"""


def test_two_samplers_at_once_do_not_hang(on_two_pool_threads):
    """log q of 256 chains on two threads at once (two cohort members' steps) on a 2-thread
    XLA pool (``PJRT_NPROC=2``) finishes. With ``jnp.linalg.qr`` (jaxlib's batched LAPACK QR,
    which splits the batch over that pool and blocks there) both threads were still waiting
    after 120 s, twice in two runs on this project's 2-core machine."""
    on_two_pool_threads(_TWO_SAMPLERS, "f(y + 0.1, y, A).block_until_ready()", repeats=200,
                        stall_s=60)


@pytest.mark.compile_bound
def test_proposal_is_differentiable_in_tunables_and_position():
    """Reparameterized draws: d x*/d ν = M H ξ₂ etc.; log q has finite gradients."""
    key = jax.random.key(3)
    Z = jax.random.normal(key, (30, 2))
    y = jnp.array([0.2, 0.1])
    k = jax.random.key(4)
    f = jax.jit(
        lambda nu, gamma, sigma, y: jnp.sum(kameleon_proposal_sample(k, y, Z, sigma, gamma, nu))
    )
    g_nu, g_gamma, g_sigma, g_y = jax.jit(jax.grad(f, argnums=(0, 1, 2, 3)))(1.0, 0.1, 1.0, y)
    eps = 1e-2
    fd_nu = (f(1.0 + eps, 0.1, 1.0, y) - f(1.0 - eps, 0.1, 1.0, y)) / (2 * eps)
    fd_sigma = (f(1.0, 0.1, 1.0 + eps, y) - f(1.0, 0.1, 1.0 - eps, y)) / (2 * eps)
    assert float(g_nu) == pytest.approx(float(fd_nu), rel=1e-3)
    assert float(g_sigma) == pytest.approx(float(fd_sigma), rel=2e-2)
    assert np.all(np.isfinite(np.asarray(g_y))) and np.isfinite(float(g_gamma))
    x = y + 0.3
    logq = jax.jit(lambda nu, gamma, sigma: kameleon_proposal_logdensity(x, y, Z, sigma, gamma, nu))
    grads = jax.jit(jax.grad(logq, argnums=(0, 1, 2)))(1.0, 0.1, 1.0)
    fd = (logq(1.0 + eps, 0.1, 1.0) - logq(1.0 - eps, 0.1, 1.0)) / (2 * eps)
    assert float(grads[0]) == pytest.approx(float(fd), rel=1e-2)
    assert all(np.isfinite(float(g)) for g in grads)


def test_defaults():
    assert default_nu(7) == pytest.approx(2.38 / np.sqrt(6))
    assert default_nu(2) == pytest.approx(2.38 / np.sqrt(2))
    pts = np.array([[0.0, 0.0], [3.0, 0.0], [0.0, 4.0]])  # distances 3, 4, 5
    assert median_heuristic(pts) == pytest.approx(4.0)


# ---------------------------------------------------------------- exactness on the banana

NUM_CHAINS, NUM_STEPS, TAIL, GAMMA = 1000, 160, 80, 0.1
QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95)


@pytest.fixture(scope="module")
def banana_setup():
    sketch = banana_exact(jax.random.key(10), 1000)
    # chains start from exact draws: a correct kernel keeps them exactly distributed
    x0 = banana_exact(jax.random.key(11), NUM_CHAINS)
    reference = np.asarray(banana_exact(jax.random.key(12), 400_000), np.float64)
    thresholds = np.quantile(reference, QUANTILES, axis=0)  # (5, 2)
    return sketch, x0, thresholds


def _quantile_z(positions, thresholds):
    """z-scores of P(x_k < threshold) over the last TAIL steps vs the nominal quantiles.

    Each chain's time-average of the indicator is one independent draw, so the Monte Carlo
    standard error is the across-chain standard deviation over sqrt(C).
    """
    tail = np.asarray(positions[-TAIL:], np.float64)  # (T, C, 2)
    ind = (tail[:, :, None, :] < thresholds[None, None]).mean(axis=0)  # (C, 5, 2)
    frac = ind.mean(axis=0)
    mcse = ind.std(axis=0, ddof=1) / np.sqrt(ind.shape[0])
    return (frac - np.asarray(QUANTILES)[:, None]) / mcse


def test_kameleon_exact_on_banana(banana_setup):
    sketch, x0, thresholds = banana_setup
    alg = jg.mcmc.kameleon(banana_logdensity, sketch, gamma=GAMMA, adapt_steps=0)
    positions, infos = jg.mcmc.sample(jax.random.key(13), alg, x0, NUM_STEPS)
    z = _quantile_z(positions, thresholds)
    assert np.all(np.abs(z) < 4.5), z
    acc = float(infos.is_accepted.mean())
    assert 0.2 < acc < 0.99, acc  # the chain moves (measured ≈ 0.8)


def test_dropping_reverse_term_breaks_exactness(banana_setup, break_library):
    """The companion of the exactness test: the library's own kernel without its Hastings
    term log q(y|x*) − log q(x*|y) is clearly biased on the same check."""
    sketch, x0, thresholds = banana_setup
    break_library(KAMELEON, "_logq", lambda x_new, y, A, gamma, nu: jnp.zeros((), x_new.dtype))
    alg = jg.mcmc.kameleon(banana_logdensity, sketch, gamma=GAMMA, adapt_steps=0)
    positions, _ = jg.mcmc.sample(jax.random.key(13), alg, x0, NUM_STEPS)
    z_wrong = _quantile_z(positions, thresholds)
    assert np.max(np.abs(z_wrong)) > 8.0, z_wrong


# ---------------------------------------------------------------- adaptation, retracing


@pytest.mark.compile_bound
def test_subsample_adapts_then_freezes():
    sketch = jax.random.normal(jax.random.key(20), (300, 2))
    alg = jg.mcmc.kameleon(lambda x: -0.5 * jnp.sum(x**2), sketch, gamma=0.1, adapt_steps=4)
    seen = []
    _, _, state = jg.mcmc.sample(
        jax.random.key(21),
        alg,
        jnp.zeros((3, 2)),
        7,
        chunk_size=1,
        callback=lambda t, s, p, i: seen.append(np.asarray(s.subsample)),
        return_state=True,
    )
    changed = [not np.array_equal(seen[i], seen[i - 1]) for i in range(1, 7)]
    assert changed == [True, True, True, False, False, False]
    assert np.asarray(state.step).tolist() == [7, 7, 7]
    assert np.asarray(state.history_count).tolist() == [4, 4, 4]
    # history rows are the chain states x_0..x_3
    assert np.all(np.asarray(state.history)[:, 0] == 0.0)


@pytest.mark.compile_bound
def test_no_retrace_when_tunables_change():
    traces = []

    def logdensity(x):
        traces.append(1)  # runs only while tracing
        return -0.5 * jnp.sum(x**2)

    sketch = jax.random.normal(jax.random.key(30), (50, 2))
    x0 = jnp.zeros((4, 2))
    counts = []
    for nu, gamma, sigma in [(1.0, 0.1, 1.0), (0.5, 0.2, 2.0), (2.0, 1e-4, 0.7)]:
        alg = jg.mcmc.kameleon(logdensity, sketch, gamma=gamma, nu=nu, sigma=sigma)
        jg.mcmc.sample(jax.random.key(31), alg, x0, 5)
        counts.append(len(traces))
    after_first = counts[0]
    assert counts == [after_first] * 3
    assert len(traces) == after_first > 0
    # a new sketch of the same shape does not retrace either
    alg = jg.mcmc.kameleon(logdensity, sketch + 1.0, gamma=0.1, nu=1.0, sigma=1.0)
    jg.mcmc.sample(jax.random.key(31), alg, x0, 5)
    assert len(traces) == after_first


@pytest.mark.parametrize(
    "sketch, kwargs, match",
    [
        (np.zeros((1, 2)), {}, "at least 2"),
        (np.zeros(5), {}, "dimensions"),
        (np.array([[0.0, np.nan], [1.0, 1.0]]), {}, "non-finite"),
        (np.random.default_rng(0).normal(size=(10, 2)), {"gamma": -1.0}, "gamma"),
        (np.random.default_rng(0).normal(size=(10, 2)), {"gamma": 0.0}, "positive"),
        (np.random.default_rng(0).normal(size=(10, 2)), {"nu": -1.0}, "nu"),
        (np.random.default_rng(0).normal(size=(10, 2)), {"sigma": -1.0}, "sigma"),
        (np.random.default_rng(0).normal(size=(10, 2)), {"subsample_size": 0}, "subsample"),
        (np.random.default_rng(0).normal(size=(10, 2)), {"adapt_steps": -1}, "adapt_steps"),
        (np.zeros((10, 2)), {}, "median heuristic"),
    ],
)
def test_bad_arguments(sketch, kwargs, match):
    with pytest.raises(ValueError, match=match):
        jg.mcmc.kameleon(lambda x: 0.0, sketch, **kwargs)


def test_bad_position():
    alg = jg.mcmc.kameleon(lambda x: 0.0, np.eye(3))
    with pytest.raises(ValueError, match=r"\(3,\)"):
        alg.init(jnp.zeros(2))
    with pytest.raises(ValueError, match="non-finite"):
        alg.init(jnp.array([0.0, jnp.inf, 0.0]))
