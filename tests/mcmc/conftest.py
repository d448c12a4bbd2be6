"""The sampler tests run their chains far longer than they compile: XLA at -O2 for them, but
for those marked ``compile_bound`` (a few short chains), which keep the suite's -O0."""

import pytest


@pytest.fixture(autouse=True)
def _optimized(request):
    """Compiles at -O2 (``xla_optimized`` in ``tests/conftest.py``) unless ``compile_bound``."""
    if request.node.get_closest_marker("compile_bound") is None:
        request.getfixturevalue("xla_optimized")
