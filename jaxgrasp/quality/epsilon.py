"""Epsilon in pure JAX: jittable and vmappable, fixed-size masked contact arrays.

:func:`epsilon` is the value of one contact set, :func:`epsilon_from_wrenches` the same from
a wrench set (the method is described there), and :func:`epsilon_batch` is :func:`epsilon` of
a batch where needed (0 elsewhere), the search's runs of all its trials dealt to a few vmapped
lanes: the same values up to round-off (which can, rarely, pick another best vertex and so
another antipode start). Also here: a wrench set's preparation for the search (masked rows,
scale, start directions) and the epsilon read from the search's best value.
"""

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgrasp._batching import fold_vmap
from jaxgrasp._reduce import max_last
from jaxgrasp.quality.simplex import _lane_search, _search, _simplex_directions
from jaxgrasp.quality.wrenches import WRENCH_DIM, _check_contacts, contact_wrenches

#: The search's start directions by default, and how many are eigen-directions (see
#: :func:`epsilon_from_wrenches`); the physics trial takes fewer (``protocol.TRIAL_STARTS``).
NUM_STARTS = 16
NUM_EIGEN_STARTS = 6
#: epsilon below ``ZERO_TOL * max |w_k|`` is reported as exactly 0 (rank-deficient sets give
#: float32 round-off of this order; the reported error is bounded by the same amount).
ZERO_TOL = 1e-5
#: Most 6x6 matrices per LAPACK eigh call: jaxlib's CPU eigh splits a batch of >= 186 over
#: XLA's intra-op pool and blocks until the pieces run; two such calls at once on a 2-thread
#: pool wait for each other forever (docs/design.md, "Scaling").
_EIGH_BATCH = 128


def _random_directions(num: int, seed: int = 0) -> np.ndarray:
    """A fixed set of ``num`` pseudo-random unit directions in R^6 (a trace-time constant)."""
    u = np.random.default_rng(seed).standard_normal((num, WRENCH_DIM))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def _antipode(best_x):
    """The start of the last run: opposite the nearest facet found (wrench sets of opposing
    contacts are nearly centrally symmetric: the facet opposite a local minimum of ``h`` is
    often a nearer one, which the fixed starts miss)."""
    norm = jnp.linalg.norm(best_x)
    fallback = jnp.asarray(_simplex_directions()[0], best_x.dtype)
    return jnp.where(norm > 0, -best_x / jnp.maximum(norm, 1e-30), fallback)


def epsilon_batch(points, normals, mask, need, mu, center, radius, num_edges=8, *,
                  lanes: int = 16, num_starts: int = NUM_STARTS,
                  num_eigen_starts: int = NUM_EIGEN_STARTS,
                  max_run_iters: int = 80, max_total_iters: int | None = None,
                  antipode: bool = True):
    """:func:`epsilon` of a batch of contact sets (leading dim T) where ``need`` (T,), 0
    elsewhere, the search's runs dealt to ``lanes`` vmapped lanes (:func:`_lane_runs`): its
    cost follows the needed trials' total pivots, not ``T`` times the slowest trial's.
    ``mu``, ``center``, ``radius``: one for all, or one per trial ((T,), (T, 3), (T,)).
    Same values as ``vmap(epsilon)`` where ``need`` (each run takes the same steps; float
    round-off may differ with the batch shape; where two vertices tie for the best local
    minimum, the antipode's start may be the other one's). Inside an outer ``vmap`` the loop runs
    until every batch member is done: there ``vmap(epsilon)`` costs the same."""
    max_total_iters = _check_starts(num_starts, max_total_iters)
    if not (isinstance(lanes, int | np.integer) and lanes >= 1):
        raise ValueError(f"lanes must be a positive int, got {lanes!r}")
    points = jnp.asarray(points, jnp.result_type(float))
    normals, mask, need = jnp.asarray(normals), jnp.asarray(mask, bool), jnp.asarray(need, bool)
    if points.ndim != 3 or need.shape != points.shape[:1]:
        raise ValueError(f"need points (T, K, 3) and need (T,), got {points.shape}, "
                         f"{need.shape}")
    T = points.shape[0]
    _check_contacts(points.shape[1:], normals.shape[1:], mask.shape[1:], jnp.shape(center)[-1:],
                    num_edges)
    if T == 0:
        return jnp.zeros(0, points.dtype)
    mu, radius = (jnp.broadcast_to(jnp.asarray(a, points.dtype), (T,)) for a in (mu, radius))
    center = jnp.broadcast_to(jnp.asarray(center, points.dtype), (T, 3))
    search = partial(_batch_search, num_edges=num_edges, lanes=lanes, num_starts=num_starts,
                     num_eigen_starts=num_eigen_starts, max_run_iters=max_run_iters,
                     max_total_iters=max_total_iters, antipode=antipode)
    # Nothing needed (a call of misses): skip the wrenches' eigh and the search's setup too.
    return jax.lax.cond(jnp.any(need), search, lambda *_: jnp.zeros(T, points.dtype),
                        points, normals, mask, need, mu, center, radius)


