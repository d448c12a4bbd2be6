"""The protocol's decisions, written once for both physics backends.

Placement, instability, displacement, pad touch, miss, slip and the outcome: each is one
function here that both backends call, the MuJoCo C host side with ``xp=numpy`` (float64,
batched over trials and steps) and the MJX rollout with ``xp=jax.numpy`` (float32, one trial,
vmapped). A threshold lives in :class:`~jaxgrasp.physics.protocol.TrialParams` and a rule here:
changing either changes both backends. Leading axes broadcast unless noted.

:func:`trial_result` turns the raw decisions of one trial (:func:`raw_trial`) into its
:class:`~jaxgrasp.physics.protocol.TrialResult` (JAX, both backends).
"""

import jax
import jax.numpy as jnp
import numpy as np

from jaxgrasp import so3
from jaxgrasp.physics.contacts import CONTACT_PIECES, geom_poses, grasp_contacts, patch_reach
from jaxgrasp.physics.protocol import Outcome, TrialResult, graspable, map_where

__all__ = [
    "SAFE_GRASP",
    "finite_grasps",
    "normalize_grasps",
    "object_pose_from_grasp",
    "below_support",
    "placement_collision",
    "stable",
    "displacement",
    "settle_window",
    "pad_distances",
    "touching",
    "finger_closed",
    "missed",
    "slipped",
    "decide_outcome",
    "raw_trial",
    "trial_result",
    "trial_results",
    "assemble_results",
    "batch_contacts",
    "two_sided",
    "assemble_result",
    "invalid_grasps",
    "flag_invalid",
]

#: Stand-in for a non-finite grasp: placed and checked, never simulated (a ``COLLISION``).
SAFE_GRASP = (0, 0, 1.0, 1, 0, 0, 0)


# ------------------------------------------------------------------------------ placement
def finite_grasps(grasps, xp=jnp):
    """``(finite (...,), grasps)``: non-finite grasps (..., 7) replaced by :data:`SAFE_GRASP`
    (non-finite input never reaches the physics; it is reported as a collision)."""
    finite = xp.all(xp.isfinite(grasps), axis=-1)
    return finite, xp.where(finite[..., None], grasps, xp.asarray(SAFE_GRASP, grasps.dtype))


def invalid_grasps(grasps):
    """(B,) bool: rows that are not a pose (NaN/inf, beyond float32, zero quaternion), read
    from the grasps as given (float64 numpy keeps values that float32 would turn to inf)."""
    xp = jnp if isinstance(grasps, jax.Array) else np
    g = grasps if xp is jnp else np.asarray(grasps, np.float64)
    beyond = xp.abs(g) > np.finfo(np.float32).max
    bad = ~xp.all(xp.isfinite(g), axis=-1) | xp.any(beyond, axis=-1)
    return bad | (xp.linalg.norm(xp.nan_to_num(g[..., 3:]), axis=-1) < 1e-6)


def flag_invalid(res: TrialResult, grasps) -> TrialResult:
    """``res`` with :func:`invalid_grasps` of the grasps it was made from flagged, each such
    row a ``COLLISION`` with nothing measured (whatever a stand-in pose gave)."""
    invalid = invalid_grasps(grasps)
    if not isinstance(invalid, jax.core.Tracer) and not np.any(invalid):
        return res  # the common case, without a dispatch: res.invalid is all False

    def where(bad, x, y):
        return jnp.where(jnp.reshape(bad, bad.shape + (1,) * (jnp.ndim(y) - 1)), x, y)

    return res._replace(
        outcome=where(invalid, int(Outcome.COLLISION), res.outcome).astype(res.outcome.dtype),
        epsilon=where(invalid, 0.0, res.epsilon).astype(res.epsilon.dtype),
        displacement=where(invalid, 0.0, res.displacement).astype(res.displacement.dtype),
        contact_points=where(invalid, 0.0, res.contact_points).astype(jnp.float32),
        contact_normals=where(invalid, 0.0, res.contact_normals).astype(jnp.float32),
        contact_mask=where(invalid, False, res.contact_mask),
        pad_contact=where(invalid, False, res.pad_contact),
        unstable=where(invalid, False, res.unstable),
        invalid=jnp.asarray(invalid),
    )


