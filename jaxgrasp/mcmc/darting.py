"""Generalized Darting Monte Carlo jumps (Sminchisescu & Welling 2011; paper §3.2).

Jump regions are ellipsoids ``{x : (x − μ_i)ᵀ Σ_i⁻¹ (x − μ_i) ≤ ε²}`` around the modes μ_i
(demonstrated grasps). With ``Σ_i = U_i S_i U_iᵀ`` (S_i = diag(λ_i)) a region's volume is

    V_i = π^{d/2} ε^d ∏_j sqrt(λ_ij) / Γ(1 + d/2)

(the semi-axes are ε·sqrt(λ); the paper's formula omits the square root). A jump from x picks
a source region uniformly among the n(x) regions that contain x, a target region j with
probability V_j / Σ V, and maps

    x' = μ_j + U_j S_j^{1/2} S_i^{-1/2} U_iᵀ (x − μ_i)

We use this **plus** sign (the paper prints a minus, a point reflection, which is also valid).
The map is a bijection of region i onto region j with Jacobian V_j/V_i and ``T_{j→i}`` undoes
``T_{i→j}``, so choosing the target ∝ volume cancels the Jacobian and the move satisfies
detailed balance with acceptance

    min(1, π(x') n(x) / (π(x) n(x'))).

The paper prints this ratio inverted and "accept if u₂ > P_accept"; that does not satisfy
detailed balance, so we implement the ratio above. A jump attempted from outside every region
leaves the state unchanged (x' = x; reported as not accepted).

``uniform=True`` replaces the map by a draw uniform in the target region j (still chosen with
probability V_j / Σ V): then ``q(x' | x) = Σ_j (V_j/ΣV)(1[x' ∈ R_j]/V_j) = n(x')/ΣV`` for any x
inside some region, so the Hastings ratio ``q(x | x')/q(x' | x) = n(x)/n(x')`` and the
acceptance is the same ``min(1, π(x') n(x) / (π(x) n(x')))``. A chain resting on a mode then
jumps to new points of the other regions instead of exactly onto their centres.

Regions are built on the host (validation, eigendecompositions) and carried as a
:class:`JumpRegions` pytree of arrays.
"""

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgrasp.mcmc import _base
from jaxgrasp.types import Array, PRNGKey

__all__ = [
    "JumpRegions",
    "make_regions",
    "log_ellipsoid_volume",
    "region_membership",
    "jump_proposal",
    "jump_log_ratio",
]


class JumpRegions(NamedTuple):
    """m ellipsoidal jump regions in R^d.

    means : (m, d) centers μ_i (the modes).
    rotations : (m, d, d) eigenvectors U_i of Σ_i (columns).
    sqrt_eigvals : (m, d) sqrt(λ_i), the semi-axes divided by ε.
    log_volumes : (m,) log V_i.
    epsilon : () region size ε (Mahalanobis radius).
    """

    means: Array
    rotations: Array
    sqrt_eigvals: Array
    log_volumes: Array
    epsilon: Array


def log_ellipsoid_volume(eigvals, epsilon, d: int):
    """``log(π^{d/2} ε^d ∏ sqrt(λ) / Γ(1 + d/2))`` (works on numpy or JAX arrays)."""
    xp = jnp if isinstance(eigvals, jax.Array) else np
    return (
        0.5 * d * math.log(math.pi)
        + d * xp.log(epsilon)
        + 0.5 * xp.sum(xp.log(eigvals), axis=-1)
        - math.lgamma(1.0 + 0.5 * d)
    )


