"""The MJX scene of a grasp trial and its placement, shared by the MJX trial
(:mod:`jaxgrasp.physics.trial`) and the MJX-Warp trial (:mod:`jaxgrasp.physics.warp_backend`):
the per-scene arrays uploaded for JAX (:class:`SceneConsts`) and the placement pass (one
collision pass with open fingers, every piece, no rollout)."""

from typing import NamedTuple

import jax
import jax.numpy as jnp
from mujoco import mjx

from jaxgrasp import so3
from jaxgrasp.physics import rules
from jaxgrasp.physics.collision import min_distance, piece_frames, slot_model, stacked_hulls
from jaxgrasp.physics.contacts import ContactConsts, contact_consts
from jaxgrasp.physics.protocol import G, schedule

__all__ = ["SceneConsts", "object_pose", "place", "scene_consts", "slot_layout"]


class SceneConsts(NamedTuple):
    """Per-scene arrays the trial reads (a pytree; passed to the jitted core as an argument).

    m : mjx.Model; d0 : mjx.Data with open fingers (full scene: every piece collides, for
    placement); m_roll, d0_roll: the rollout model with per-trial contact slots
    (:func:`jaxgrasp.physics.collision.slot_model`); frames: the pieces' poses on the object
    body; ctrl (T, 2), weight (T,), perturb (T, 3): the protocol schedule; corners (24, 3)
    gripper corners in the grasp frame; com (3,); weight_n: the object's weight (N);
    support_z; radius: max_radius; mu: pad friction; hulls: stacked piece hulls;
    contacts: what :func:`jaxgrasp.physics.contacts.grasp_contacts` reads.
    """

    m: mjx.Model
    d0: mjx.Data
    ctrl: jax.Array
    weight: jax.Array
    perturb: jax.Array
    corners: jax.Array
    com: jax.Array
    weight_n: jax.Array
    support_z: jax.Array
    radius: jax.Array
    mu: jax.Array
    hulls: dict
    m_roll: mjx.Model
    d0_roll: mjx.Data
    frames: dict
    contacts: ContactConsts


def slot_layout(scene):
    """(rollout MjModel, SlotLayout) of a scene: pads then palm, as ``ids.layout.box_geoms``."""
    p, layout = scene.params, scene.ids.layout
    n = len(layout.piece_geoms)
    per_box = [min(n, p.pieces_per_pad)] * 2 + [min(n, p.pieces_per_palm)]
    if layout.box_geoms != (*scene.ids.pad_geoms, scene.ids.palm_geom):
        raise ValueError(f"unexpected gripper geom order {layout.box_geoms}")
    return slot_model(scene.xml, layout, per_box)


def scene_consts(scene, rollout_model=None) -> SceneConsts:
    """Upload a scene's model and protocol arrays for the MJX trial (``rollout_model``: the
    first of :func:`slot_layout`, computed here if not given)."""
    m = mjx.put_model(scene.mj_model)
    q0 = jnp.asarray(scene.qpos0(), jnp.float32)
    d0 = mjx.make_data(m).replace(qpos=q0)
    m_roll = mjx.put_model(slot_layout(scene)[0] if rollout_model is None else rollout_model)
    hulls = stacked_hulls(scene.mj_model, scene.ids.layout.piece_geoms)
    sched = schedule(scene.params, scene.gripper.open_width)
    ids = scene.ids
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    return SceneConsts(
        m=m,
        d0=d0,
        ctrl=f32(sched.ctrl),
        weight=f32(sched.weight),
        perturb=f32(sched.perturb),
        corners=f32(scene.corners),
        com=f32(scene.obj.com),
        weight_n=f32(float(scene.obj.mass) * G),
        support_z=f32(scene.obj.support_z),
        radius=f32(scene.obj.max_radius),
        mu=f32(scene.friction),
        hulls={k: jnp.asarray(v) for k, v in hulls.items()},
        m_roll=m_roll,
        d0_roll=mjx.make_data(m_roll).replace(qpos=q0),
        frames={
            k: jnp.asarray(v)
            for k, v in piece_frames(scene.mj_model, ids.layout.piece_geoms).items()
        },
        contacts=contact_consts(scene, m, d0, hulls),
    )


def object_pose(q, oq):
    """(position (3,), rotation (3, 3)) of the object in the gripper frame at qpos ``q``."""
    return q[oq : oq + 3], so3.unit_to_matrix(q[oq + 3 : oq + 7])


def place(c: SceneConsts, grasp, params, ids):
    """Placed state and the collision decision of one grasp (one collision pass, no rollout).

    Returns (qpos (nq,), collision bool, penetration float).
    """
    finite, g = rules.finite_grasps(grasp)
    g = rules.normalize_grasps(g)
    pos, quat, _ = rules.object_pose_from_grasp(g)
    oq = ids.object_qpos
    qpos = c.d0.qpos.at[oq : oq + 3].set(pos).at[oq + 3 : oq + 7].set(quat)
    d = mjx.kinematics(c.m, c.d0.replace(qpos=qpos))
    penetration = -min_distance(c.m, d, c.hulls, ids.layout)
    below = rules.below_support(g, c.corners, c.support_z)
    return qpos, rules.placement_collision(finite, below, penetration, params), penetration
