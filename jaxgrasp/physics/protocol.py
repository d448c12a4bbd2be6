"""The grasp-trial protocol, shared by every physics backend.

One place holds what a backend must replicate exactly: the outcome codes, the result record,
the protocol parameters, the per-step control/load schedule, the grasp -> object placement
and the outcome decision. The MJX backend (``trial.py``) and a MuJoCo C backend use these
functions unchanged; they only differ in how they step the physics.

Protocol (DESIGN §5, RobWork's GraspTaskSimulator as reference), with the gripper fixed in
the simulation world (the grasp frame) and the object placed at the inverse grasp pose:

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

__all__ = [
    "Outcome",
    "TrialResult",
    "TrialParams",
    "schedule",
    "normalize_grasps",
    "object_pose_from_grasp",
    "quat_to_mat",
    "decide_outcome",
    "assemble_result",
    "with_epsilon",
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
    """

    outcome: jax.Array
    epsilon: jax.Array
    displacement: jax.Array
    contact_points: jax.Array
    contact_normals: jax.Array
    contact_mask: jax.Array
    pad_contact: jax.Array
    unstable: jax.Array


@dataclass(frozen=True)
class TrialParams:
    """Protocol parameters (thresholds, step counts, timestep, solver).

    Defaults are chosen for MJX on a CPU, where a step costs ~0.1 ms per scene: 80 steps.

    Attributes
    ----------
    timestep : float
        3 ms: well under half the default contact time constant (20 ms), so contacts stay
        stable, and large enough that a trial is short.
    close_ramp_steps, close_settle_steps : int
        20 + 10 steps (90 ms): the pads cross the 8.5 cm stroke at <= 0.75 m/s, gently enough
        not to knock a light object out, and the grip force settles before the hold.
    close_target : float
        Position target (per-finger opening, metres) at the end of the ramp; negative, i.e.
        past the closed limit, so the actuator force saturates at the gripper's force limit:
        -0.035 m, since with the default ``finger_kp`` = 2000 N/m the actuator force at the
        closed limit is 2000 * 0.035 = 70 N = the default force limit (at -0.01 it was only
        20 + 2000 q N, so a 70 N limit was never reached on thin walls and handles).
    hold_steps : int
        50 steps (150 ms) under the weight: a free fall covers 11 cm, a net slipping
        acceleration of 0.9 m/s^2 (0.09 g) already exceeds ``slip_tol``.
    perturbations : tuple of (3,) tuples
        Extra loads in the gripper frame, in units of the object's weight, each applied on top
        of the weight for ``perturbation_steps``; none by default (the paper holds the weight).
    perturbation_steps : int
    slip_tol : float
        1 cm displacement relative to the gripper (RobWork's success band). MuJoCo's soft
        friction creeps slowly inside the cone; over 150 ms the creep stays in the mm range.
    collision_tol : float
        2 mm penetration allowed at placement (pads just touching the surface are not a
        collision; the convex pieces of a decomposition are only within ~mm of the mesh).
    contact_tol : float
        A pad counts as touching when its signed distance to the object drops below 1 mm
        during the settle phase (a pad chattering on a stiff contact still touches).
    patch_tol : float
        Depth of the pad contact patch that epsilon reads (:mod:`jaxgrasp.physics.contacts`):
        the object's points within 1 mm of a pad face (= ``contact_tol``). A patch on a
        facet of width W spans it only while the pad's tilt stays below ~patch_tol / W, so
        epsilon hinges on sub-degree tilts that two solvers do not reproduce: on the 158
        pitcher grasps both backends hold (``benchmarks/backend_agreement.py``) epsilon
        agreed within 10 % on 93.0 % with 1 mm and 98.7 % with 3 mm. But a deep patch
        also credits tilted, barely touching pads with a wide patch: summed over the 14
        cells of the default bench (pitcher + pan), 3 mm found 164 successes / 484 slips
        (seed 0) and 203 / 451 (seed 1), 1 mm 272 / 430 and 251 / 403. The density should
        tell holding grasps apart: 1 mm.
    closed_tol : float
        A finger within 1 mm of its closed limit closed on nothing (or on a sliver).
    max_speed : float
        Any |qvel| above 1000 (m/s or rad/s) is a blow-up. Real trial motions stay below
        ~10 m/s, but a heavy object dropping out of a 70 N grip can tumble off a pad edge at
        more than 50 rad/s in MJX (seen on the 3 kg slippery box): that is a slip, not a
        numerical blow-up. Divergent states overshoot by orders of magnitude or turn non-finite.
    iterations, ls_iterations : int
        Constraint-solver iterations (Newton converges in a few for this small system).
    num_contacts : int
        K, the number of contacts kept for epsilon (half per pad, spread over the patch; see
        :mod:`jaxgrasp.physics.contacts`).
    pieces_per_pad, pieces_per_palm : int
        MJX rollouts collide each pad (palm) with only its 3 (2) nearest convex pieces,
        chosen per trial and per step (:func:`jaxgrasp.physics.collision.collide_slots`):
        contact slots and constraint rows drop from 4 x 3 x pieces to 4 x 8. Over every
        state of the C rollouts of the 512 agreement poses of pitcher, pan and plate
        (``benchmarks/backend_agreement.py``, 30720 states each) a pad was within 1 mm of at
        most 3 pieces at once, the palm of at most 2. Placement always uses every piece.
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


def quat_to_mat(q):
    """Rotation matrix of a unit quaternion (w, x, y, z); works on jax and numpy arrays."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


