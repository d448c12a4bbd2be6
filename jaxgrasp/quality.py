"""Grasp quality: epsilon of the L1 grasp wrench space (Ferrari & Canny 1992, Miller & Allen 1999).

Convention (DESIGN §6). Contact ``i`` has point ``p_i`` and unit normal ``n_i`` pointing INTO
the object (the direction the finger pushes). Its friction cone (coefficient ``mu``) is
linearized with ``num_edges`` edges of unit normal component::

    f_ik = n_i + mu (cos θ_k t1_i + sin θ_k t2_i),   θ_k = 2π k / num_edges
    w_ik = (f_ik, (p_i - c) × f_ik / r)                (6,)

with ``c`` the object's center of mass and ``r`` its max radius (torque scale). The grasp
wrench space (GWS) is the convex hull of all ``w_ik`` and

    epsilon = distance from the origin to the boundary of the GWS,

0 when the origin is not strictly inside (origin outside or on the boundary, flat/rank-deficient
wrench sets such as two point contacts). Equivalently, with the support function
``h(u) = max_k u · w_k``, ``epsilon = max(0, min_{|u|=1} h(u))``.

Two implementations with identical arguments:

* :func:`epsilon_qhull` - the reference: numpy (float64) + ``scipy.spatial.ConvexHull``.
* :func:`epsilon` - pure JAX, jittable and vmappable, fixed-size masked contact arrays; the
  method is described in :func:`epsilon_from_wrenches`.

The tangent basis ``(t1, t2)`` of a normal is a fixed function of the normal
(:func:`tangent_basis`), so the linearized cone is equivariant under rotations about ``z`` for
normals with ``|n_z| < 0.9`` and epsilon is exactly invariant under translating the whole grasp;
under other rotations the edges turn about the normal and epsilon changes by the polygonal
approximation error of the cone (small for many edges).
"""

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "tangent_basis",
    "contact_wrenches",
    "epsilon",
    "epsilon_from_wrenches",
    "epsilon_qhull",
    "epsilon_qhull_from_wrenches",
]

WRENCH_DIM = 6
#: Tangent helper axis switches from z to x when |n_z| >= this (keeps t1 well defined).
_HELPER_SWITCH = 0.9
#: epsilon below ``ZERO_TOL * max |w_k|`` is reported as exactly 0 (rank-deficient sets give
#: float32 round-off of this order; the reported error is bounded by the same amount).
ZERO_TOL = 1e-5


# --------------------------------------------------------------------------------------------
# Wrenches
# --------------------------------------------------------------------------------------------


def tangent_basis(normals):
    """Unit tangents ``t1, t2`` with ``(t1, t2, n)`` right-handed; a fixed function of ``n``.

    ``t1 = normalize(a × n)`` with helper ``a = e_z`` (or ``e_x`` when ``|n_z| >= 0.9``),
    ``t2 = n × t1``. For side contacts (normal horizontal) the edges are aligned with the
    vertical, which keeps symmetric grasps symmetric.

    Parameters
    ----------
    normals : (..., 3) array
        Unit normals.

    Returns
    -------
    t1, t2 : (..., 3) arrays
    """
    n = jnp.asarray(normals)
    ez = jnp.array([0.0, 0.0, 1.0], n.dtype)
    ex = jnp.array([1.0, 0.0, 0.0], n.dtype)
    helper = jnp.where(jnp.abs(n[..., 2:3]) < _HELPER_SWITCH, ez, ex)
    t1 = jnp.cross(helper, n)
    t1 = t1 / jnp.maximum(jnp.linalg.norm(t1, axis=-1, keepdims=True), 1e-12)
    t2 = jnp.cross(n, t1)
    return t1, t2


def contact_wrenches(points, normals, mu, center, radius, num_edges=8):
    """Primitive wrenches of linearized friction cones, DESIGN §6 convention.

    Parameters
    ----------
    points : (K, 3) array
        Contact points.
    normals : (K, 3) array
        Unit normals pointing into the object (renormalized here; zero rows are allowed and
        give finite wrenches, for masked-out buffer slots).
    mu : float
        Friction coefficient.
    center : (3,) array
        Torque origin (object center of mass).
    radius : float
        Torque scale (object max radius).
    num_edges : int, static
        Cone edges per contact.

    Returns
    -------
    (K * num_edges, 6) array
        Row ``i * num_edges + k`` is ``w_ik = (f_ik, (p_i - c) × f_ik / r)``.
    """
    points = jnp.asarray(points)
    normals = jnp.asarray(normals, points.dtype)
    n = normals / jnp.maximum(jnp.linalg.norm(normals, axis=-1, keepdims=True), 1e-12)
    t1, t2 = tangent_basis(n)
    theta = 2.0 * jnp.pi * jnp.arange(num_edges, dtype=points.dtype) / num_edges
    tangential = (
        jnp.cos(theta)[None, :, None] * t1[:, None, :]
        + jnp.sin(theta)[None, :, None] * t2[:, None, :]
    )
    forces = n[:, None, :] + mu * tangential  # (K, E, 3)
    arms = (points - jnp.asarray(center, points.dtype))[:, None, :]
    torques = jnp.cross(jnp.broadcast_to(arms, forces.shape), forces) / radius
    return jnp.concatenate([forces, torques], axis=-1).reshape(-1, WRENCH_DIM)