def normalize_grasps(grasps, xp=jnp):
    """Normalize the quaternion part of (..., 7) grasps; a zero quaternion becomes identity."""
    pos, q = grasps[..., :3], grasps[..., 3:]
    n = xp.linalg.norm(q, axis=-1, keepdims=True)
    # |q| > ~1e19 overflows the float32 norm (q / inf = 0: a zero quaternion, NaN physics):
    # scale those down first (finite entries <= 3.4e38 -> <= 3.4e8, the largest >= ~1e-11;
    # a multiply: dividing by the max would flush its subnormal reciprocal to zero). Every
    # other quaternion is untouched.
    big = ~xp.isfinite(n) & xp.all(xp.isfinite(q), axis=-1, keepdims=True)
    q = xp.where(big, q * xp.asarray(1e-30, q.dtype), q)
    n = xp.where(big, xp.linalg.norm(q, axis=-1, keepdims=True), n)
    ok = n > 1e-9
    q = xp.where(ok, q / xp.where(ok, n, 1.0), xp.asarray([1, 0, 0, 0], q.dtype))
    return xp.concatenate([pos, q], axis=-1)


def object_pose_from_grasp(grasp, xp=jnp):
    """Object pose in the gripper (= simulation world) frame: the inverse of the grasp.

    Parameters
    ----------
    grasp : (..., 7) normalized gripper pose in the object frame (x, y, z, qw, qx, qy, qz).

    Returns
    -------
    pos : (..., 3) object-frame origin in the gripper frame.
    quat : (..., 4) object orientation in the gripper frame (w, x, y, z), the conjugate.
    rot : (..., 3, 3) rotation gripper <- object (``rot @ p_obj + pos = p_grip``).
    """
    q_inv = so3.conjugate(grasp[..., 3:], xp)
    rot = so3.unit_to_matrix(q_inv, xp)
    return -xp.einsum("...ij,...j->...i", rot, grasp[..., :3]), q_inv, rot


def below_support(grasps, corners, support_z, xp=jnp):
    """(...,) whether any gripper corner (``corners`` (C, 3), grasp frame) of the normalized
    grasps lies below the support plane ``z = support_z`` of the object frame."""
    # z of the corners in the object frame: (C, ...), corners first.
    up = xp.moveaxis(so3.unit_to_matrix(grasps[..., 3:], xp)[..., 2, :], -1, 0)
    z = corners @ up + grasps[..., 2]
    return xp.any(z < support_z, axis=0)


def placement_collision(finite, below, penetration, params):
    """``COLLISION`` at placement: non-finite input, a corner below the support plane, or a
    penetration (metres, from one collision pass with open fingers) beyond ``collision_tol``."""
    return (penetration > params.collision_tol) | below | ~finite


# -------------------------------------------------------------------------------- rollout
def stable(qpos, qvel, params, xp=jnp):
    """Whether states (..., nq), (..., nv) are sound: finite, every speed below ``max_speed``."""
    return (
        xp.all(xp.isfinite(qpos), axis=-1)
        & xp.all(xp.isfinite(qvel), axis=-1)
        & (xp.max(xp.abs(qvel), axis=-1) < params.max_speed)
    )


def displacement(pos_s, rot_s, pos_t, rot_t, com, xp=jnp):
    """Object displacement relative to the gripper from the pose after closing ``(pos_s,
    rot_s)`` to the pose ``(pos_t, rot_t)``: the larger move of the COM (``com``, object
    frame) and of the material point that sat at the grasp center after closing (catches
    rotation about the grasp axis too)."""
    com_s = rot_s @ com + pos_s
    com_t = rot_t @ com + pos_t
    center = xp.einsum("...ji,...j->...i", rot_s, -pos_s)  # grasp center, object frame
    center_t = xp.einsum("...ij,...j->...i", rot_t, center) + pos_t
    return xp.maximum(xp.linalg.norm(com_t - com_s, axis=-1), xp.linalg.norm(center_t, axis=-1))


def settle_window(params):
    """Steps ``[start, stop)`` of the settle phase, where a pad must touch the object."""
    return params.close_ramp_steps, params.close_steps


def pad_distances(dist, geom, pad_geoms, xp=jnp):
    """(..., 2) closest contact distance of each pad (inf where it has none) from contact
    distances (..., n) and geom pairs (..., n, 2)."""
    return xp.stack([xp.min(xp.where(xp.any(geom == pad, axis=-1), dist, xp.inf), axis=-1,
                            initial=xp.inf) for pad in pad_geoms], axis=-1)


