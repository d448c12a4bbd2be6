"""Reductions over a long minor axis that XLA CPU keeps in one fusion.

XLA CPU's tree-reduction pass rewrites a reduction over more than 32 elements into a
reduce-window and a reduce; the reduce-window is a kernel of its own (~1 us a call), which
the pivot loops and the contacts would pay every iteration (docs/design.md, "The JAX tail:
contacts and epsilon").
Folding the axis by halves first gives the same min, max or any (exact in any order) with
no reduce-window."""

import jax.numpy as jnp

__all__ = ["any_last", "fold_last", "max_last", "min_last", "running_count"]

#: XLA CPU's tree-reduction pass splits reductions over more elements than this.
TREE_REDUCE = 32


def fold_last(x, op, fill):
    """``x`` (..., N) folded along its last axis by halves (``op`` elementwise, ``fill`` its
    identity, padding an odd length) to at most :data:`TREE_REDUCE` elements."""
    while x.shape[-1] > TREE_REDUCE:
        if x.shape[-1] % 2:
            x = jnp.concatenate([x, jnp.full(x.shape[:-1] + (1,), fill, x.dtype)], axis=-1)
        half = x.shape[-1] // 2
        x = op(x[..., :half], x[..., half:])
    return x


def min_last(x, fill):
    """``jnp.min(x, axis=-1)``; ``fill``: an upper bound of ``x`` (e.g. inf)."""
    return jnp.min(fold_last(x, jnp.minimum, fill), axis=-1)


def max_last(x, fill):
    """``jnp.max(x, axis=-1)``; ``fill``: a lower bound of ``x`` (e.g. -inf)."""
    return jnp.max(fold_last(x, jnp.maximum, fill), axis=-1)


def any_last(x):
    """``jnp.any(x, axis=-1)`` of a bool array."""
    return jnp.any(fold_last(x, jnp.logical_or, False), axis=-1)


def running_count(x):
    """``jnp.cumsum(x)`` of a bool vector (int32), as a masked sum over a triangular mask:
    a cumsum is an unfused reduce-window on XLA CPU."""
    n = x.shape[-1]
    return jnp.sum(x[None, :] & jnp.tri(n, dtype=bool), axis=1, dtype=jnp.int32)