# --------------------------------------------------------------------------------------------
# JAX epsilon
# --------------------------------------------------------------------------------------------


def _fibonacci_free_directions(num: int, seed: int = 0) -> np.ndarray:
    """A fixed set of ``num`` random unit directions in R^6 (constant folded at trace time)."""
    u = np.random.default_rng(seed).standard_normal((num, WRENCH_DIM))
    return (u / np.linalg.norm(u, axis=1, keepdims=True)).astype(np.float32)


def _simplex_directions() -> np.ndarray:
    """The 7 vertices of a regular simplex centred at 0 in R^6: a positively spanning set."""
    e = np.eye(WRENCH_DIM + 1) - 1.0 / (WRENCH_DIM + 1)
    # Orthonormal basis of the hyperplane sum(x) = 0 in R^7, then coordinates in it.
    q, _ = np.linalg.qr(e[:, :WRENCH_DIM])
    v = e @ q
    return (v / np.linalg.norm(v, axis=1, keepdims=True)).astype(np.float32)


class _LPState(NamedTuple):
    """One run of the active-set LP  max c·x  s.t.  W x <= 1  (the polar polytope P°).

    x : (6,) current feasible point of P°
    c : (6,) unit objective; replaced by x/|x| at each LP optimum (successive LP)
    slots : (6,) int32 indices of working-set constraints (rows of W)
    on : (6,) bool, which slots are in use
    best_norm : float, |x| at the previous LP optimum (convergence test)
    done, unbounded : bool
    it : int32 iterations taken
    """

    x: jax.Array
    c: jax.Array
    slots: jax.Array
    on: jax.Array
    best_norm: jax.Array
    done: jax.Array
    unbounded: jax.Array
    it: jax.Array


def _lp_init(c):
    dtype = c.dtype
    return _LPState(
        x=jnp.zeros(WRENCH_DIM, dtype),
        c=c,
        slots=jnp.zeros(WRENCH_DIM, jnp.int32),
        on=jnp.zeros(WRENCH_DIM, bool),
        best_norm=jnp.zeros((), dtype),
        done=jnp.zeros((), bool),
        unbounded=jnp.zeros((), bool),
        it=jnp.zeros((), jnp.int32),
    )


def _lp_step(W, valid, row_norm, s: _LPState, tol_dir, tol_lam, tol_conv):
    """One iteration of the primal active-set method for an inequality-form LP."""
    A = W[s.slots] * s.on[:, None]  # working-set rows, zero for free slots
    gram = A @ A.T + jnp.diag((~s.on).astype(W.dtype))  # SPD: working rows are independent
    lam = jnp.linalg.solve(gram, A @ s.c)
    d = s.c - A.T @ lam  # projection of c onto the null space of the working rows
    dnorm = jnp.linalg.norm(d)
    full = jnp.all(s.on)
    move = (dnorm > tol_dir) & ~full

    # Move along d until the first constraint blocks (ratio test, lowest index on ties).
    in_ws = jnp.zeros(W.shape[0], bool).at[s.slots].max(s.on)
    rate = W @ d
    slack = jnp.maximum(1.0 - W @ s.x, 0.0)
    blocking = valid & ~in_ws & (rate > tol_dir * row_norm * dnorm)
    ratio = jnp.where(blocking, slack / jnp.where(blocking, rate, 1.0), jnp.inf)
    k = jnp.argmin(ratio)
    unbounded_now = move & ~jnp.any(blocking)
    free = jnp.argmin(s.on)
    x_move = s.x + jnp.where(unbounded_now, 0.0, ratio[k]) * d
    slots_move = s.slots.at[free].set(k.astype(jnp.int32))
    on_move = s.on.at[free].set(~unbounded_now)

    # Stationary: drop the most negative multiplier, or stop (LP optimal for c).
    lam_on = jnp.where(s.on, lam, jnp.inf)
    j = jnp.argmin(lam_on)
    drop = ~move & (lam_on[j] < -tol_lam)
    on_drop = s.on.at[j].set(False)

    # LP optimal: successive linearization of |x|^2, c <- x/|x|; stop once |x| stalls.
    optimal = ~move & ~drop
    xnorm = jnp.linalg.norm(s.x)
    stalled = xnorm <= s.best_norm * (1.0 + tol_conv)
    c_next = jnp.where(xnorm > 0, s.x / jnp.maximum(xnorm, 1e-30), s.c)

    new = _LPState(
        x=jnp.where(move, x_move, s.x),
        c=jnp.where(optimal, c_next, s.c),
        slots=jnp.where(move, slots_move, s.slots),
        on=jnp.where(move, on_move, jnp.where(drop, on_drop, s.on)),
        best_norm=jnp.where(optimal, xnorm, s.best_norm),
        done=unbounded_now | (optimal & stalled),
        unbounded=unbounded_now,
        it=s.it + 1,
    )
    # Finished lanes stay frozen (batched while_loop runs until every lane is done).
    return jax.tree.map(lambda a, b: jnp.where(s.done, a, b), s, new)


