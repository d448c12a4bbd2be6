"""Random walk on grasps: recovers a known Gaussian (position) × vMF (orientation) target."""

import importlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp import so3

RW = importlib.import_module("jaxgrasp.mcmc.random_walk")  # the module; mcmc exports random_walk()
MEAN = jnp.array([0.1, -0.2, 0.3])
STD = jnp.array([0.05, 0.1, 0.02])
MU = so3.normalize(jnp.array([0.3, -0.5, 0.2, 0.7]))
KAPPA_TARGET = 20.0


def logdensity(g):
    logp = -0.5 * jnp.sum(((g[:3] - MEAN) / STD) ** 2) + KAPPA_TARGET * jnp.dot(g[3:], MU)
    return logp, {"quality": jnp.dot(g[3:], MU)}


def _sample():
    alg = jg.mcmc.random_walk(logdensity, position_scale=1.2 * STD, kappa=40.0)
    num_chains, num_steps = 400, 300
    # all chains start off-target, so this checks convergence as well as invariance
    start = jnp.concatenate([MEAN + 3 * STD, jnp.array([1.0, 0.0, 0.0, 0.0])])
    x0 = jnp.tile(start, (num_chains, 1))
    positions, infos = jg.mcmc.sample(jax.random.key(0), alg, x0, num_steps)
    return np.asarray(positions, np.float64), infos


@pytest.fixture(scope="module")
def run():
    return _sample()


def _check(per_chain, expected, name):
    """per_chain: (C, k) time-averages of independent chains; 5 MCSE tolerance."""
    mean = per_chain.mean(axis=0)
    mcse = per_chain.std(axis=0, ddof=1) / np.sqrt(per_chain.shape[0])
    assert np.all(np.abs(mean - expected) < 5 * mcse), (name, mean, expected, mcse)


def test_recovers_gaussian_times_vmf(run):
    _check_moments(run[0])


def test_companion_a_kernel_that_accepts_everything_fails(break_library):
    # The library's own kernel with its Metropolis test broken: a plain random walk.
    break_library(RW, "mh_accept", lambda key, log_ratio: (jnp.array(True), jnp.array(1.0)))
    with pytest.raises(AssertionError):
        _check_moments(_sample()[0])


def _check_moments(positions):
    tail = positions[150:]
    _check(tail[..., :3].mean(0), np.asarray(MEAN), "position mean")
    _check(((tail[..., :3] - np.asarray(MEAN)) ** 2).mean(0), np.asarray(STD) ** 2, "variance")
    a = so3.vmf_mean_resultant_length(KAPPA_TARGET)
    _check((tail[..., 3:] @ np.asarray(MU)).mean(0)[:, None], np.array([a]), "resultant")


def test_quaternion_stays_unit_and_info(run):
    positions, infos = run
    np.testing.assert_allclose(np.linalg.norm(positions[..., 3:], axis=-1), 1.0, atol=1e-5)
    acc = float(infos.is_accepted.mean())
    assert 0.05 < acc < 0.95
    # aux of the evaluated proposal passes through
    np.testing.assert_allclose(
        infos.aux["quality"], np.asarray(infos.proposal)[..., 3:] @ np.asarray(MU), atol=1e-5
    )
    assert not np.any(np.asarray(infos.is_jump))


def test_symmetric_acceptance_formula():
    """acceptance_rate = min(1, π(g*)/π(g)) for one step."""
    alg = jg.mcmc.random_walk(lambda g: -jnp.sum(g**2), position_scale=0.1, kappa=10.0)
    state = jax.jit(alg.init)(jnp.array([0.1, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]))
    new, info = jax.jit(alg.step)(jax.random.key(3), state)
    ratio = np.exp(min(0.0, float(info.logdensity - state.logdensity)))
    assert float(info.acceptance_rate) == pytest.approx(ratio, rel=1e-5)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"position_scale": -0.1, "kappa": 1.0}, "non-negative"),
        ({"position_scale": 0.1, "kappa": -1.0}, "kappa"),
        ({"position_scale": jnp.ones(2), "kappa": 1.0}, "position_scale"),
        (
            {"position_scale": jnp.array([[1.0, 2.0, 0], [2.0, 1.0, 0], [0, 0, 1]]), "kappa": 1.0},
            "positive-definite",
        ),
        ({"position_scale": float("nan"), "kappa": 1.0}, "finite"),
    ],
)
def test_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        jg.mcmc.random_walk(lambda g: 0.0, **kwargs)


def test_bad_position():
    alg = jg.mcmc.random_walk(lambda g: 0.0, position_scale=0.1, kappa=1.0)
    with pytest.raises(ValueError, match=r"\(7,\)"):
        alg.init(jnp.zeros(6))
    with pytest.raises(ValueError, match="non-finite"):
        alg.init(jnp.full(7, jnp.nan))
