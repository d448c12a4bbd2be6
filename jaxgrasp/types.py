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
    """

    init: Callable
    step: Callable
