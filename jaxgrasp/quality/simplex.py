"""The search behind epsilon (private machinery of :mod:`jaxgrasp.quality.epsilon`).

Revised simplex LPs and greedy vertex walks on the polar polytope ``P° = {x : W x <= 1}``
(the method: :func:`jaxgrasp.quality.epsilon_from_wrenches`), run one at a time for one
wrench set (:func:`_search`) or dealt to a few vmapped lanes over a batch of sets
(:func:`_lane_search`).
"""

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgrasp._reduce import max_last, min_last, running_count
from jaxgrasp.quality.wrenches import WRENCH_DIM

#: A row blocks an edge e only if w·e > _RATE_TOL |w| |e|: rows (nearly) in the span of the
#: rest of the basis never enter it, and an edge that nothing blocks has h(e) <= ~ZERO_TOL.
_RATE_TOL = 1e-5
#: Largest residual ``|I - B inv|`` entry of a basis inverse a walk trusts (a pivot on a
#: basis float32 made nearly singular can zero or overflow a column: docs/design.md, "Epsilon
#: of the grasp wrench space"). Below it the refined inverse's
#: residual is <= ~1e-4, so the basis rows (which the ratio test skips) block no edge by more
#: than that: 1e-3 missed one more of 3 329 real trial contact sets against Qhull, 1e-2 none.
_RESID_MAX = 1e-2


def _simplex_directions(dim: int = WRENCH_DIM) -> np.ndarray:
    """The ``dim + 1`` unit vertices of a regular simplex centred at 0 in R^dim."""
    e = np.eye(dim + 1) - 1.0 / (dim + 1)
    q, _ = np.linalg.qr(e[:, :dim])  # orthonormal basis of the hyperplane sum(x) = 0
    v = e @ q
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _start_basis(c, half_angle: float = 0.5):
    """Artificial starting basis of the walk: a pointed cone of 6 edges around direction ``c``.

    The walk starts at the vertex ``x = 0`` of 6 artificial constraints ``z_i·x <= 0`` whose
    edges ``d_j = cos(φ) c + sin(φ) s_j`` (``s_j`` a regular simplex in ``c``'s orthogonal
    complement, built with a Householder reflection) surround ``c``. With ``s_i·s_j = -1/5``
    (i != j) the rows are ``z_i = -c / (6 cos φ) - 5 s_i / (6 sin φ)`` (so ``z_i·(-d_j) = δ_ij``).

    Returns
    -------
    inv : (6, 6) basis inverse ``-D^T`` (edges ``-inv[:, j] = d_j``)
    rows : (6, 6) artificial rows ``z_i``
    """
    dim = WRENCH_DIM
    sigma = jnp.where(c[0] > 0, -1.0, 1.0)
    v = jnp.zeros(dim, c.dtype).at[0].set(1.0) - sigma * c  # |v|^2 >= 2
    house = jnp.eye(dim, dtype=c.dtype) - 2.0 * jnp.outer(v, v) / jnp.dot(v, v)
    simplex = jnp.asarray(_simplex_directions(dim - 1), c.dtype)  # (6, 5)
    s = simplex @ house[:, 1:].T  # rows: unit simplex vertices orthogonal to c
    cos, sin = np.cos(half_angle), np.sin(half_angle)
    edges = cos * c[None, :] + sin * s
    rows = -c[None, :] / (6.0 * cos) - 5.0 * s / (6.0 * sin)
    return -edges.T, rows


class _WalkState(NamedTuple):
    """A vertex walk on the polar polytope ``P° = {x : W x <= 1}`` (plus artificial rows).

    inv : (6, 6) inverse of the basis matrix (its rows are the basis constraints)
    slots : (6,) int32 basis rows; ``slots >= N`` are the artificial start rows
    stalled : bool, the last pivot was degenerate (the next one follows Bland's rule)
    done, unbounded : bool
    it : int32 iterations of this run
    h : float, the smallest ``h(x/|x|)`` at the vertices a walk step started from (inf
        before; a walk's vertices have falling ``h``, up to float32 round-off)
    x : (6,) that vertex (zeros before)
    prev : (6,) int32 the basis rows before the last walk step (an LP carries its start's)
    """

    inv: jax.Array
    slots: jax.Array
    stalled: jax.Array
    done: jax.Array
    unbounded: jax.Array
    it: jax.Array
    h: jax.Array
    x: jax.Array
    prev: jax.Array


def _walk_init(inv0, slots):
    return _WalkState(
        inv=inv0,
        slots=slots,
        stalled=jnp.zeros((), bool),
        done=jnp.zeros((), bool),
        unbounded=jnp.zeros((), bool),
        it=jnp.zeros((), jnp.int32),
        h=jnp.asarray(jnp.inf, inv0.dtype),
        x=jnp.zeros(WRENCH_DIM, inv0.dtype),
        prev=slots,
    )


def _mm(a, b):
    """``a (i, k) @ b (k, j)`` as an unrolled sum over the small ``k`` (elementwise products:
    XLA CPU fuses and vectorizes them along ``j``, unlike a batched dot of 6 x 6 blocks)."""
    out = a[:, 0, None] * b[None, 0, :]
    for k in range(1, a.shape[1]):
        out = out + a[:, k, None] * b[None, k, :]
    return out


def _mv(a, v):
    """``a (i, k) @ v (k,)`` as a reduction (the pivot loops' 6 x 6 products: vmapped, a dot
    is a thunk of its own on XLA CPU; this fuses with its neighbours)."""
    return jnp.sum(a * v[None, :], axis=1)


def _vm(v, a):
    """``v (k,) @ a (k, j)``, as :func:`_mv`."""
    return jnp.sum(v[:, None] * a, axis=0)


def _vertex(Wt, art_rows, s: _WalkState):
    """The basis of ``s`` refined: (inverse, artificial mask, vertex x, residual
    ``I - B inv`` of the inverse before the refinement).

    The inverse gets one Newton-Schulz step every pivot (float32 drift of rank-one updates).
    """
    n = Wt.shape[1]
    eye = jnp.eye(WRENCH_DIM, dtype=Wt.dtype)
    art = s.slots >= n
    basis = jnp.where(art[:, None], art_rows[jnp.clip(s.slots - n, 0, WRENCH_DIM - 1)],
                      Wt[:, jnp.clip(s.slots, 0, n - 1)].T)
    resid = eye - jnp.sum(basis[:, :, None] * s.inv[None, :, :], axis=1)
    inv = s.inv + jnp.sum(s.inv[:, :, None] * resid[None, :, :], axis=1)
    return inv, art, _mv(inv, jnp.where(art, 0.0, 1.0).astype(Wt.dtype)), resid


def _sane(resid):
    """Whether a basis inverse is still an inverse: its residual ``I - B inv`` (before the
    refinement) is small. Past that (a basis float32 made nearly singular: a pivot can round
    a column of the inverse to exact zeros, or overflow it), its edges and vertex mean
    nothing and a zero or overflowed edge reads as a ray: a false "origin outside". Then
    the basis rows, which the ratio test skips, cannot block an edge either."""
    return jnp.all(jnp.abs(resid) <= _RESID_MAX)


def _is_ray(edge_norm):
    """(E,) which edges with an infinite step (no row blocks them) are rays: not a zero or
    overflowed edge. A ray ``e`` has ``h(e / |e|) <= _RATE_TOL max |w|``: epsilon ~0."""
    return (edge_norm > 0) & jnp.isfinite(edge_norm)


def _pivot(Wt, inv, slots, j, k, do):
    """Row ``k`` replaces basis row ``j`` (rank-one update of the inverse) where ``do``."""
    eye = jnp.eye(WRENCH_DIM, dtype=Wt.dtype)
    g = _vm(Wt[:, k], inv)  # g_j = a_k·inv[:, j] = -rate < 0
    inv_pivot = inv - jnp.outer(inv[:, j] / g[j], g - eye[j])
    return (jnp.where(do, inv_pivot, inv),
            jnp.where(do, slots.at[j].set(k.astype(jnp.int32)), slots))


def _ratio_test(rates, slack, valid, slots, edge_norm, row_norm):
    """Step length (E,) and entering row (E,) along each of E edges, ``rates`` (E, N).

    Rows that (nearly) lie in the span of the other basis rows have rate ~ 0: never enter.
    The entering row is the first at the minimum (two plain reductions: no variadic argmin);
    an edge that no row blocks gets an infinite step (and row 0).
    """
    n = rates.shape[1]
    # A scatter, not a compare against every slot: XLA CPU then rates the lanes' ratio fusion
    # as memory-bound and does not split it over its thread pool (docs/design.md, "The JAX
    # tail: contacts and epsilon").
    in_basis = jnp.zeros(n, bool).at[slots].set(True, mode="drop")
    block = (valid & ~in_basis)[None, :] & (rates > _RATE_TOL * edge_norm[:, None] * row_norm)
    ratio = jnp.where(block, slack[None, :] / jnp.where(block, rates, 1.0), jnp.inf)
    step = min_last(ratio, jnp.inf)
    entering = min_last(jnp.where(ratio == step[:, None], jnp.arange(n)[None, :], n), n)
    return step, jnp.where(entering < n, entering, 0)


def _bland(lam, edge_norm, slots):
    """Improving edges (negative multipliers) and the one Bland's rule takes."""
    negative = lam < -1e-6 * edge_norm
    return negative, jnp.argmin(jnp.where(negative, slots, jnp.iinfo(jnp.int32).max))


def _lp_step(Wt, valid, row_norm, c0, art_rows, s: _WalkState):
    """One pivot of the revised simplex method for ``max c0·x`` over ``P°``.

    The artificial rows leave first (most negative multiplier); then the steepest edge
    (most negative multiplier per edge length), or Bland's rule right after a degenerate
    pivot (no cycling). One ratio test per pivot: the entering edge's only.
    """
    inv, art, x, resid = _vertex(Wt, art_rows, s)
    edges = -inv  # e_j = -inv[:, j] leaves row j and keeps the others tight
    edge_norm = jnp.linalg.norm(edges, axis=0)
    lam = _vm(c0, inv)  # multipliers: lam_j = -c0·e_j
    negative, bland = _bland(lam, edge_norm, s.slots)
    steep = jnp.argmin(jnp.where(negative, lam / edge_norm, jnp.inf))
    any_art = jnp.any(art)
    j = jnp.where(any_art, jnp.argmin(jnp.where(art, lam, jnp.inf)),
                  jnp.where(s.stalled, bland, steep))
    pivot = any_art | jnp.any(negative)

    rx = _mm(jnp.stack([edges[:, j], x]), Wt)  # (2, N): rates along e_j, then W x
    slack = jnp.maximum(1.0 - rx[1], 0.0)
    step, k = _ratio_test(rx[:1], slack, valid, s.slots, edge_norm[j, None], row_norm)
    step, k = step[0], k[0]
    # An edge that no row blocks is a ray in the recession cone: P° unbounded, origin outside
    # (if the edge checks out on every row). A basis float32 made (nearly) singular, or an
    # edge no row checks out as blocked or as a ray, proves nothing: the run ends.
    sane = _sane(resid)
    ray = step == jnp.inf
    unbounded = sane & pivot & ray & _is_ray(edge_norm[j])
    do = sane & pivot & ~ray
    inv, slots = _pivot(Wt, inv, s.slots, j, k, do)
    # A (nearly) tight entering row: a degenerate pivot, x did not move.
    return _WalkState(inv=inv, slots=slots, stalled=do & (slack[k] <= 1e-6), done=~do,
                      unbounded=unbounded, it=s.it + 1, h=s.h, x=jnp.where(sane, x, s.x),
                      prev=s.prev)  # only a walk reads prev


