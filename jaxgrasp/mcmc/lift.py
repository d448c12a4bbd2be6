"""Lifting a grasp log-density (unit quaternion) to R^7, where Kameleon's Gaussian proposals live.

``log π7(pos, q) = log π(pos, q/|q|) + log ρ(|q|)`` with a fixed radial density: the density on
R^4 is ∝ ``exp(−(log r)²/(2 w²)) / r⁴`` (r = |q|), which makes |q| ~ LogNormal(0, w²) (median 1)
independently of the direction. Integrating r out leaves π on the unit sphere for any ρ, so an
exact MH chain on R^7 is an exact chain for grasps ``(pos, q/|q|)``. ``q`` and ``−q`` are kept
distinct (the grasp density is the same at both); canonicalize only for reporting.
"""

from dataclasses import dataclass
from functools import partial

import jax.numpy as jnp

from jaxgrasp import so3
from jaxgrasp._wrapper import register_wrapper
from jaxgrasp.mcmc._base import ValueHashed, call_target, hash_key
from jaxgrasp.types import Array, LogDensityFn

__all__ = ["LiftedQuaternion", "lift_quaternion", "to_grasp", "log_radial_density"]


def log_radial_density(r: Array, width) -> Array:
    """Unnormalized log ρ on R^4 at radius r: |q| ~ LogNormal(0, width²)."""
    log_r = jnp.log(jnp.maximum(r, jnp.finfo(jnp.result_type(r)).tiny))
    return -0.5 * jnp.square(log_r / width) - 4.0 * log_r


def to_grasp(x: Array) -> Array:
    """``(pos, q/|q|)``: the grasp a lifted point (…, 7) stands for."""
    x = jnp.asarray(x)
    return jnp.concatenate([x[..., :3], so3.normalize(x[..., 3:])], axis=-1)


@partial(register_wrapper, child="grasp_logdensity")
@dataclass(frozen=True, eq=False)
class LiftedQuaternion(ValueHashed):
    """The lifted R^7 log-density (hashable by value, so rebuilding it reuses compiled code)."""

    grasp_logdensity: LogDensityFn
    width: float = 0.05

    def _key(self):
        return (hash_key(self.grasp_logdensity), self.width)

    @property
    def stochastic(self) -> bool:
        return bool(getattr(self.grasp_logdensity, "stochastic", False))

    def __call__(self, x: Array, key=None):
        x = jnp.asarray(x)
        out = call_target(self.grasp_logdensity, to_grasp(x), key)
        log_rho = log_radial_density(jnp.linalg.norm(x[3:]), self.width)
        if isinstance(out, tuple):
            logdensity, aux = out
            return logdensity + log_rho, aux
        return out + log_rho


def lift_quaternion(grasp_logdensity: LogDensityFn, *, width: float = 0.05) -> LiftedQuaternion:
    """Turn ``grasp (7,) -> log π`` (or ``(log π, aux)``) into a log-density on R^7.

    Parameters
    ----------
    grasp_logdensity : log-density on grasps ``(x, y, z, qw, qx, qy, qz)`` with unit q.
    width : log-normal width of |q| (0.05: |q| within about ±10 % of 1).
    """
    width = float(width)
    if not (width > 0 and jnp.isfinite(width)):
        raise ValueError(f"width must be positive and finite, got {width}")
    return LiftedQuaternion(grasp_logdensity, width)
