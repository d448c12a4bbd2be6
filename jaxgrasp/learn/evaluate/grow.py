"""More distinct grasps after a run: a flood from every distinct success.

The chains of a run revisit what they found (a chain resting on a grasp re-proposes it, and
MH keeps it there); a flood never tries a grasp twice. :func:`grow` rolls out the untried
neighbours (:func:`~jaxgrasp.learn.evaluate.atlas.neighbour_poses`: one distinct-grasp step
along and about each axis of the grasp frame, not colliding where placed) of every distinct
successful grasp, then of the new ones, round by round until the budget is spent or no untried
neighbour is left: the atlas builder's flood, seeded with the run's grasps. Where it runs dry
with budget left it goes on from the same grasps elsewhere on the object (the copies under its
symmetry), from islands (antipodal draws) and, last, from everything found at a finer spacing,
where a pose that failed left a grasp untried. Its grasps are successes of the same trial;
whether they hold under a robot's pose error is :func:`jaxgrasp.learn.robustness`'s to say.

>>> grown = jg.learn.grow(result, trial=sim, budget=4000)   # the run's proposals count as tried
>>> grown = jg.learn.grow(result, trial=sim, budget=4000, antipodal=2000,
...                       symmetry=result.info.get("symmetry"))     # the one the chains followed
>>> grown.grasps, grown.added, grown.trials
"""

from typing import NamedTuple

import numpy as np

from jaxgrasp.learn.evaluate.atlas import flood
from jaxgrasp.learn.evaluate.copies import as_symmetry, same_around, symmetric_copies
from jaxgrasp.learn.evaluate.distinct import canonical_grasps
from jaxgrasp.learn.files.export import GraspSet, select_grasps, to_transforms
from jaxgrasp.learn.setup.antipodal import placement_collisions, some_antipodal_grasps
from jaxgrasp.learn.sim import as_simulator
from jaxgrasp.physics import Outcome

__all__ = ["DEFER", "FINEST", "Flooded", "grow"]

# grow_robust's kinds of flood step (of 12) that wait while others are queued: those that
# held least
DEFER = 3

# the finest retry: a grasp where a pose failed is tried again 2.5 mm / 2.5° from every tried one
FINEST = 0.25


class Flooded(NamedTuple):
    """What :func:`grow` found: ``grasps`` (the input set, then the distinct successes added,
    in order found), ``added`` (those last rows), ``trials`` (rollouts), ``rounds`` and
    ``rolled`` (the neighbours simulated, in order)."""

    grasps: GraspSet
    added: int
    trials: int
    rounds: int
    rolled: np.ndarray


