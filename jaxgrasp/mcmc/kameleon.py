"""Kameleon MCMC: kernel adaptive Metropolis-Hastings (Sejdinovic et al. 2014; paper §3.1).

With the Gaussian kernel ``k(x, z) = exp(-|x − z|² / (2σ²))`` and a subsample ``Z`` (n, d) of
the sketch and the chain history, the proposal at ``y`` is

    q_Z(· | y) = N(y, γ² I + ν² M_y H M_yᵀ),   M_y = 2 [∇_x k(x, z_i)|_{x=y}]_i  (d, n),

with the centering matrix ``H = I − 11ᵀ/n``. ``M_y`` comes from ``jax.jacfwd`` of the kernel
(equal to the closed form ``(2/σ²) k(y, z_i)(z_i − y)``). A draw is the reparameterized

    x* = y + γ ξ₁ + ν M_y H ξ₂,   ξ₁ ~ N(0, I_d), ξ₂ ~ N(0, I_n),

so no n×n matrix is formed and ``jax.grad`` flows through x* to ν, γ, σ and y. The
covariance depends on ``y``: the proposal is **not symmetric** and the acceptance is

    log π(x*) − log π(y) + log q_Z(y | x*) − log q_Z(x* | y),

both terms with the *same* Z. ``log q`` is computed from a QR factorization of
``[γ I; ν (M H)ᵀ]`` (the Cholesky factor of the covariance without squaring it), which stays
accurate in float32 although γ² = 1e-8 next to O(1) eigenvalues.

Adaptation (burn-in): during the first ``adapt_steps`` steps Z is redrawn every step from the
sketch plus the chain history (a preallocated (adapt_steps, d) buffer and a count); afterwards
Z is frozen and the chain is an exact MH chain for π. Subsamples are drawn uniformly *with*
replacement (O(n) per step whatever the sketch size; duplicates only lower the rank a little).

Optionally (``target_acceptance``), the burn-in also adapts a per-chain scale λ of the whole
proposal (``γ → λγ``, ``ν → λν``) by Robbins–Monro on ``log λ`` toward a target acceptance
rate, as the Kameleon authors' reference code does for ν; λ is frozen with Z after burn-in.
"""

import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgrasp.mcmc import _base
from jaxgrasp.mcmc.mh import logdensity_and_aux, mh_accept, select
from jaxgrasp.types import Array, LogDensityFn, PRNGKey, SamplingAlgorithm

__all__ = [
    "KameleonState",
    "KameleonInfo",
    "gaussian_kernel",
    "kernel_gradients",
    "kameleon_proposal_covariance",
    "kameleon_proposal_logdensity",
    "kameleon_proposal_sample",
    "median_heuristic",
    "default_nu",
    "init",
    "kernel",
    "kameleon",
]


class KameleonState(NamedTuple):
    """State of one Kameleon chain.

    position : (d,) current point.
    logdensity : () log π(position) (cached: one target evaluation per step).
    aux : aux pytree of the target at ``position`` (``()`` if none).
    subsample : (n, d) the subsample Z used by the last step (frozen after adaptation).
    history : (max(adapt_steps, 1), d) chain history buffer used for adaptation.
    history_count : () int32, number of valid rows of ``history``.
    step : () int32, steps taken so far (adaptation runs while ``step < adapt_steps``).
    log_scale : () log λ, the proposal scale (0 unless ``target_acceptance`` adapts it).
    """

    position: Array
    logdensity: Array
    aux: Any
    subsample: Array
    history: Array
    history_count: Array
    step: Array
    log_scale: Array


class KameleonInfo(NamedTuple):
    """What one step did.

    acceptance_rate : () MH acceptance probability ``min(1, exp(log_ratio))``.
    is_accepted : () bool.
    is_jump : () bool, always False here (the darting kernel sets it).
    proposal : (d,) the evaluated proposal x*.
    logdensity : () log π(x*).
    aux : aux of the target at x*.
    """

    acceptance_rate: Array
    is_accepted: Array
    is_jump: Array
    proposal: Array
    logdensity: Array
    aux: Any


