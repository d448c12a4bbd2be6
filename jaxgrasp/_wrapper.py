"""Targets that wrap a target (or a trial) as pytrees: see :mod:`jaxgrasp.mcmc._base`."""

import jax

__all__ = ["register_wrapper"]


def register_wrapper(cls, child: str):
    """Register the frozen dataclass ``cls`` as a pytree whose one child is the field
    ``child`` (a wrapped target or trial) and whose other fields are static; unflattening
    skips ``__post_init__`` (the fields were checked when the object was built). A wrapper
    around a plain function flattens to that function, a static leaf: nothing changes for
    it."""
    names = [f for f in cls.__dataclass_fields__ if f != child]

    def flatten(obj):
        return (getattr(obj, child),), tuple(getattr(obj, n) for n in names)

    def unflatten(aux, children):
        obj = object.__new__(cls)
        object.__setattr__(obj, child, children[0])
        for n, v in zip(names, aux, strict=True):
            object.__setattr__(obj, n, v)
        return obj

    jax.tree_util.register_pytree_node(cls, flatten, unflatten)
    return cls
