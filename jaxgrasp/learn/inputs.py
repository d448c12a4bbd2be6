"""What the learning entry points accept: objects, parameters, seeds, chain counts.

Each check runs before any physics or sampling, so a bad argument is one clear ``ValueError``.
"""

import numpy as np

from jaxgrasp import objects
from jaxgrasp.learn.params import LearnParams

__all__ = ["resolve_object", "resolve_params", "check_seed", "check_chains", "check_every"]


def resolve_object(obj):
    """A GraspObject from a name (a kitchen object or ``random_NNN`` of the any-object set), a
    Scene or a GraspObject."""
    if isinstance(obj, str):
        return objects.load_any(obj)
    obj = getattr(obj, "obj", obj)
    if not hasattr(obj, "mesh") or not hasattr(obj, "content_hash"):
        raise ValueError(f"expected a GraspObject, a Scene or an object name, got {obj!r}")
    return obj


def resolve_params(params, *, iterations=None, burn_in=None) -> LearnParams:
    """``params`` (default :class:`LearnParams`) with ``iterations``/``burn_in`` overrides."""
    if params is None:
        params = LearnParams()
    if not isinstance(params, LearnParams):
        raise ValueError(f"params must be a LearnParams, got {type(params).__name__}")
    changes = {k: v for k, v in (("iterations", iterations), ("burn_in", burn_in))
               if v is not None}
    return params.replace(**changes) if changes else params


def check_seed(seed) -> int:
    if not isinstance(seed, int | np.integer) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"seed must be a non-negative int, got {seed!r}")
    return int(seed)


def check_chains(chains) -> int:
    if not isinstance(chains, int | np.integer) or isinstance(chains, bool) or chains < 1:
        raise ValueError(f"chains must be a positive int, got {chains!r}")
    return int(chains)


def check_every(every):
    """``checkpoint_every``: a positive int or None."""
    if every is not None and (not isinstance(every, int | np.integer) or isinstance(every, bool)
                              or every < 1):
        raise ValueError(f"checkpoint_every must be a positive int or None, got {every!r}")
    return every
