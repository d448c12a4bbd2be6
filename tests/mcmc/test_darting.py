"""GDMC jump regions and the combined Kameleon-darting kernel."""

import importlib
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp.mcmc.darting import jump_log_ratio, jump_proposal, make_regions, region_membership

DARTING = importlib.import_module("jaxgrasp.mcmc.darting")

# ---------------------------------------------------------------- regions


def test_volume_uses_sqrt_of_eigenvalues():
    """A 2-D ellipse with semi-axes ε·sqrt(λ) has area π ε² sqrt(λ1 λ2)."""
    cov = np.array([[4.0, 0.0], [0.0, 0.25]])
    regions = make_regions(np.zeros((1, 2)), cov, epsilon=0.7)
    assert float(jnp.exp(regions.log_volumes[0])) == pytest.approx(math.pi * 0.49 * 1.0, rel=1e-5)
    # 3-D ball of radius ε: 4/3 π ε³
    regions = make_regions(np.zeros((1, 3)), np.eye(3), epsilon=2.0)
    assert float(jnp.exp(regions.log_volumes[0])) == pytest.approx(4 / 3 * math.pi * 8, rel=1e-5)


def test_jump_map_is_a_bijection_between_regions():
    """From region i the map lands in region j at the same Mahalanobis radius; j -> i undoes it."""
    rng = np.random.default_rng(0)
    a = rng.normal(size=(3, 3, 3))
    covs = a @ np.swapaxes(a, -1, -2) + 0.1 * np.eye(3)
    modes = np.array([[0.0, 0, 0], [10.0, 0, 0], [0, 10.0, 0]])
    regions = make_regions(modes, covs, epsilon=1.0)
    x = jnp.asarray(modes[0] + 0.3 * np.linalg.cholesky(covs[0]) @ np.array([0.5, -0.5, 0.7]))
    maha = lambda x, i: float((x - modes[i]) @ np.linalg.solve(covs[i], x - modes[i]))  # noqa: E731
    propose = jax.jit(jump_proposal)
    landed = set()
    for s in range(40):
        x_new, n_x, n_new = propose(jax.random.key(s), x, regions)
        j = int(np.argmin(np.linalg.norm(modes - np.asarray(x_new), axis=1)))
        landed.add(j)
        assert int(n_x) == 1 and int(n_new) == 1
        assert maha(np.asarray(x_new, np.float64), j) == pytest.approx(
            maha(np.asarray(x), 0), rel=1e-4
        )
        # the reverse map (source j, target 0) returns to x
        w = (
            np.linalg.inv(np.diag(np.asarray(regions.sqrt_eigvals[j])))
            @ np.asarray(regions.rotations[j]).T
            @ (np.asarray(x_new) - modes[j])
        )
        back = modes[0] + np.asarray(regions.rotations[0]) @ (
            np.asarray(regions.sqrt_eigvals[0]) * w
        )
        np.testing.assert_allclose(back, x, atol=1e-4)
    assert landed == {0, 1, 2}


def test_outside_every_region_stays():
    regions = make_regions(np.zeros((2, 2)) + [[0, 0], [5, 0]], np.eye(2), epsilon=0.5)
    x = jnp.array([2.5, 0.0])
    assert not np.any(np.asarray(region_membership(x, regions)))
    x_new, n_x, _ = jax.jit(jump_proposal)(jax.random.key(0), x, regions)
    np.testing.assert_array_equal(x_new, x)
    assert int(n_x) == 0
    assert float(jump_log_ratio(jnp.float32(0.0), jnp.float32(0.0), n_x, n_x)) == -np.inf


def test_acceptance_ratio_is_the_correct_one():
    """min(1, π(x') n(x) / (π(x) n(x'))), not the paper's inverted ratio."""
    got = jump_log_ratio(jnp.float32(-1.0), jnp.float32(-3.0), jnp.int32(2), jnp.int32(1))
    assert float(got) == pytest.approx(-1.0 + 3.0 + math.log(2.0))


# ---------------------------------------------------------------- unequal-weight mixture

WEIGHTS = jnp.array([0.3, 0.7])
MODES = jnp.array([[-5.0, 0.0], [5.0, 0.0]])
SDS = jnp.array([[0.5, 0.5], [1.0, 0.5]])
# different region shapes per mode: exercises the volume-weighted target choice
REGION_COV = jnp.array([np.diag([0.25, 0.25]), np.diag([1.0, 0.25])])
NUM_CHAINS, NUM_STEPS = 400, 300
KAMELEON = {"gamma": 0.1, "nu": 0.15, "sigma": 1.0, "adapt_steps": 50}


