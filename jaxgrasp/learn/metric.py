"""The sampler's coordinates for grasps: position in units of a length scale, quaternion as is.

Kameleon's kernel, its γ and the GDMC regions are isotropic in the sampler's R^7. In metres
and quaternion components, 1 cm of position weighs as little as 0.01 of a quaternion
component (about 1°), so every kernel width and step is set by orientation alone. Sampling
``u = (pos / L, q)`` with ``L = 0.01 / sin(5°) ≈ 0.115 m`` makes 1 cm of position count as
much as 10° of rotation, the two tolerances of "the same grasp"
(:mod:`jaxgrasp.learn.evaluate.distinct`). The map is linear, so its Jacobian is a constant and the
scaled target ``π_u(u) ∝ π(pos = L u_pos, q)`` is sampled exactly.
"""

import math
from dataclasses import dataclass
from functools import partial

import jax.numpy as jnp
import numpy as np

from jaxgrasp._wrapper import register_wrapper
from jaxgrasp.mcmc._base import ValueHashed, call_target, hash_key

__all__ = ["GRASP_LENGTH_SCALE", "GraspMetric", "ScaledTarget"]

#: 1 cm of position ~ 10° of rotation (a quaternion moves by sin(5°) for a 10° turn).
GRASP_LENGTH_SCALE = 0.01 / math.sin(math.radians(5.0))


@dataclass(frozen=True)
class GraspMetric:
    """``u = (pos / length_scale, q)``; ``length_scale = 1`` is the paper's raw coordinates."""

    length_scale: float = 1.0

    def _scale(self, xp):
        return xp.asarray([1.0 / self.length_scale] * 3 + [1.0] * 4)

    def to_sampler(self, grasps) -> np.ndarray:
        g = np.asarray(grasps, np.float32)
        return (g * self._scale(np)).astype(np.float32)

    def to_grasp(self, u) -> np.ndarray:
        u = np.asarray(u, np.float32)
        return (u / self._scale(np)).astype(np.float32)

    def wrap(self, logdensity):
        """The target in sampler coordinates (``logdensity`` itself when the scale is 1)."""
        return logdensity if self.length_scale == 1.0 else ScaledTarget(logdensity,
                                                                        self.length_scale)


@partial(register_wrapper, child="logdensity")
@dataclass(frozen=True, eq=False)
class ScaledTarget(ValueHashed):
    """``u -> logdensity((L u_pos, u_q))``, hashable by value (rebuilt targets share code)."""

    logdensity: object
    length_scale: float

    def _key(self):
        return (hash_key(self.logdensity), self.length_scale)

    @property
    def stochastic(self) -> bool:
        return bool(getattr(self.logdensity, "stochastic", False))

    def __call__(self, u, key=None):
        u = jnp.asarray(u)
        return call_target(self.logdensity, jnp.concatenate([u[:3] * self.length_scale, u[3:]]),
                           key)
