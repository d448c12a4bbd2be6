"""Stacked gripper-object collision for MJX: one vmapped call for all convex pieces.

MJX's collision driver runs one separately compiled convex-convex function per distinct mesh
(its shapes are static), so a 16-piece object traces 16 copies into every step: compile time
and run time grow with the number of pieces. Here the pieces' hull data (vertices, faces,
normals, edges) are padded to common shapes and stacked, and MJX's own box-convex kernel
(``_convex_convex``) is vmapped once over all (gripper geom, piece) pairs. The result is
written into the contact slots in exactly the order MJX's driver uses, so
``mjx.make_constraint`` and the solver see the same problem as with ``mjx.collision``.
Padding repeats the last vertex/face/edge: duplicated separating-axis candidates change
nothing. ``tests/physics/test_collision.py`` checks agreement with ``mjx.collision``.
"""

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx
from mujoco.mjx._src import collision_driver, math, mesh
from mujoco.mjx._src.collision_convex import _convex_convex
from mujoco.mjx._src.collision_types import ConvexInfo, GeomInfo

__all__ = ["PairLayout", "pair_layout", "stacked_hulls", "collide", "step_with_collision"]

_NCON = 4  # box-mesh contacts per pair in MJX


def _pad_rows(x, n):
    x = np.asarray(x)
    return np.concatenate([x, np.repeat(x[-1:], n - x.shape[0], axis=0)]) if x.shape[0] < n else x


class PairLayout(NamedTuple):
    """Static description of the collidable pairs (hashable: a jit static argument).

    box_geoms, piece_geoms : gripper box geom ids, object mesh geom ids.
    pair_box, pair_piece : for each pair in MJX's slot order, indices into those two tuples.
    """

    box_geoms: tuple
    piece_geoms: tuple
    pair_box: tuple
    pair_piece: tuple


def pair_layout(mj_model, box_geoms, piece_geoms) -> PairLayout:
    """The (box, piece) pairs in MJX's contact-slot order; checks they are all box-mesh."""
    box_geoms, piece_geoms = tuple(box_geoms), tuple(piece_geoms)
    groups = collision_driver._geom_groups(mj_model)
    box_mesh = (int(mjx.GeomType.BOX), int(mjx.GeomType.MESH))
    for key in groups:
        if tuple(int(t) for t in key.types) != box_mesh or key.condim != 3:
            raise ValueError(f"stacked collision needs condim-3 box-mesh pairs, got {key}")
    pairs = [(int(g1), int(g2)) for key in groups for g1, g2, _ in groups[key]]
    return PairLayout(
        box_geoms=box_geoms,
        piece_geoms=piece_geoms,
        pair_box=tuple(box_geoms.index(g1) for g1, _ in pairs),
        pair_piece=tuple(piece_geoms.index(g2) for _, g2 in pairs),
    )


def stacked_hulls(mj_model, piece_geoms) -> dict:
    """Hull data (vert, face, face_normal, edge, edge_face_normal) of every piece, padded to
    common shapes and stacked along a leading piece axis (numpy)."""
    hulls = [mesh.convex(mj_model, int(mj_model.geom_dataid[g])) for g in piece_geoms]
    # > 8 vertices: the box (8) stays the first argument of the kernel, as in MJX.
    nv = max(9, max(h.vert.shape[0] for h in hulls))
    nf = max(h.face.shape[0] for h in hulls)
    fv = max(h.face.shape[1] for h in hulls)
    ne = max(h.edge.shape[0] for h in hulls)

    def pad_face(f):
        f = np.asarray(f)
        f = np.concatenate([f, np.repeat(f[:, -1:], fv - f.shape[1], axis=1)], axis=1)
        return _pad_rows(f, nf)

    return {
        "vert": np.stack([_pad_rows(h.vert, nv) for h in hulls]).astype(np.float32),
        "face": np.stack([pad_face(h.face) for h in hulls]).astype(np.float32),
        "face_normal": np.stack([_pad_rows(h.face_normal, nf) for h in hulls]).astype(np.float32),
        "edge": np.stack([_pad_rows(h.edge, ne) for h in hulls]).astype(np.int32),
        "edge_face_normal": np.stack([_pad_rows(h.edge_face_normal, ne) for h in hulls]).astype(
            np.float32
        ),
    }


def collide(m: mjx.Model, d: mjx.Data, hulls: dict, layout: PairLayout) -> mjx.Data:
    """Drop-in for ``mjx.collision`` when every collidable pair is (gripper box, piece)."""
    bg, pg = np.asarray(layout.box_geoms), np.asarray(layout.piece_geoms)
    bi, pi = np.asarray(layout.pair_box), np.asarray(layout.pair_piece)
    boxes = mesh.box(GeomInfo(d.geom_xpos[bg], d.geom_xmat[bg], m.geom_size[bg]))
    batched = ("pos", "mat", "size", "vert", "face")  # mesh.box batches these over boxes
    b = boxes.replace(**{k: getattr(boxes, k)[bi] for k in batched})
    box_axes = jax.tree.map(lambda x: None, b).replace(**{k: 0 for k in batched})
    pieces = ConvexInfo(
        pos=d.geom_xpos[pg][pi],
        mat=d.geom_xmat[pg][pi],
        size=m.geom_size[pg][pi],
        **{k: jnp.asarray(v)[pi] for k, v in hulls.items()},
    )
    dist, pos, n = jax.vmap(_convex_convex, in_axes=(box_axes, 0))(b, pieces)
    frame = jax.vmap(jax.vmap(math.make_frame))(n)
    # Contact parameters (geom ids, friction, solref...) in MJX's slot order, 4 per pair.
    groups = collision_driver._contact_groups(m, d).values()
    contact = jax.tree.map(
        lambda *x: jnp.concatenate([jnp.repeat(v, _NCON, axis=0) for v in x]), *groups
    )
    contact = contact.replace(
        dist=dist.reshape(-1), pos=pos.reshape(-1, 3), frame=frame.reshape(-1, 3, 3)
    )
    return d.tree_replace({"_impl.contact": contact})


def step_with_collision(m: mjx.Model, d: mjx.Data, collide) -> mjx.Data:
    """``mjx.step`` (Euler, no sensors) with ``collide`` in place of ``mjx.collision``."""
    d = mjx.kinematics(m, d)
    d = mjx.com_pos(m, d)
    d = mjx.tendon(m, d)
    d = mjx.crb(m, d)
    d = mjx.tendon_armature(m, d)
    d = mjx.factor_m(m, d)
    d = collide(m, d)
    d = mjx.make_constraint(m, d)
    d = mjx.transmission(m, d)
    d = mjx.fwd_velocity(m, d)
    d = mjx.fwd_actuation(m, d)
    d = mjx.fwd_acceleration(m, d)
    d = mjx.solve(m, d)
    return mjx.euler(m, d)