def _batch_search(points, normals, mask, need, mu, center, radius, *, num_edges, lanes,
                  num_starts, num_eigen_starts, max_run_iters, max_total_iters, antipode):
    """:func:`epsilon_batch` of a batch with at least one row needed."""
    W = jax.vmap(partial(contact_wrenches, num_edges=num_edges))(points, normals, mu, center,
                                                                 radius)
    valid = jnp.repeat(mask, num_edges, axis=1)
    pre = jax.vmap(partial(_prepare, num_starts=num_starts,
                           num_eigen_starts=num_eigen_starts))(W, valid)
    best, best_x, unbounded = _lane_search(pre, pre.directions, need, lanes, max_run_iters,
                                           max_total_iters)
    if antipode:
        more = need & ~unbounded & jnp.isfinite(best)
        anti, _, anti_unbounded = _lane_search(pre, jax.vmap(_antipode)(best_x)[:, None], more,
                                               lanes, max_run_iters, max_total_iters)
        best = jnp.minimum(best, jnp.where(more, anti, jnp.inf))
        unbounded = unbounded | (more & anti_unbounded)
    eps = jax.vmap(_result)(pre, best, unbounded)
    return jnp.where(need, eps, 0.0)


def epsilon_from_wrenches(
    wrenches,
    valid,
    *,
    num_starts: int = NUM_STARTS,
    num_eigen_starts: int = NUM_EIGEN_STARTS,
    max_run_iters: int = 80,
    max_total_iters: int | None = None,
    antipode: bool = True,
):
    """Distance from the origin to the boundary of ``conv{w_k : valid_k}``, 0 if not inside.

    Method
    ------
    ``epsilon = max(0, min_{|u|=1} h(u))`` with ``h(u) = max_k u·w_k``. Any unit ``u`` gives
    an upper bound ``h(u)``, but a sampled minimum is far off in 6-D (a median 130% above
    the true value with 256 random directions on random grasps), so we search the vertices of
    the polar polytope ``P° = {x : W x <= 1}``. When the origin is strictly inside the hull,
    ``P°`` is bounded, its vertices are ``n_F / d_F`` for the hull facets ``F`` (unit outward
    normal ``n_F``, distance ``d_F``) and ``epsilon = min_F d_F = 1 / max_{x in P°} |x|``.
    Maximizing ``|x|`` over a polytope is a vertex search:

    1. From each start direction ``c`` (the 7 vertices of a regular simplex, a positively
       spanning set; then ``±`` the eigenvectors of ``WᵀW`` with the smallest eigenvalues,
       the directions in which the wrench set is thinnest; then fixed pseudo-random
       directions; ``num_starts`` in all) a revised
       simplex method with a 6 x 6 basis inverse solves ``max c·x s.t. W x <= 1`` exactly,
       starting from an artificial basis at ``x = 0`` (its optimum is the polar vertex of
       the facet that the ray along ``c`` hits). The artificial rows leave first, then the
       steepest edge enters (Bland's rule right after a degenerate pivot: no cycling); a
       pivot needs the ratio test of its own edge only. Rows in the span of the rest of the
       basis never enter; the inverse is rank-one updated and refined by one Newton-Schulz
       step every pivot (float32 drift). All the LPs run first.
    2. From each distinct LP optimum (a walk is a function of its start vertex) a greedy
       vertex walk moves to the farthest of the 6 adjacent polar
       vertices (the neighbouring facets) while that increases ``|x|``, taking degenerate
       Bland pivots for ``max (x/|x|)·y`` when stuck on a degenerate vertex. It stops at a
       vertex no neighbour of which is farther: a facet nearer than all its neighbours, whose
       foot point lies inside it (a local minimum of ``h`` on the sphere), or where
       float32 round-off sends it back to the basis of one step ago; each step
       ratio-tests all 6 edges. The answer is the best ``h`` these walks met. A single
       start finds the global one on ~55-60% of random grasps.
    2b. One more LP and walk start opposite the best local minimum found (its antipode):
       the wrenches of opposing contacts are nearly centrally symmetric, and the nearest
       facet is often the one opposite a slightly farther local minimum that the fixed
       starts reached. On 12 000 random grasps of 2-16 contacts (the property test's kind)
       6 differ from Qhull by more than 1 % (5 in :func:`epsilon_batch`; 13 without the
       antipode; 24 fixed starts and no antipode: 1 of the first 6 000),
       all over-estimates by at most 3.2 %: such grasps have 20-100 local minima within a
       few % of each other, and only a full hull enumeration is exact on all of them.
    3. If a pivot's edge is blocked by no row (``W e <= 0``, i.e. ``h(e) <= 0``) the origin
       is not strictly inside -> 0. An unbounded ``P°`` is always caught by one of the 7
       simplex starts (some ``c`` has ``c·e > 0`` for a ray ``e``: that LP is unbounded, and
       the simplex method ends on an unblocked improving edge).
    4. Every walk is scored by ``h(x/|x|)`` evaluated directly, so the result is always a
       true value of ``h``: an upper bound on the exact answer even if a walk was cut
       short, exact when the best local minimum is the global one. Values below
       ``ZERO_TOL * max|w|`` (rank-deficient sets such as two point contacts, origin on the
       boundary) are returned as exactly 0.

    Parameters
    ----------
    wrenches : (N, 6) array
    valid : (N,) bool array
        Rows that count; all-False gives 0.
    num_starts : int, static
        Start directions (>= 7); the cost is about proportional.
    num_eigen_starts : int, static
        How many of them are the thinnest eigen-directions (then random ones).
    max_run_iters, max_total_iters : int, static
        Pivot caps per run and per phase, LPs or walks (default ``30 * num_starts``).
    antipode : bool, static
        Run step 2b (one more LP and walk per set; False: faster, ~2.5x more misses).

    Returns
    -------
    scalar array (wrench dtype)
    """
    max_total_iters = _check_starts(num_starts, max_total_iters)
    pre = _prepare(wrenches, valid, num_starts, num_eigen_starts)
    search = _search(pre.W.T, pre.valid, pre.row_norm, pre.directions, max_run_iters,
                     max_total_iters)
    best, unbounded = search.best, search.unbounded
    if antipode:
        anti = _search(pre.W.T, pre.valid, pre.row_norm, _antipode(search.best_x)[None],
                       max_run_iters, max_total_iters, outside=unbounded)
        best, unbounded = jnp.minimum(best, anti.best), unbounded | anti.unbounded
    return _result(pre, best, unbounded)


