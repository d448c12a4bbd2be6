"""The grasp-trial protocol, shared by every physics backend: outcome codes, the result
record, the protocol parameters and the per-step control/load schedule. The decisions
(placement, slip, miss, ...) are in :mod:`jaxgrasp.physics.rules`; the backends differ only in
how they step the physics.

Protocol (RobWork's GraspTaskSimulator as reference; rationale in ``docs/design.md``), with
the gripper fixed in the simulation world (the grasp frame) and the object placed at the
inverse grasp pose:

1. **place** fingers open; any penetration deeper than ``collision_tol`` or any gripper corner
   below the support plane (``z < support_z`` in the object frame) -> ``COLLISION``
   (decided from one collision pass, no rollout);
2. **close** ``close_ramp_steps`` steps of linearly ramped position targets from open to
   ``close_target`` (past the closed limit so the grip force saturates at the finger force
   limit), then ``close_settle_steps`` steps holding it; no gravity, no loads;
3. **miss** if either pad never came within ``contact_tol`` of the object during the settle
   phase, or either finger is at its closed limit;
4. **contacts** after closing (the pad patches, ``patch_tol`` deep) -> epsilon
   (``jaxgrasp.quality.epsilon``);
5. **hold** ``hold_steps`` steps under the object's weight (world -z of the object frame,
   expressed in the gripper frame, applied at the COM), then each of ``perturbations``
   (extra loads in the gripper frame, in units of the weight) for ``perturbation_steps``;
   the object's displacement relative to the gripper (max over the hold, of the COM and of
   the material point at the grasp center) < ``slip_tol`` and both pads still in contact ->
   ``SUCCESS``, else ``SLIPPED``.

Trials whose physics becomes non-finite or blows up are reported ``MISS`` with
``unstable=True``: a failure that never yields a density above the floor, never a NaN.
"""

from dataclasses import dataclass
from enum import IntEnum
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgrasp.quality import epsilon, epsilon_batch

__all__ = [
    "Outcome",
    "TrialResult",
    "result_shapes",
    "TrialParams",
    "schedule",
    "with_epsilon",
    "graspable",
    "epsilon_where",
    "epsilon_fn",
]

#: Standard gravity (m/s^2); the hold load is ``mass * G`` along the object's world -z.
G = 9.81


class Outcome(IntEnum):
    """Outcome of one grasp trial (the paper's four classes)."""

    SUCCESS = 0
    SLIPPED = 1
    COLLISION = 2
    MISS = 3


class TrialResult(NamedTuple):
    """Result of a batch of grasp trials (all fields have leading dimension B).

    Attributes
    ----------
    outcome : (B,) int32
        :class:`Outcome` code.
    epsilon : (B,) float32
        Ferrari-Canny epsilon of the contacts after closing; 0 for collision/miss/unstable.
    displacement : (B,) float32
        Largest object displacement relative to the gripper during the hold (metres);
        0 for collision/miss.
    contact_points : (B, K, 3) float32
        Pad-object contact points after closing, object frame (zeros where masked).
    contact_normals : (B, K, 3) float32
        Unit contact normals, object frame, pointing INTO the object (the direction the
        finger pushes); zeros where masked.
    contact_mask : (B, K) bool
        Which contact slots hold a real contact.
    pad_contact : (B, 2) bool
        Whether the (left, right) pad touches the object after closing.
    unstable : (B,) bool
        Non-finite or blown-up physics was seen (the trial is reported as ``MISS``).
    invalid : (B,) bool
        The row is not a grasp pose (NaN/inf, a value beyond float32, a zero quaternion): never
        simulated, reported as ``COLLISION`` (a failure for the sampler), and flagged here so a
        typo is not mistaken for a real collision.
    """

    outcome: jax.Array
    epsilon: jax.Array
    displacement: jax.Array
    contact_points: jax.Array
    contact_normals: jax.Array
    contact_mask: jax.Array
    pad_contact: jax.Array
    unstable: jax.Array
    invalid: jax.Array


