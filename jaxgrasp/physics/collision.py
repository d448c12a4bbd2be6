"""Stacked gripper-object collision for MJX: one vmapped call for all convex pieces.

MJX's collision driver runs one separately compiled convex-convex function per distinct mesh
(its shapes are static), so a 16-piece object traces 16 copies into every step: compile time
and run time grow with the number of pieces. Here the pieces' hull data (vertices, faces,
normals, edges) are padded to common shapes and stacked, and MJX's own box-convex kernel is
vmapped once over all (gripper geom, piece) pairs (MJX internals: ``_mjx_internals``). The result is
written into the contact slots in exactly the order MJX's driver uses, so
``mjx.make_constraint`` and the solver see the same problem as with ``mjx.collision``.
Padding repeats the last vertex/face/edge: duplicated separating-axis candidates change
nothing. ``tests/physics/test_collision.py`` checks agreement with ``mjx.collision``.
"""

from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from jaxgrasp.physics import _mjx_internals as mi

__all__ = [
    "PairLayout",
    "SlotLayout",
    "pair_layout",
    "stacked_hulls",
    "collide",
    "collide_slots",
    "min_distance",
    "pair_collision",
    "piece_frames",
    "separation_bound",
    "slot_model",
]

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
    groups = mi.geom_groups(mj_model)
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
    hulls = [mi.convex_mesh(mj_model, int(mj_model.geom_dataid[g])) for g in piece_geoms]
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


def pair_collision(box_pos, box_mat, box_size, pair_box, pieces: mi.ConvexInfo):
    """MJX's box-convex kernel vmapped over pairs: box ``pair_box[i]`` vs ``pieces[i]``.

    Returns (dist (n, 4), pos (n, 4, 3), normal (n, 4, 3)); normals point from box to piece.
    """
    boxes = mi.box_mesh(mi.GeomInfo(box_pos, box_mat, box_size))
    batched = ("pos", "mat", "size", "vert", "face")  # mesh.box batches these over boxes
    b = boxes.replace(**{k: getattr(boxes, k)[pair_box] for k in batched})
    box_axes = jax.tree.map(lambda x: None, b).replace(**{k: 0 for k in batched})
    return jax.vmap(mi.convex_convex, in_axes=(box_axes, 0))(b, pieces)


def _write_contacts(m, d, bg, pair_box, pieces):
    """Contacts of (box, piece) pairs written into the data's slots, in MJX's slot order."""
    dist, pos, n = pair_collision(
        d.geom_xpos[bg], d.geom_xmat[bg], m.geom_size[bg], pair_box, pieces
    )
    frame = jax.vmap(jax.vmap(mi.make_frame))(n)
    # Contact parameters (geom ids, friction, solref...) in MJX's slot order, 4 per pair.
    groups = mi.contact_groups(m, d).values()
    contact = jax.tree.map(
        lambda *x: jnp.concatenate([jnp.repeat(v, _NCON, axis=0) for v in x]), *groups
    )
    contact = contact.replace(
        dist=dist.reshape(-1), pos=pos.reshape(-1, 3), frame=frame.reshape(-1, 3, 3)
    )
    return mi.with_contacts(d, contact)


def _pieces(pos, mat, size, hulls, pi):
    """The kernel's second argument: pieces ``pi`` (one per pair) from every piece's world
    pose, geom size and stacked hull."""
    return mi.ConvexInfo(pos=pos[pi], mat=mat[pi], size=size[pi],
                         **{k: jnp.asarray(v)[pi] for k, v in hulls.items()})


def _all_pieces(d, m, hulls, layout):
    pg = np.asarray(layout.piece_geoms)
    return _pieces(d.geom_xpos[pg], d.geom_xmat[pg], m.geom_size[pg], hulls,
                   np.asarray(layout.pair_piece))


def collide(m: mjx.Model, d: mjx.Data, hulls: dict, layout: PairLayout) -> mjx.Data:
    """Drop-in for ``mjx.collision`` when every collidable pair is (gripper box, piece)."""
    pieces = _all_pieces(d, m, hulls, layout)
    return _write_contacts(m, d, np.asarray(layout.box_geoms), np.asarray(layout.pair_box), pieces)


def min_distance(m: mjx.Model, d: mjx.Data, hulls: dict, layout: PairLayout):
    """Smallest contact distance over every (box, piece) pair (negative: penetration), the
    same numbers as :func:`collide` without building the contact record (placement needs
    only this; skipping the record took ~0.3 s off a warm start)."""
    bg = np.asarray(layout.box_geoms)
    dist, _, _ = pair_collision(d.geom_xpos[bg], d.geom_xmat[bg], m.geom_size[bg],
                                np.asarray(layout.pair_box), _all_pieces(d, m, hulls, layout))
    return jnp.min(dist)


# ------------------------------------------------------------------------ per-trial slots
class SlotLayout(NamedTuple):
    """Contact slots of the rollout model (hashable: a jit static argument).

    Each gripper box ``box_geoms[b]`` collides, at every step, with only the
    ``per_box[b]`` object pieces nearest to it (chosen per trial and per step). The rollout
    model has one placeholder geom per (box, rank); ``pair_box``/``pair_rank`` give, for each
    pair in MJX's contact-slot order, the box index and the rank of its piece.
    """

    box_geoms: tuple
    per_box: tuple
    pair_box: tuple
    pair_rank: tuple