def touching(pad_dist, params):
    """Whether each pad touches: its closest contact is nearer than ``contact_tol``."""
    return pad_dist < params.contact_tol


def finger_closed(finger_q, params, xp=jnp):
    """Whether a finger (``finger_q`` (..., 2) after closing) reached its closed limit: a
    ``MISS`` whatever the pads touched."""
    return xp.any(finger_q < params.closed_tol, axis=-1)


def missed(pad_contact, finger_q, params, xp=jnp):
    """``MISS``: a pad never touched during the settle phase (``pad_contact`` (..., 2)), or a
    finger reached its closed limit (:func:`finger_closed`)."""
    return ~xp.all(pad_contact, axis=-1) | finger_closed(finger_q, params, xp)


def slipped(max_disp, held, params):
    """``SLIPPED``: moved more than ``slip_tol`` during the hold, or not held by both pads at
    its end."""
    return (max_disp > params.slip_tol) | ~held


def decide_outcome(collision, miss, slip, unstable, xp=jnp):
    """Outcome code with the protocol's precedence: collision > unstable/miss > slip."""
    out = xp.where(slip, Outcome.SLIPPED, Outcome.SUCCESS)
    out = xp.where(miss | unstable, Outcome.MISS, out)
    out = xp.where(collision, Outcome.COLLISION, out)
    return out.astype(xp.int32)


# ----------------------------------------------------------------------------- the result
def raw_trial(collision, miss, slipped, bad, max_disp, pad_contact, pre_q, snap_q):
    """The decisions and states of trials, as both backends hand them on (a dict: a pytree).

    collision, miss, slipped, bad (unstable), max_disp, pad_contact (..., 2); pre_q: the state
    whose contacts count after closing; snap_q: the state after closing.
    """
    return dict(collision=collision, miss=miss, slipped=slipped, bad=bad, max_disp=max_disp,
                pad_contact=pad_contact, pre_q=pre_q, snap_q=snap_q)


def trial_result(raw, cc, params, ids, epsilon_fn=None, renormalize=False) -> TrialResult:
    """One trial's :class:`TrialResult` from its :func:`raw_trial` (JAX, unbatched).

    The contacts are :func:`jaxgrasp.physics.contacts.grasp_contacts` of ``pre_q`` in the
    object frame of ``snap_q``. ``renormalize``: renormalize that state's quaternion (states
    that come as float64 cast to float32 are not unit in float32).
    """
    pts, nrm, msk = _contacts(raw, cc, params, ids, renormalize)
    return assemble_result(raw["collision"], raw["miss"], raw["slipped"], raw["bad"], msk, pts,
                           nrm, raw["max_disp"], raw["pad_contact"], epsilon_fn)


def _contacts(raw, cc, params, ids, renormalize, max_pieces=None, poses=None, reach=None):
    oq = ids.object_qpos
    quat = raw["snap_q"][oq + 3 : oq + 7]
    if renormalize:
        quat = quat / jnp.linalg.norm(quat)  # a state's quaternion is never zero
    rot_s = so3.unit_to_matrix(quat)
    return grasp_contacts(cc, raw["pre_q"], raw["snap_q"][oq : oq + 3], rot_s, params, ids,
                          max_pieces=max_pieces, poses=poses, reach=reach)


#: Trials per contact chunk in :func:`trial_results`.
CONTACT_CHUNK = 16


def trial_results(raw, cc, params, ids, renormalize=False, chunk=CONTACT_CHUNK) -> TrialResult:
    """:func:`trial_result` of a batch (leading dim B, no epsilon), the contacts by
    :func:`batch_contacts`. Same result as ``vmap(trial_result)``."""
    return assemble_results(raw, batch_contacts(raw, cc, params, ids, renormalize, chunk))


def assemble_results(raw, contacts, epsilon=None, xp=jnp) -> TrialResult:
    """:func:`assemble_result` of a batch (leading dim B) from its raw trial and contacts
    (points, normals, mask); ``epsilon`` (B,) is kept for SUCCESS/SLIPPED only (None: 0).
    ``xp=np``: the same arrays in numpy, on the host (no JAX dispatch)."""
    pts, nrm, msk = contacts
    args = (raw["collision"], raw["miss"], raw["slipped"], raw["bad"], msk, pts, nrm,
            raw["max_disp"], raw["pad_contact"])
    # Elementwise: one call on the whole batch is the vmap.
    res = (jax.vmap(assemble_result)(*args) if xp is jnp
           else assemble_result(*args, xp=xp))
    if epsilon is None:
        return res
    return res._replace(epsilon=xp.where(graspable(res.outcome), epsilon, 0.0).astype(
        xp.float32))