# ------------------------------------------------------------------------- proposal (public)


def gaussian_kernel(x: Array, z: Array, sigma: Array) -> Array:
    """``k(x, z) = exp(-|x − z|² / (2σ²))``; ``z`` may be (d,) or (n, d)."""
    return jnp.exp(-jnp.sum(jnp.square(x - z), axis=-1) / (2.0 * sigma**2))


def kernel_gradients(y: Array, Z: Array, sigma: Array) -> Array:
    """``M_y = 2 [∇_x k(x, z_i)|_{x=y}]_i``, shape (d, n), by forward-mode autodiff."""
    return 2.0 * jax.jacfwd(gaussian_kernel)(y, Z, sigma).T


def _centered_gradients(y: Array, Z: Array, sigma: Array) -> Array:
    """``M_y H`` (d, n): centering the columns is multiplying by H, without forming H."""
    M = kernel_gradients(y, Z, sigma)
    return M - jnp.mean(M, axis=1, keepdims=True)


def kameleon_proposal_covariance(y: Array, Z: Array, sigma, gamma, nu) -> Array:
    """The proposal covariance ``γ² I + ν² M_y H M_yᵀ`` (d, d) at ``y`` for subsample ``Z``."""
    A = _centered_gradients(y, Z, sigma)
    return gamma**2 * jnp.eye(y.shape[-1], dtype=A.dtype) + nu**2 * (A @ A.T)


def _r_factor(Bt: Array) -> Array:
    """``R`` of ``B = QR`` from ``Bt = Bᵀ`` (d, m), m >= d, by Householder reflections in
    plain ``jnp`` (d is small: the loop unrolls; rows of ``Bt`` are ``B``'s columns, so every
    product runs along the long minor axis). Not ``jnp.linalg.qr``: jaxlib's batched LAPACK
    QR splits a batch over XLA's thread pool and blocks there, and two samplers stepping at
    once (a cohort's members) hung in it for good (docs/design.md, "The sampler: where the
    paper is silent or wrong")."""
    d, m = Bt.shape
    cols = jnp.arange(m)
    Rt = Bt
    for k in range(d):
        # Full-length reflections (entries < k masked): earlier columns of R change below
        # their diagonal only, which the final triu drops; no dynamic slices to copy.
        x = jnp.where(cols >= k, Rt[k], 0.0)
        norm = jnp.sqrt(jnp.sum(x * x))
        v = x + jnp.where(cols == k, jnp.where(x[k] < 0, -norm, norm), 0.0)  # no cancellation
        vv = jnp.sum(v * v)
        scale = jnp.where(vv > 0, 2.0 / jnp.where(vv > 0, vv, 1.0), 0.0)
        Rt = Rt - scale * jnp.sum(Rt * v[None, :], axis=1)[:, None] * v[None, :]
    return jnp.triu(Rt[:, :d].T)


def _solve_rt(R: Array, r: Array) -> Array:
    """``w`` with ``Rᵀ w = r`` for upper-triangular ``R`` (forward substitution, unrolled)."""
    w = []
    for i in range(R.shape[0]):
        acc = r[i] - sum((R[j, i] * w[j] for j in range(i)), jnp.zeros((), r.dtype))
        w.append(acc / R[i, i])
    return jnp.stack(w)


def _logq(x_new: Array, y: Array, A: Array, gamma, nu) -> Array:
    """log N(x_new; y, γ² I + ν² A Aᵀ) from the QR factor of ``[γ I; ν Aᵀ]``."""
    d = y.shape[-1]
    R = _r_factor(jnp.concatenate([gamma * jnp.eye(d, dtype=A.dtype), nu * A], axis=1))
    w = _solve_rt(R, x_new - y)
    log_det_half = jnp.sum(jnp.log(jnp.abs(jnp.diagonal(R))))
    return -0.5 * jnp.sum(w**2) - log_det_half - 0.5 * d * math.log(2.0 * math.pi)


