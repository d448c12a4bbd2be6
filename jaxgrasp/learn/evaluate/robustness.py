"""Will a robot hold it? Each grasp tried again under the pose error of a real arm.

A grasp found by the sampler is one pose; a robot reaches it with calibration and control
error. :func:`robustness` tries each grasp ``tries`` times, each at a perturbed pose (position
``+ N(0, position_sd)`` per axis, orientation turned about a uniformly random axis by
``|N(0, angle_sd)|``), with the same physics trial the learner scores, and reports how often it
held (``SUCCESS``). A grasp is **robust** when it held in at least ``min_share`` of its tries
(default 8 of 10 under 3 mm / 3°). The perturbations are seeded: the same call gives the same
answer.

>>> rob = jg.learn.robustness(result, trial=sim)      # the distinct successes of a run
>>> rob.robust_share, rob.probability[:5]
>>> result = result.with_robustness(rob)              # saved with the run

:class:`PoseNoise` and :class:`Robustness` live in :mod:`jaxgrasp.learn.evaluate.hold` (no
physics), so a ``LearnResult`` can carry a measurement.
"""

import numpy as np
from scipy.spatial.transform import Rotation

from jaxgrasp.learn.evaluate.hold import DEFAULT_NOISE, PoseNoise, Robustness
from jaxgrasp.learn.files.export import GraspSet, select_grasps
from jaxgrasp.learn.sim import as_simulator
from jaxgrasp.physics import Outcome
from jaxgrasp.physics.inputs import check_grasps

__all__ = ["PoseNoise", "Robustness", "perturbed_poses", "ranked", "robustness"]


def perturbed_poses(grasps, noise: PoseNoise = DEFAULT_NOISE, seed: int = 0) -> np.ndarray:
    """(N, tries, 7) the grasps at ``tries`` poses each, perturbed by ``noise`` (seeded)."""
    g = np.asarray(check_grasps(grasps, finite=True), np.float64)
    noise = PoseNoise(*noise).check()
    rng = np.random.default_rng([int(seed), 0x70B])
    n, k = len(g), int(noise.tries)
    pos = g[:, None, :3] + rng.normal(0.0, noise.position_sd, (n, k, 3))
    axis = rng.normal(size=(n, k, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    angle = np.abs(rng.normal(0.0, np.deg2rad(noise.angle_sd), (n, k, 1)))
    turn = Rotation.from_rotvec((axis * angle).reshape(-1, 3))
    base = Rotation.from_quat(np.repeat(g[:, 3:], k, axis=0), scalar_first=True)
    # A turn in the grasp frame; for a uniformly random axis the world frame is the same law.
    q = (base * turn).as_quat(scalar_first=True).reshape(n, k, 4)
    return np.concatenate([pos, q], axis=-1)


def robustness(grasps, obj=None, *, trial=None, noise: PoseNoise = DEFAULT_NOISE, seed: int = 0,
               backend: str = "auto", stop_early: bool = False) -> Robustness:
    """How often each grasp holds under a robot's pose error.

    Parameters
    ----------
    grasps : (N, 7) array, a GraspSet, or a LearnResult (its distinct successful grasps, as
        ``jg.learn.export_grasps`` writes them).
    obj : GraspObject, Scene or str, optional
        The object (default: the result's shipped object, or ``trial``'s).
    trial : Simulator or callable, optional
        The physics trial (a learning run's Simulator is reused; built from ``obj`` if None).
    noise : PoseNoise
        Position and orientation error, tries per grasp, the robust threshold.
    seed : int
        Seeds the perturbations.
    backend : str
        Physics backend when the trial is built here.
    stop_early : bool
        Stop trying a grasp once it has failed more than ``tries - min_held`` times (it can
        no longer be robust): the robust grasps and their counts are the full measurement's
        (the same perturbed poses, tried in the same order), the others cost fewer trials
        and report ``held`` of their ``tried``.
    """
    g = _grasps_of(grasps)
    if obj is None:
        obj = getattr(trial, "obj", None) or getattr(grasps, "object_name", None)
    if obj is None:
        raise ValueError("robustness needs the object: pass obj (or trial=, a Simulator)")
    noise = PoseNoise(*noise).check()
    if len(g) == 0:
        return Robustness(g.reshape(0, 7), np.zeros(0, np.int64), noise)
    sim = as_simulator(obj, backend=backend, trial=trial)
    poses = perturbed_poses(g, noise, seed).astype(np.float32)
    if not stop_early:
        outcome = np.asarray(sim.simulate_now(poses.reshape(-1, 7), merged=True).outcome)
        held = (outcome == int(Outcome.SUCCESS)).reshape(len(g), noise.tries).sum(axis=1)
        return Robustness(g, held.astype(np.int64), noise)
    held, tried = np.zeros(len(g), np.int64), np.zeros(len(g), np.int64)
    for k in range(noise.tries):  # one batched call per round, of the grasps still open
        open_ = np.flatnonzero(tried - held <= noise.tries - noise.min_held)
        if len(open_) == 0:
            break
        outcome = np.asarray(sim.simulate_now(poses[open_, k], merged=True).outcome)
        held[open_] += outcome == int(Outcome.SUCCESS)
        tried[open_] += 1
    return Robustness(g, held, noise, tried)


def _grasps_of(grasps) -> np.ndarray:
    if hasattr(grasps, "proposals") and hasattr(grasps, "outcomes"):  # a LearnResult
        grasps = select_grasps(grasps)
    if hasattr(grasps, "grasps") and hasattr(grasps, "transforms"):  # a GraspSet
        grasps = grasps.grasps
    g = np.asarray(check_grasps(grasps, finite=True), np.float64)
    g[:, 3:] /= np.linalg.norm(g[:, 3:], axis=1, keepdims=True)
    return g


def ranked(grasps: GraspSet, rob: Robustness) -> GraspSet:
    """``grasps`` (the set ``rob`` measured) with their hold probability, most robust first
    (equal probabilities keep their order)."""
    if len(rob.held) != len(grasps.grasps):
        raise ValueError(f"{len(rob.held)} measured grasps for a set of {len(grasps.grasps)}")
    order, rob = rob.most_robust_first()
    rows = {k: np.asarray(v)[order] for k, v in grasps._asdict().items()
            if k in ("grasps", "transforms", "width", "epsilon", "outcome")}
    return grasps._replace(**rows, robustness=rob.probability)
