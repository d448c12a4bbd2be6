"""Kameleon darting on the lifted R^7 grasp space keeps a known Gaussian × vMF grasp target
(slow: a 7-D run with 300 chains)."""

import importlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp import so3

LIFT = importlib.import_module("jaxgrasp.mcmc.lift")
MEAN = jnp.array([0.1, -0.2, 0.3])
STD = jnp.array([0.05, 0.1, 0.02])
MU = so3.normalize(jnp.array([0.3, -0.5, 0.2, 0.7]))
KAPPA, WIDTH = 20.0, 0.05


def grasp_logdensity(g):
    return -0.5 * jnp.sum(((g[:3] - MEAN) / STD) ** 2) + KAPPA * jnp.dot(g[3:], MU)


def exact_lifted(key, n):
    """Exact draws of the lifted target: grasp ~ π, |q| ~ LogNormal(0, WIDTH²)."""
    k1, k2, k3 = jax.random.split(key, 3)
    pos = MEAN + STD * jax.random.normal(k1, (n, 3))
    q = jax.vmap(lambda k: so3.sample_vmf(k, MU, KAPPA))(jax.random.split(k2, n))
    r = jnp.exp(WIDTH * jax.random.normal(k3, (n, 1)))
    return jnp.concatenate([pos, r * q], axis=1)


NUM_CHAINS, NUM_STEPS = 300, 600


@pytest.mark.slow
def test_kameleon_darting_on_lifted_grasps():
    positions, infos = _run()
    for name, ok in _moments_within_mcse(positions).items():
        assert ok, name
    assert float(infos.is_accepted.mean()) > 0.2


@pytest.mark.slow
def test_companion_lift_without_its_jacobian_fails(break_library):
    # The lifted density without the 1/r^4 of polar coordinates on R^4: |q| is no longer
    # LogNormal(0, w^2), and the same check must see it.
    def no_jacobian(r, width):
        log_r = jnp.log(jnp.maximum(r, jnp.finfo(jnp.result_type(r)).tiny))
        return -0.5 * jnp.square(log_r / width)

    break_library(LIFT, "log_radial_density", no_jacobian)
    assert not all(_moments_within_mcse(_run()[0]).values())


def _run():
    num_chains, num_steps = NUM_CHAINS, NUM_STEPS
    sketch = exact_lifted(jax.random.key(0), 500)
    lifted = jg.mcmc.lift_quaternion(grasp_logdensity, width=WIDTH)
    # ν is scale-dependent (M has units 1/length): 0.005 suits this sketch (σ ≈ 0.5)
    alg = jg.mcmc.kameleon_darting(lifted, sketch, sketch[:5], nu=0.005, gamma=0.005)
    x0 = exact_lifted(jax.random.key(1), num_chains)
    return jg.mcmc.sample(jax.random.key(2), alg, x0, num_steps)


def _moments_within_mcse(positions):
    """Each statistic of the lifted target: is its chain average within 5 MCSE?"""
    num_chains, num_steps = NUM_CHAINS, NUM_STEPS
    p = np.asarray(positions[num_steps // 2 :], np.float64)
    r = np.linalg.norm(p[..., 3:], axis=-1)
    stats = {
        "mean": (p[..., :3], np.asarray(MEAN)),
        "var": ((p[..., :3] - np.asarray(MEAN)) ** 2, np.asarray(STD) ** 2),
        "resultant": (
            (p[..., 3:] / r[..., None]) @ np.asarray(MU),
            so3.vmf_mean_resultant_length(KAPPA),
        ),
        "log_r": (np.log(r), 0.0),
        "log_r_sq": (np.log(r) ** 2, WIDTH**2),
    }
    ok = {}
    for name, (values, expected) in stats.items():
        per_chain = values.reshape(values.shape[0], num_chains, -1).mean(axis=0)
        mcse = per_chain.std(axis=0, ddof=1) / np.sqrt(num_chains)
        ok[name] = bool(np.all(np.abs(per_chain.mean(axis=0) - expected) < 5 * mcse))
    return ok