def batch_contacts(raw, cc, params, ids, renormalize=False, chunk=CONTACT_CHUNK):
    """Contacts (points, normals, mask; leading dim B) of a batch from its ``collision``,
    ``bad``, ``pre_q`` and ``snap_q`` (the rest of ``raw`` is not read): computed only for
    the trials whose contacts count (neither colliding nor unstable; elsewhere the mask is
    False) and where some piece reaches a pad's patch (the others have none: a finger that
    closed past the object), in chunks of ``chunk`` (:func:`protocol.map_where`), examining
    only the pieces that reach each pad (``CONTACT_PIECES``; all pieces for the trials where
    more reach)."""
    # The geom poses and the reaching pieces once for every state (cheap), for the chunks.
    poses = jax.vmap(lambda q: geom_poses(cc, q))(raw["pre_q"])
    reach = jax.vmap(lambda p: patch_reach(cc, p, params, ids))(poses)
    need = ~(raw["collision"] | raw["bad"]) & jnp.any(reach, axis=(1, 2))
    args = (raw["snap_q"], reach, *poses)  # the poses stand for pre_q in the chunks

    def contacts(max_pieces):
        return lambda snap_q, reach, *poses: _contacts(
            {"pre_q": None, "snap_q": snap_q}, cc, params, ids, renormalize, max_pieces, poses,
            reach)

    *culled, over = map_where(contacts(CONTACT_PIECES), need, args, chunk)
    full = map_where(contacts(None), need & over, args, chunk)  # rarely any: chunks skip
    pts, nrm, msk = (jnp.where(jnp.reshape(over, over.shape + (1,) * (c.ndim - 1)), f, c)
                     for f, c in zip(full, culled, strict=True))
    return pts, nrm, msk & need[:, None]  # a computed chunk also fills its unneeded rows


def two_sided(mask):
    """(...,) whether both pads have a contact in a contact mask (..., K) (the first K/2
    slots are the left pad's): without, every wrench pushes one way and epsilon is 0."""
    half = mask.shape[-1] // 2
    return jnp.any(mask[..., :half], axis=-1) & jnp.any(mask[..., half:], axis=-1)


def assemble_result(collision, miss, slip, unstable, mask, points, normals, max_disp,
                    pad_contact, epsilon_fn=None, xp=jnp):
    """One trial's :class:`TrialResult` from the protocol's decisions (JAX; ``xp=np``: numpy,
    any leading batch dims).

    Contacts of colliding/unstable trials are masked out; epsilon and displacement count only
    for trials that made contact (SUCCESS/SLIPPED) and are never NaN. ``epsilon_fn(points,
    normals, mask)`` gives the quality (None: 0, e.g. before quality is wanted).
    """
    outcome = decide_outcome(collision, miss, slip, unstable, xp)
    keep = ~(collision | unstable)
    msk = mask & keep[..., None]
    pts = xp.where(msk[..., None], xp.nan_to_num(points), 0.0)
    nrm = xp.where(msk[..., None], xp.nan_to_num(normals), 0.0)
    made_contact = graspable(outcome)
    eps = xp.float32(0.0) if epsilon_fn is None else epsilon_fn(pts, nrm, msk)
    eps = xp.where(made_contact, xp.nan_to_num(eps, nan=0.0, posinf=0.0, neginf=0.0), 0.0)
    disp = xp.where(made_contact, xp.nan_to_num(max_disp, nan=1.0, posinf=1.0), 0.0)
    return TrialResult(
        outcome=outcome,
        epsilon=eps.astype(xp.float32),
        displacement=disp.astype(xp.float32),
        contact_points=pts.astype(xp.float32),
        contact_normals=nrm.astype(xp.float32),
        contact_mask=msk,
        pad_contact=pad_contact & keep[..., None],
        unstable=unstable & ~collision,
        invalid=xp.zeros_like(collision),  # set from the grasps by flag_invalid
    )