def _draw(key: PRNGKey, y: Array, A: Array, gamma, nu) -> Array:
    """``y + γ ξ₁ + ν A ξ₂``."""
    k1, k2 = jax.random.split(key)
    xi1 = jax.random.normal(k1, y.shape, A.dtype)
    xi2 = jax.random.normal(k2, (A.shape[1],), A.dtype)
    return y + gamma * xi1 + nu * (A @ xi2)


def kameleon_proposal_logdensity(x_new: Array, y: Array, Z: Array, sigma, gamma, nu) -> Array:
    """``log q_Z(x_new | y) = log N(x_new; y, γ² I + ν² M_y H M_yᵀ)`` (normalized).

    The covariance factor comes from the QR factorization of ``[γ I_d; ν (M_y H)ᵀ]`` (its R
    satisfies RᵀR = covariance), differentiable in every argument.
    """
    return _logq(x_new, y, _centered_gradients(y, Z, sigma), gamma, nu)


def kameleon_proposal_sample(key: PRNGKey, y: Array, Z: Array, sigma, gamma, nu) -> Array:
    """One draw ``x* = y + γ ξ₁ + ν M_y H ξ₂`` from ``q_Z(· | y)`` (reparameterized)."""
    return _draw(key, y, _centered_gradients(y, Z, sigma), gamma, nu)


# ------------------------------------------------------------------------- defaults (host)


def median_heuristic(points, max_points: int = 1000) -> float:
    """σ = median pairwise Euclidean distance of ``points`` (at most ``max_points`` of them,
    evenly spaced, so a large sketch costs O(max_points²))."""
    # why: scipy.spatial is a heavy import that only this host-side default needs.
    from scipy.spatial.distance import pdist

    pts = np.asarray(points, dtype=np.float64)
    if pts.shape[0] > max_points:
        pts = pts[np.linspace(0, pts.shape[0] - 1, max_points).astype(int)]
    # The pairs i < j only, in C (a dense (n, n, d) difference cost 0.3 s per learning run).
    sigma = float(np.median(pdist(pts))) if pts.shape[0] > 1 else float("nan")
    if not sigma > 0:
        raise ValueError(
            "median heuristic gives sigma = 0 (most sketch points coincide); pass sigma explicitly"
        )
    return sigma


def default_nu(d: int) -> float:
    """The paper's ν = 2.38/sqrt(d_eff): d_eff = 6 for grasps (d = 7: a 6-DoF pose), else d."""
    d_eff = 6 if d == 7 else d
    return 2.38 / math.sqrt(d_eff)


# ------------------------------------------------------------------------- kernel


def _initial_subsample(sketch: Array, n: int) -> Array:
    """Deterministic evenly spaced rows of the sketch (Z when adapt_steps = 0)."""
    idx = (np.arange(n) * sketch.shape[0]) // n
    return sketch[idx]


def init(
    position: Array,
    *,
    logdensity_fn: LogDensityFn,
    sketch: Array,
    subsample_size: int,
    adapt_steps: int,
) -> KameleonState:
    """Cache log π(position), seed Z with evenly spaced sketch rows, start the history."""
    _base.check_position(position, sketch.shape[1])
    position = jnp.asarray(position, sketch.dtype)
    logdensity, aux = logdensity_and_aux(logdensity_fn, position)
    history = jnp.zeros((max(adapt_steps, 1), sketch.shape[1]), sketch.dtype).at[0].set(position)
    return KameleonState(
        position=position,
        logdensity=logdensity,
        aux=aux,
        subsample=_initial_subsample(sketch, subsample_size),
        history=history,
        history_count=jnp.asarray(1 if adapt_steps > 0 else 0, jnp.int32),
        step=jnp.zeros((), jnp.int32),
        log_scale=jnp.zeros((), sketch.dtype),
    )


def draw_subsample(key: PRNGKey, sketch: Array, history: Array, history_count: Array, n: int):
    """n rows drawn uniformly with replacement from ``sketch`` ∪ ``history[:history_count]``."""
    pool = sketch.shape[0] + history_count
    u = jax.random.uniform(key, (n,))
    idx = jnp.minimum((u * pool).astype(jnp.int32), pool - 1)
    from_sketch = sketch[jnp.minimum(idx, sketch.shape[0] - 1)]
    from_history = history[jnp.clip(idx - sketch.shape[0], 0, history.shape[0] - 1)]
    return jnp.where((idx < sketch.shape[0])[:, None], from_sketch, from_history)


