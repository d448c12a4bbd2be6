"""Results of the learning workflows and their chain files (atomic .npz arrays + JSON metadata).

A saved result is a directory holding ``result.npz`` (plain arrays, read back with
``allow_pickle=False``) and ``result.json`` (object, manifest content hash, parameters, seed,
versions, outcome counts, and the SHA-256 of the array file so a torn pair is detected).
Every file is written to a temporary name in the same directory and moved into place with
``os.replace``, so a kill never leaves a half-written file under the real name.
"""

import hashlib
import io
import json
import os
import platform
import tempfile
import zipfile
import zlib
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxgrasp.learn.distinct import learned_grasps
from jaxgrasp.learn.params import LearnParams

__all__ = [
    "OUTCOME_NAMES",
    "Demos",
    "LearnResult",
    "load",
    "canonical_grasps",
    "unique_grasps",
    "outcome_counts",
]

#: Column order of the outcome counts; equal to ``jg.physics.Outcome`` values 0..3.
OUTCOME_NAMES = ("success", "slipped", "collision", "miss")
FORMAT = "jaxgrasp.learn.result"
FORMAT_VERSION = 1
RESULT_ARRAYS = "result.npz"
RESULT_META = "result.json"


class _DemosFields(NamedTuple):
    poses: np.ndarray
    results: tuple


class Demos(_DemosFields):
    """Demonstrated grasps: the poses that succeeded in a physics trial.

    Attributes
    ----------
    poses : (m, 7) float array
        Gripper poses in the object frame, (x, y, z, qw, qx, qy, qz), unit quaternion, qw >= 0.
        Checked on construction (:func:`jaxgrasp.physics.check_grasps`): finite, a non-zero
        quaternion, integer or float dtype (they become GDMC modes and chain starts).
    results : TrialResult-like NamedTuple of numpy arrays, leading dim m
        The trial of each pose (all ``outcome == SUCCESS``).
    """

    __slots__ = ()

    def __new__(cls, poses, results=None):
        from jaxgrasp.physics.inputs import check_grasps

        return super().__new__(cls, check_grasps(poses, "Demos.poses", finite=True), results)


# ---------------------------------------------------------------------------------------------
# Atomic files


