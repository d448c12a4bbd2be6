"""Pure, vmappable MCMC kernels on R^d (blackjax conventions). Knows nothing of MuJoCo.

Factories return a :class:`~jaxgrasp.types.SamplingAlgorithm` for one chain (``init(position)``,
``step(key, state)``); :func:`sample` vmaps it over chains and scans over steps.

- :func:`random_walk` — Gaussian position + vMF orientation on grasps (the paper's baseline).
- :func:`kameleon` — kernel adaptive MH (paper §3.1).
- :func:`kameleon_darting` — Kameleon with GDMC jumps between modes (paper §3.2, §4).
- :func:`lift_quaternion` — a grasp log-density as a log-density on R^7 for Kameleon.
"""

from jaxgrasp.mcmc import darting, diagnostics, symmetry
from jaxgrasp.mcmc.darting import JumpRegions, make_regions
from jaxgrasp.mcmc.kameleon import (
    KameleonInfo,
    KameleonState,
    kameleon,
    kameleon_proposal_covariance,
    kameleon_proposal_logdensity,
    kameleon_proposal_sample,
    kernel_gradients,
    median_heuristic,
)
from jaxgrasp.mcmc.kameleon_darting import KameleonDartingInfo, kameleon_darting
from jaxgrasp.mcmc.lift import lift_quaternion, to_grasp
from jaxgrasp.mcmc.random_walk import RandomWalkInfo, RandomWalkState, random_walk
from jaxgrasp.mcmc.sample import sample

__all__ = [
    "random_walk",
    "kameleon",
    "kameleon_darting",
    "sample",
    "lift_quaternion",
    "to_grasp",
    "kameleon_proposal_covariance",
    "kameleon_proposal_logdensity",
    "kameleon_proposal_sample",
    "kernel_gradients",
    "median_heuristic",
    "make_regions",
    "JumpRegions",
    "RandomWalkState",
    "RandomWalkInfo",
    "KameleonState",
    "KameleonInfo",
    "KameleonDartingInfo",
    "darting",
    "symmetry",
    "diagnostics",
]
