"""Shared Metropolis-Hastings pieces: target evaluation with aux, the accept step, selection.

Every kernel in :mod:`jaxgrasp.mcmc` evaluates the target exactly once per step through
:func:`logdensity_and_aux` and accepts through :func:`mh_accept`.
"""

from typing import Any

import jax
import jax.numpy as jnp

from jaxgrasp.types import Array, ArrayTree, LogDensityFn, PRNGKey

__all__ = ["logdensity_and_aux", "mh_accept", "select"]


def logdensity_and_aux(logdensity_fn: LogDensityFn, position: Array) -> tuple[Array, Any]:
    """Evaluate the target once: ``(logdensity, aux)``.

    ``logdensity_fn`` may return a scalar or a tuple ``(scalar, aux pytree)``; which one is
    decided at trace time. Without aux, ``()`` is returned. NaN log-densities become ``-inf``
    so that a failed evaluation is rejected instead of poisoning the chain.
    """
    out = logdensity_fn(position)
    if isinstance(out, tuple):
        if len(out) != 2:
            raise ValueError(
                "logdensity_fn must return a scalar or a (logdensity, aux) pair, "
                f"got a tuple of length {len(out)}"
            )
        logdensity, aux = out
    else:
        logdensity, aux = out, ()
    logdensity = jnp.asarray(logdensity)
    if logdensity.shape != ():
        raise ValueError(
            f"logdensity_fn must return a scalar log-density, got shape {logdensity.shape}"
        )
    logdensity = jnp.where(jnp.isnan(logdensity), -jnp.inf, logdensity)
    return logdensity, aux


def mh_accept(key: PRNGKey, log_ratio: Array) -> tuple[Array, Array]:
    """Metropolis-Hastings test in log space.

    Parameters
    ----------
    key : PRNGKey
    log_ratio : scalar, ``log π(x*) − log π(x) + log q(x | x*) − log q(x* | x)`` (the caller
        includes the Hastings terms; symmetric proposals pass just the density difference).

    Returns
    -------
    is_accepted : bool scalar
    acceptance_rate : scalar in [0, 1], ``min(1, exp(log_ratio))`` (0 for NaN ratios).
    """
    log_ratio = jnp.where(jnp.isnan(log_ratio), -jnp.inf, log_ratio)
    acceptance_rate = jnp.exp(jnp.minimum(log_ratio, 0.0))
    log_u = jnp.log(jax.random.uniform(key, (), acceptance_rate.dtype))
    return log_u < log_ratio, acceptance_rate


def select(pred: Array, on_true: ArrayTree, on_false: ArrayTree) -> ArrayTree:
    """Leaf-wise ``jnp.where(pred, on_true, on_false)`` (per-chain branch choice under vmap)."""
    return jax.tree.map(lambda a, b: jnp.where(pred, a, b), on_true, on_false)
