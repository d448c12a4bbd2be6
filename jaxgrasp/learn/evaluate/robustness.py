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
>>> grown = jg.learn.grow_robust(result, rob, trial=sim, budget=8000)  # more robust ones near
>>> grown.grasps, grown.robustness                    # the run's grasps, then the added ones

:func:`grow_robust` floods out from the robust grasps: each one's neighbours one distinct-grasp
step away (:func:`jaxgrasp.learn.evaluate.atlas.neighbour_poses`), those not tried before and
not colliding where placed are simulated, the new successes scored the same way, and the
flood goes on from the new robust ones until its budget (rollouts and scoring) is spent or no
neighbour is left.

:class:`PoseNoise` and :class:`Robustness` live in :mod:`jaxgrasp.learn.evaluate.hold` (no
physics), so a ``LearnResult`` can carry a measurement.
"""

from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from jaxgrasp.learn.evaluate.atlas import flood
from jaxgrasp.learn.evaluate.copies import as_symmetry, same_around, symmetric_copies
from jaxgrasp.learn.evaluate.distinct import (
    canonical_grasps,
    distinct_grasps,
    same_as_any,
    same_grasp,
)
from jaxgrasp.learn.evaluate.grow import DEFER, FINEST, epsilon_of, with_added
from jaxgrasp.learn.evaluate.hold import DEFAULT_NOISE, PoseNoise, Robustness
from jaxgrasp.learn.files.export import GraspSet, select_grasps, to_transforms
from jaxgrasp.learn.setup.antipodal import placement_collisions, some_antipodal_grasps
from jaxgrasp.learn.sim import as_simulator
from jaxgrasp.physics import Outcome
from jaxgrasp.physics.inputs import check_grasps

__all__ = ["Grown", "PoseNoise", "Robustness", "grow_robust", "perturbed_poses", "ranked",
           "robustness", "tries_stopping_early"]


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
        outcome = sim.outcomes(poses.reshape(-1, 7))
        held = (outcome == int(Outcome.SUCCESS)).reshape(len(g), noise.tries).sum(axis=1)
        return Robustness(g, held.astype(np.int64), noise)
    out = tries_stopping_early(sim, poses, noise)
    held = (out == int(Outcome.SUCCESS)).sum(axis=1).astype(np.int64)
    return Robustness(g, held, noise, (out >= 0).sum(axis=1).astype(np.int64))


def tries_stopping_early(sim, poses, noise: PoseNoise) -> np.ndarray:
    """The outcome of each perturbed pose (N, tries, 7), -1 where not tried: a grasp is no
    longer tried once it has failed more than ``tries - min_held`` times (one batched call
    per round, of the grasps still open)."""
    out = np.full(poses.shape[:2], -1, np.int64)
    for k in range(noise.tries):
        failed = ((out >= 0) & (out != int(Outcome.SUCCESS))).sum(axis=1)
        open_ = np.flatnonzero(failed <= noise.tries - noise.min_held)
        if len(open_) == 0:
            break
        out[open_, k] = sim.outcomes(poses[open_, k])
    return out


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


class Grown(NamedTuple):
    """What :func:`grow_robust` found.

    grasps : GraspSet, the input set (``swapped`` of its grasps replaced by a robust symmetric
        copy in the same place) followed by the distinct successes added (in order found).
    robustness : Robustness of ``grasps`` (the input's measurement, then the new grasps').
    added : distinct successful grasps added (the last rows).
    trials : trials spent, rollouts and their scoring.
    rounds : flood rounds.
    rolled : (n, 7) the neighbours, then the symmetric copies, then the finer floods'
        neighbours it simulated, in order (the successes among them, less repeats of a grasp,
        are the added grasps).
    swapped : grasps of the input set replaced by a robust symmetric copy in the same place.
    """

    grasps: GraspSet
    robustness: Robustness
    added: int
    trials: int
    rounds: int
    rolled: np.ndarray
    swapped: int = 0


def grow_robust(grasps, rob: Robustness, obj=None, *, budget: int, trial=None, tried=None,
                seed: int = 0, backend: str = "auto", collides=None,
                antipodal: int = 0, symmetry=None, finest: float = FINEST,
                defer: int = DEFER) -> Grown:
    """More robust grasps next to the robust ones of ``grasps``, for at most ``budget`` trials.

    Parameters
    ----------
    grasps : GraspSet or LearnResult
        Distinct successful grasps in the order ``rob`` measured them (a LearnResult: its
        ``select_grasps``, as ``robustness(result, ...)`` measures them, and its proposals as
        ``tried``).
    rob : Robustness
        Their measurement (``robustness(grasps, ...)``); its noise scores the new grasps.
    obj : GraspObject, Scene or str, optional
        The object (default: ``trial``'s, or the set's shipped object).
    trial : Simulator or callable, optional
        The object's trial (the learning run's Simulator is reused; built from ``obj`` if
        None); placement collisions are decided on the object's scene with MuJoCo C.
    budget : int
        Trials the flood may spend, rollouts and scoring (it stops early when no untried
        neighbour is left).
    tried : (..., 7) array, optional
        Poses tried before (a run's ``proposals``): their neighbours are not tried again.
    seed : int
        Seeds the scoring's perturbations (round ``r`` uses ``seed + 1000 * r``).
    backend : str
        Physics backend when the trial is built here.
    collides : callable, optional
        ``poses -> bool mask`` of placement collisions (default: MuJoCo C on the scene).
    antipodal : int
        Antipodal grasps (:func:`~jaxgrasp.learn.setup.antipodal.antipodal_grasps`) drawn
        first: those not the same grasp as one tried or drawn before are simulated within the
        budget, and their robust successes seed the flood too (islands of robust grasps the
        chains did not touch). 0: the flood starts from ``grasps`` alone.
    symmetry : Symmetry, str or None
        The object's symmetry (:class:`jaxgrasp.objects.Symmetry`, its text form, or
        ``"auto"``: found from the mesh). With the budget the flood leaves, each robust grasp's
        copies under its turns and mirror planes
        (:func:`~jaxgrasp.learn.evaluate.copies.symmetric_copies`, where the object looks the
        same around the copy) are tried, also where the chains tried that grasp before: a
        robust copy replaces a grasp of the set that is not robust in the same place (scored
        again for the export, ``Grown.swapped``), a successful one is added where the set has
        none. None: no copies.

    With budget left after all that, the flood goes again from every robust grasp, trying
    again where a pose failed (:func:`~jaxgrasp.learn.evaluate.atlas.flood`'s ``near``): at
    half the same-grasp distance from every pose tried, then a quarter (``finest``, a share of
    that distance; 1: never). ``defer``: :func:`~jaxgrasp.learn.evaluate.atlas.flood`'s (the
    kinds of step that held least often wait while others are queued).
    """
    if hasattr(grasps, "proposals") and hasattr(grasps, "outcomes"):  # a LearnResult
        tried = grasps.proposals if tried is None else tried
        grasps = select_grasps(grasps)
    g = np.asarray(grasps.grasps, np.float64)
    if len(rob.held) != len(g):
        raise ValueError(f"{len(rob.held)} measured grasps for a set of {len(g)}")
    if budget < 0:
        raise ValueError(f"budget must be >= 0, got {budget}")
    if antipodal < 0:
        raise ValueError(f"antipodal must be >= 0, got {antipodal}")
    obj = obj if obj is not None else getattr(trial, "obj", None) or grasps.object_name
    sim, noise = as_simulator(obj, backend=backend, trial=trial), rob.noise
    start = sim.num_trials
    epsilons, measured = [], []

    def run(poses):
        # calls of the learning run's batch: on a new object each other shape compiles the
        # trial's contacts again (seconds each), more than the larger batch saves
        res = sim.simulate_now(poses)
        epsilons.append(np.asarray(res.epsilon, np.float64))
        return np.asarray(res.outcome), np.nan_to_num(epsilons[-1], nan=0.0)

    def expand(new):
        r = robustness(new, trial=sim, noise=noise, seed=seed + 1000 * (len(measured) + 1),
                       stop_early=True)
        measured.append(r)
        order = np.argsort(-r.probability, kind="stable")
        return new[order][r.robust[order]], r.num_trials

    order = np.argsort(-rob.probability, kind="stable")
    before = [g] if tried is None else [np.asarray(tried, np.float64).reshape(-1, 7), g]
    state = {"tried": before, "found": g}
    collides = placement_collisions(sim) if collides is None else collides
    first = None if not antipodal else some_antipodal_grasps(
        sim.obj, int(antipodal), seed=seed, collides=collides,
        gripper=getattr(sim.scene, "gripper", None))
    # a round tries at most budget / (1 + tries) neighbours: the budget holds their scoring
    rolled, counts = flood(run, g[order][rob.robust[order]], collides, int(budget), state,
                           expand=expand, cost=1 + noise.tries, first=first, defer=defer)
    new = canonical_grasps(state["found"][len(g):])
    out = with_added(grasps, new, epsilon_of(
        new, rolled, np.concatenate(epsilons) if epsilons else np.zeros(0)))
    both = _joined(rob, measured)
    sym, copied, swapped = as_symmetry(sim.obj, symmetry), [], 0
    if sym is not None:  # what the flood left: cheaper per robust grasp where it ran dry
        out, both, copied, swapped = _copied_robust(
            out, both, sim, sym, run, collides, int(budget) - (sim.num_trials - start),
            seed=seed + 500)
    rolled, rounds = [rolled, *copied], counts["flood_rounds"]
    state["tried"].extend(copied)
    near = 1.0
    while (left := int(budget) - (sim.num_trials - start)) > 0 and near / 2 >= finest:
        # budget left: the flood again from every robust grasp, trying again where a pose failed
        near, state["found"], scored = near / 2, np.asarray(out.grasps, np.float64), len(measured)
        more, c = flood(run, np.asarray(out.grasps, np.float64)[both.robust], collides, left,
                        state, expand=expand, cost=1 + noise.tries, near=near, defer=defer)
        rolled.append(more)
        rounds += c["flood_rounds"]
        new = canonical_grasps(state["found"][len(out.grasps):])
        out = with_added(out, new, epsilon_of(new, np.concatenate(rolled), np.concatenate(
            epsilons) if epsilons else np.zeros(0)))
        both = _joined(both, measured[scored:])
    return Grown(out, both, int(len(out.grasps) - len(g)), int(sim.num_trials - start),
                 rounds, np.concatenate(rolled), swapped)


def _joined(rob: Robustness, more) -> Robustness:
    """``rob`` followed by the measurements ``more`` (of the same noise)."""
    return Robustness(np.concatenate([rob.grasps, *(r.grasps for r in more)]),
                      np.concatenate([rob.held, *(r.held for r in more)]).astype(np.int64),
                      rob.noise, np.concatenate([rob.tries_made, *(r.tries_made for r in more)]))


def _copied_robust(grasps: GraspSet, rob: Robustness, sim, sym, run, collides, budget: int,
                   seed: int):
    """Each robust grasp's copies under ``sym``, rolled out and scored, round by round from the
    new robust ones, while ``budget`` lasts. A copy is tried unless it is the same grasp as a
    robust one or as a copy tried before. Where the set has a grasp that is not robust, a
    robust copy takes its place (the same grasp, one that holds more often) and is scored
    again: the exported measurement is that second one, since a copy chosen for passing one
    noisy test passes it more often than its hold probability says. Where the set has none, a
    successful copy is added. Returns the set and its measurement so changed, the copies rolled
    out and how many grasps were replaced."""
    noise, looks_same = rob.noise, same_around(sim, sym)
    cost = 1 + 2 * noise.tries  # a rollout, its scoring and, for a swap, the second scoring
    rows = np.asarray(grasps.grasps, np.float64).copy()
    eps = np.asarray(grasps.epsilon, np.float64).copy()
    held, tries = rob.held.astype(np.int64).copy(), rob.tries_made.copy()
    robust = held >= noise.min_held
    start, copied, swapped = sim.num_trials, [], 0
    order = np.argsort(-rob.probability, kind="stable")
    frontier = rows[order][robust[order]]
    while len(frontier):
        left = budget - (sim.num_trials - start)
        cand = symmetric_copies(frontier, sym, looks_same).astype(np.float64)
        cand = distinct_grasps(cand) if len(cand) else cand
        for done in ([rows[robust]] if robust.any() else []) + copied:
            cand = cand[~same_as_any(cand, done)] if len(cand) else cand
        cand = cand[~np.asarray(collides(cand), bool)] if len(cand) else cand
        cand = canonical_grasps(cand[:max(left, 0) // cost]).astype(np.float32)
        if len(cand) == 0:
            break
        outcome, epsilon = run(cand)
        copied.append(cand)
        ok = np.flatnonzero(outcome == Outcome.SUCCESS)
        if len(ok) == 0:
            break
        seed_r = seed + 1000 * len(copied)
        r = robustness(cand[ok], trial=sim, noise=noise, seed=seed_r, stop_early=True)
        same = same_grasp(cand[ok], rows)
        swaps, added = {}, []  # row -> copy; copies in no grasp's place
        for k in np.argsort(-r.probability, kind="stable"):
            hits = np.flatnonzero(same[k])
            spot = [h for h in hits if not robust[h] and h not in swaps]
            if r.robust[k] and spot:
                swaps[spot[0]] = k
            elif len(hits) == 0:
                added.append(k)
        if swaps:
            again = robustness(cand[ok[list(swaps.values())]], trial=sim, noise=noise,
                               seed=seed_r + 500, stop_early=True)
            for (i, k), h, t in zip(swaps.items(), again.held, again.tries_made, strict=True):
                rows[i], eps[i], held[i], tries[i] = cand[ok[k]], epsilon[ok[k]], h, t
                robust[i] = h >= noise.min_held
            swapped += len(swaps)
        for k in added:
            rows = np.concatenate([rows, cand[ok[k]][None].astype(np.float64)])
            eps, held = np.append(eps, epsilon[ok[k]]), np.append(held, r.held[k])
            tries, robust = np.append(tries, r.tries_made[k]), np.append(robust, r.robust[k])
        # the next round copies the copies that passed their first test
        frontier = cand[ok[[k for k in [*swaps.values(), *added] if r.robust[k]]]]
        frontier = np.asarray(frontier, np.float64).reshape(-1, 7)
    rows[:, 3:] /= np.linalg.norm(rows[:, 3:], axis=1, keepdims=True)
    n = len(grasps.grasps)
    # the replaced rows in place, the added ones after
    kept = grasps._replace(grasps=rows[:n].astype(grasps.grasps.dtype),
                           transforms=to_transforms(rows[:n]), epsilon=eps[:n])
    return (with_added(kept, rows[n:], eps[n:]), Robustness(rows, held, noise, tries), copied,
            swapped)
