"""The sampler tests run their chains far longer than they compile: XLA at -O2 for them."""

import pytest


@pytest.fixture(autouse=True)
def _optimized(xla_optimized):
    """Every test here compiles at -O2 (``xla_optimized`` in ``tests/conftest.py``)."""