def _walk_step(Wt, valid, row_norm, art_rows, s: _WalkState):
    """One step of the greedy walk on ``|x|`` from an LP optimum (no artificial rows left).

    Move to the farthest of the 6 adjacent vertices while that increases ``|x|``; at a
    degenerate vertex take Bland pivots for ``max (x/|x|)·y`` (no cycling in exact
    arithmetic); stop when neither applies (a local maximum of ``|x|``: a locally nearest
    facet) or when the step returns to the basis of one step ago. ``h`` is the smallest
    ``h(x/|x|)`` of the vertices the walk's steps started from.

    ``Wt`` is the wrench matrix transposed, (6, N): the per-row work (rates, slacks, ratio
    tests) runs along its long minor axis.
    """
    inv, _, x, resid = _vertex(Wt, art_rows, s)
    edges = -inv
    edge_norm = jnp.linalg.norm(edges, axis=0)
    wx = _mm(x[None], Wt)[0]  # W x (vectorized along the rows)
    slack = jnp.maximum(1.0 - wx, 0.0)
    # Each edge's rates and ratio test on its own (1, N), as the LP step's: XLA CPU rates
    # such a fusion memory-bound and runs it on the calling thread; one (6, N) fusion it
    # splits over its thread pool, which takes more CPU than it saves where a core is free
    # (docs/design.md, "The JAX tail: contacts and epsilon").
    tests = [_ratio_test(_mm(edges[:, j][None], Wt), slack, valid, s.slots, edge_norm[j, None],
                         row_norm) for j in range(WRENCH_DIM)]
    step = jnp.concatenate([t[0] for t in tests])
    entering = jnp.concatenate([t[1] for t in tests])
    bounded = jnp.isfinite(step)
    neighbours = x[:, None] + jnp.where(bounded, step, 0.0) * edges
    nnorm = jnp.where(bounded, jnp.linalg.norm(neighbours, axis=0), -jnp.inf)
    xnorm = jnp.linalg.norm(x)
    h = max_last(jnp.where(valid, wx, -jnp.inf), -jnp.inf) / jnp.maximum(xnorm, 1e-30)

    negative, bland = _bland(_vm(x / jnp.maximum(xnorm, 1e-30), inv), edge_norm, s.slots)
    far = jnp.argmax(nnorm)
    improving = nnorm[far] > xnorm * (1.0 + 1e-6)
    pivot = improving | jnp.any(negative)
    # An edge that no row blocks is a ray in the recession cone: P° unbounded, origin outside
    # (if it checks out on every row). A basis float32 made (nearly) singular proves
    # nothing: the run ends with the last vertex's h (a true value of h: an upper bound).
    sane = _sane(resid)
    unbounded = sane & jnp.any(~bounded & _is_ray(edge_norm))
    do = sane & pivot & jnp.all(bounded)
    j = jnp.where(improving, far, bland)
    inv, slots = _pivot(Wt, inv, s.slots, j, entering[j], do)
    # Back to the basis of one step ago: float32 round-off near a degenerate vertex can swap
    # two rows forever (0.6 % of real trial sets had such a walk, each run to the cap of
    # max_run_iters steps while the other lanes idled). The walk ends there, with its best h.
    cycle = jnp.all(slots == s.prev)
    better = sane & (xnorm > 0) & jnp.isfinite(xnorm) & (h < s.h)
    return _WalkState(inv=inv, slots=slots, stalled=s.stalled, done=~do | cycle,
                      unbounded=unbounded, it=s.it + 1, h=jnp.where(better, h, s.h),
                      x=jnp.where(better, x, s.x), prev=s.slots)


class _SearchState(NamedTuple):
    """Sequential runs, one at a time (keeps vmapped lanes busy until the last run).

    run : _WalkState of the current run
    start : int32 index of the current run
    slots, invs : (S, 6), (S, 6, 6) the LP optimum of every start (the walks' starts)
    best : float, smallest ``h(x/|x|)`` over finished walks
    best_x : (6,) the vertex of that walk
    unbounded : bool, some run found ``P°`` unbounded (origin not strictly inside)
    it : int32 total iterations
    """

    run: _WalkState
    start: jax.Array
    slots: jax.Array
    invs: jax.Array
    best: jax.Array
    best_x: jax.Array
    unbounded: jax.Array
    it: jax.Array