def adapted_subsample(key: PRNGKey, state: KameleonState, sketch: Array, adapt_steps: int):
    """Z for this step: redrawn while ``state.step < adapt_steps``, else the frozen one."""
    if adapt_steps == 0:
        return state.subsample
    fresh = draw_subsample(
        key, sketch, state.history, state.history_count, state.subsample.shape[0]
    )
    return jnp.where(state.step < adapt_steps, fresh, state.subsample)


def local_proposal(key: PRNGKey, y: Array, Z: Array, sigma, gamma, nu):
    """Kameleon proposal x* and its Hastings term ``log q(y | x*) − log q(x* | y)``."""
    A_y = _centered_gradients(y, Z, sigma)
    x_star = _draw(key, y, A_y, gamma, nu)
    A_star = _centered_gradients(x_star, Z, sigma)  # the reverse move's covariance, same Z
    log_hastings = _logq(y, x_star, A_star, gamma, nu) - _logq(x_star, y, A_y, gamma, nu)
    return x_star, log_hastings


def adapted_log_scale(state: KameleonState, acceptance_rate: Array, adapt_steps: int,
                      target_acceptance, adapts: Array = True) -> Array:
    """Robbins–Monro on log λ during burn-in (rate ``(1 + step)^-0.5``); frozen after."""
    if target_acceptance is None or adapt_steps == 0:
        return state.log_scale
    rate = jax.lax.rsqrt(1.0 + state.step.astype(state.log_scale.dtype))
    moved = state.log_scale + rate * (acceptance_rate - target_acceptance)
    return jnp.where((state.step < adapt_steps) & adapts, moved, state.log_scale)


def advance(
    state: KameleonState,
    is_accepted: Array,
    proposal: Array,
    logdensity: Array,
    aux: Any,
    Z: Array,
    adapt_steps: int,
    log_scale: Array | None = None,
) -> KameleonState:
    """Move to the proposal if accepted, store Z (and λ), append to the history while adapting."""
    position, logdensity, aux = select(
        is_accepted, (proposal, logdensity, aux), (state.position, state.logdensity, state.aux)
    )
    step = state.step + 1
    history, count = state.history, state.history_count
    if adapt_steps > 0:
        # the new point is used by the next draw only if that step still adapts
        keep = step < adapt_steps
        slot = jnp.minimum(count, history.shape[0] - 1)
        history = history.at[slot].set(jnp.where(keep, position, history[slot]))
        count = count + keep.astype(jnp.int32)
    log_scale = state.log_scale if log_scale is None else log_scale
    return KameleonState(position, logdensity, aux, Z, history, count, step, log_scale)


def kernel(
    key: PRNGKey,
    state: KameleonState,
    *,
    logdensity_fn: LogDensityFn,
    adapt_steps: int,
    sketch: Array,
    gamma: Array,
    nu: Array,
    sigma: Array,
    target_acceptance: float | None = None,
) -> tuple[KameleonState, KameleonInfo]:
    """One Kameleon MH step (static: ``adapt_steps``, ``target_acceptance``; arrays: sketch,
    γ, ν, σ)."""
    k_z, k_prop, k_acc = jax.random.split(key, 3)
    Z = adapted_subsample(k_z, state, sketch, adapt_steps)
    scale = jnp.exp(state.log_scale)
    proposal, log_hastings = local_proposal(k_prop, state.position, Z, sigma, scale * gamma,
                                            scale * nu)
    logdensity, aux = logdensity_and_aux(logdensity_fn, proposal, key)
    is_accepted, acceptance_rate = mh_accept(k_acc, logdensity - state.logdensity + log_hastings)
    log_scale = adapted_log_scale(state, acceptance_rate, adapt_steps, target_acceptance)
    new_state = advance(state, is_accepted, proposal, logdensity, aux, Z, adapt_steps, log_scale)
    info = KameleonInfo(
        acceptance_rate, is_accepted, jnp.zeros((), bool), proposal, logdensity, aux
    )
    return new_state, info


