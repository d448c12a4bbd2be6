"""Outer ``vmap``s folded into a function's own leading batch axis (one call on all rows)."""

import jax

__all__ = ["fold_vmap"]


def fold_vmap(fn, event_ndim: int):
    """``fn`` whose outer ``vmap``s are folded into its leading batch axis.

    ``fn`` maps ``x (*batch, *event)`` (``event_ndim`` trailing axes; ``batch`` may be empty
    where ``fn`` allows it) to a pytree of ``(*batch, ...)`` arrays. Under ``vmap`` over x
    (V, *batch, *event) the result runs ONE ``fn`` call on ``(V * prod(batch), *event)`` and
    splits the rows back (nested vmaps fold again), for a ``fn`` that must see all rows at
    once: a buffer sized for its batch, a call whose batch size it bounds. A concrete call
    runs ``fn`` as it is."""

    @jax.custom_batching.custom_vmap
    def folded(x):
        return fn(x)

    @folded.def_vmap
    def _fold(axis_size, in_batched, x):
        if not in_batched[0]:  # vmapped over something else: the same x for every member
            out = folded(x)
            return out, jax.tree.map(lambda _: False, out)
        batch = x.shape[:x.ndim - event_ndim]
        out = folded(x.reshape(-1, *x.shape[x.ndim - event_ndim:]))
        out = jax.tree.map(lambda y: y.reshape(*batch, *y.shape[1:]), out)
        return out, jax.tree.map(lambda _: True, out)

    def call(x):
        return folded(x) if isinstance(x, jax.core.Tracer) else fn(x)

    return call
