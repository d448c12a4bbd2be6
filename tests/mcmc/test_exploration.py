"""The exploration options stay exact: jumps to uniform points of the target region, and the
proposal scale adapted toward a target acceptance during burn-in (frozen after)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp.types import SamplingAlgorithm

WEIGHTS = jnp.array([0.3, 0.7])
MODES = jnp.array([[-5.0, 0.0], [5.0, 0.0]])
SDS = jnp.array([[0.5, 0.5], [1.0, 0.5]])
# regions of different volumes (ratio 2): a jump must pick its target region ∝ volume
REGION_COV = jnp.array([np.diag([0.25, 0.25]), np.diag([1.0, 0.25])])
NUM_CHAINS, NUM_STEPS, ADAPT = 400, 300, 50
KAMELEON = {"gamma": 0.5, "nu": 0.15, "sigma": 1.0, "adapt_steps": ADAPT}


def mixture_logdensity(x):
    comps = (
        jnp.log(WEIGHTS) - 0.5 * jnp.sum(((x - MODES) / SDS) ** 2, -1) - jnp.sum(jnp.log(SDS), -1)
    )
    return jax.scipy.special.logsumexp(comps)


def exact_draws(key, n):
    k1, k2 = jax.random.split(key)
    labels = jax.random.bernoulli(k1, WEIGHTS[1], (n,)).astype(jnp.int32)
    return MODES[labels] + SDS[labels] * jax.random.normal(k2, (n, 2))


@pytest.fixture(scope="module")
def setup():
    sketch = exact_draws(jax.random.key(0), 500)
    x0 = exact_draws(jax.random.key(1), NUM_CHAINS)  # exact start: a right kernel keeps it
    return sketch, x0


def _algorithm(sketch, **kw):
    return jg.mcmc.kameleon_darting(mixture_logdensity, sketch, MODES, region_cov=REGION_COV,
                                    epsilon=1.5, uniform_jumps=True, target_acceptance=0.3,
                                    **KAMELEON, **kw)


def _heavy_share(alg, x0, key):
    positions, infos = jg.mcmc.sample(key, alg, x0, NUM_STEPS)
    tail = np.asarray(positions[ADAPT + 50:], np.float64)  # after burn-in
    in_heavy = (tail[..., 0] > 0).mean(axis=0)  # per chain: independent draws
    return in_heavy.mean(), in_heavy.std(ddof=1) / np.sqrt(NUM_CHAINS), tail, infos


def test_uniform_jumps_with_adaptation_are_exact(setup):
    sketch, x0 = setup
    share, mcse, tail, infos = _heavy_share(_algorithm(sketch), x0, jax.random.key(2))
    assert abs(share - 0.7) < 4 * mcse + 1e-3, (share, mcse)
    # the second coordinate: N(0, 0.5^2) in both modes; its quantiles against exact ones
    ref = np.quantile(np.asarray(exact_draws(jax.random.key(3), 200_000))[:, 1],
                      [0.05, 0.25, 0.5, 0.75, 0.95])
    ind = (tail[:, :, 1, None] < ref).mean(axis=0)  # (C, 5)
    z = (ind.mean(axis=0) - [0.05, 0.25, 0.5, 0.75, 0.95]) / (
        ind.std(axis=0, ddof=1) / np.sqrt(NUM_CHAINS))
    assert np.all(np.abs(z) < 4.5), z
    jumps = np.asarray(infos.is_jump)
    assert np.asarray(infos.is_accepted)[jumps].mean() > 0.2  # jumps do cross


def test_uniform_target_choice_is_detected(setup):
    """Companion: picking the target region uniformly (ignoring the volumes) with the same
    acceptance is biased, and the test above would see it."""
    sketch, x0 = setup
    alg = _algorithm(sketch)
    kw = dict(alg.step.keywords)
    kw["regions"] = kw["regions"]._replace(log_volumes=jnp.zeros(2))
    wrong = SamplingAlgorithm(alg.init, jax.tree_util.Partial(alg.step.func, **kw))
    share, mcse, _, _ = _heavy_share(wrong, x0, jax.random.key(2))
    assert abs(share - 0.7) > 8 * mcse, (share, mcse)


def test_scale_adapts_in_burn_in_then_freezes():
    sketch = jax.random.normal(jax.random.key(4), (200, 3))
    logdensity = lambda x: -0.5 * jnp.sum(x**2)  # noqa: E731
    # γ = 5 is far too wide for N(0, I): λ must shrink toward 0.3 acceptance
    alg = jg.mcmc.kameleon(logdensity, sketch, gamma=5.0, nu=0.1, adapt_steps=100,
                           target_acceptance=0.3)
    state = jax.vmap(alg.init)(jax.random.normal(jax.random.key(5), (256, 3)))
    step = jax.jit(jax.vmap(alg.step))
    scales, accepted = [], []
    for t in range(200):
        state, info = step(jax.random.split(jax.random.fold_in(jax.random.key(6), t), 256),
                           state)
        scales.append(np.asarray(state.log_scale))
        accepted.append(np.asarray(info.is_accepted))
    scales = np.asarray(scales)
    assert np.all(scales[99:] == scales[99])  # frozen once burn-in is over
    assert np.median(scales[-1]) < -1.0  # it shrank
    acc = np.asarray(accepted[100:]).mean()
    assert 0.15 < acc < 0.5, acc
    # without adaptation the same kernel barely moves
    fixed = jg.mcmc.kameleon(logdensity, sketch, gamma=5.0, nu=0.1, adapt_steps=100)
    _, infos = jg.mcmc.sample(jax.random.key(7), fixed, jnp.zeros((64, 3)), 50)
    assert float(infos.is_accepted.mean()) < 0.1


def test_bad_target_acceptance():
    with pytest.raises(ValueError, match="target_acceptance"):
        jg.mcmc.kameleon(lambda x: 0.0, np.zeros((4, 2)) + np.arange(4)[:, None],
                         target_acceptance=1.5)
