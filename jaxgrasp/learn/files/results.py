"""The record of one learning run (:class:`LearnResult`) and its chain files.

A saved result is a directory holding ``result.npz`` (plain arrays, read back with
``allow_pickle=False``) and ``result.json`` (object, manifest content hash, parameters, seed,
versions, outcome counts, and the SHA-256 of the array file so a torn pair is detected),
written atomically by :func:`jaxgrasp.learn.files.atomic.write_npz_json`. A result that carries
a robustness measurement (:meth:`LearnResult.with_robustness`) adds its grasps and hold counts
to the arrays and its noise model to the JSON; a file without them loads with none.
"""

from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from jaxgrasp.learn.evaluate.distinct import canonical_grasps, learned_grasps
from jaxgrasp.learn.evaluate.hold import PoseNoise, Robustness
from jaxgrasp.learn.evaluate.trace import to_arviz
from jaxgrasp.learn.files.atomic import read_npz_json, versions, write_npz_json
from jaxgrasp.learn.inputs import resolve_object
from jaxgrasp.learn.params import LearnParams
from jaxgrasp.learn.setup.demos import Demos, demo_result_arrays, demo_results_from_arrays

__all__ = ["OUTCOME_NAMES", "LearnResult", "load", "outcome_counts"]

#: Column order of the outcome counts; equal to ``jg.physics.Outcome`` values 0..3.
OUTCOME_NAMES = ("success", "slipped", "collision", "miss")
FORMAT = "jaxgrasp.learn.result"
FORMAT_VERSION = 1
RESULT_ARRAYS = "result.npz"
RESULT_META = "result.json"


def outcome_counts(outcomes) -> np.ndarray:
    """(steps, chains) outcome codes -> (chains, 4) counts of success/slipped/collision/miss."""
    o = np.asarray(outcomes)
    if o.ndim != 2:
        raise ValueError(f"outcomes must be (steps, chains), got shape {o.shape}")
    bad = (o < 0) | (o >= len(OUTCOME_NAMES))
    if bad.any():
        raise ValueError(f"outcome codes outside 0..3: {np.unique(o[bad])}")
    return np.stack([(o == k).sum(axis=0) for k in range(len(OUTCOME_NAMES))], axis=1)


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
        ``"random"``, ``"biased"``, ``"source"`` (transfer: the source chain history),
        ``"source_resized"`` (size-aware transfer: that history moved into the target's frame)
        or ``"none"`` (random walk).
    modes_kind : str
        Where the GDMC modes come from: ``"demos"`` (own demonstrations), ``"source"``,
        ``"source_resized"``, ``"target"`` (transfer) or ``"none"``.
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
    robustness : Robustness or None
        How often the run's distinct successful grasps held under a robot's pose error
        (:func:`jaxgrasp.learn.robustness`, attached with :meth:`with_robustness`); None
        where it was not measured.
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
    robustness: Robustness | None = None

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
        rob = self.robustness
        if rob is not None and (not isinstance(rob, Robustness) or np.shape(rob.grasps) !=
                                (len(rob.held), 7)):
            raise ValueError(f"robustness must be a Robustness of (N, 7) grasps and (N,) "
                             f"hold counts, got {type(rob).__name__}")

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
        the share of repeated proposals
        (:func:`jaxgrasp.learn.evaluate.distinct.learned_grasps`)."""
        return learned_grasps(self.proposals, self.outcomes, self.demos.poses)

    @cached_property
    def grasps(self) -> np.ndarray:
        """(G, 7) learned grasps: the distinct successful proposals (1 cm / 10°, the gripper's
        180° symmetry), canonical (qw >= 0), in order of discovery."""
        return canonical_grasps(self.learned.distinct).astype(np.float32)

    def with_robustness(self, robustness: Robustness | None) -> "LearnResult":
        """A copy carrying ``robustness``, the measurement of this run's distinct successful
        grasps (``jg.learn.robustness(result, ...)``, in any order); None drops it."""
        if robustness is not None and len(robustness.held) != len(self.grasps):
            raise ValueError(f"robustness measured {len(robustness.held)} grasps, but this run "
                             f"has {len(self.grasps)} distinct successful grasps: measure "
                             "jg.learn.robustness(result, ...)")
        out = replace(self, robustness=robustness)
        # The derived reports do not depend on robustness: keep them (they cost seconds).
        out.__dict__.update({k: v for k, v in self.__dict__.items()
                             if k in ("counts", "learned", "grasps")})
        return out

    @property
    def robust_share(self) -> float | None:
        """Share of the distinct successful grasps that are robust (NaN for none; None when
        not measured)."""
        return None if self.robustness is None else self.robustness.robust_share

    @property
    def distinct_robust_new(self) -> int | None:
        """Distinct successful grasps that are robust and not a demonstration (None when
        not measured)."""
        if self.robustness is None:
            return None
        return int(self.robustness.robust_new(self.demos.poses).sum())

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

    def to_arviz(self, *, include_burn_in: bool = True):
        """The chains as ArviZ's DataTree (:func:`jaxgrasp.learn.evaluate.trace.to_arviz`; needs
        ``pip install 'jaxgrasp[arviz]'``)."""
        return to_arviz(self, include_burn_in=include_burn_in)

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
        if self.robustness is not None:
            out["robustness_grasps"] = np.asarray(self.robustness.grasps, np.float64)
            out["robustness_held"] = np.asarray(self.robustness.held, np.int64)
            out["robustness_tried"] = self.robustness.tries_made
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
            **({} if self.robustness is None else
               {"robustness": {"noise": self.robustness.noise._asdict()}}),
        }

    def save(self, directory) -> Path:
        """Write ``result.npz`` + ``result.json`` into ``directory`` (created) atomically."""
        directory = Path(directory)
        write_npz_json(directory, "result", self.arrays(), self.metadata())
        return directory


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
    want = None if obj is None else resolve_object(obj)
    want = None if want is None else (str(want.name), str(want.content_hash))
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
        **{key: arrays[key] for key in (*expected, "modes", "sketch_points")},
        demos=Demos(arrays["demo_poses"], demo_results_from_arrays(arrays)),
        source_object=meta.get("source_object", ""),
        info=meta.get("info", {}),
        robustness=_robustness_from(arrays, meta.get("robustness")),
    )


def _robustness_from(arrays: dict, record) -> Robustness | None:
    """The saved measurement, or None (none saved: results written before it was kept)."""
    if record is None:
        return None
    grasps, held = arrays["robustness_grasps"], arrays["robustness_held"]
    if grasps.ndim != 2 or grasps.shape[1] != 7 or held.shape != (len(grasps),):
        raise ValueError(f"robustness arrays of shapes {grasps.shape} and {held.shape}")
    noise = PoseNoise(**record["noise"]).check()
    tried = arrays.get("robustness_tried")  # absent: every grasp tried noise.tries times
    if tried is not None and tried.shape != held.shape:
        raise ValueError(f"robustness tries of shape {tried.shape} for {held.shape} grasps")
    return Robustness(grasps, held.astype(np.int64), noise,
                      None if tried is None else tried.astype(np.int64))
