"""Test-wide setup: the persistent compilation cache (MJX scenes are expensive to compile),
XLA's backend at -O0 (compiles dominate the suite), and headless rendering (MuJoCo picks its
GL backend when first imported, by any test)."""

import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
# Tests compile far more than they run: XLA's backend at -O0 compiles faster (cold cache, idle
# 2-core machine: the MJX trial tests 106 -> 84 s, tests/mcmc + quality + robustness 202 ->
# 184 s); what tests assert does not depend on it. XLA_FLAGS is part of JAX's cache key, so
# these executables never reach a benchmark that shares the cache directory.
if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                               + " --xla_backend_optimization_level=0").strip()

import pytest

from jaxgrasp._cache import enable_compilation_cache

REPO = Path(__file__).resolve().parents[1]


def pytest_configure(config):
    enable_compilation_cache(os.environ.get("JAXGRASP_CACHE_DIR", REPO / ".cache" / "jax"))


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO


@pytest.fixture(scope="session")
def load_benchmark():
    """``load_benchmark(name)`` imports ``benchmarks/<name>.py`` (not a package) as a module,
    for tests that reuse a benchmark's pieces."""
    import importlib.util

    def load(name: str):
        spec = importlib.util.spec_from_file_location(f"benchmarks_{name}",
                                                      REPO / "benchmarks" / f"{name}.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod

    return load
