"""JAX persistent compilation cache: called by the CLI and the tests, never at import time."""

import os
from pathlib import Path

import jax


def default_cache_dir() -> Path:
    """``$JAXGRASP_CACHE_DIR``, else ``$XDG_CACHE_HOME/jaxgrasp/jax`` (``~/.cache/...``)."""
    env = os.environ.get("JAXGRASP_CACHE_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "jaxgrasp" / "jax"


def enable_compilation_cache(path: str | os.PathLike | None = None) -> Path:
    """Turn on JAX's persistent compilation cache in ``path`` and return the directory.

    MJX scenes take 15-70 s to compile on a CPU; with the cache a second process reuses them.
    """
    cache = Path(path) if path is not None else default_cache_dir()
    cache.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(cache))
    # Cache everything that took noticeable time; small kernels are cheap to rebuild.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return cache