def normalize_grasps(grasps):
    """Normalize the quaternion part of (..., 7) grasps; a zero quaternion becomes identity."""
    pos, q = grasps[..., :3], grasps[..., 3:]
    n = jnp.linalg.norm(q, axis=-1, keepdims=True)
    # |q| > ~1e19 overflows the float32 norm (q / inf = 0: a zero quaternion, NaN physics):
    # scale those down first (finite entries <= 3.4e38 -> <= 3.4e8, the largest >= ~1e-11;
    # a multiply: dividing by the max would flush its subnormal reciprocal to zero). Every
    # other quaternion is untouched.
    big = ~jnp.isfinite(n) & jnp.all(jnp.isfinite(q), axis=-1, keepdims=True)
    q = jnp.where(big, q * jnp.asarray(1e-30, q.dtype), q)
    n = jnp.where(big, jnp.linalg.norm(q, axis=-1, keepdims=True), n)
    ok = n > 1e-9
    identity = jnp.zeros_like(q).at[..., 0].set(1.0)
    q = jnp.where(ok, q / jnp.where(ok, n, 1.0), identity)
    # Non-finite input must not reach the physics; it is reported as a collision instead.
    return jnp.concatenate([pos, q], axis=-1)


def object_pose_from_grasp(grasp):
    """Object pose in the gripper (= simulation world) frame: the inverse of the grasp.

    Parameters
    ----------
    grasp : (7,) normalized gripper pose in the object frame (x, y, z, qw, qx, qy, qz).

    Returns
    -------
    pos : (3,) object-frame origin in the gripper frame.
    quat : (4,) object orientation in the gripper frame (w, x, y, z), the conjugate.
    rot : (3, 3) rotation gripper <- object (``rot @ p_obj + pos = p_grip``).
    """
    t, q = grasp[:3], grasp[3:]
    q_inv = q * jnp.array([1.0, -1.0, -1.0, -1.0], dtype=q.dtype)
    rot = quat_to_mat(q_inv)
    return -rot @ t, q_inv, rot


def decide_outcome(collision, miss, slipped, unstable):
    """Outcome code with the protocol's precedence: collision > unstable/miss > slip."""
    out = jnp.where(slipped, Outcome.SLIPPED, Outcome.SUCCESS)
    out = jnp.where(miss | unstable, Outcome.MISS, out)
    out = jnp.where(collision, Outcome.COLLISION, out)
    return out.astype(jnp.int32)