def _lp_solve(W, valid, row_norm, c, max_iters, tol_dir, tol_lam, tol_conv):
    def cond(s):
        return ~s.done & (s.it < max_iters)

    def body(s):
        return _lp_step(W, valid, row_norm, s, tol_dir, tol_lam, tol_conv)

    return jax.lax.while_loop(cond, body, _lp_init(c))


def epsilon_from_wrenches(
    wrenches,
    valid,
    *,
    num_directions: int = 256,
    num_starts: int = 8,
    max_iters: int = 48,
):
    """Distance from the origin to the boundary of ``conv{w_k : valid_k}``, 0 if not inside.

    Method
    ------
    ``epsilon = max(0, min_{|u|=1} h(u))`` with ``h(u) = max_k u·w_k``. Any unit ``u`` gives
    an upper bound ``h(u)``; a sampled minimum alone can be far off in 6-D. We use the polar
    polytope ``P° = {x : W x <= 1}``: when the origin is strictly inside the hull, ``P°`` is
    bounded, its vertices are ``n_F / d_F`` for the hull facets ``F`` (unit normal ``n_F``,
    distance ``d_F``), and ``epsilon = min_F d_F = 1 / max_{x in P°} |x|``.

    1. Sample ``num_directions`` fixed directions and evaluate ``h`` (cheap upper bounds;
       ``h <= 0`` already proves the origin is not strictly inside).
    2. From the 7 vertices of a regular simplex (a positively spanning set) and the
       ``num_starts`` best sampled directions, run successive linear programming on
       ``max |x|^2`` over ``P°``: solve ``max c·x, W x <= 1`` exactly with a primal
       active-set (simplex-type) method, set ``c = x/|x|``, repeat until ``|x|`` stalls.
       Each LP is a ray shot: its optimum is the polar vertex of the facet hit by the ray
       along ``c``, so the facet distance decreases monotonically and stops at a facet whose
       foot point lies inside it (a local minimum of ``h`` on the sphere). The global minimum
       is the best of these local minima over the starts.
    3. If any LP is unbounded (no constraint blocks a direction ``d``: ``W d <= 0``, i.e.
       ``h(d) <= 0``), the origin is not strictly inside -> 0. An unbounded ``P°`` is
       always caught by one of the 7 simplex starts, since some of them has ``c·d > 0``.
    4. Every candidate is scored by ``h(x/|x|)`` evaluated directly, so the result is always
       a true value of ``h`` (an upper bound on the exact answer even if an LP stopped early);
       values below ``ZERO_TOL * max|w|`` (rank-deficient sets: two point contacts) are 0.

    Parameters
    ----------
    wrenches : (N, 6) array
    valid : (N,) bool array
        Rows that count; all-False gives 0.
    num_directions, num_starts, max_iters : int, static
        Sampled directions, local starts from the best of them, iteration cap per start.

    Returns
    -------
    scalar array (wrench dtype)
    """
    W = jnp.asarray(wrenches)
    dtype = W.dtype if jnp.issubdtype(W.dtype, jnp.floating) else jnp.float32
    W = W.astype(dtype)
    valid = jnp.asarray(valid, bool)
    W = jnp.where(valid[:, None] & jnp.isfinite(W), W, 0.0)  # masked rows must not poison sums
    row_norm = jnp.linalg.norm(W, axis=1)
    scale = jnp.max(jnp.where(valid, row_norm, 0.0))

    def support(u):
        return jnp.max(jnp.where(valid, W @ u, -jnp.inf))

    # 1. Sampled support function.
    dirs = jnp.asarray(_fibonacci_free_directions(num_directions), dtype)
    h_dirs = jnp.max(jnp.where(valid[None, :], dirs @ W.T, -jnp.inf), axis=1)
    _, best = jax.lax.top_k(-h_dirs, num_starts)

    # 2. Successive LP from the simplex directions and the best sampled directions.
    starts = jnp.concatenate([jnp.asarray(_simplex_directions(), dtype), dirs[best]], axis=0)
    tol_dir = jnp.asarray(1e-6, dtype)
    runs = jax.vmap(
        lambda c: _lp_solve(W, valid, row_norm, c, max_iters, tol_dir, 1e-6, 1e-6)
    )(starts)
    xnorm = jnp.linalg.norm(runs.x, axis=1, keepdims=True)
    u_lp = runs.x / jnp.maximum(xnorm, 1e-30)
    h_lp = jnp.where(xnorm[:, 0] > 0, jax.vmap(support)(u_lp), jnp.inf)

    # Smallest-variance direction of the wrench set: h there is ~0 for rank-deficient sets.
    _, vecs = jnp.linalg.eigh(W.T @ W)
    u_null = vecs[:, 0]
    h_null = jnp.minimum(support(u_null), support(-u_null))

    raw = jnp.minimum(jnp.minimum(jnp.min(h_dirs), jnp.min(h_lp)), h_null)
    outside = jnp.any(runs.unbounded) | ~jnp.any(valid)
    zero = outside | (raw <= ZERO_TOL * scale)
    return jnp.where(zero, 0.0, raw).astype(dtype)