def atomic_write_bytes(path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same directory + os.replace."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        # A failed write must not leave its temporary file behind.
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def npz_bytes(arrays: dict) -> bytes:
    """Serialize a dict of arrays as an (uncompressed) .npz, refusing object arrays."""
    for key, value in arrays.items():
        if np.asarray(value).dtype == object:
            raise ValueError(f"array {key!r} has dtype object; chain files hold plain arrays only")
    buf = io.BytesIO()
    np.savez(buf, **{k: np.asarray(v) for k, v in arrays.items()})
    return buf.getvalue()


def read_npz(data, label) -> dict:
    """The arrays of an .npz (bytes or path), read with ``allow_pickle=False``.

    ValueError naming ``label`` for anything that is not an intact archive of plain arrays
    (truncated, not a zip, a pickle, object arrays), never an error from inside zipfile.
    """
    source = io.BytesIO(data) if isinstance(data, bytes) else data
    try:
        with np.load(source, allow_pickle=False) as npz:
            return {k: npz[k] for k in npz.files}
    except (OSError, ValueError, EOFError, KeyError, AttributeError, zipfile.BadZipFile,
            zlib.error) as err:
        raise ValueError(f"{label} is not an intact .npz of plain arrays ({type(err).__name__}: "
                         f"{err}); delete it and run again, or restore it") from None


def write_npz_json(directory, stem: str, arrays: dict, meta: dict) -> None:
    """Atomically write ``stem.npz`` then ``stem.json`` (the JSON records the npz's SHA-256).

    Both are serialized before either is written, so a value JSON refuses (NaN/inf in the
    metadata) leaves no file behind.
    """
    directory = Path(directory)
    data = npz_bytes(arrays)
    meta = dict(meta)
    meta["arrays"] = {"file": f"{stem}.npz", "sha256": hashlib.sha256(data).hexdigest()}
    try:
        text = json.dumps(_jsonable(meta), indent=1, sort_keys=True, allow_nan=False)
    except (ValueError, TypeError) as err:
        raise ValueError(f"{stem}.json: metadata is not plain JSON ({err}); NaN/inf and "
                         "objects can't be saved") from None
    atomic_write_bytes(directory / f"{stem}.npz", data)
    atomic_write_bytes(directory / f"{stem}.json", text.encode())


def read_npz_json(directory, stem: str) -> tuple[dict, dict]:
    """Read a pair written by :func:`write_npz_json`; ValueError when missing, torn or corrupt."""
    directory = Path(directory)
    meta_path, npz_path = directory / f"{stem}.json", directory / f"{stem}.npz"
    if not meta_path.is_file() or not npz_path.is_file():
        raise ValueError(f"no chain file {stem!r} in {str(directory)!r} (need {stem}.json and "
                         f"{stem}.npz)")
    try:
        meta = json.loads(meta_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ValueError(f"{meta_path} is not valid JSON: {err}") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("arrays"), dict):
        raise ValueError(f"{meta_path} is not a jaxgrasp chain file (no 'arrays' record)")
    data = npz_path.read_bytes()
    if meta["arrays"].get("sha256") != hashlib.sha256(data).hexdigest():
        raise ValueError(f"{npz_path} does not match the checksum recorded in {meta_path} "
                         "(the pair was not written together; the file is torn or edited)")
    return read_npz(data, npz_path), meta


def _jsonable(x):
    """Numpy scalars/arrays to plain JSON types (and refuse NaN/inf via json's allow_nan)."""
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    return x


def versions() -> dict:
    """Versions of the packages a result depends on (metadata; never compared on load)."""
    import jax

    import jaxgrasp

    out = {"jaxgrasp": jaxgrasp.__version__, "jax": jax.__version__, "numpy": np.__version__,
           "python": platform.python_version()}
    try:
        import mujoco

        out["mujoco"] = mujoco.__version__
    except ImportError:  # pragma: no cover - mujoco is a dependency
        pass
    return out


# ---------------------------------------------------------------------------------------------
# Grasp post-processing


def canonical_grasps(grasps) -> np.ndarray:
    """Normalize the quaternion part and flip it to qw >= 0 (q and -q are the same rotation)."""
    g = np.array(grasps, dtype=np.float64, copy=True).reshape(-1, 7)
    q = g[:, 3:]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    g[:, 3:] = q
    return g


def unique_grasps(grasps, *, position_tol=1e-4, quaternion_tol=1e-4) -> np.ndarray:
    """Canonical grasps with repeats removed (a chain that stays put re-proposes its state).

    Two grasps are the same when they round to the same grid cell: ``position_tol`` metres,
    ``quaternion_tol`` per quaternion component. Order of first appearance is kept.
    """
    g = canonical_grasps(grasps)
    if len(g) == 0:
        return g
    scale = np.array([position_tol] * 3 + [quaternion_tol] * 4)
    keys = np.round(g / scale).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return g[np.sort(first)]


def outcome_counts(outcomes) -> np.ndarray:
    """(steps, chains) outcome codes -> (chains, 4) counts of success/slipped/collision/miss."""
    o = np.asarray(outcomes)
    if o.ndim != 2:
        raise ValueError(f"outcomes must be (steps, chains), got shape {o.shape}")
    bad = (o < 0) | (o >= len(OUTCOME_NAMES))
    if bad.any():
        raise ValueError(f"outcome codes outside 0..3: {np.unique(o[bad])}")
    return np.stack([(o == k).sum(axis=0) for k in range(len(OUTCOME_NAMES))], axis=1)


# ---------------------------------------------------------------------------------------------
# The result


@dataclass(frozen=True, eq=False)
class LearnResult:
    """What one active- or transfer-learning run produced (all chains of one object).

    Arrays are numpy, leading axis ``steps = burn_in + iterations`` then ``chains``.

    Attributes
    ----------
    object_name, object_hash : str
        The object learned (``GraspObject.name`` and its manifest ``content_hash``).
    workflow : str
        ``"active"`` or ``"transfer"``.
    method : str
        ``"random_walk"`` or ``"kameleon_darting"``.
    sketch : str
        ``"random"``, ``"biased"``, ``"source"`` (transfer: the source chain history) or
        ``"none"`` (random walk).
    modes_kind : str
        Where the GDMC modes come from: ``"demos"`` (own demonstrations), ``"source"``,
        ``"target"`` (transfer) or ``"none"``.
    seed : int
    backend : str
    params : LearnParams
    positions : (steps, chains, 7) float32
        Chain history: the state after each step (lifted R^7 for Kameleon: |q| != 1).
    proposals : (steps, chains, 7) float32
        The point evaluated (simulated) at each step, accepted or not.
    outcomes : (steps, chains) int8
        Outcome of each proposal's trial (``jg.physics.Outcome``), from the density's aux.
    epsilons : (steps, chains) float32
        GWS epsilon of each proposal.
    accepted, is_jump : (steps, chains) bool
        MH acceptance; whether the step attempted a GDMC jump (False for the random walk).
    initial_positions : (chains, 7) float32
        Where the chains started.
    modes : (m, 7) float
        GDMC modes (demonstrated grasps) used; the random walk's start points otherwise.
    sketch_points : (n, 7) float
        The rough sketch handed to Kameleon ((0, 7) for the random walk).
    demos : Demos
        Demonstrations made for this run (for transfer with source modes: the source's).
    source_object : str
        Transfer: the source object's name; ``""`` otherwise.
    info : dict
        Free-form metadata (timings, the source's hash, ...), saved in the JSON.
    """

    object_name: str
    object_hash: str
    workflow: str
    method: str
    sketch: str
    modes_kind: str
    seed: int
    backend: str
    params: LearnParams
    positions: np.ndarray
    proposals: np.ndarray
    outcomes: np.ndarray
    epsilons: np.ndarray
    accepted: np.ndarray
    is_jump: np.ndarray
    initial_positions: np.ndarray
    modes: np.ndarray
    sketch_points: np.ndarray
    demos: Demos
    source_object: str = ""
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        s, c = np.shape(self.outcomes)[:2] if np.ndim(self.outcomes) == 2 else (-1, -1)
        if s < 0:
            raise ValueError(f"outcomes must be (steps, chains), got {np.shape(self.outcomes)}")
        for name in ("positions", "proposals"):
            if np.shape(getattr(self, name)) != (s, c, 7):
                raise ValueError(f"{name} must have shape {(s, c, 7)} (steps, chains, 7), got "
                                 f"{np.shape(getattr(self, name))}")
        for name in ("epsilons", "accepted", "is_jump"):
            if np.shape(getattr(self, name)) != (s, c):
                raise ValueError(f"{name} must have shape {(s, c)}, got "
                                 f"{np.shape(getattr(self, name))}")
        if np.shape(self.initial_positions) != (c, 7):
            raise ValueError(f"initial_positions must be ({c}, 7), got "
                             f"{np.shape(self.initial_positions)}")
        for name in ("modes", "sketch_points"):
            shape = np.shape(getattr(self, name))
            if len(shape) != 2 or shape[1] != 7:
                raise ValueError(f"{name} must be (n, 7), got {shape}")
        if np.ndim(self.demos.poses) != 2 or np.shape(self.demos.poses)[1] != 7:
            raise ValueError(f"demos.poses must be (m, 7), got {np.shape(self.demos.poses)}")
        if s != self.params.num_steps:
            raise ValueError(f"{s} steps recorded but params ask for burn_in + iterations = "
                             f"{self.params.num_steps}")

    # -- derived quantities ---------------------------------------------------------------

    @property
    def num_chains(self) -> int:
        return int(np.shape(self.outcomes)[1])

    @property
    def num_steps(self) -> int:
        return int(np.shape(self.outcomes)[0])

    @cached_property
    def counts(self) -> np.ndarray:
        """(chains, 4) int: success / slipped / collision / miss over all proposals."""
        return outcome_counts(self.outcomes)

    @property
    def counts_dict(self) -> dict:
        """``{"success": [per chain], ...}``: the table row of each chain."""
        return {name: self.counts[:, k].tolist() for k, name in enumerate(OUTCOME_NAMES)}

    @cached_property
    def learned(self):
        """The run's distinct successful grasps, the new ones among them (not a demo) and
        the share of repeated proposals (:func:`jaxgrasp.learn.distinct.learned_grasps`)."""
        return learned_grasps(self.proposals, self.outcomes, self.demos.poses)

    @cached_property
    def grasps(self) -> np.ndarray:
        """(G, 7) learned grasps: the distinct successful proposals (1 cm / 10°, the gripper's
        180° symmetry), canonical (qw >= 0), in order of discovery."""
        return canonical_grasps(self.learned.distinct).astype(np.float32)

    @property
    def acceptance_rate(self) -> np.ndarray:
        """(chains,) fraction of accepted proposals."""
        return self.accepted.mean(axis=0)

    @property
    def jump_rate(self) -> np.ndarray:
        """(chains,) fraction of steps that attempted a GDMC jump."""
        return self.is_jump.mean(axis=0)

    @property
    def jump_acceptance_rate(self) -> np.ndarray:
        """(chains,) fraction of attempted jumps that were accepted (NaN with no attempt)."""
        tried = self.is_jump.sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(tried > 0, (self.is_jump & self.accepted).sum(axis=0) / tried,
                            np.nan)

    def summary(self) -> str:
        tot = self.counts.sum(axis=0)
        cells = " ".join(f"{n}={t}" for n, t in zip(OUTCOME_NAMES, tot, strict=True))
        return (f"{self.workflow} {self.object_name} {self.method} sketch={self.sketch} "
                f"modes={self.modes_kind}: {self.num_chains} chains x {self.num_steps} "
                f"proposals, {cells}, {len(self.learned.distinct)} distinct successful "
                f"grasps ({len(self.learned.new)} new), repeat share "
                f"{self.learned.repeat_share:.2f}, acceptance {self.acceptance_rate.mean():.3f}")

    # -- files ----------------------------------------------------------------------------

    def arrays(self) -> dict:
        out = {
            "positions": np.asarray(self.positions, np.float32),
            "proposals": np.asarray(self.proposals, np.float32),
            "outcomes": np.asarray(self.outcomes, np.int8),
            "epsilons": np.asarray(self.epsilons, np.float32),
            "accepted": np.asarray(self.accepted, bool),
            "is_jump": np.asarray(self.is_jump, bool),
            "initial_positions": np.asarray(self.initial_positions, np.float32),
            "modes": np.asarray(self.modes),
            "sketch_points": np.asarray(self.sketch_points),
            "demo_poses": np.asarray(self.demos.poses),
            "grasps": self.grasps,
            "counts": self.counts,
        }
        out.update(demo_result_arrays(self.demos.results))
        return out

    def metadata(self) -> dict:
        return {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "object": {"name": self.object_name, "content_hash": self.object_hash},
            "manifest_hash": self.object_hash,
            "workflow": self.workflow,
            "method": self.method,
            "sketch": self.sketch,
            "modes": self.modes_kind,
            "source_object": self.source_object,
            "seed": int(self.seed),
            "backend": self.backend,
            "params": self.params.to_dict(),
            "chains": self.num_chains,
            "steps": self.num_steps,
            "dim": 7,
            "counts": self.counts_dict,
            "totals": dict(zip(OUTCOME_NAMES, self.counts.sum(axis=0).tolist(), strict=True)),
            "num_grasps": int(len(self.grasps)),
            "num_demos": int(len(self.demos.poses)),
            "acceptance_rate": self.acceptance_rate.tolist(),
            "versions": versions(),
            "info": self.info,
        }

    def save(self, directory) -> Path:
        """Write ``result.npz`` + ``result.json`` into ``directory`` (created) atomically."""
        directory = Path(directory)
        write_npz_json(directory, "result", self.arrays(), self.metadata())
        return directory


def demo_result_arrays(results) -> dict:
    """A TrialResult-like NamedTuple as ``demo_result_<field>`` arrays."""
    if results is None:
        return {}
    return {f"demo_result_{k}": np.asarray(v) for k, v in results._asdict().items()}


def demo_results_from_arrays(arrays: dict):
    """Inverse of :func:`demo_result_arrays`: a ``jg.physics.TrialResult`` when it fits."""
    fields = {k[len("demo_result_"):]: v for k, v in arrays.items()
              if k.startswith("demo_result_")}
    if not fields:
        return None
    try:
        from jaxgrasp.physics import TrialResult

        if set(TrialResult._fields) == set(fields):
            return TrialResult(**fields)
    except ImportError:  # pragma: no cover - physics is part of the package
        pass
    return NamedTuple("DemoResults", [(k, np.ndarray) for k in fields])(**fields)


def object_identity(obj) -> tuple[str, str]:
    """(name, content_hash) of a GraspObject, a Scene holding one, or an object name."""
    if isinstance(obj, str):
        from jaxgrasp import objects

        obj = objects.load(obj)
    obj = getattr(obj, "obj", obj)
    return str(obj.name), str(obj.content_hash)


def load(directory, obj=None) -> LearnResult:
    """Read a result saved with :meth:`LearnResult.save`.

    Parameters
    ----------
    directory : path
        Directory holding ``result.npz`` and ``result.json``.
    obj : GraspObject, Scene or str, optional
        When given, the file must belong to this object (same name and content hash).

    Raises
    ------
    ValueError
        Missing/torn/corrupt files, another format, the wrong object, or arrays whose
        dimensions do not match the metadata.
    """
    want = None if obj is None else object_identity(obj)
    arrays, meta = read_npz_json(directory, "result")
    if meta.get("format") != FORMAT:
        raise ValueError(f"{directory} is not a jaxgrasp learning result "
                         f"(format {meta.get('format')!r})")
    if meta.get("format_version") != FORMAT_VERSION:
        raise ValueError(f"{directory}: result format version {meta.get('format_version')} "
                         f"is not supported (expected {FORMAT_VERSION})")
    try:
        return _result_from(arrays, meta, want)
    except KeyError as err:
        raise ValueError(f"{directory}: metadata field or array {err} is missing") from None
    except (ValueError, TypeError, AttributeError) as err:
        raise ValueError(f"{directory}: {err} (the file is damaged or from another "
                         "version)") from None


def _result_from(arrays: dict, meta: dict, want) -> LearnResult:
    """:func:`load`'s checks and construction; any error here names no file (load adds it)."""
    params = LearnParams.from_dict(meta["params"])
    steps, chains, dim = (int(meta[k]) for k in ("steps", "chains", "dim"))
    name, content_hash = str(meta["object"]["name"]), str(meta["object"]["content_hash"])
    expected = {"positions": (steps, chains, dim), "proposals": (steps, chains, dim),
                "outcomes": (steps, chains), "epsilons": (steps, chains),
                "accepted": (steps, chains), "is_jump": (steps, chains),
                "initial_positions": (chains, dim)}
    for key, shape in expected.items():
        if arrays[key].shape != tuple(shape):
            raise ValueError(f"array {key!r} has shape {arrays[key].shape}, the metadata says "
                             f"{tuple(shape)} (steps, chains, dim)")
    for key in ("modes", "sketch_points", "demo_poses"):
        if arrays.get(key) is None or arrays[key].ndim != 2 or arrays[key].shape[1] != dim:
            raise ValueError(f"array {key!r} must be (n, {dim})")
    if want is not None and want != (name, content_hash):
        raise ValueError(f"it holds a result for object {name!r} (hash {content_hash[:12]!r}), "
                         f"not for {want[0]!r} (hash {want[1][:12]!r})")
    return LearnResult(
        object_name=name,
        object_hash=content_hash,
        workflow=meta["workflow"],
        method=meta["method"],
        sketch=meta["sketch"],
        modes_kind=meta["modes"],
        seed=int(meta["seed"]),
        backend=meta["backend"],
        params=params,
        positions=arrays["positions"],
        proposals=arrays["proposals"],
        outcomes=arrays["outcomes"],
        epsilons=arrays["epsilons"],
        accepted=arrays["accepted"],
        is_jump=arrays["is_jump"],
        initial_positions=arrays["initial_positions"],
        modes=arrays["modes"],
        sketch_points=arrays["sketch_points"],
        demos=Demos(arrays["demo_poses"], demo_results_from_arrays(arrays)),
        source_object=meta.get("source_object", ""),
        info=meta.get("info", {}),
    )