def assemble_result(collision, miss, slipped, unstable, mask, points, normals, max_disp,
                    pad_contact, epsilon_fn=None):
    """One trial's :class:`TrialResult` from the protocol's decisions (every backend).

    Contacts of colliding/unstable trials are masked out; epsilon and displacement count only
    for trials that made contact (SUCCESS/SLIPPED) and are never NaN. ``epsilon_fn(points,
    normals, mask)`` gives the quality (None: 0, e.g. before quality is wanted).
    """
    outcome = decide_outcome(collision, miss, slipped, unstable)
    keep = ~(collision | unstable)
    msk = mask & keep
    pts = jnp.where(msk[..., None], jnp.nan_to_num(points), 0.0)
    nrm = jnp.where(msk[..., None], jnp.nan_to_num(normals), 0.0)
    graspable = (outcome == Outcome.SUCCESS) | (outcome == Outcome.SLIPPED)
    eps = jnp.float32(0.0) if epsilon_fn is None else epsilon_fn(pts, nrm, msk)
    eps = jnp.where(graspable, jnp.nan_to_num(eps, nan=0.0, posinf=0.0, neginf=0.0), 0.0)
    disp = jnp.where(graspable, jnp.nan_to_num(max_disp, nan=1.0, posinf=1.0), 0.0)
    return TrialResult(
        outcome=outcome,
        epsilon=eps.astype(jnp.float32),
        displacement=disp.astype(jnp.float32),
        contact_points=pts.astype(jnp.float32),
        contact_normals=nrm.astype(jnp.float32),
        contact_mask=msk,
        pad_contact=pad_contact & keep,
        unstable=unstable & ~collision,
    )


def epsilon_fn(mu, com, radius):
    """``(points, normals, mask) -> epsilon`` of one trial: ``jaxgrasp.quality.epsilon`` with
    the object's friction, torque origin (COM) and torque scale (max radius)."""
    from jaxgrasp.quality import epsilon

    return lambda p, n, m: epsilon(p, n, m, mu, com, radius)


#: Trials per epsilon chunk in :func:`with_epsilon` (per-trial cost is flat from 4 to 16).
EPSILON_CHUNK = 8


def with_epsilon(result: TrialResult, epsilon_fn, chunk: int = EPSILON_CHUNK) -> TrialResult:
    """Fill in epsilon for a batch (leading dim B) of results, computed only where needed.

    Epsilon (an LP per trial, ~1.6 ms on a CPU core) costs more than a MuJoCo C rollout, yet
    only SUCCESS/SLIPPED trials have one: the batch is sorted so those come first and split
    into chunks of ``chunk`` trials; a chunk without any runs no epsilon (``lax.cond`` inside
    ``lax.map``). Same values as ``vmap(epsilon_fn)`` where graspable, 0 elsewhere. Under an
    outer ``vmap`` the cond becomes a select: the same cost as computing every epsilon.
    """
    need = (result.outcome == Outcome.SUCCESS) | (result.outcome == Outcome.SLIPPED)
    B = need.shape[0]
    chunk = max(1, min(int(chunk), B))
    n = -(-B // chunk) * chunk
    order = jnp.argsort(~need, stable=True)  # graspable trials first
    order = jnp.concatenate([order, jnp.broadcast_to(order[:1], (n - B,))])
    args = (result.contact_points, result.contact_normals, result.contact_mask)
    args = tuple(a[order].reshape(n // chunk, chunk, *a.shape[1:]) for a in args)
    todo = (need[order] & (jnp.arange(n) < B)).reshape(n // chunk, chunk)  # padding: no work

    def run(x):
        todo_c, pts, nrm, msk = x
        return jax.lax.cond(
            jnp.any(todo_c),
            lambda: jax.vmap(epsilon_fn)(pts, nrm, msk).astype(jnp.float32),
            lambda: jnp.zeros(chunk, jnp.float32),
        )

    eps = jax.lax.map(run, (todo, *args)).reshape(n)[:B]
    eps = jnp.zeros(B, jnp.float32).at[order[:B]].set(eps)
    eps = jnp.where(need, jnp.nan_to_num(eps, nan=0.0, posinf=0.0, neginf=0.0), 0.0)
    return result._replace(epsilon=eps)
