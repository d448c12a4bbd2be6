"""Random-walk Metropolis-Hastings on grasp space (the paper's baseline and rough sketch).

A grasp is ``(x, y, z, qw, qx, qy, qz)`` with a unit quaternion. The proposal moves the position
by a Gaussian ``N(pos, Σ)`` and draws the orientation from ``vMF(q, κ)`` on S^3 (paper §4).
Both pieces are symmetric (``exp(κ qᵀq')`` is symmetric in q, q'), so the Hastings ratio is
``π(g*) / π(g)``. The quaternion stays on the unit sphere: the target is evaluated on grasps,
not on the lifted R^7 space that Kameleon uses.
"""

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgrasp import so3
from jaxgrasp.mcmc import _base
from jaxgrasp.mcmc.mh import logdensity_and_aux, mh_accept, select
from jaxgrasp.types import Array, LogDensityFn, PRNGKey, SamplingAlgorithm

__all__ = ["RandomWalkState", "RandomWalkInfo", "init", "kernel", "random_walk"]

GRASP_DIM = 7


class RandomWalkState(NamedTuple):
    """State of one chain.

    position : (7,) grasp ``(x, y, z, qw, qx, qy, qz)``, unit quaternion.
    logdensity : () log π at ``position`` (cached: one target evaluation per step).
    aux : aux pytree the target returned at ``position`` (``()`` if none).
    """

    position: Array
    logdensity: Array
    aux: Any


class RandomWalkInfo(NamedTuple):
    """What one step did.

    acceptance_rate : () ``min(1, π(g*)/π(g))``.
    is_accepted : () bool.
    is_jump : () bool, always False (same fields as the darting kernels).
    proposal : (7,) the evaluated proposal ``g*``.
    logdensity : () log π(g*).
    aux : aux of the target at ``g*``.
    """

    acceptance_rate: Array
    is_accepted: Array
    is_jump: Array
    proposal: Array
    logdensity: Array
    aux: Any


def init(position: Array, logdensity_fn: LogDensityFn) -> RandomWalkState:
    """Normalize the quaternion of ``position`` (7,) and cache its log-density."""
    _base.check_position(position, GRASP_DIM)
    position = jnp.asarray(position, jnp.result_type(float))
    position = jnp.concatenate([position[:3], so3.normalize(position[3:])])
    logdensity, aux = logdensity_and_aux(logdensity_fn, position)
    return RandomWalkState(position, logdensity, aux)


def _position_step(key: PRNGKey, pos: Array, position_scale: Array) -> Array:
    noise = jax.random.normal(key, (3,), pos.dtype)
    if jnp.ndim(position_scale) == 2:
        # a (3, 3) covariance Σ
        return pos + jnp.linalg.cholesky(position_scale) @ noise
    return pos + position_scale * noise


def kernel(
    key: PRNGKey,
    state: RandomWalkState,
    *,
    logdensity_fn: LogDensityFn,
    position_scale: Array,
    kappa: Array,
) -> tuple[RandomWalkState, RandomWalkInfo]:
    """One random-walk MH step.

    Parameters
    ----------
    key : PRNGKey
    state : RandomWalkState
    logdensity_fn : grasp (7,) -> log π or (log π, aux).
    position_scale : scalar or (3,) standard deviations, or a (3, 3) covariance Σ.
    kappa : scalar vMF concentration of the orientation proposal.
    """
    k_pos, k_ori, k_acc = jax.random.split(key, 3)
    pos, q = state.position[:3], state.position[3:]
    proposal = jnp.concatenate(
        [_position_step(k_pos, pos, position_scale), so3.sample_vmf(k_ori, q, kappa)]
    )
    logdensity, aux = logdensity_and_aux(logdensity_fn, proposal, key)
    is_accepted, acceptance_rate = mh_accept(k_acc, logdensity - state.logdensity)
    new_state = select(is_accepted, RandomWalkState(proposal, logdensity, aux), state)
    info = RandomWalkInfo(
        acceptance_rate, is_accepted, jnp.zeros((), bool), proposal, logdensity, aux
    )
    return new_state, info


def _check_position_scale(position_scale):
    if not _base.is_concrete(position_scale):
        return position_scale
    a = np.asarray(position_scale, dtype=np.float64)
    if a.shape not in ((), (3,), (3, 3)):
        raise ValueError(
            f"position_scale must be a scalar, (3,) standard deviations or a (3, 3) covariance, "
            f"got shape {a.shape}"
        )
    if not np.all(np.isfinite(a)):
        raise ValueError("position_scale must be finite")
    if a.ndim < 2 and np.any(a < 0):
        raise ValueError(f"position_scale must be non-negative, got {a}")
    if a.ndim == 2 and (not np.allclose(a, a.T) or np.linalg.eigvalsh(0.5 * (a + a.T)).min() <= 0):
        raise ValueError("a (3, 3) position_scale must be a symmetric positive-definite covariance")
    return jnp.asarray(position_scale, jnp.result_type(float))


def random_walk(
    logdensity_fn: LogDensityFn, *, position_scale: Array, kappa: Array
) -> SamplingAlgorithm:
    """Random-walk MH on grasps: Gaussian position step, von Mises-Fisher orientation step.

    Parameters
    ----------
    logdensity_fn : grasp (7,) -> scalar log π, or (log π, aux pytree).
    position_scale : scalar or (3,) standard deviation(s) of the position step (metres), or a
        (3, 3) covariance Σ.
    kappa : concentration of the vMF orientation proposal (larger = smaller rotations; the
        typical rotation angle is about ``2·sqrt(3/κ)`` rad for large κ).

    Returns
    -------
    SamplingAlgorithm with ``init(position (7,))`` and ``step(key, state)``. ``position_scale``
    and ``kappa`` are pytree leaves: changing them does not recompile :func:`sample`.
    """
    position_scale = _check_position_scale(position_scale)
    kappa = _base.check_scalar(kappa, "kappa")
    return SamplingAlgorithm(
        init=_base.bind(init, logdensity_fn, {}, {}),
        step=_base.bind(
            kernel, logdensity_fn, {}, {"position_scale": position_scale, "kappa": kappa}
        ),
    )
