"""Test-wide setup: the persistent compilation cache (MJX scenes are expensive to compile)."""

from pathlib import Path

import pytest

from jaxgrasp._cache import enable_compilation_cache

REPO = Path(__file__).resolve().parents[1]


def pytest_configure(config):
    import os

    enable_compilation_cache(os.environ.get("JAXGRASP_CACHE_DIR", REPO / ".cache" / "jax"))


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO
