"""Simulated demonstrations: the user's demonstrated grasps (paper §4, last paragraph).

Candidate poses at seeded surface points (:mod:`jaxgrasp.learn.setup.candidates`: optimized poses,
top-down wall pinches and tilted rim-edge pinches) are tried in physics, and only grasps whose
trial SUCCEEDS are kept, in candidate order, until ``num`` are found (up to ``MAX_ROUNDS``
rounds); with ``LearnParams.demo_choice = "spread"`` the ``num`` demos are chosen farthest
apart among every success of those rounds; with ``"antipodal"`` among the successes of one
batch of antipodal grasps (:mod:`jaxgrasp.learn.setup.antipodal`), the candidate search's
first ones where too few of those succeed. The other successes are the spares (starts for
chains beyond the demos). Everything is seeded: the same seed gives the same demonstrations.
"""

import warnings
from typing import NamedTuple

import jax
import numpy as np
from tqdm.auto import tqdm

from jaxgrasp.learn.evaluate.distinct import distinct_grasps, grasp_distances, is_new
from jaxgrasp.learn.params import LearnParams
from jaxgrasp.learn.setup.antipodal import placement_collisions, some_antipodal_grasps
from jaxgrasp.learn.setup.candidates import (
    MIN_NORMAL_Z,
    candidate_poses,
    edge_poses,
    rim_poses,
    surface_points,
)
from jaxgrasp.learn.sim import as_simulator
from jaxgrasp.physics import GripperParams, TrialResult
from jaxgrasp.physics.inputs import check_grasps

__all__ = ["Demos", "demonstrations", "demo_result_arrays", "demo_results_from_arrays"]

#: Candidate rounds before giving up on finding ``num`` successful demos.
MAX_ROUNDS = 8
#: Top-down wall pinches tried per optimized candidate (cheap: no optimization, one batch).
RIM_PER_POINT = 4
#: ``demo_choice="antipodal"``: antipodal grasps drawn per wanted demo (one batch).
ANTIPODAL_PER_DEMO = 40
ANTIPODAL_PART = "demos_antipodal"  # its checkpoint file stem


class _DemosFields(NamedTuple):
    poses: np.ndarray
    results: tuple
    spares: np.ndarray


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
    spares : (k, 7) float32 array
        The search's other successful candidates, distinct from the demos and from each other
        (1 cm / 10°), highest target density first (epsilon, weighed down by the hold's
        displacement as ``LearnParams.slip_scale`` does): starts for chains beyond the m demos
        (``LearnParams.spread_starts``). Empty by default.
    """

    __slots__ = ()

    def __new__(cls, poses, results=None, spares=None):
        spares = (np.zeros((0, 7), np.float32) if spares is None
                  else check_grasps(spares, "Demos.spares", finite=True).astype(np.float32))
        return super().__new__(cls, check_grasps(poses, "Demos.poses", finite=True), results,
                               spares)


def _part_name(round_: int, family: int) -> str:
    """Checkpoint file stem of one simulated batch of the demo search."""
    return f"demos_round{round_}_family{family}"


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
    if "invalid" not in fields and "unstable" in fields:  # saved before the field existed
        fields["invalid"] = np.zeros_like(fields["unstable"])
    if set(TrialResult._fields) == set(fields):
        return TrialResult(**fields)
    return NamedTuple("DemoResults", [(k, np.ndarray) for k in fields])(**fields)


def demonstrations(obj_or_scene, *, num: int = 5, seed: int = 0, trial=None, backend="auto",
                   params: LearnParams | None = None, gripper=None,
                   progress: bool = False, checkpoint=None) -> Demos:
    """Simulated demonstrated grasps that succeed in physics.

    Parameters
    ----------
    obj_or_scene : GraspObject, Scene or str
    num : int
        Wanted demonstrations (paper: 5).
    seed : int
        Seeds the surface points and the cost's point cloud; same seed, same demos.
    trial : Simulator or callable, optional
        The object's physics trial (built from the object when None).
    backend : str
        ``"auto"`` (MuJoCo C on a CPU, MJX on an accelerator), ``"mjx"`` or ``"mujoco"``.
    params : LearnParams, optional
        ``demo_candidates``: surface points tried per wanted demo and round;
        ``demo_fallback``: what to do when fewer than ``num`` succeed.
    gripper : GripperParams, optional
        Default: the scene's gripper, else the physics default.
    progress : bool
        Show a tqdm bar of the candidates simulated and the demos found.
    checkpoint : CheckpointDir, optional
        Each simulated batch of candidates (poses and trial results) is saved there as it
        finishes; a search run again with the same checkpoint reads them back instead of
        optimizing and simulating them again, and finds the same demos.

    Returns
    -------
    Demos
        ``poses`` (m, 7) with m <= num (a warning when fewer than ``num`` succeed) and the
        trial ``results`` of those poses. ValueError when none succeeds.
    """
    if not isinstance(num, int) or num < 1:
        raise ValueError(f"num must be a positive int, got {num!r}")
    if not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be a non-negative int, got {seed!r}")
    params = params if params is not None else LearnParams()
    sim = as_simulator(obj_or_scene, backend=backend, trial=trial)
    obj = sim.obj
    if gripper is None:
        gripper = getattr(sim.scene, "gripper", None) or GripperParams()
    if params.demo_choice == "antipodal":
        chosen = _antipodal_demos(sim, num, int(seed), gripper, params, checkpoint)
        if chosen is not None:
            return chosen
    per_round = num * params.demo_candidates
    kept, slipped, others = [], [], []  # (poses, results) per round; other successes
    found = tried = 0
    spread = params.demo_choice == "spread"  # keep every success, choose the demos at the end
    with tqdm(desc=f"{obj.name} demos", unit="trial", disable=not progress,
              leave=False) as bar:
        for round_ in range(MAX_ROUNDS):
            saved = [None, None] if checkpoint is None else [
                checkpoint.load_part(_part_name(round_, i)) for i in range(2)]
            # Cheap rim candidates at more points of the same seeded stream, simulated in the
            # same batch (the physics runs hundreds of trials per second on a CPU).
            r_pts, r_nrm = surface_points(obj.mesh, RIM_PER_POINT * per_round,
                                          int(seed) * MAX_ROUNDS + round_ + 104729,
                                          min_normal_z=MIN_NORMAL_Z)
            if saved[0] is not None:  # the optimized candidates of a saved batch: not again
                optimized = saved[0]["poses"]
            else:
                points, normals = surface_points(obj.mesh, per_round,
                                                 int(seed) * MAX_ROUNDS + round_,
                                                 min_normal_z=MIN_NORMAL_Z)
                optimized = np.concatenate([
                    candidate_poses(obj, points, normals, gripper=gripper, seed=int(seed)),
                    rim_poses(r_pts, r_nrm, float(obj.support_z), gripper)])
            # Tilted edge pinches at the same points last, simulated only when the earlier
            # families leave demos missing (or the slipped fallback may need them): demos are kept
            # in candidate order, so this changes no result; a plate's rim is held only this way.
            families = [optimized, edge_poses(r_pts, r_nrm, float(obj.support_z), gripper)]
            for i, poses in enumerate(families):
                if len(poses) == 0 or (i > 0 and found >= num
                                       and params.demo_fallback != "slipped"):
                    continue
                if saved[i] is not None:
                    res = demo_results_from_arrays(saved[i])
                else:
                    res = sim(poses)
                    if checkpoint is not None:
                        checkpoint.save_part(_part_name(round_, i), {
                            "poses": poses, **demo_result_arrays(jax.tree.map(np.asarray, res))})
                tried += len(poses)
                outcome = np.asarray(res.outcome)
                succ = np.flatnonzero(outcome == 0)
                ok = succ if spread else succ[: num - found]
                found += len(ok)
                bar.update(len(poses))
                bar.set_postfix(found=f"{min(found, num)}/{num}")
                kept.append((poses[ok], jax.tree.map(lambda x, ok=ok: np.asarray(x)[ok], res)))
                spare = succ[len(ok):]
                others.append((poses[spare], _held_quality(res, spare, params.slip_scale)))
                slip = np.flatnonzero(outcome == 1)
                slipped.append((poses[slip], jax.tree.map(lambda x, s=slip: np.asarray(x)[s], res)))
            if found >= num:
                break
    if spread and found > num:
        kept, rest = _spread_choice(kept, num, params)
        others.append(rest)
    if found < num and params.demo_fallback == "slipped":
        # Opt-in: top up with the slipped candidates of highest epsilon (they touched the
        # object on both pads), for objects where no candidate holds.
        s_poses = np.concatenate([p for p, _ in slipped])
        s_res = jax.tree.map(lambda *xs: np.concatenate(xs), *[r for _, r in slipped])
        order = np.argsort(-np.asarray(s_res.epsilon), kind="stable")[: num - found]
        kept.append((s_poses[order], jax.tree.map(lambda x: np.asarray(x)[order], s_res)))
        if len(order):
            warnings.warn(f"{len(order)} of the demonstrations on {obj.name!r} slipped in "
                          "physics (demo_fallback='slipped')", stacklevel=2)
    poses = np.concatenate([p for p, _ in kept]) if kept else np.zeros((0, 7), np.float32)
    if len(poses) == 0:
        raise ValueError(f"no demonstrated grasp on {obj.name!r} succeeded in physics after "
                         f"{tried} candidates")
    if len(poses) < num:
        warnings.warn(f"only {len(poses)} of {num} demonstrations on {obj.name!r} succeeded",
                      stacklevel=2)
    results = jax.tree.map(lambda *xs: np.concatenate(xs), *[r for _, r in kept])
    return Demos(poses.astype(np.float32), results, spare_starts(others, poses))


def _antipodal_demos(sim, num: int, seed: int, gripper, params: LearnParams, checkpoint):
    """``num`` demos spread over the successes of ``num x ANTIPODAL_PER_DEMO`` collision-free
    antipodal grasps (one batch, saved to ``checkpoint`` like the search's), or None where
    fewer than ``num`` of them succeed (or no pair places): the candidate search then runs."""
    saved = None if checkpoint is None else checkpoint.load_part(ANTIPODAL_PART)
    if saved is not None:
        poses, res = saved["poses"], demo_results_from_arrays(saved)
    else:
        poses = some_antipodal_grasps(sim.obj, num * ANTIPODAL_PER_DEMO, seed=seed,
                                      gripper=gripper, collides=placement_collisions(sim))
        res = jax.tree.map(np.asarray, sim(poses)) if len(poses) else None
        if checkpoint is not None and res is not None:
            checkpoint.save_part(ANTIPODAL_PART, {"poses": poses, **demo_result_arrays(res)})
    if res is None:
        return None
    succ = np.flatnonzero(np.asarray(res.outcome) == 0)
    if len(succ) < num:
        return None
    kept = [(poses[succ], jax.tree.map(lambda x: np.asarray(x)[succ], res))]
    [(demos, demo_res)], rest = _spread_choice(kept, num, params)
    return Demos(demos.astype(np.float32), demo_res, spare_starts([rest], demos))


def _spread_choice(kept, num: int, params: LearnParams):
    """``num`` of the successes ``kept`` spread over the object: the first in candidate order,
    then each time the one farthest (``grasp_distances``) from those chosen. Returns the
    chosen ``[(poses, results)]`` and the others' ``(poses, quality)``."""
    poses = np.concatenate([p for p, _ in kept])
    res = jax.tree.map(lambda *xs: np.concatenate(xs), *[r for _, r in kept])
    dist = grasp_distances(poses, poses, length_scale=params.length_scale)
    chosen = [0]
    nearest = dist[0].copy()
    for _ in range(num - 1):
        nearest[chosen] = -1.0  # never twice, even where successes repeat a pose
        chosen.append(int(np.argmax(nearest)))
        nearest = np.minimum(nearest, dist[chosen[-1]])
    pick = np.asarray(chosen)
    rest = np.setdiff1d(np.arange(len(poses)), pick)
    return ([(poses[pick], jax.tree.map(lambda x: np.asarray(x)[pick], res))],
            (poses[rest], _held_quality(res, rest, params.slip_scale)))


def _held_quality(res, rows, slip_scale: float) -> np.ndarray:
    """The target density's weight of successes ``rows``: epsilon, less where they slid."""
    eps = np.asarray(res.epsilon, np.float64)[rows]
    if slip_scale > 0:
        eps = eps * np.exp(-np.asarray(res.displacement, np.float64)[rows] / slip_scale)
    return eps


def spare_starts(successes, demos) -> np.ndarray:
    """The distinct successful candidates that are not a demo, best held first: (k, 7)."""
    poses = np.concatenate([np.zeros((0, 7)), *[p for p, _ in successes]])
    quality = np.concatenate([np.zeros(0), *[q for _, q in successes]])
    # Best held first, so each cluster's representative is its best start.
    poses = poses[np.argsort(-quality, kind="stable")]
    distinct = distinct_grasps(poses) if len(poses) else poses
    return distinct[is_new(distinct, demos)].astype(np.float32)
