"""The paper's sampler: Kameleon MCMC with GDMC jumps between demonstrated grasps (§4).

Each step, independently of the state: with probability ``1 − p_check`` attempt a darting jump
(:mod:`jaxgrasp.mcmc.darting`), otherwise take a local Kameleon step
(:mod:`jaxgrasp.mcmc.kameleon`) or, with probability ``p_symmetry`` (taken from the local
share), a symmetry move (:mod:`jaxgrasp.mcmc.symmetry`; off unless planes are given). All are
MH kernels leaving π invariant (once Kameleon's Z is frozen), so their state-independent
mixture is too. Under ``vmap`` both proposals are computed,
the one to use is picked with ``jnp.where``, and the target is evaluated **once**, at it.
"""

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from jaxgrasp.mcmc import _base, darting, symmetry
from jaxgrasp.mcmc.kameleon import (
    KameleonState,
    adapted_log_scale,
    adapted_subsample,
    advance,
    check_kameleon_args,
    check_target_acceptance,
    local_proposal,
)
from jaxgrasp.mcmc.kameleon import init as kameleon_init
from jaxgrasp.mcmc.mh import logdensity_and_aux, mh_accept
from jaxgrasp.types import Array, LogDensityFn, PRNGKey, SamplingAlgorithm

__all__ = ["KameleonDartingInfo", "kernel", "kameleon_darting"]


class KameleonDartingInfo(NamedTuple):
    """What one step did.

    acceptance_rate : () MH acceptance probability of the chosen move.
    is_accepted : () bool.
    is_jump : () bool, a darting jump was attempted this step (probability 1 − p_check).
    num_regions : () int32, n(x): jump regions containing the state before the step.
    proposal : (d,) the evaluated proposal (``x`` itself for a jump from outside all regions).
    logdensity : () log π(proposal).
    aux : aux of the target at the proposal.
    """

    acceptance_rate: Array
    is_accepted: Array
    is_jump: Array
    num_regions: Array
    proposal: Array
    logdensity: Array
    aux: Any


def kernel(
    key: PRNGKey,
    state: KameleonState,
    *,
    logdensity_fn: LogDensityFn,
    adapt_steps: int,
    sketch: Array,
    regions: darting.JumpRegions,
    p_check: Array,
    gamma: Array,
    nu: Array,
    sigma: Array,
    target_acceptance: float | None = None,
    uniform_jumps: bool = False,
    symmetry_planes: tuple = (),
    p_symmetry: Array = 0.0,
    symmetry_scale: Array = 0.0,
    symmetry_weights: Array = None,
    symmetry_geometry: tuple = (),
) -> tuple[KameleonState, KameleonDartingInfo]:
    """One Kameleon-or-jump(-or-symmetry) step (static: ``adapt_steps``,
    ``target_acceptance``, ``uniform_jumps``, ``symmetry_planes`` without their turns' and
    mirrors' numbers; everything else arrays, ``symmetry_geometry`` those numbers)."""
    k_choice, k_z, k_local, k_jump, k_acc = jax.random.split(key, 5)
    x = state.position
    # state-independent choice: the mixture of invariant kernels stays invariant
    u = jax.random.uniform(k_choice, (), x.dtype)
    is_jump = u >= p_check

    Z = adapted_subsample(k_z, state, sketch, adapt_steps)
    scale = jnp.exp(state.log_scale)
    x_local, log_hastings = local_proposal(k_local, x, Z, sigma, scale * gamma, scale * nu)
    x_jump, n_x, n_jump = darting.jump_proposal(k_jump, x, regions, uniform_jumps)

    is_local = ~is_jump
    if symmetry_planes:  # (without planes the random stream is the paper sampler's)
        is_symmetry = u < p_symmetry
        is_local = is_local & ~is_symmetry
        k_symmetry = jax.random.fold_in(k_local, 1)
        symmetry_planes = symmetry.join_groups(symmetry_planes, symmetry_geometry)
        if len(symmetry_planes) == 1:
            x_symmetry = symmetry.symmetry_proposal(k_symmetry, x, symmetry_planes[0],
                                                    symmetry_scale)
        else:
            x_symmetry = symmetry.mixture_proposal(k_symmetry, x, symmetry_planes,
                                                   symmetry_scale, symmetry_weights)
        x_local = jnp.where(is_symmetry, x_symmetry, x_local)
        log_hastings = jnp.where(is_symmetry, 0.0, log_hastings)  # a symmetric proposal

    proposal = jnp.where(is_jump, x_jump, x_local)
    logdensity, aux = logdensity_and_aux(logdensity_fn, proposal, key)  # the one evaluation
    log_ratio = jnp.where(
        is_jump,
        darting.jump_log_ratio(logdensity, state.logdensity, n_x, n_jump),
        logdensity - state.logdensity + log_hastings,
    )
    is_accepted, acceptance_rate = mh_accept(k_acc, log_ratio)
    # λ tunes the local Kameleon step only: other moves say nothing about its size
    log_scale = adapted_log_scale(state, acceptance_rate, adapt_steps, target_acceptance,
                                  is_local)
    new_state = advance(state, is_accepted, proposal, logdensity, aux, Z, adapt_steps, log_scale)
    info = KameleonDartingInfo(
        acceptance_rate, is_accepted, is_jump, n_x, proposal, logdensity, aux
    )
    return new_state, info


