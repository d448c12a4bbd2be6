"""The experiments of a profile: one cell per table entry, its seed, where it is saved, and
whether a saved result belongs to this configuration.

Layout of an output directory::

    runs/active/<object>/<method>/result.{npz,json}         Table II cells (LearnResult.save)
    runs/transfer/<set>/<object>/<modes>/result.{npz,json}  Table III cells
    runs/<...>/checkpoint/                                  learn checkpoints (long profiles)
    results.json  tables.md  tables.csv  results.schema.json  figures/*.png

Tables are always recomputed from the saved results, so a killed bench loses at most the
experiment it was running, and ``--resume`` continues where it stopped.
"""

import zlib
from pathlib import Path

from jaxgrasp.bench.profiles import (
    ACTIVE_METHODS,
    ACTIVE_OBJECTS,
    TRANSFER_MODES,
    TRANSFER_SETS,
    TRANSFER_SOURCE_METHOD,
    Profile,
)
from jaxgrasp.learn.files.results import load
from jaxgrasp.learn.params import LearnParams
from jaxgrasp.physics import GripperParams, TrialParams


def cell_seed(seed: int, row_id: str) -> int:
    """Reproducible seed per table row (a subset of objects gives the same numbers).

    All cells of a row share it, so the three methods on one object start from the same
    demonstrated grasps (as in the paper) and the two transfer modes from the same keys.
    """
    return int((seed * 1_000_003 + zlib.crc32(row_id.encode())) % (2**31 - 1))


class Cell:
    """One experiment: where it is saved and how to run it."""

    def __init__(self, table, key, obj, column, path, source=None):
        self.table = table  # "active" | "transfer"
        self.key = key  # ("pitcher", "random_walk") | ("transfer_a", "tall_pitcher", "source")
        self.obj = obj
        self.column = column
        self.path = Path(path)
        self.source = source  # transfer: the active Cell whose result is reused

    @property
    def id(self) -> str:
        return "/".join((self.table,) + self.key)

    @property
    def row_id(self) -> str:
        return "/".join((self.table,) + self.key[:-1])


def plan(profile: Profile, out: Path) -> list:
    """The cells of ``profile`` in run order (every transfer after its source)."""
    runs = out / "runs"
    cells, by_key = [], {}
    for o in profile.objects:
        for m in ACTIVE_METHODS:
            c = Cell("active", (o, m), o, m, runs / "active" / o / m)
            cells.append(c)
            by_key[(o, m)] = c
    for s in profile.transfer_sets:
        for a, t in zip(ACTIVE_OBJECTS, TRANSFER_SETS[s], strict=True):
            if a not in profile.objects:
                continue
            for mode in TRANSFER_MODES:
                cells.append(Cell("transfer", (s, t, mode), t, mode,
                                  runs / "transfer" / s / t / mode,
                                  source=by_key[(a, TRANSFER_SOURCE_METHOD)]))
    return cells


def learn_params(profile: Profile) -> LearnParams:
    return LearnParams(iterations=profile.iterations, burn_in=profile.burn_in,
                       **dict(profile.params))


def physics_key() -> str:
    """The gripper and protocol the bench's trials run on (the library defaults). Saved
    results record it (``info["physics"]``), so a run directory from before a physics change
    is never resumed or tabled as this physics."""
    return repr((GripperParams(), TrialParams()))


def matches(result, cell: Cell, profile: Profile, backend: str) -> bool:
    """A saved result belongs to this configuration (``--resume`` reuses only those)."""
    return (
        result.info.get("physics") == physics_key()
        and result.object_name == cell.obj
        and result.num_chains == profile.chains
        and result.num_steps == profile.proposals
        and result.seed == cell_seed(profile.seed, cell.row_id)
        and result.backend == backend
        and result.params == learn_params(profile)
    )


def load_saved(cell: Cell):
    """The LearnResult saved for ``cell``, or None."""
    if not (cell.path / "result.json").is_file():
        return None
    return load(cell.path)
