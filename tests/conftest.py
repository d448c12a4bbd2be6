"""Test-wide setup: the persistent compilation cache (MJX scenes are expensive to compile),
and headless rendering (MuJoCo picks its GL backend when first imported, by any test)."""

import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

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