def slot_model(xml: str, layout: PairLayout, per_box) -> tuple:
    """(rollout MjModel, SlotLayout): the scene with its pieces replaced by placeholder slot
    geoms, each collidable with exactly one gripper box, so MJX allocates ``4 * sum(per_box)``
    contact slots (and constraint rows) instead of ``4 * boxes * pieces``.

    Bodies, joints, inertia and contact parameters are unchanged (pieces share one body and
    one set of contact parameters), so the constraint rows of a slot are those of its piece.
    """
    spec = mujoco.MjSpec.from_string(xml)
    m_full = spec.compile()
    names = [m_full.geom(g).name for g in layout.piece_geoms]
    template = spec.geom(names[0])
    body = template.parent
    box_names = [m_full.geom(g).name for g in layout.box_geoms]
    kw = {a: getattr(template, a) for a in ("condim", "friction", "solref", "solimp", "margin",
                                           "gap", "solmix", "priority")}
    for b, name in enumerate(box_names):
        bit = 1 << (b + 2)  # contype/conaffinity 1 and 2 belong to the full scene
        spec.geom(name).contype, spec.geom(name).conaffinity = 0, bit
        for r in range(int(per_box[b])):
            body.add_geom(name=f"slot_{b}_{r}", type=mujoco.mjtGeom.mjGEOM_MESH,
                          meshname=template.meshname, contype=bit, conaffinity=0, **kw)
    for n in names:
        spec.delete(spec.geom(n))
    m = spec.compile()
    if [m.geom(g).name for g in layout.box_geoms] != box_names:
        raise ValueError("slot model changed the gripper geom ids")
    slot_ids = {m.geom(f"slot_{b}_{r}").id: (b, r)
                for b in range(len(box_names)) for r in range(int(per_box[b]))}
    groups = mi.geom_groups(m)
    pairs = [(int(g1), int(g2)) for key in groups for g1, g2, _ in groups[key]]
    slot_of = [slot_ids[g2] if g2 in slot_ids else slot_ids[g1] for g1, g2 in pairs]
    if sorted(slot_of) != sorted(slot_ids.values()):
        raise ValueError(f"slot model pairs {pairs} are not one per slot")
    return m, SlotLayout(
        box_geoms=layout.box_geoms,
        per_box=tuple(int(k) for k in per_box),
        pair_box=tuple(b for b, _ in slot_of),
        pair_rank=tuple(r for _, r in slot_of),
    )


def piece_frames(mj_model, piece_geoms) -> dict:
    """Pieces' poses (pos, mat) in the object body frame and their geom sizes (numpy)."""
    mats = []
    for g in piece_geoms:
        mat = np.zeros(9)
        mujoco.mju_quat2Mat(mat, mj_model.geom_quat[g])
        mats.append(mat.reshape(3, 3))
    return {
        "pos": np.asarray(mj_model.geom_pos[list(piece_geoms)], np.float32),
        "mat": np.stack(mats).astype(np.float32),
        "size": np.asarray(mj_model.geom_size[list(piece_geoms)], np.float32),
    }


def separation_bound(box_pos, box_mat, box_half, piece_pos, piece_mat, hulls):
    """(P,) lower bound on the distance between one box and each piece (world poses).

    The separating-axis value over the pieces' face normals and the box's axes (edge-edge
    axes left out): <= the true separation, and > 0 only if the two are apart by at least
    that much. Cheap (no clipping): it ranks pieces for the slot selection.
    """
    rel = jnp.einsum("pji,pj->pi", piece_mat, box_pos - piece_pos)  # box center, piece frame
    axes = jnp.einsum("pji,jk->pik", piece_mat, box_mat)  # box axes (columns), piece frame
    n = hulls["face_normal"]  # (P, F, 3)
    offset = jnp.sum(n * hulls["face"][:, :, 0, :], axis=-1)  # plane n.x = offset per face
    reach = jnp.sum(jnp.abs(jnp.einsum("pfi,pik->pfk", n, axes)) * box_half, axis=-1)
    face_gap = jnp.max(jnp.einsum("pfi,pi->pf", n, rel) - offset - reach, axis=1)
    # Box axes: project the piece vertices (box frame) against the half extents.
    v = jnp.einsum("pvi,pik->pvk", hulls["vert"] - rel[:, None], axes)
    box_gap = jnp.max(jnp.maximum(jnp.min(v, 1) - box_half, -jnp.max(v, 1) - box_half), axis=1)
    return jnp.maximum(face_gap, box_gap)


def collide_slots(m, d, hulls, frames, slots: SlotLayout, object_body: int):
    """Collision for the rollout model: each box against its nearest pieces (per trial)."""
    bg = np.asarray(slots.box_geoms)
    box_pos, box_mat, box_half = d.geom_xpos[bg], d.geom_xmat[bg], m.geom_size[bg]
    body_pos, body_mat = d.xpos[object_body], d.xmat[object_body]
    piece_pos = body_pos + frames["pos"] @ body_mat.T
    piece_mat = jnp.einsum("ij,pjk->pik", body_mat, frames["mat"])
    chosen = []
    for b, k in enumerate(slots.per_box):
        gap = separation_bound(box_pos[b], box_mat[b], box_half[b], piece_pos, piece_mat, hulls)
        chosen.append(jax.lax.top_k(-gap, k)[1])
    pi = jnp.stack([chosen[b][r] for b, r in zip(slots.pair_box, slots.pair_rank, strict=True)])
    pieces = _pieces(piece_pos, piece_mat, frames["size"], hulls, pi)
    return _write_contacts(m, d, bg, np.asarray(slots.pair_box), pieces)