def result_shapes(batch: int, num_contacts: int) -> TrialResult:
    """The ShapeDtypeStructs of a :class:`TrialResult` of ``batch`` trials with ``num_contacts``
    contact slots, known without tracing a trial."""
    def s(*shape, dtype=jnp.float32):
        return jax.ShapeDtypeStruct((batch, *shape), dtype)

    k = num_contacts
    return TrialResult(outcome=s(dtype=jnp.int32), epsilon=s(), displacement=s(),
                       contact_points=s(k, 3), contact_normals=s(k, 3),
                       contact_mask=s(k, dtype=jnp.bool_), pad_contact=s(2, dtype=jnp.bool_),
                       unstable=s(dtype=jnp.bool_), invalid=s(dtype=jnp.bool_))


@dataclass(frozen=True)
class TrialParams:
    """Protocol parameters: step counts, thresholds, timestep and solver (SI units).

    Why each default is what it is (with the measurements) is in ``docs/design.md``.

    Attributes
    ----------
    timestep : float
        Simulation step (s), in (0, 0.01].
    close_ramp_steps, close_settle_steps : int
        Steps of the linear closing ramp, then steps holding the closing target (no loads).
    close_target : float
        Per-finger position target (m) at the end of the ramp; negative, i.e. past the closed
        limit, so the grip force saturates at ``GripperParams.force_limit`` (it must lie
        ``force_limit / finger_kp`` past it).
    hold_steps : int
        Steps under the object's weight after closing.
    perturbations : tuple of (3,) tuples
        Extra loads in the gripper frame, in units of the object's weight, each applied on top
        of the weight for ``perturbation_steps`` after the hold; none by default.
    perturbation_steps : int
    slip_tol : float
        Largest displacement (m) relative to the gripper during the hold of a ``SUCCESS``.
    collision_tol : float
        Penetration (m) allowed at placement before it is a ``COLLISION``.
    contact_tol : float
        A pad touches when its signed distance to the object drops below this (m); it must
        touch at some step of the settle phase (else ``MISS``) and at the end of the hold.
    patch_tol : float
        Depth (m) of the pad contact patch epsilon reads (:mod:`jaxgrasp.physics.contacts`).
    closed_tol : float
        A finger within this (m) of its closed limit closed on nothing: ``MISS``.
    max_speed : float
        Any |qvel| above this (m/s or rad/s) is a blow-up: ``MISS`` with ``unstable``.
    iterations, ls_iterations : int
        Constraint-solver iterations.
    num_contacts : int
        K, the number of contacts kept for epsilon (half per pad).
    pieces_per_pad, pieces_per_palm : int
        MJX rollouts collide each pad (palm) with only its nearest convex pieces, chosen per
        trial and per step (:func:`jaxgrasp.physics.collision.collide_slots`); placement
        always uses every piece.
    """

    timestep: float = 0.003
    close_ramp_steps: int = 20
    close_settle_steps: int = 10
    close_target: float = -0.035
    hold_steps: int = 50
    perturbations: tuple = ()
    perturbation_steps: int = 20
    slip_tol: float = 0.01
    collision_tol: float = 0.002
    contact_tol: float = 0.001
    patch_tol: float = 0.001
    closed_tol: float = 0.001
    max_speed: float = 1000.0
    iterations: int = 6
    ls_iterations: int = 6
    num_contacts: int = 8
    pieces_per_pad: int = 3
    pieces_per_palm: int = 2

    def __post_init__(self):
        if not 0.0 < self.timestep <= 0.01:
            raise ValueError(f"timestep must be in (0, 0.01] s, got {self.timestep}")
        for name in ("close_ramp_steps", "close_settle_steps", "hold_steps"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.perturbation_steps < 0:
            raise ValueError(f"perturbation_steps must be >= 0, got {self.perturbation_steps}")
        for p in self.perturbations:
            if len(p) != 3:
                raise ValueError(f"each perturbation must be a 3-vector, got {p!r}")
        for name in ("slip_tol", "collision_tol", "contact_tol", "patch_tol", "closed_tol",
                     "max_speed"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if self.iterations < 1 or self.ls_iterations < 1:
            raise ValueError("iterations and ls_iterations must be >= 1")
        if self.pieces_per_pad < 1 or self.pieces_per_palm < 1:
            raise ValueError("pieces_per_pad and pieces_per_palm must be >= 1")
        if self.num_contacts < 2 or self.num_contacts % 2:
            raise ValueError(f"num_contacts must be even and >= 2, got {self.num_contacts}")

    @property
    def close_steps(self) -> int:
        return self.close_ramp_steps + self.close_settle_steps

    @property
    def num_steps(self) -> int:
        n_perturb = len(self.perturbations) * self.perturbation_steps
        return self.close_steps + self.hold_steps + n_perturb


class Schedule(NamedTuple):
    """Per-step inputs of the rollout (numpy, identical for every trial).

    ctrl : (T, 2) finger position targets (left, right), metres of opening per finger.
    weight : (T,) 0/1, whether the object's weight acts at that step.
    perturb : (T, 3) extra load in the gripper frame, in units of the weight.
    """

    ctrl: np.ndarray
    weight: np.ndarray
    perturb: np.ndarray


def schedule(params: TrialParams, open_width: float) -> Schedule:
    """The control and load schedule of one trial (``open_width`` = per-finger opening)."""
    n_ramp, n_settle = params.close_ramp_steps, params.close_settle_steps
    # Ramp ends exactly at the target on its last step.
    ramp = open_width + (params.close_target - open_width) * np.arange(1, n_ramp + 1) / n_ramp
    n_hold = params.num_steps - params.close_steps
    target = np.concatenate([ramp, np.full(n_settle + n_hold, params.close_target)])
    ctrl = np.stack([target, target], axis=1).astype(np.float32)
    weight = np.concatenate([np.zeros(params.close_steps), np.ones(n_hold)]).astype(np.float32)
    perturb = np.zeros((params.num_steps, 3), np.float32)
    t = params.close_steps + params.hold_steps
    for p in params.perturbations:
        perturb[t : t + params.perturbation_steps] = p
        t += params.perturbation_steps
    return Schedule(ctrl=ctrl, weight=weight, perturb=perturb)


#: A trial keeping more contacts than this runs epsilon's antipode start
#: (:func:`jaxgrasp.quality.epsilon_from_wrenches`, step 2b). On sets of at most 8 contacts it
#: fixed nothing measurable (0 of 8 000 random sets of 2-8 contacts missed Qhull by 1 %, with
#: or without it) and costs 3-29 % of epsilon, the most at small batches (docs/design.md,
#: "Epsilon of the grasp wrench space"); on 2-16 contacts it halves
#: the misses.
ANTIPODE_ABOVE = 8
#: Start directions of a trial's epsilon search up to :data:`ANTIPODE_ABOVE` contacts (7 simplex
#: vertices, 4 thinnest eigen-directions, 1 random): on 3 329 real trial contact sets of the 9
#: objects as many miss Qhull by 1 % as with the library's 16 (2), and the search costs a third
#: less; 10 starts miss 4 (docs/design.md, "Epsilon of the grasp wrench space").
TRIAL_STARTS = 12
TRIAL_EIGEN_STARTS = 4


def epsilon_fn(mu, com, radius, num_contacts=8, *, num_starts=None, num_eigen_starts=None):
    """``(points, normals, mask) -> epsilon`` of one trial: ``jaxgrasp.quality.epsilon`` with
    the object's friction, torque origin (COM) and torque scale (max radius), for contact
    sets of ``num_contacts`` slots (the antipode start and the library's start directions
    only above :data:`ANTIPODE_ABOVE`, else :data:`TRIAL_STARTS`; ``num_starts`` and
    ``num_eigen_starts``, given together, replace those start directions).
    Its ``batch`` attribute, ``(points, normals, mask, need) -> (B,)``, is
    ``jaxgrasp.quality.epsilon_batch`` with the same constants (what :func:`epsilon_where`
    runs)."""
    antipode = num_contacts > ANTIPODE_ABOVE
    starts = {} if antipode else dict(num_starts=TRIAL_STARTS,
                                      num_eigen_starts=TRIAL_EIGEN_STARTS)
    if num_starts is not None:
        starts = dict(num_starts=num_starts, num_eigen_starts=num_eigen_starts)

    def fn(p, n, m):
        return epsilon(p, n, m, mu, com, radius, antipode=antipode, **starts)

    def batch(p, n, m, need):
        lanes = EPSILON_LANES if jax.default_backend() == "cpu" else ACCELERATOR_LANES
        return epsilon_batch(p, n, m, need, mu, com, radius, lanes=lanes, antipode=antipode,
                             **starts)

    fn.batch = batch
    return fn


#: Lanes of the epsilon search on a CPU (:func:`jaxgrasp.quality.epsilon_batch`); 8, 24 and
#: 32 were slower on the 2-core machine (docs/design.md, "Epsilon of the grasp wrench space").
EPSILON_LANES = 16
#: ... on an accelerator, where 16 lanes would leave it idle; not measured (no GPU lent).
ACCELERATOR_LANES = 1024


#: Trials per epsilon chunk in :func:`with_epsilon` (per-trial cost is flat from 16 to 100
#: graspable trials; 8 costs ~1.4x more per trial: the loop's per-op overhead dominates).
EPSILON_CHUNK = 16


def map_where(fn, need, args, chunk: int):
    """``vmap(fn)(*args)`` on the rows where ``need`` (B,), paying only for those: the rows
    are sorted needed-first and split into chunks of ``chunk``; a chunk without any runs
    nothing (``lax.cond`` inside ``lax.map``) and gives zeros. The other rows of a chunk
    that runs get ``fn`` of their own arguments: callers mask by ``need``. Under an outer
    ``vmap`` the cond becomes a select: the cost of every row."""
    B = need.shape[0]
    if B == 0:  # nothing to compute (and nothing to sort or split)
        return jax.tree.map(lambda e: jnp.zeros(e.shape, e.dtype),
                            jax.eval_shape(jax.vmap(fn), *args))
    chunk = max(1, min(int(chunk), B))
    n = -(-B // chunk) * chunk
    order = jnp.argsort(~need, stable=True)  # needed rows first
    order = jnp.concatenate([order, jnp.broadcast_to(order[:1], (n - B,))])
    args = tuple(a[order].reshape(n // chunk, chunk, *a.shape[1:]) for a in args)
    todo = (need[order] & (jnp.arange(n) < B)).reshape(n // chunk, chunk)  # padding: no work
    batched = jax.vmap(fn)
    empty = jax.eval_shape(batched, *(a[0] for a in args))

    def run(x):
        todo_c, *chunk_args = x
        return jax.lax.cond(jnp.any(todo_c), lambda: batched(*chunk_args),
                            lambda: jax.tree.map(lambda e: jnp.zeros(e.shape, e.dtype), empty))

    out = jax.lax.map(run, (todo, *args))
    return jax.tree.map(lambda a: jnp.zeros((B, *a.shape[2:]), a.dtype)
                        .at[order[:B]].set(a.reshape(n, *a.shape[2:])[:B]), out)


def with_epsilon(result: TrialResult, epsilon_fn, chunk: int | None = None) -> TrialResult:
    """Fill in epsilon for a batch (leading dim B) of results, computed only where needed.

    Epsilon (an LP per trial, ~1 ms on a CPU core) costs about a MuJoCo C rollout, yet
    only SUCCESS/SLIPPED trials have one: :func:`epsilon_where` computes only those. Same
    values as ``vmap(epsilon_fn)`` where graspable, 0 elsewhere.
    """
    need = graspable(result.outcome)
    eps = epsilon_where(result.contact_points, result.contact_normals, result.contact_mask,
                        need, epsilon_fn, chunk)
    return result._replace(epsilon=eps)


def graspable(outcome):
    """Which outcomes made contact and have an epsilon (SUCCESS, SLIPPED)."""
    return (outcome == Outcome.SUCCESS) | (outcome == Outcome.SLIPPED)


def epsilon_where(points, normals, mask, need, epsilon_fn, chunk: int | None = None):
    """(B,) ``epsilon_fn`` of the contacts (leading dim B) where ``need``, 0 elsewhere and
    never NaN: ``epsilon_fn.batch`` where it has one and ``chunk`` is None (the search's runs
    dealt to lanes), else :func:`map_where` in chunks of ``chunk`` (None:
    :data:`EPSILON_CHUNK`)."""
    if chunk is None and hasattr(epsilon_fn, "batch"):
        eps = epsilon_fn.batch(points, normals, mask, need).astype(jnp.float32)
    else:
        eps = map_where(lambda p, n, m: epsilon_fn(p, n, m).astype(jnp.float32), need,
                        (points, normals, mask), EPSILON_CHUNK if chunk is None else chunk)
    return jnp.where(need, jnp.nan_to_num(eps, nan=0.0, posinf=0.0, neginf=0.0), 0.0)
