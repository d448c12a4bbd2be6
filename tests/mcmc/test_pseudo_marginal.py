"""Pseudo-marginal MH: a stochastic target (a non-negative, unbiased estimate of the density
per evaluation) is sampled exactly when the current state's estimate is kept, and not when it
is refreshed every step (the companion)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp.mcmc.mh import logdensity_and_aux

S1, B = 10.0, 0.1  # the banana of tests/mcmc/test_kameleon.py
SMOOTH = 1.0  # the estimate averages the banana over N(0, SMOOTH^2) offsets
KEEP = 0.2  # chance of a non-zero estimate where x1 > 0
NUM_CHAINS, NUM_STEPS, TAIL = 4000, 200, 100
QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95)
MODES = jnp.array([[-8.0, 3.6], [8.0, 3.6]])  # on the banana's arms: x2 = -B (x1^2 - S1^2)


def banana_logdensity(x):
    return -0.5 * (x[0] / S1) ** 2 - 0.5 * (x[1] + B * (x[0] ** 2 - S1**2)) ** 2


class SmoothedBanana:
    """``q(x + d) / p(x)`` with probability ``p(x)``, else 0; d ~ N(0, SMOOTH^2 I): an
    unbiased, non-negative estimate of the banana smoothed by N(0, SMOOTH^2), whose exact
    samples are banana + SMOOTH z. Its noise depends on x (``p = KEEP`` where x1 > 0, else 1),
    as a grasp's hold-rate estimate does, so refreshing the current state's estimate biases
    the chain."""

    stochastic = True

    def __call__(self, x, key):
        k_offset, k_keep = jax.random.split(key)
        offset = SMOOTH * jax.random.normal(k_offset, x.shape, x.dtype)
        p = jnp.where(x[0] > 0, KEEP, 1.0)
        kept = jax.random.uniform(k_keep, (), x.dtype) < p
        return jnp.where(kept, banana_logdensity(x + offset) - jnp.log(p), -jnp.inf), {}


def smoothed_exact(key, n):
    k1, k2 = jax.random.split(key)
    z = jax.random.normal(k1, (n, 2))
    x1 = S1 * z[:, 0]
    banana = jnp.stack([x1, z[:, 1] - B * (x1**2 - S1**2)], axis=1)
    return banana + SMOOTH * jax.random.normal(k2, (n, 2))


@pytest.fixture(scope="module")
def setup():
    sketch = smoothed_exact(jax.random.key(20), 1000)
    x0 = smoothed_exact(jax.random.key(21), NUM_CHAINS)
    reference = np.asarray(smoothed_exact(jax.random.key(22), 400_000), np.float64)
    return sketch, x0, np.quantile(reference, QUANTILES, axis=0)


def _algorithm(sketch):
    return jg.mcmc.kameleon_darting(SmoothedBanana(), sketch, MODES,
                                    region_cov=jnp.eye(2), epsilon=1.0, gamma=0.1,
                                    subsample_size=20, adapt_steps=0)


def _quantile_z(positions, thresholds):
    """z-scores of P(x_k < threshold) over the last TAIL steps (MCSE across chains)."""
    tail = np.asarray(positions[-TAIL:], np.float64)
    ind = (tail[:, :, None, :] < thresholds[None, None]).mean(axis=0)  # (C, 5, 2)
    mcse = ind.std(axis=0, ddof=1) / np.sqrt(ind.shape[0])
    return (ind.mean(axis=0) - np.asarray(QUANTILES)[:, None]) / mcse


def test_kept_estimate_is_exact(setup):
    sketch, x0, thresholds = setup
    positions, infos = jg.mcmc.sample(jax.random.key(23), _algorithm(sketch), x0, NUM_STEPS)
    z = _quantile_z(positions, thresholds)
    assert np.all(np.abs(z) < 4.5), z
    assert 0.1 < float(infos.is_accepted.mean()) < 0.9  # it moves
    assert 0.2 < float(infos.is_jump.mean()) < 0.6  # jumps and local moves both run


def _refreshing(alg):
    """The same kernel re-estimating the current state every step (Monte Carlo within
    Metropolis): not exact for the smoothed density."""
    target = SmoothedBanana()

    def step(key, state):
        k_fresh, k_step = jax.random.split(key)
        logp, aux = logdensity_and_aux(target, state.position, k_fresh)
        return alg.step(k_step, state._replace(logdensity=logp, aux=aux))

    return jg.types.SamplingAlgorithm(alg.init, step)


def test_companion_refreshing_the_estimate_fails(setup):
    sketch, x0, thresholds = setup
    alg = _refreshing(_algorithm(sketch))
    positions, _ = jg.mcmc.sample(jax.random.key(23), alg, x0, NUM_STEPS)
    z = _quantile_z(positions, thresholds)
    # far outside the exact test's 4.5 (measured 9.0)
    assert np.max(np.abs(z)) > 6.5, z


def test_noise_key_per_step_and_start():
    """Each step's estimate draws new noise; a chain start's draws from its position."""
    target = SmoothedBanana()
    x = jnp.array([-1.0, 2.0])  # where every estimate is non-zero
    a = logdensity_and_aux(target, x, jax.random.key(0))[0]
    b = logdensity_and_aux(target, x, jax.random.key(1))[0]
    c, d = (logdensity_and_aux(target, x)[0] for _ in range(2))
    e = logdensity_and_aux(target, x + 1e-3)[0]
    assert a != b and c == d and c != e
