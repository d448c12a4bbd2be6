"""``python -m jaxgrasp.bench``: the paper's Tables II and III, trial speed, and grasp figures.

Run ``python -m jaxgrasp.bench --help``. Modules: :mod:`~jaxgrasp.bench.profiles` (what to
run), :mod:`~jaxgrasp.bench.run` (experiments, saved results, outputs),
:mod:`~jaxgrasp.bench.tables` / :mod:`~jaxgrasp.bench.figures` (rendering),
:mod:`~jaxgrasp.bench.paper` (published numbers and claims), :mod:`~jaxgrasp.bench.schema`.
"""

__all__ = ["main"]


def main(argv=None) -> int:
    """Entry point of ``python -m jaxgrasp.bench`` and the ``jaxgrasp-bench`` script."""
    from jaxgrasp.bench.cli import main as _main

    return _main(argv)