def _runs(step, first, num, stop, max_run_iters, max_total_iters, init, store):
    """``while_loop`` over runs ``0..num-1`` (``num`` may be traced), one step per iteration.

    ``first(i) -> _WalkState`` starts run ``i``; ``step(i, run) -> run``; ``stop(s)`` ends
    the loop early; a finished run's ``h`` is folded into ``best`` and, if ``store`` (static),
    its basis stored at index ``i`` of ``slots``/``invs``."""

    def cond(s):
        return (s.start < num) & ~stop(s) & (s.it < max_total_iters)

    def body(s):
        i = s.start
        run = step(i, s.run)
        finished = run.done | (run.it >= max_run_iters)
        nxt = i + finished.astype(jnp.int32)
        fresh = first(nxt)
        slots, invs = s.slots, s.invs
        if store:
            slots = slots.at[i].set(jnp.where(finished, run.slots, slots[i]), mode="drop")
            invs = invs.at[i].set(jnp.where(finished, run.inv, invs[i]), mode="drop")
        return _SearchState(
            run=jax.tree.map(lambda a, b: jnp.where(finished, a, b), fresh, run),
            start=nxt,
            slots=slots,
            invs=invs,
            best=jnp.where(finished, jnp.minimum(s.best, run.h), s.best),
            best_x=jnp.where(finished & (run.h < s.best), run.x, s.best_x),
            unbounded=s.unbounded | run.unbounded,
            it=s.it + 1,
        )

    return jax.lax.while_loop(cond, body, init._replace(run=first(jnp.zeros((), jnp.int32))))


def _distinct_optima(slots, n):
    """(S,) which LP optima start a walk: free of artificial rows (``slots >= n``; a run
    that did not finish keeps its artificial start slots) and not the basis of an earlier
    start (a walk is a function of its start vertex)."""
    num = slots.shape[0]
    key = jnp.sort(slots, axis=1)
    ok = jnp.all(key < n, axis=1)
    same = jnp.all(key[:, None, :] == key[None, :, :], axis=-1)
    earlier = jnp.tril(jnp.ones((num, num), bool), -1)
    return ok & ~jnp.any(same & earlier & ok[None, :], axis=1)


def _search(Wt, valid, row_norm, directions, max_run_iters, max_total_iters, outside=False):
    """LPs from every start direction, then greedy walks from their distinct optima
    (none if ``outside``: the origin is already known not to be inside)."""
    num = directions.shape[0]
    n = Wt.shape[1]
    invs, rows = jax.vmap(_start_basis)(directions)
    art_slots = n + jnp.arange(WRENCH_DIM, dtype=jnp.int32)
    init = _SearchState(
        run=_walk_init(invs[0], art_slots),
        start=jnp.zeros((), jnp.int32),
        slots=jnp.broadcast_to(art_slots, (num, WRENCH_DIM)),
        invs=invs,
        best=jnp.asarray(jnp.inf, Wt.dtype),
        best_x=jnp.zeros(WRENCH_DIM, Wt.dtype),
        unbounded=jnp.asarray(outside, bool),
        it=jnp.zeros((), jnp.int32),
    )

    # 1. The LP max c·x from each start: most pivots (real grasps: ~16 per start, ~5 per walk).
    def lp_first(i):
        return _walk_init(invs[jnp.minimum(i, num - 1)], art_slots)

    def lp_step(i, run):
        i = jnp.minimum(i, num - 1)
        return _lp_step(Wt, valid, row_norm, directions[i], rows[i], run)

    lp = _runs(lp_step, lp_first, num, lambda s: s.unbounded, max_run_iters, max_total_iters,
               init, store=True)

    # 2. Walks from the distinct LP optima left without artificial rows (a walk is a
    # function of its start vertex: duplicates would repeat it).
    todo = _distinct_optima(lp.slots, n)
    order = jnp.argsort(~todo, stable=True)
    count = jnp.sum(todo)

    def walk_first(i):
        i = order[jnp.minimum(i, num - 1)]
        return _walk_init(lp.invs[i], lp.slots[i])

    def walk_step(i, run):
        return _walk_step(Wt, valid, row_norm, rows[0], run)

    walk = _runs(walk_step, walk_first, count, lambda s: s.unbounded, max_run_iters,
                 max_total_iters, init._replace(unbounded=lp.unbounded), store=False)
    return walk


class _LaneState(NamedTuple):
    """The lanes of :func:`_lane_runs`: each runs one job (a run of some trial) at a time.

    run : _WalkState of each lane's job, leading dim L
    job : (L,) int32 the lane's job, -1 when idle
    next : int32 the next job to hand out
    best, best_x, unbounded, it : (T,), (T, 6), (T,), (T,) per trial, as in
        :class:`_SearchState`
    slots, invs : (T, S, 6), (T, S, 6, 6) the finished runs' bases (the LP optima)
    """

    run: _WalkState
    job: jax.Array
    next: jax.Array
    best: jax.Array
    best_x: jax.Array
    unbounded: jax.Array
    it: jax.Array
    slots: jax.Array
    invs: jax.Array


def _lane_runs(step, first, where, num_jobs, lanes, max_run_iters, max_total_iters, init,
               store):
    """Runs of many trials on ``lanes`` vmapped lanes: a lane that finishes its run takes
    the next job, so no lane idles until the last job is handed out (a vmapped
    :func:`_runs` per trial waits for its slowest trial: ~1.4x the mean).

    ``where(job) -> (trial, start)``, ``first(job) -> _WalkState`` and ``step(job, run)``
    take a lane's job; each run is the same sequence of steps as in :func:`_runs`. A
    trial stops when a run finds ``P°`` unbounded or its runs took ``max_total_iters``
    steps: its other runs in progress are dropped (they are run concurrently here, so
    which ones differs from :func:`_runs` then; only the cap's rare cut depends on it).
    """
    T = init.best.shape[0]
    first_v, step_v = jax.vmap(first), jax.vmap(step)

    def cond(s):
        return jnp.any(s.job >= 0)

    def body(s):
        active = s.job >= 0
        job = jnp.maximum(s.job, 0)
        run = step_v(job, s.run)
        trial, start = where(job)
        hit = jnp.where(active, trial, T)  # idle lanes scatter out of bounds (dropped)
        it = s.it.at[hit].add(1, mode="drop")
        unbounded = s.unbounded.at[jnp.where(run.unbounded, hit, T)].set(True, mode="drop")
        finished = active & (run.done | (run.it >= max_run_iters))
        stopped = active & ~finished & (unbounded[trial] | (it[trial] >= max_total_iters))
        fold = jnp.where(finished, trial, T)
        best = s.best.at[fold].min(run.h, mode="drop")
        won = _last_lane_per_trial(finished & (run.h <= best[trial]) & (run.h < s.best[trial]),
                                   trial, T)
        s = s._replace(best=best, best_x=s.best_x.at[won].set(run.x, mode="drop"))
        if store:
            s = s._replace(
                slots=s.slots.at[fold, start].set(run.slots, mode="drop"),
                invs=s.invs.at[fold, start].set(run.inv, mode="drop"),
            )
        free = ~active | finished | stopped
        new = s.next + running_count(free) - 1  # free lanes take the next jobs in order
        take = free & (new < num_jobs)
        fresh = first_v(jnp.clip(new, 0, jnp.maximum(num_jobs - 1, 0)))
        return s._replace(
            run=jax.tree.map(lambda a, b: jnp.where(
                take.reshape(take.shape + (1,) * (a.ndim - 1)), a, b), fresh, run),
            job=jnp.where(take, new, jnp.where(free, -1, s.job)).astype(jnp.int32),
            next=jnp.minimum(s.next + jnp.sum(free), num_jobs).astype(jnp.int32),
            unbounded=unbounded,
            it=it,
        )

    job = jnp.arange(lanes, dtype=jnp.int32)
    job = jnp.where(job < num_jobs, job, -1)
    init = init._replace(run=first_v(jnp.maximum(job, 0)), job=job,
                         next=jnp.minimum(lanes, num_jobs).astype(jnp.int32))
    return jax.lax.while_loop(cond, body, init)