def check_target_acceptance(target_acceptance) -> float | None:
    """None (no scale adaptation) or a rate in (0, 1), as a static Python float."""
    if target_acceptance is None:
        return None
    t = float(target_acceptance)
    if not 0.0 < t < 1.0:
        raise ValueError(f"target_acceptance must lie in (0, 1) or be None, got {t}")
    return t


def check_kameleon_args(sketch, gamma, nu, sigma, subsample_size, adapt_steps):
    """Validate the shared Kameleon arguments; return (sketch, gamma, nu, sigma) as arrays."""
    sketch = _base.check_array(sketch, "sketch", ndim=2, min_rows=2)
    if int(subsample_size) != subsample_size or subsample_size < 1:
        raise ValueError(f"subsample_size must be a positive integer, got {subsample_size}")
    if int(adapt_steps) != adapt_steps or adapt_steps < 0:
        raise ValueError(f"adapt_steps must be a non-negative integer, got {adapt_steps}")
    d = sketch.shape[1]
    gamma = _base.check_scalar(gamma, "gamma", positive=True)
    nu = _base.check_scalar(default_nu(d) if nu is None else nu, "nu")
    if sigma is None:
        sigma = median_heuristic(sketch)
    sigma = _base.check_scalar(sigma, "sigma", positive=True)
    return sketch, gamma, nu, sigma


def kameleon(
    logdensity_fn: LogDensityFn,
    sketch: Array,
    *,
    gamma=1e-4,
    nu=None,
    sigma=None,
    subsample_size: int = 100,
    adapt_steps: int = 100,
    target_acceptance: float | None = None,
) -> SamplingAlgorithm:
    """Kameleon MCMC on R^d.

    Parameters
    ----------
    logdensity_fn : position (d,) -> scalar log π, or (log π, aux pytree).
    sketch : (N, d), N >= 2, rough sketch of π (e.g. the proposals of a random-walk run, or
        the chain history of a similar object). Z is drawn from it and the chain history.
    gamma : exploration noise γ > 0 (Table I: 1e-4).
    nu : scale ν of the kernel part; None = 2.38/sqrt(d_eff) (d_eff = 6 for d = 7 grasps).
        ν is not scale-free: M_y has units 1/length and n columns, so the kernel part's
        standard deviation is about ν·sqrt(n)·(2/σ²)·|k (z − y)|. The paper writes
        ``M = 2η[∇k]`` with a gradient step η; ``nu = 2.38/sqrt(d_eff) · σ²/(2·sqrt(n))``
        (η = σ²/2 and the 1/n of the empirical covariance operator) gives an
        adaptive-Metropolis-like scale where 2.38/sqrt(d) means what it usually does.
    sigma : Gaussian kernel width σ; None = median heuristic on the sketch.
    subsample_size : n, rows of Z (Table I: 100).
    adapt_steps : steps during which Z is redrawn (burn-in; Table I: 100); frozen afterwards.
    target_acceptance : None (the paper: fixed γ, ν) or a rate in (0, 1): during the
        ``adapt_steps`` the proposal scale λ (γ, ν → λγ, λν) is adapted toward it per chain.

    Returns
    -------
    SamplingAlgorithm; ``init(position (d,))``, ``step(key, state)``. γ, ν, σ and the sketch are
    array leaves (no recompilation when they change).
    """
    sketch, gamma, nu, sigma = check_kameleon_args(
        sketch, gamma, nu, sigma, subsample_size, adapt_steps
    )
    static_init = {"subsample_size": int(subsample_size), "adapt_steps": int(adapt_steps)}
    static_step = {"adapt_steps": int(adapt_steps),
                   "target_acceptance": check_target_acceptance(target_acceptance)}
    return SamplingAlgorithm(
        init=_base.bind(init, logdensity_fn, static_init, {"sketch": sketch}),
        step=_base.bind(
            kernel,
            logdensity_fn,
            static_step,
            {"sketch": sketch, "gamma": gamma, "nu": nu, "sigma": sigma},
        ),
    )