def epsilon(points, normals, mask, mu, center, radius, num_edges=8):
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

    Returns
    -------
    scalar array
        Distance from the origin to the GWS boundary; 0 when the origin is not strictly
        inside (including fewer than 7 wrenches, flat sets, two point contacts, all masked).

    Notes
    -----
    Builds the wrenches with :func:`contact_wrenches` and calls
    :func:`epsilon_from_wrenches` (exact successive-LP method, described there).
    """
    points = jnp.asarray(points, jnp.result_type(float))
    W = contact_wrenches(points, normals, mu, center, radius, num_edges)
    valid = jnp.repeat(jnp.asarray(mask, bool), num_edges)
    return epsilon_from_wrenches(W, valid)


# --------------------------------------------------------------------------------------------
# Qhull reference
# --------------------------------------------------------------------------------------------


def _contact_wrenches_np(points, normals, mu, center, radius, num_edges):
    """float64 numpy twin of :func:`contact_wrenches` (reference path, independent of JAX)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    helper = np.where(
        np.abs(n[:, 2:3]) < _HELPER_SWITCH, np.array([0.0, 0.0, 1.0]), np.array([1.0, 0, 0])
    )
    t1 = np.cross(helper, n)
    t1 /= np.maximum(np.linalg.norm(t1, axis=1, keepdims=True), 1e-12)
    t2 = np.cross(n, t1)
    theta = 2.0 * np.pi * np.arange(num_edges) / num_edges
    f = n[:, None, :] + mu * (
        np.cos(theta)[None, :, None] * t1[:, None, :] + np.sin(theta)[None, :, None] * t2[:, None]
    )
    arms = np.broadcast_to((p - np.asarray(center, np.float64))[:, None, :], f.shape)
    tau = np.cross(arms, f) / float(radius)
    return np.concatenate([f, tau], axis=-1).reshape(-1, WRENCH_DIM)


def epsilon_qhull_from_wrenches(wrenches) -> float:
    """Reference epsilon of a wrench set (rows of ``wrenches``) with scipy's Qhull, float64.

    Flat sets (affine rank < 6, detected by SVD; Qhull would fail or joggle) and Qhull
    errors give 0. Otherwise ``epsilon = max(0, min_F -offset_F)`` over the hull facets
    (``hull.equations`` rows ``[n_F, offset_F]`` with unit outward ``n_F``, interior
    ``n_F·x + offset_F <= 0``), which is 0 when the origin is outside or on the boundary.
    """
    from scipy.spatial import ConvexHull, QhullError

    W = np.asarray(wrenches, np.float64).reshape(-1, WRENCH_DIM)
    if W.shape[0] <= WRENCH_DIM:
        return 0.0
    sv = np.linalg.svd(W - W.mean(axis=0), compute_uv=False)
    if sv[-1] <= 1e-10 * max(sv[0], 1e-300):
        return 0.0
    try:
        hull = ConvexHull(W)
    except QhullError:
        return 0.0
    return float(max(0.0, np.min(-hull.equations[:, -1])))


def epsilon_qhull(points, normals, mask, mu, center, radius, num_edges=8) -> float:
    """Reference epsilon (numpy + ``scipy.spatial.ConvexHull``), same arguments as :func:`epsilon`.

    Returns
    -------
    float
        Distance from the origin to the GWS boundary, 0 when not strictly inside or flat.
    """
    W = _contact_wrenches_np(points, normals, mu, center, radius, num_edges)
    keep = np.repeat(np.asarray(mask, bool).reshape(-1), num_edges)
    return epsilon_qhull_from_wrenches(W[keep])
