"""Pure, vmappable MCMC kernels on R^d (blackjax conventions). Knows nothing of MuJoCo.

Factories return a :class:`~jaxgrasp.types.SamplingAlgorithm` for one chain; :func:`sample`
vmaps it over chains and scans over steps.
"""

from jaxgrasp.mcmc.random_walk import random_walk
from jaxgrasp.mcmc.sample import sample

__all__ = ["random_walk", "sample"]