def kameleon_darting(
    logdensity_fn: LogDensityFn,
    sketch: Array,
    modes: Array,
    *,
    region_cov=None,
    p_check=0.6,
    epsilon=0.7,
    gamma=1e-4,
    nu=None,
    sigma=None,
    subsample_size: int = 100,
    adapt_steps: int = 100,
    target_acceptance: float | None = None,
    uniform_jumps: bool = False,
    symmetry_planes=(),
    p_symmetry=0.0,
    symmetry_scale=0.5,
    symmetry_weights=None,
) -> SamplingAlgorithm:
    """Kameleon MCMC with Generalized Darting Monte Carlo jumps (defaults: paper Table I).

    Parameters
    ----------
    logdensity_fn : position (d,) -> scalar log π, or (log π, aux pytree).
    sketch : (N, d), N >= 2, rough sketch of π (Kameleon's subsample source).
    modes : (m, d) jump-region centers (the demonstrated grasps).
    region_cov : None (covariance of the sketch, shared), (d, d) shared, or (m, d, d).
    p_check : probability of a local Kameleon step; a jump is attempted with 1 − p_check.
    epsilon : region size ε (Mahalanobis radius).
    gamma, nu, sigma, subsample_size, adapt_steps, target_acceptance : as
        :func:`jaxgrasp.mcmc.kameleon` (λ adapts on the local steps only).
    uniform_jumps : jump to a uniform point of the target region instead of the mapped one
        (:mod:`jaxgrasp.mcmc.darting`; same acceptance).
    symmetry_planes : ``((i, j, rate), ...)``; empty (default) for no symmetry moves, e.g.
        :data:`jaxgrasp.mcmc.symmetry.Z_AXIS_PLANES` to turn grasps about the object's z axis;
        or several such groups, a mixture (:func:`jaxgrasp.mcmc.symmetry.mixture_proposal`).
    p_symmetry : probability of a symmetry move, taken from the local share (<= p_check).
    symmetry_scale : standard deviation of the symmetry move's angle (radians); per group
        (G,) with several groups.
    symmetry_weights : (G,) probabilities of the groups (default equal).

    Returns
    -------
    SamplingAlgorithm with ``init(position (d,))`` -> KameleonState and
    ``step(key, state)`` -> (KameleonState, KameleonDartingInfo).
    """
    sketch, gamma, nu, sigma = check_kameleon_args(
        sketch, gamma, nu, sigma, subsample_size, adapt_steps
    )
    p_check = _base.check_scalar(p_check, "p_check")
    if _base.is_concrete(p_check) and float(p_check) > 1:
        raise ValueError(f"p_check must be a probability in [0, 1], got {float(p_check)}")
    planes = symmetry.check_groups(symmetry_planes, sketch.shape[1])
    p_symmetry = _base.check_scalar(p_symmetry, "p_symmetry")
    if _base.is_concrete(p_symmetry) and _base.is_concrete(p_check) and not (
            0.0 <= float(p_symmetry) <= float(p_check)):
        raise ValueError(f"p_symmetry must lie in [0, p_check = {float(p_check)}], got "
                         f"{float(p_symmetry)}")
    if len(planes) > 1:
        symmetry_scale = jnp.broadcast_to(jnp.asarray(symmetry_scale, jnp.float32),
                                          (len(planes),))
        weights = (jnp.ones(len(planes)) if symmetry_weights is None
                   else jnp.asarray(symmetry_weights, jnp.float32))
        if weights.shape != (len(planes),):
            raise ValueError(f"symmetry_weights must have shape ({len(planes)},), got "
                             f"{weights.shape}")
        symmetry_weights = weights / jnp.sum(weights)
    else:
        symmetry_scale = _base.check_scalar(symmetry_scale, "symmetry_scale")
    regions = darting.make_regions(modes, region_cov, epsilon, sketch)
    if regions.means.shape[1] != sketch.shape[1]:
        raise ValueError(
            f"modes have dimension {regions.means.shape[1]} but the sketch has {sketch.shape[1]}"
        )
    static_init = {"subsample_size": int(subsample_size), "adapt_steps": int(adapt_steps)}
    arrays = {
        "sketch": sketch,
        "regions": regions,
        "p_check": p_check,
        "gamma": gamma,
        "nu": nu,
        "sigma": sigma,
    }
    static_step = {"adapt_steps": int(adapt_steps),
                   "target_acceptance": check_target_acceptance(target_acceptance),
                   "uniform_jumps": bool(uniform_jumps)}
    static_step["symmetry_planes"], geometry = symmetry.split_groups(planes)
    if planes:
        arrays.update(p_symmetry=p_symmetry, symmetry_scale=symmetry_scale,
                      symmetry_geometry=geometry)
    if len(planes) > 1:
        arrays.update(symmetry_weights=symmetry_weights)
    return SamplingAlgorithm(
        init=_base.bind(kameleon_init, logdensity_fn, static_init, {"sketch": sketch}),
        step=_base.bind(kernel, logdensity_fn, static_step, arrays),
    )