def _last_lane_per_trial(mask, trial, T):
    """(L,) each lane's trial where ``mask`` and no higher lane of that trial has ``mask``,
    else ``T`` (dropped by a scatter): a scatter's duplicate indices are applied in no fixed
    order on accelerators; on a CPU the last one wins, as here."""
    lane = jnp.arange(mask.shape[0], dtype=jnp.int32)
    last = jnp.full(T + 1, -1, jnp.int32).at[jnp.where(mask, trial, T)].max(lane)
    return jnp.where(mask & (last[trial] == lane), trial, T)


def _lane_search(pre, directions, need, lanes, max_run_iters, max_total_iters):
    """:func:`_search` from ``directions`` (T, S, 6) of every trial where ``need`` (leading
    dim T of ``pre``), its runs dealt to ``lanes`` lanes (:func:`_lane_runs`): LPs of all
    trials, then walks. Returns the walks' ``best``, ``best_x`` and ``unbounded``."""
    T, n = pre.W.shape[:2]
    num = directions.shape[1]
    Wt = jnp.swapaxes(pre.W, 1, 2)
    invs, rows = jax.vmap(jax.vmap(_start_basis))(directions)
    art_slots = n + jnp.arange(WRENCH_DIM, dtype=jnp.int32)
    dtype = pre.W.dtype
    init = _LaneState(
        run=None, job=None, next=None,
        best=jnp.full(T, jnp.inf, dtype),
        best_x=jnp.zeros((T, WRENCH_DIM), dtype),
        unbounded=jnp.zeros(T, bool),
        it=jnp.zeros(T, jnp.int32),
        slots=jnp.broadcast_to(art_slots, (T, num, WRENCH_DIM)),
        invs=invs,
    )

    # 1. LPs: job j is start j % S of the j // S-th needed trial.
    trials = jnp.argsort(~need, stable=True).astype(jnp.int32)

    def lp_where(j):
        return trials[j // num], j % num

    def lp_first(j):
        t, i = lp_where(j)
        return _walk_init(invs[t, i], art_slots)

    def lp_step(j, run):
        t, i = lp_where(j)
        return _lp_step(Wt[t], pre.valid[t], pre.row_norm[t], directions[t, i], rows[t, i],
                        run)

    lp = _lane_runs(lp_step, lp_first, lp_where, jnp.sum(need) * num, lanes, max_run_iters,
                    max_total_iters, init, store=True)

    # 2. Walks from each trial's distinct optima (none for a trial found outside).
    todo = jax.vmap(partial(_distinct_optima, n=n))(lp.slots)
    todo = todo & (need & ~lp.unbounded)[:, None]
    pairs = jnp.argsort(~todo.reshape(-1), stable=True).astype(jnp.int32)

    def walk_where(j):
        return pairs[j] // num, pairs[j] % num

    def walk_first(j):
        t, i = walk_where(j)
        return _walk_init(lp.invs[t, i], lp.slots[t, i])

    def walk_step(j, run):
        t, _ = walk_where(j)
        return _walk_step(Wt[t], pre.valid[t], pre.row_norm[t], rows[t, 0], run)

    walk = _lane_runs(walk_step, walk_first, walk_where, jnp.sum(todo), lanes, max_run_iters,
                      max_total_iters, init._replace(unbounded=lp.unbounded), store=False)
    return walk.best, walk.best_x, walk.unbounded