def mixture_logdensity(x):
    comps = (
        jnp.log(WEIGHTS) - 0.5 * jnp.sum(((x - MODES) / SDS) ** 2, -1) - jnp.sum(jnp.log(SDS), -1)
    )
    return jax.scipy.special.logsumexp(comps)


@pytest.fixture(scope="module")
def mixture():
    labels = jax.random.bernoulli(jax.random.key(0), 0.7, (500,)).astype(jnp.int32)
    sketch = MODES[labels] + SDS[labels] * jax.random.normal(jax.random.key(1), (500, 2))
    # every chain starts in the light mode
    x0 = MODES[0] + 0.1 * jax.random.normal(jax.random.key(2), (NUM_CHAINS, 2))
    return sketch, x0


def test_local_kernel_stays_in_its_mode(mixture):
    sketch, x0 = mixture
    alg = jg.mcmc.kameleon(mixture_logdensity, sketch, **KAMELEON)
    positions, infos = jg.mcmc.sample(jax.random.key(3), alg, x0, NUM_STEPS)
    assert not np.any(np.asarray(positions[..., 0]) > 0)
    assert float(infos.is_accepted.mean()) > 0.2  # it moves, just not across


def _darting_run(mixture):
    sketch, x0 = mixture
    alg = jg.mcmc.kameleon_darting(
        mixture_logdensity, sketch, MODES, region_cov=REGION_COV, epsilon=1.5, **KAMELEON
    )
    return jg.mcmc.sample(jax.random.key(4), alg, x0, NUM_STEPS)


def _check_mode_weight(positions):
    in_heavy = (np.asarray(positions[NUM_STEPS // 2 :, :, 0]) > 0).mean(axis=0)  # per chain
    mcse = in_heavy.std(ddof=1) / np.sqrt(NUM_CHAINS)
    assert abs(in_heavy.mean() - 0.7) < 4 * mcse + 1e-3, (in_heavy.mean(), mcse)


def test_darting_recovers_mode_weights(mixture):
    positions, infos = _darting_run(mixture)
    _check_mode_weight(positions)
    is_jump = np.asarray(infos.is_jump)
    assert abs(is_jump.mean() - 0.4) < 0.01  # 1 − p_check
    assert np.asarray(infos.is_accepted)[is_jump].mean() > 0.3


def test_companion_jumps_to_regions_chosen_uniformly_fail(mixture, break_library):
    # The default jump picks its target region in proportion to its volume, which cancels the
    # map's Jacobian. The library's kernel with equal volumes (the regions here differ 2x)
    # picks uniformly and no longer keeps the mode weights.
    break_library(DARTING, "log_ellipsoid_volume", lambda eigvals, epsilon, d: jnp.zeros(
        jnp.shape(eigvals)[:-1]))
    with pytest.raises(AssertionError):
        _check_mode_weight(_darting_run(mixture)[0])


def test_one_target_evaluation_per_step():
    calls = []

    def logdensity(x):
        calls.append(1)
        return -0.5 * jnp.sum(x**2), {"tag": jnp.sum(x)}

    sketch = jax.random.normal(jax.random.key(5), (20, 2))
    alg = jg.mcmc.kameleon_darting(logdensity, sketch, sketch[:3], gamma=0.1)
    state = alg.init(jnp.zeros(2))
    calls.clear()
    _, info = jax.make_jaxpr(alg.step, return_shape=True)(jax.random.key(6), state)[1]
    assert len(calls) == 1
    assert set(info.aux) == {"tag"}


@pytest.mark.parametrize(
    "modes, kwargs, match",
    [
        (np.zeros((2, 3)), {}, "dimension|shape"),
        (np.zeros((0, 2)), {}, "at least 1"),
        (np.zeros((2, 2)), {"region_cov": np.eye(3)}, "region_cov"),
        (np.zeros((2, 2)), {"region_cov": np.ones((2, 2))}, "positive definite"),
        (np.zeros((2, 2)), {"region_cov": np.array([[1.0, 0.5], [0.0, 1.0]])}, "symmetric"),
        (np.zeros((2, 2)), {"region_cov": np.ones((3, 2, 2))}, "region_cov"),
        (np.zeros((2, 2)), {"epsilon": 0.0}, "epsilon"),
        (np.zeros((2, 2)), {"p_check": 1.5}, "p_check"),
        (np.zeros((2, 2)), {"p_check": -0.1}, "p_check"),
        (np.array([[0.0, np.inf]]), {}, "non-finite"),
    ],
)
def test_bad_arguments(modes, kwargs, match):
    sketch = np.random.default_rng(0).normal(size=(10, 2))
    with pytest.raises(ValueError, match=match):
        jg.mcmc.kameleon_darting(lambda x: 0.0, sketch, modes, **kwargs)