def _check_starts(num_starts, max_total_iters):
    if num_starts < WRENCH_DIM + 1:
        raise ValueError(f"num_starts must be >= {WRENCH_DIM + 1}, got {num_starts}")
    return 30 * num_starts if max_total_iters is None else max_total_iters


class _Prepared(NamedTuple):
    """A wrench set ready for the search: masked rows zeroed, row norms, scale (largest
    row norm), start directions (S, 6) and ``h_null`` (``h`` along the thinnest axis)."""

    W: jax.Array
    valid: jax.Array
    row_norm: jax.Array
    scale: jax.Array
    directions: jax.Array
    h_null: jax.Array


def _eigh_in_chunks(gram):
    """``jnp.linalg.eigh`` of (6, 6) or (N, 6, 6) matrices, at most :data:`_EIGH_BATCH` per
    call."""
    if gram.ndim == 2:
        return tuple(jnp.linalg.eigh(gram))
    return jax.lax.map(lambda g: tuple(jnp.linalg.eigh(g)), gram, batch_size=_EIGH_BATCH)


#: eigh of one 6 x 6 matrix that stays chunked under any number of ``vmap``s.
_eigh = fold_vmap(_eigh_in_chunks, event_ndim=2)


def _prepare(wrenches, valid, num_starts, num_eigen_starts) -> _Prepared:
    W = jnp.asarray(wrenches)
    dtype = W.dtype if jnp.issubdtype(W.dtype, jnp.floating) else jnp.float32
    W = W.astype(dtype)
    valid = jnp.asarray(valid, bool)
    W = jnp.where(valid[:, None] & jnp.isfinite(W), W, 0.0)  # masked rows must not poison sums
    row_norm = jnp.linalg.norm(W, axis=1)
    scale = max_last(jnp.where(valid, row_norm, 0.0), 0.0)

    # Thinnest directions of the wrench set (smallest second moments) are likely near the
    # nearest facet's normal; the smallest one also catches rank-deficient sets (h ~ 0 there).
    _, vecs = _eigh(W.T @ W)
    u_null = vecs[:, 0]
    num_eig = min(num_eigen_starts, num_starts - WRENCH_DIM - 1)
    thin = vecs[:, : (num_eig + 1) // 2].T
    directions = jnp.concatenate(
        [
            jnp.asarray(_simplex_directions(), dtype),
            jnp.stack([thin, -thin], axis=1).reshape(-1, WRENCH_DIM)[:num_eig],
            jnp.asarray(_random_directions(num_starts - WRENCH_DIM - 1 - num_eig), dtype),
        ],
        axis=0,
    )
    h_null = jnp.minimum(
        max_last(jnp.where(valid, W @ u_null, -jnp.inf), -jnp.inf),
        max_last(jnp.where(valid, -(W @ u_null), -jnp.inf), -jnp.inf),
    )
    return _Prepared(W, valid, row_norm, scale, directions, h_null)


def _result(pre: _Prepared, best, unbounded):
    """Epsilon from the search's best ``h`` (0 when outside or below round-off)."""
    raw = jnp.minimum(best, pre.h_null)
    outside = unbounded | ~jnp.any(pre.valid)
    zero = outside | (raw <= ZERO_TOL * pre.scale)
    return jnp.where(zero, 0.0, raw).astype(pre.W.dtype)


def epsilon(points, normals, mask, mu, center, radius, num_edges=8, *, antipode=True,
            num_starts: int = NUM_STARTS, num_eigen_starts: int = NUM_EIGEN_STARTS):
    """Grasp quality epsilon of the L1 GWS (pure JAX, jittable, vmappable).

    Parameters
    ----------
    points : (K, 3) array
        Contact points (object frame).
    normals : (K, 3) array
        Unit contact normals pointing INTO the object.
    mask : (K,) bool array
        Which contact slots are real; wrenches of masked-out slots do not count.
    mu : float
        Friction coefficient.
    center : (3,) array
        Object center of mass (torque origin).
    radius : float
        Object max radius (torque scale).
    num_edges : int, static
        Friction-cone edges per contact.
    antipode : bool, static
        The search's last start, opposite the best local minimum (see
        :func:`epsilon_from_wrenches`).
    num_starts, num_eigen_starts : int, static
        Start directions of the search, and how many are eigen-directions (see
        :func:`epsilon_from_wrenches`).

    Returns
    -------
    scalar array
        Distance from the origin to the GWS boundary; 0 when the origin is not strictly
        inside (including fewer than 7 wrenches, flat sets, two point contacts, all masked).

    Notes
    -----
    Builds the wrenches with :func:`contact_wrenches` and calls
    :func:`epsilon_from_wrenches` (multi-start LPs and vertex walks on the polar polytope,
    described there).
    """
    points = jnp.asarray(points, jnp.result_type(float))
    normals, mask = jnp.asarray(normals), jnp.asarray(mask)
    _check_contacts(points.shape, normals.shape, mask.shape, jnp.shape(center), num_edges)
    W = contact_wrenches(points, normals, mu, center, radius, num_edges)
    valid = jnp.repeat(mask.astype(bool), num_edges)
    return epsilon_from_wrenches(W, valid, num_starts=num_starts,
                                 num_eigen_starts=num_eigen_starts, antipode=antipode)
