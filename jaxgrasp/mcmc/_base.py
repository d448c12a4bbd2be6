"""Plumbing shared by the kernels: a hashable binding of (kernel, target, static options) and
input checks.

A :class:`~jaxgrasp.types.SamplingAlgorithm` built by the factories holds
``jax.tree_util.Partial(Bound(...), **arrays)``: the kernel function, the target and the static
options are *static* (compared by value, so rebuilding an algorithm with the same target hits
JAX's cache) and the array tunables and data (scales, ν, γ, σ, sketch, modes) are pytree
*leaves*. :func:`jaxgrasp.mcmc.sample` passes those leaves into ``jit`` as arguments, so a new
ν/γ/σ does not retrace and a large sketch is not baked into the program as a constant.

A target that is itself a pytree with array leaves (a wrapper registered with
:func:`jaxgrasp._wrapper.register_wrapper` around, say, a host trial that takes its
simulator's id as an array) goes among the leaves too: its arrays are arguments, its structure
and options static, so targets that differ only in those arrays share the compiled sampler.
"""

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import numpy as np

__all__ = ["Bound", "ValueHashed", "bind", "check_scalar", "check_array", "is_concrete",
           "call_target", "is_stochastic"]


def hash_key(obj: Any) -> Any:
    """``obj`` when hashable, else its identity (an unhashable target still works, it just
    does not share compiled code with an equal copy)."""
    try:
        hash(obj)
    except TypeError:
        return ("id", id(obj))
    return obj


def is_stochastic(fn: Callable) -> bool:
    """Whether ``fn`` is a stochastic (pseudo-marginal) target ``(x, key) -> ...``."""
    return bool(getattr(fn, "stochastic", False))


def call_target(fn: Callable, x: Any, key: Any = None):
    """``fn(x)``, or ``fn(x, key)`` when ``fn`` is a stochastic target: the wrappers of a
    target (lift, scaling) hand the noise key on."""
    return fn(x, key) if is_stochastic(fn) else fn(x)


class ValueHashed:
    """Hash and equality by ``type`` and ``self._key()``: rebuilt equal targets and kernels
    share JAX's compiled code."""

    def _key(self):
        raise NotImplementedError

    def __hash__(self):
        return hash(self._key())

    def __eq__(self, other):
        return type(other) is type(self) and self._key() == other._key()


@dataclass(frozen=True, eq=False)
class Bound(ValueHashed):
    """``fn(*args, logdensity_fn=logdensity_fn, **static, **kwargs)``, hashable by value."""

    fn: Callable
    logdensity_fn: Callable | None = None
    static: tuple = ()

    def _key(self):
        return (self.fn, hash_key(self.logdensity_fn), self.static)

    def __call__(self, *args, **kwargs):
        if self.logdensity_fn is not None:
            kwargs["logdensity_fn"] = self.logdensity_fn
        return self.fn(*args, **dict(self.static), **kwargs)


def has_arrays(tree: Any) -> bool:
    """Whether a pytree holds array leaves (a target with arrays is passed as one)."""
    return any(isinstance(x, (jax.Array, np.ndarray, jax.core.Tracer))
               for x in jax.tree.leaves(tree))


def bind(fn: Callable, logdensity_fn: Callable | None, static: dict, arrays: dict):
    """A pytree callable: static parts in the treedef, ``arrays`` as leaves (a target with
    array leaves among them: :func:`has_arrays`)."""
    if logdensity_fn is not None and has_arrays(logdensity_fn):
        arrays, logdensity_fn = {**arrays, "logdensity_fn": logdensity_fn}, None
    return jax.tree_util.Partial(Bound(fn, logdensity_fn, tuple(sorted(static.items()))), **arrays)


def is_concrete(x: Any) -> bool:
    """True when ``x`` holds values we can check on the host (not a tracer)."""
    return not isinstance(x, jax.core.Tracer)


def check_scalar(x: Any, name: str, *, positive: bool = False, allow_none: bool = False):
    """Validate a non-negative (or positive) finite scalar tunable; return it as an array."""
    if x is None:
        if allow_none:
            return None
        raise ValueError(f"{name} is required")
    if not is_concrete(x):
        return x
    a = np.asarray(x, dtype=np.float64)
    if a.shape != ():
        raise ValueError(f"{name} must be a scalar, got shape {a.shape}")
    if not np.isfinite(a):
        raise ValueError(f"{name} must be finite, got {a}")
    if a < 0 or (positive and a == 0):
        raise ValueError(f"{name} must be {'positive' if positive else 'non-negative'}, got {a}")
    return jax.numpy.asarray(x, dtype=jax.numpy.result_type(float))


def check_array(x: Any, name: str, *, ndim: int | None = None, shape_tail=None, min_rows=None):
    """Validate a finite float array (shape, finiteness) and return it as a JAX array."""
    if not is_concrete(x):
        return x
    a = np.asarray(x)
    if not np.issubdtype(a.dtype, np.number):
        raise ValueError(f"{name} must be a numeric array, got dtype {a.dtype}")
    if ndim is not None and a.ndim != ndim:
        raise ValueError(f"{name} must have {ndim} dimensions, got shape {a.shape}")
    if shape_tail is not None and tuple(a.shape[a.ndim - len(shape_tail) :]) != tuple(shape_tail):
        raise ValueError(f"{name} must have trailing shape {tuple(shape_tail)}, got {a.shape}")
    if min_rows is not None and a.shape[0] < min_rows:
        raise ValueError(f"{name} needs at least {min_rows} points, got {a.shape[0]}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains non-finite values")
    return jax.numpy.asarray(x, dtype=jax.numpy.result_type(float))


def check_position(position: Any, d: int | None, name: str = "position"):
    """Shape (static, always checked) and finiteness (when concrete) of an initial position."""
    shape = np.shape(position)
    if len(shape) != 1 or (d is not None and shape[0] != d):
        want = f"({d},)" if d is not None else "(d,)"
        raise ValueError(f"{name} must have shape {want}, got {shape}")
    if is_concrete(position) and not np.all(np.isfinite(np.asarray(position))):
        raise ValueError(f"{name} contains non-finite values")