def make_regions(modes, region_cov=None, epsilon=0.7, sketch=None) -> JumpRegions:
    """Validate and build jump regions.

    Parameters
    ----------
    modes : (m, d) region centers, m >= 1.
    region_cov : None, (d, d) or (m, d, d)
        None: the covariance of ``sketch`` (the paper's "covariance of the Markov chain"),
        shared by all regions; (d, d): shared; (m, d, d): one ellipsoid per mode. Symmetric
        positive definite.
    epsilon : ε > 0.
    sketch : (N, d), needed when ``region_cov`` is None.
    """
    modes = np.asarray(_base.check_array(modes, "modes", ndim=2, min_rows=1), np.float64)
    m, d = modes.shape
    eps = float(_base.check_scalar(epsilon, "epsilon", positive=True))
    if region_cov is None:
        if sketch is None:
            raise ValueError("region_cov=None needs a sketch to take the covariance of")
        sk = np.asarray(sketch, np.float64)
        if sk.ndim != 2 or sk.shape[1] != d:
            raise ValueError(f"sketch must have shape (N, {d}) to match modes, got {sk.shape}")
        cov = np.broadcast_to(np.atleast_2d(np.cov(sk, rowvar=False)), (m, d, d))
    else:
        cov = np.asarray(_base.check_array(region_cov, "region_cov"), np.float64)
        if cov.shape == (d, d):
            cov = np.broadcast_to(cov, (m, d, d))
        elif cov.shape != (m, d, d):
            raise ValueError(
                f"region_cov must have shape ({d}, {d}) or ({m}, {d}, {d}) for {m} modes in "
                f"R^{d}, got {cov.shape}"
            )
    if not np.allclose(cov, np.swapaxes(cov, -1, -2), rtol=1e-6, atol=1e-12):
        raise ValueError("region_cov must be symmetric")
    eigvals, rotations = np.linalg.eigh(0.5 * (cov + np.swapaxes(cov, -1, -2)))
    if not np.all(eigvals > 0):
        raise ValueError(
            f"region_cov must be positive definite (smallest eigenvalue {eigvals.min():.3g}); "
            "a sketch covariance is singular when the sketch spans fewer than d dimensions"
        )
    dtype = jnp.result_type(float)
    return JumpRegions(
        means=jnp.asarray(modes, dtype),
        rotations=jnp.asarray(rotations, dtype),
        sqrt_eigvals=jnp.asarray(np.sqrt(eigvals), dtype),
        log_volumes=jnp.asarray(log_ellipsoid_volume(eigvals, eps, d), dtype),
        epsilon=jnp.asarray(eps, dtype),
    )


def _whiten(x: Array, regions: JumpRegions) -> Array:
    """``S_i^{-1/2} U_iᵀ (x − μ_i)`` for every region: (m, d)."""
    local = jnp.einsum("mdk,md->mk", regions.rotations, x - regions.means)
    return local / regions.sqrt_eigvals


def region_membership(x: Array, regions: JumpRegions) -> Array:
    """(m,) bool: which regions contain ``x`` (Mahalanobis distance ≤ ε)."""
    return jnp.sum(jnp.square(_whiten(x, regions)), axis=-1) <= regions.epsilon**2


def _uniform_in_ball(key: PRNGKey, d: int, dtype) -> Array:
    """A point uniform in the unit ball of R^d (direction × radius u^(1/d))."""
    k_dir, k_rad = jax.random.split(key)
    v = jax.random.normal(k_dir, (d,), dtype)
    r = jax.random.uniform(k_rad, (), dtype) ** (1.0 / d)
    return r * v / jnp.linalg.norm(v)


def jump_proposal(key: PRNGKey, x: Array, regions: JumpRegions, uniform: bool = False):
    """Propose a darting jump from ``x`` (``uniform``: a uniform point of the target region
    instead of the mapped one; static).

    Returns
    -------
    x_new : (d,) the mapped point (``x`` itself when x is in no region).
    num_regions : () int32, n(x).
    num_regions_new : () int32, n(x_new).
    """
    k_src, k_tgt, k_ball = jax.random.split(key, 3)
    inside = region_membership(x, regions)
    n_x = jnp.sum(inside.astype(jnp.int32))
    # source: uniform among the containing regions (arbitrary, unused, when there are none)
    src = jax.random.categorical(k_src, jnp.where(inside, 0.0, -jnp.inf))
    src = jnp.where(n_x > 0, src, 0)
    tgt = jax.random.categorical(k_tgt, regions.log_volumes)
    if uniform:
        w = regions.epsilon * _uniform_in_ball(k_ball, x.shape[-1], x.dtype)
    else:
        w = _whiten(x, regions)[src]
    mapped = regions.means[tgt] + regions.rotations[tgt] @ (regions.sqrt_eigvals[tgt] * w)
    x_new = jnp.where(n_x > 0, mapped, x)
    n_new = jnp.sum(region_membership(x_new, regions).astype(jnp.int32))
    return x_new, n_x, n_new


def jump_log_ratio(logdensity_new, logdensity, num_regions, num_regions_new):
    """``log[π(x') n(x) / (π(x) n(x'))]``; ``-inf`` (a stay) when x is in no region."""
    ratio = (
        logdensity_new
        - logdensity
        + jnp.log(jnp.maximum(num_regions, 1).astype(logdensity.dtype))
        - jnp.log(jnp.maximum(num_regions_new, 1).astype(logdensity.dtype))
    )
    return jnp.where(num_regions > 0, ratio, -jnp.inf)
