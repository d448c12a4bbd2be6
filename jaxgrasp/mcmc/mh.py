"""Shared Metropolis-Hastings pieces: target evaluation with aux, the accept step, selection.

Every kernel in :mod:`jaxgrasp.mcmc` evaluates the target exactly once per step through
:func:`logdensity_and_aux` and accepts through :func:`mh_accept`.

**Stochastic targets (pseudo-marginal MH).** A target with ``stochastic = True`` is called as
``logdensity_fn(position, key)`` and returns the log of a non-negative, unbiased estimate of the
density. The kernels store the estimate of the current state with the state and never
evaluate it again, so the chain is exact for the estimated density (Andrieu & Roberts 2009):
it is the marginal of an MH chain on (position, noise). A chain's initial estimate uses a
key derived from the start position (drawn once, independent of the moves that follow).
"""

from typing import Any

import jax
import jax.numpy as jnp

from jaxgrasp.mcmc._base import call_target, is_stochastic
from jaxgrasp.types import Array, ArrayTree, LogDensityFn, PRNGKey

__all__ = ["logdensity_and_aux", "mh_accept", "select", "is_stochastic", "TARGET_STREAM"]

#: ``fold_in`` data of a step key for a stochastic target's noise: far from the small split
#: counters the kernels draw their moves from.
TARGET_STREAM = 0x7A46E7


def _start_key(position: Array) -> PRNGKey:
    """A key from the bits of a start position, for a stochastic target's initial estimate."""
    bits = jax.lax.bitcast_convert_type(jnp.asarray(position, jnp.float32), jnp.uint32)
    key = jax.random.key(TARGET_STREAM)
    for i in range(bits.shape[0]):  # d is static and small
        key = jax.random.fold_in(key, bits[i])
    return key


def logdensity_and_aux(logdensity_fn: LogDensityFn, position: Array,
                       key: PRNGKey | None = None) -> tuple[Array, Any]:
    """Evaluate the target once: ``(logdensity, aux)``.

    ``key``: the step's key; a stochastic target draws its noise from
    ``fold_in(key, TARGET_STREAM)`` (without a key, from the position's bits: a chain start).

    ``logdensity_fn`` may return a scalar or a tuple ``(scalar, aux pytree)``; which one is
    decided at trace time. Without aux, ``()`` is returned. NaN log-densities become ``-inf``
    so that a failed evaluation is rejected instead of poisoning the chain.
    """
    if is_stochastic(logdensity_fn):
        key = _start_key(position) if key is None else jax.random.fold_in(key, TARGET_STREAM)
    out = call_target(logdensity_fn, position, key)
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
