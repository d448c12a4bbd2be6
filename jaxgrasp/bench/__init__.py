"""``python -m jaxgrasp.bench``: the paper's Tables II and III, trial speed, and grasp figures.

Run ``python -m jaxgrasp.bench --help``. Modules, each importing only those after it:
:mod:`~jaxgrasp.bench.cli` (flags, output directory); :mod:`~jaxgrasp.bench.run` (experiments,
trial speed) and :mod:`~jaxgrasp.bench.report` (results.json, tables.md/csv, summary, figures);
:mod:`~jaxgrasp.bench.plan` (the cells of a profile and their saved results);
:mod:`~jaxgrasp.bench.figures` / :mod:`~jaxgrasp.bench.tables` (rendering);
:mod:`~jaxgrasp.bench.profiles` (what to run), :mod:`~jaxgrasp.bench.paper` (published numbers
and claims), :mod:`~jaxgrasp.bench.schema`, :mod:`~jaxgrasp.bench.env`,
:mod:`~jaxgrasp.bench.throughput`.
"""

__all__ = ["main"]


def main(argv=None) -> int:
    """Entry point of ``python -m jaxgrasp.bench`` and the ``jaxgrasp-bench`` script."""
    # ``import jaxgrasp.bench`` stays free of the CLI's imports until it runs.
    from jaxgrasp.bench.cli import main as _main

    return _main(argv)
