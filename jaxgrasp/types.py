"""Shared type aliases and the sampler interface (blackjax conventions)."""

from collections.abc import Callable
from typing import Any, NamedTuple

import jax

Array = jax.Array
PRNGKey = jax.Array
ArrayTree = Any
#: position (d,) -> scalar log-density, or (scalar, aux pytree) when built with ``has_aux``.
LogDensityFn = Callable[[Array], Any]


class SamplingAlgorithm(NamedTuple):
    """A single-chain MCMC kernel: pure functions, ``jax.vmap`` them for many chains.

    init : position (d,) -> state
    step : (key, state) -> (state, info)

    The factories in :mod:`jaxgrasp.mcmc` fill both with ``jax.tree_util.Partial`` objects:
    the kernel, the target and static options are hashable aux data, the array tunables and
    data (scales, ν, γ, σ, sketch, jump regions) are pytree leaves, so
    :func:`jaxgrasp.mcmc.sample` passes them to ``jit`` as arguments (no retrace when they
    change). Plain functions work too; they are treated as static.
    """

    init: Callable
    step: Callable
