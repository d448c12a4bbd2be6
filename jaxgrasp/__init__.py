"""jaxgrasp: learning robot grasps by kernel adaptive MCMC with darting jumps, physics in MJX.

Submodules load lazily so that ``import jaxgrasp`` stays cheap and the sampler never pulls in
MuJoCo: ``jg.mcmc`` imports no physics, ``jg.physics`` imports no sampler.
"""

import importlib

__version__ = "0.1.0"

_SUBMODULES = ("so3", "mcmc", "objects", "physics", "quality", "density", "learn", "types")

__all__ = list(_SUBMODULES) + ["enable_compilation_cache"]


def __getattr__(name):
    if name in _SUBMODULES:
        return importlib.import_module(f"jaxgrasp.{name}")
    if name == "enable_compilation_cache":
        # Lazy like the submodules: it imports jax.
        from jaxgrasp._cache import enable_compilation_cache

        return enable_compilation_cache
    raise AttributeError(f"module 'jaxgrasp' has no attribute {name!r}")


def __dir__():
    return sorted(__all__)