def grow(grasps, obj=None, *, budget: int, trial=None, tried=None, backend: str = "auto",
         collides=None, symmetry=None, antipodal: int = 0, seed: int = 0,
         finest: float = FINEST, defer: int = 0, rank: bool = True) -> Flooded:
    """Distinct successful grasps next to those of ``grasps``, for at most ``budget`` trials.

    ``grasps``: a GraspSet of distinct successful grasps, or a LearnResult (its
    ``select_grasps``, and its proposals as ``tried``). ``tried``: poses tried before, whose
    neighbours are not tried again. ``trial``: the object's Simulator (built from ``obj`` if
    None); ``collides``: ``poses -> bool mask`` of placement collisions (default: MuJoCo C on
    the scene). ``symmetry`` (a :class:`~jaxgrasp.objects.Symmetry`, its text form, a run's
    ``info["symmetry"]`` or ``"auto"``; None: none): with the budget the flood leaves, the
    copies of every success under the object's turns and mirror planes
    (:func:`~jaxgrasp.learn.evaluate.copies.symmetric_copies`, where the object looks the same
    around the copy) are tried, those not tried before, and flooded from; then the copies of
    what that found. ``antipodal``: then, with the budget left, that many antipodal grasps
    (:func:`~jaxgrasp.learn.setup.antipodal.some_antipodal_grasps`, seeded by ``seed``, then
    ``seed + 1``, ...) are drawn, those not tried before rolled out and flooded from (islands
    the run did not touch), and their copies; another batch while the last one found any.
    Then, budget left, the flood goes again from everything found, trying again where a pose
    failed (:func:`~jaxgrasp.learn.evaluate.atlas.flood`'s ``near``): at half the same-grasp
    distance from every tried pose, then a quarter (``finest``; 1: never). It stops when the
    budget is spent or nothing is left to try. ``rank``: where more neighbours are queued
    than a round of the budget, every flood tries first those most likely to hold, as the
    successes and failures it rolled out around them say
    (:func:`~jaxgrasp.learn.evaluate.atlas.flood`'s ``rank``): where the budget runs out
    first, it was spent where grasps hold. ``defer``: the neighbours of the ``defer`` kinds of
    step that held least often so far wait while others are queued (``flood``'s ``defer``;
    ranking measured better without it).
    """
    if hasattr(grasps, "proposals") and hasattr(grasps, "outcomes"):  # a LearnResult
        tried = grasps.proposals if tried is None else tried
        grasps = select_grasps(grasps)
    if budget < 0 or antipodal < 0:
        raise ValueError(f"budget and antipodal must be >= 0, got {budget}, {antipodal}")
    obj = obj if obj is not None else getattr(trial, "obj", None) or grasps.object_name
    sim = as_simulator(obj, backend=backend, trial=trial)
    start, epsilons = sim.num_trials, []

    def run(poses):
        res = sim.simulate_now(poses)  # the run's batch: one compiled shape
        epsilons.append(np.asarray(res.epsilon, np.float64))
        return np.asarray(res.outcome), np.nan_to_num(epsilons[-1], nan=0.0)

    g = np.asarray(grasps.grasps, np.float64)
    before = [g] if tried is None else [np.asarray(tried, np.float64).reshape(-1, 7), g]
    state = {"tried": before, "found": g}
    collides = placement_collisions(sim) if collides is None else collides
    order = np.argsort(-np.asarray(grasps.epsilon, np.float64), kind="stable")
    rolled, counts = flood(run, g[order], collides, int(budget), state, defer=defer, rank=rank)
    rolled, rounds = [rolled], counts["flood_rounds"]
    sym, fresh, batches = as_symmetry(sim.obj, symmetry), state["found"], 0
    near, drawing = 1.0, antipodal > 0
    same = same_around(sim, sym) if sym is not None else None
    while (left := budget - (sim.num_trials - start)) > 0:
        # where the flood ran dry: the same grasps elsewhere on the object, then islands
        # (another batch of draws while the last one found any), then a finer flood
        frontier, first, drew = np.zeros((0, 7)), None, False
        if sym is not None and len(fresh):
            first = symmetric_copies(fresh, sym, same)
        elif drawing:
            first = some_antipodal_grasps(sim.obj, int(antipodal), seed=seed + batches,
                                          collides=collides,
                                          gripper=getattr(sim.scene, "gripper", None))
            batches, drew = batches + 1, True
        elif near / 2 >= finest:
            near, frontier = near / 2, state["found"]
        else:
            break
        found = len(state["found"])
        more, c = flood(run, frontier, collides, left, state, first=first, near=near,
                        defer=defer, rank=rank)
        rolled.append(more)
        rounds += c["flood_rounds"]
        fresh = state["found"][found:]
        drawing = drawing and (len(fresh) > 0 or not drew)
    rolled = np.concatenate(rolled)
    new = canonical_grasps(state["found"][len(g):])
    eps = epsilon_of(new, rolled, np.concatenate(epsilons) if epsilons else np.zeros(0))
    return Flooded(with_added(grasps, new, eps), int(len(new)), int(sim.num_trials - start),
                   rounds, rolled)


def with_added(grasps: GraspSet, new, epsilon) -> GraspSet:
    """``grasps`` followed by the successful grasps ``new`` (their epsilons given)."""
    new = np.asarray(new, np.float64).reshape(-1, 7)
    width = grasps.width[:1] if len(grasps.width) else np.zeros(1)
    return GraspSet(np.concatenate([grasps.grasps, new]).astype(grasps.grasps.dtype),
                    np.concatenate([grasps.transforms, to_transforms(new)]),
                    np.concatenate([grasps.width, np.repeat(width, len(new))]),
                    np.concatenate([grasps.epsilon, epsilon]),
                    np.concatenate([grasps.outcome, np.full(len(new), int(Outcome.SUCCESS),
                                                            grasps.outcome.dtype)]),
                    grasps.object_name, grasps.object_hash)


def epsilon_of(grasps, rolled, epsilon) -> np.ndarray:
    """Each of ``grasps`` (rows of ``rolled``, canonical) its epsilon from that rollout."""
    if len(grasps) == 0:
        return np.zeros(0)
    key = {tuple(np.round(row, 6)): e for row, e in zip(canonical_grasps(rolled), epsilon,
                                                        strict=True)}
    return np.array([key.get(tuple(np.round(row, 6)), np.nan) for row in grasps])
