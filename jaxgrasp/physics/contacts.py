"""The contacts that epsilon is computed from, the same function for every physics backend.

The solver's contact slots are a poor record of the grasp: MJX's box-convex clipping keeps
only the *penetrating* points of the contact polygon and fills the remaining slots with
copies of them, and for exactly parallel faces (a pad flat on a box) its separating-axis
search returns a single point; MuJoCo C returns yet another point set. Epsilon would then
measure the collision routine, not the grasp.

So epsilon reads the geometry of the state after closing instead: both backends hand over
that state (``qpos``) and :func:`grasp_contacts` computes each pad's contact patch directly:
the cross-section of every convex piece with the plane ``patch_tol`` in front of the pad's
inner face (the region where the piece comes within ``patch_tol`` of the face), clipped to
the pad's rectangle. Its corners are (a) piece edges crossing that plane, inside the
rectangle, and (b) the ends of the rectangle's edges clipped to the piece (Cyrus-Beck).
Per pad it keeps up to ``K / 2`` corners spread over the patch (farthest-point selection,
points closer than ``DEDUPE_TOL`` dropped), moved back onto the pad face (where the forces
act), each with the pad's closing direction as normal.

Only a piece that reaches the patch (its vertices on both sides of the plane and its
in-plane extent over the rectangle) has corners, so with ``max_pieces`` only the reaching
pieces are examined (at most that many, in their order; ``overflow`` says when more reach):
the same valid corners in the same order, for a fraction of the work.
"""

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

from jaxgrasp._reduce import any_last, fold_last, max_last, min_last, running_count
from jaxgrasp.physics import _mjx_internals as mi
from jaxgrasp.physics.collision import stacked_hulls

__all__ = [
    "CONTACT_PIECES",
    "ContactConsts",
    "contact_consts",
    "geom_poses",
    "grasp_contacts",
    "padded_size",
    "patch_reach",
    "shared_consts",
    "shared_ids",
]

#: Points of one pad closer than this (metres) are one contact.
DEDUPE_TOL = 2e-4
#: Pieces per pad examined by the batched C-trial path (``max_pieces``): on 64 pitcher
#: states, 0-4 pieces reached a pad's patch (docs/design.md, "The JAX tail: contacts and epsilon").
CONTACT_PIECES = 4
#: A piece within this (metres) of the patch plane or rectangle counts as reaching it (the
#: test only has to keep every piece with a corner, so it errs on the generous side).
_REACH_SLACK = 1e-5


#: Where the shared contact stage puts the pieces it pads an object with (object body frame,
#: metres): no pad's patch is ever within reach of them.
_FAR = 1e3


class ContactConsts(NamedTuple):
    """Arrays for :func:`grasp_contacts` (a pytree): the full-scene MJX model and data, the
    stacked piece hulls, each piece's face-plane offsets, and per pad a selection (3, 3) of
    its axes (in-plane u, in-plane v, closing axis) with the matching half sizes (3,).

    With ``pieces`` — each piece's position (P, 3) and quaternion (P, 4) in the object body's
    frame — ``m`` is the scene of a stand-in object with the same gripper and the pieces
    follow its object body (:func:`shared_consts`): then the consts of two objects differ
    only in array values and padded shapes, and one compiled contact stage serves both."""

    m: mjx.Model
    d0: mjx.Data
    hulls: dict
    offset: jax.Array
    pad_axes: jax.Array
    pad_half: jax.Array
    pieces: tuple | None = None


def contact_consts(scene, m=None, d0=None, hulls=None) -> ContactConsts:
    """Upload what :func:`grasp_contacts` needs (reuses ``m``/``d0``/``hulls`` if given)."""
    m = mjx.put_model(scene.mj_model) if m is None else m
    d0 = mjx.make_data(m) if d0 is None else d0
    if hulls is None:
        hulls = stacked_hulls(scene.mj_model, scene.ids.layout.piece_geoms)
    hulls = {k: np.asarray(v) for k, v in hulls.items()}
    offset = _face_offsets(hulls)
    size = np.asarray(scene.mj_model.geom_size[list(scene.ids.pad_geoms)], np.float64)
    order = [np.argsort(-sz, kind="stable") for sz in size]  # thin (closing) axis last
    return ContactConsts(
        m=m,
        d0=d0,
        hulls={k: jnp.asarray(hulls[k]) for k in ("vert", "edge", "face_normal")},
        offset=jnp.asarray(offset, jnp.float32),
        pad_axes=jnp.asarray(np.stack([np.eye(3)[:, o] for o in order]), jnp.float32),
        pad_half=jnp.asarray(np.take_along_axis(size, np.stack(order), axis=1), jnp.float32),
    )


def padded_size(n: int) -> int:
    """The size the shared contact stage pads a count to: the smallest of 4, 6, 8, 12, 16,
    24, ... (powers of two and 1.5 times them) >= ``n``, so few shapes cover every object."""
    size = 4
    while size < n:
        size = size * 3 // 2 if size & (size - 1) == 0 else size * 4 // 3
    return size


def _face_offsets(hulls):
    """Inside of a piece: ``n_f . x <= offset_f`` for every face f (piece frame)."""
    return np.sum(hulls["face_normal"] * hulls["face"][:, :, 0, :], axis=-1)


def _pad_to(x, n, axis):
    """``x`` with its last entry along ``axis`` repeated up to length ``n`` (a repeated
    vertex, edge or face plane changes no patch)."""
    widths = [(0, 0)] * np.ndim(x)
    widths[axis] = (0, n - np.shape(x)[axis])
    return np.pad(x, widths, mode="edge")


def shared_consts(stand_in: ContactConsts, scene) -> ContactConsts:
    """``scene``'s contact consts over the kinematics of ``stand_in`` (:func:`contact_consts`
    of a scene of the same gripper; read with :func:`shared_ids`): the hulls padded to
    :func:`padded_size` pieces, vertices, edges and faces, the extra pieces :data:`_FAR` away
    where no pad's patch reaches them. Contacts equal those of ``contact_consts(scene)``."""
    m = scene.mj_model
    geoms = list(scene.ids.layout.piece_geoms)
    h = stacked_hulls(m, geoms)
    arrays = {"vert": h["vert"], "edge": h["edge"], "face_normal": h["face_normal"],
              "offset": _face_offsets(h).astype(np.float32),
              "pos": m.geom_pos[geoms].astype(np.float32),
              "quat": m.geom_quat[geoms].astype(np.float32)}
    nv, ne, nf = (padded_size(h[k].shape[1]) for k in ("vert", "edge", "face_normal"))
    for k, n in (("vert", nv), ("edge", ne), ("face_normal", nf), ("offset", nf)):
        arrays[k] = _pad_to(arrays[k], n, 1)
    p = padded_size(len(geoms))
    arrays = {k: _pad_to(v, p, 0) for k, v in arrays.items()}
    arrays["pos"][len(geoms):] = _FAR
    return stand_in._replace(
        hulls={k: jnp.asarray(arrays[k]) for k in ("vert", "edge", "face_normal")},
        offset=jnp.asarray(arrays["offset"]),
        pieces=(jnp.asarray(arrays["pos"]), jnp.asarray(arrays["quat"])))


def shared_ids(ids, ngeom: int, num_pieces: int):
    """The scene ids that :func:`grasp_contacts` reads with :func:`shared_consts`: the
    stand-in scene's (``ids``, ``ngeom`` geoms), its object's pieces the ``num_pieces``
    after them (where :func:`geom_poses` puts them)."""
    return ids._replace(layout=ids.layout._replace(
        piece_geoms=tuple(range(ngeom, ngeom + num_pieces))))


def _patch_corners(vert, edge, normal, offset, p0, n, u, v, hu, hv):
    """Candidate corners (E + 8, 3) and validity of one piece's patch under one pad.

    All in the piece frame: the patch plane through ``p0`` with normal ``n`` and in-plane
    axes ``u``, ``v``; the pad rectangle is ``|u| <= hu``, ``|v| <= hv`` around ``p0``.
    """
    s = (vert - p0) @ n
    a, b = vert[edge[:, 0]], vert[edge[:, 1]]
    sa, sb = s[edge[:, 0]], s[edge[:, 1]]
    cross = sa * sb < 0
    t = sa / jnp.where(cross, sa - sb, 1.0)
    x = a + t[:, None] * (b - a)
    ru, rv = (x - p0) @ u, (x - p0) @ v
    ok_a = cross & (jnp.abs(ru) <= hu) & (jnp.abs(rv) <= hv)
    # Rectangle edges clipped to the piece's half-spaces n_f . x <= offset_f.
    corners = jnp.stack([p0 + su * hu * u + sv * hv * v
                         for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    A, B = corners, jnp.roll(corners, -1, axis=0)
    num = offset[None] - A @ normal.T  # (4, F)
    den = (B - A) @ normal.T
    enter = jnp.max(jnp.where(den < 0, num / jnp.where(den < 0, den, 1.0), 0.0), axis=1)
    leave = jnp.min(jnp.where(den > 0, num / jnp.where(den > 0, den, 1.0), 1.0), axis=1)
    parallel_out = jnp.any((den == 0) & (num < 0), axis=1)
    ok_b = (enter <= leave) & ~parallel_out
    ends = jnp.concatenate([A + enter[:, None] * (B - A), A + leave[:, None] * (B - A)])
    return jnp.concatenate([x, ends]), jnp.concatenate([ok_a, ok_b, ok_b])


def _argmax(x):
    """``jnp.argmax`` of a vector (the first NaN, else the first maximum) as two plain
    reductions: XLA CPU runs argmax's variadic reduce elementwise, ~4x slower here."""
    n = x.shape[0]
    hit = (x == max_last(x, -jnp.inf)) | jnp.isnan(x)
    return min_last(jnp.where(hit, jnp.arange(n, dtype=jnp.int32), n), n)


def _spread(points, valid, k, tol):
    """Indices (k,) and mask (k,) of up to k valid points spread apart: first the one
    farthest from their centroid, then each time the one farthest from those chosen; none
    closer than ``tol`` to another."""
    w = valid.astype(points.dtype)
    count = jnp.sum(fold_last(valid.astype(jnp.int32), jnp.add, 0), axis=-1)
    center = (w @ points) / jnp.maximum(count.astype(points.dtype), 1.0)
    xyz = points.T  # (3, P): the distances below are elementwise along P (a norm's reduce
    # over a minor axis of 3 is ~40x slower on XLA CPU)

    def far(p):
        d = xyz - p[:, None]
        return jnp.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])

    first = _argmax(jnp.where(valid, far(center), -1.0))
    gap = jnp.where(valid, far(points[first]), -1.0)
    idx, ok = [first], [any_last(valid)]
    for _ in range(k - 1):
        j = _argmax(gap)
        idx.append(j)
        ok.append(gap[j] > tol)
        gap = jnp.minimum(gap, far(points[j]))
    return jnp.stack(idx), jnp.stack(ok)


def _reaches(vert, pads):
    """(2, P) which pieces can have patch corners on each pad's patch: vertices on both sides
    of the plane and an in-plane extent that overlaps the pad rectangle (all in each piece's
    frame). Both pads' 6 axes in one (P, V, 6) product: 12 min/max reductions of their own
    XLA CPU split over its thread pool (docs/design.md, "The JAX tail: contacts and epsilon")."""
    axes = jnp.stack([a for *_, (_, n, u, v) in pads for a in (n, u, v)], axis=1)  # (P, 6, 3)
    origin = jnp.stack([f[0] for *_, f in pads for _ in range(3)], axis=1)  # (P, 6, 3)
    # components, not a minor-axis reduce (XLA CPU)
    r = sum((vert[:, :, None, k] - origin[:, None, :, k]) * axes[:, None, :, k]
            for k in range(3))
    lim = jnp.stack([jnp.asarray(x, vert.dtype) for _, hu, hv, _ in pads
                     for x in (0.0, hu, hv)]) + _REACH_SLACK
    ok = (jnp.min(r, axis=1) <= lim) & (jnp.max(r, axis=1) >= -lim)  # (P, 6)
    return jnp.all(ok.reshape(-1, 2, 3), axis=2).T


def _reaching_first(reach, k):
    """``argsort(~reach, stable=True)[:k]``: the reaching pieces, then the others, each in
    order; each piece's rank by counting, one scatter (no sort)."""
    p = reach.shape[0]
    before = running_count(reach) - reach  # the reaching pieces before each one
    rank = jnp.where(reach, before, jnp.sum(reach) + jnp.arange(p) - before)
    return jnp.zeros(k, jnp.int32).at[rank].set(jnp.arange(p, dtype=jnp.int32), mode="drop")


def geom_poses(cc: ContactConsts, qpos):
    """Every geom's position (G, 3) and orientation (G, 3, 3) in the state ``qpos``; with
    ``cc.pieces``, the stand-in scene's geoms, then the pieces (:func:`shared_ids`)."""
    d = mjx.kinematics(cc.m, cc.d0.replace(qpos=qpos))
    if cc.pieces is None:
        return d.geom_xpos, d.geom_xmat
    body = cc.m.nbody - 1  # the object body is the scene's last (scene_xml)
    pos, mat = jax.vmap(mi.local_to_global, in_axes=(None, None, 0, 0))(
        d.xpos[body], d.xquat[body], *cc.pieces)
    return jnp.concatenate([d.geom_xpos, pos]), jnp.concatenate([d.geom_xmat, mat])


def _patches(cc: ContactConsts, poses, params, ids):
    """Per pad, from the geom poses (:func:`geom_poses`): the patch's normal (closing
    direction, into the object), its half sizes ``hu``, ``hv`` and the patch frame in every
    piece's own frame (``p0``, ``n``, ``u``, ``v``, each (P, 3))."""
    xpos, xmat = poses
    pg, pads = np.asarray(ids.layout.piece_geoms), np.asarray(ids.pad_geoms)
    piece_pos, piece_mat = xpos[pg], xmat[pg]
    pad_pos = xpos[pads]
    out = []
    for k in range(2):
        u, v, a = (xmat[pads[k]] @ cc.pad_axes[k]).T
        hu, hv, ha = cc.pad_half[k]
        # The pad's thin axis is its closing axis; its inner face looks at the other pad.
        n = a * jnp.sign((pad_pos[1 - k] - pad_pos[k]) @ a)
        p0 = pad_pos[k] + (ha + params.patch_tol) * n

        def local(pos, mat, n=n, p0=p0, u=u, v=v):
            return (p0 - pos) @ mat, n @ mat, u @ mat, v @ mat

        out.append((n, hu, hv, jax.vmap(local)(piece_pos, piece_mat)))
    return piece_pos, piece_mat, out


def patch_reach(cc: ContactConsts, poses, params, ids):
    """(2, P) which pieces reach each pad's patch, from a state's geom poses
    (:func:`geom_poses`; unbatched). Where none does, :func:`grasp_contacts` has no contact
    (its mask is all False), so it need not run."""
    *_, pads = _patches(cc, poses, params, ids)
    return _reaches(cc.hulls["vert"], pads)


def grasp_contacts(cc: ContactConsts, qpos, pos_s, rot_s, params, ids, dedupe_tol=DEDUPE_TOL,
                   max_pieces=None, poses=None, reach=None):
    """Pad-object contacts of one state, in the object frame, for epsilon (unbatched).

    Parameters
    ----------
    cc : ContactConsts
    qpos : (nq,) the state whose contacts count (the solver's "after closing" state); not
        read where ``poses`` is given.
    pos_s, rot_s : (3,), (3, 3) the object's pose after closing (object frame -> gripper).
    params : TrialParams (``num_contacts``, ``patch_tol``); ids : SceneIds.
    max_pieces : int or None, static
        Examine only the pieces that reach each pad's patch, at most this many (see the
        module docstring); None: every piece.
    poses, reach : ``geom_poses(cc, qpos)`` and :func:`patch_reach` of them where the caller
        has them (None: computed here).

    Returns
    -------
    points (K, 3), normals (K, 3) pointing into the object, mask (K,): the first K/2 slots
    belong to the left pad, the rest to the right one. With ``max_pieces``, also
    ``overflow``: more pieces reached a patch (the result is then incomplete: recompute
    with None).
    """
    half = params.num_contacts // 2
    poses = geom_poses(cc, qpos) if poses is None else poses
    piece_pos, piece_mat, pads = _patches(cc, poses, params, ids)
    cull = max_pieces is not None and max_pieces < piece_pos.shape[0]
    if cull and reach is None:
        reach = _reaches(cc.hulls["vert"], pads)
    pts, nrm, msk, overflow = [], [], [], jnp.zeros((), bool)
    for k, (n, hu, hv, frames) in enumerate(pads):
        h = cc.hulls
        args = (h["vert"], h["edge"], h["face_normal"], cc.offset, piece_pos, piece_mat,
                *frames)
        if cull:
            r = reach[k]
            overflow |= jnp.sum(r) > max_pieces
            keep = _reaching_first(r, max_pieces)
            args = tuple(x[keep] for x in args)

        def piece(vert, edge, normal, offset, pos, mat, p0_, n_, u_, v_, hu=hu, hv=hv):
            x, ok = _patch_corners(vert, edge, normal, offset, p0_, n_, u_, v_, hu, hv)
            return x @ mat.T + pos, ok

        x, ok = jax.vmap(piece)(*args)
        x, ok = x.reshape(-1, 3), ok.reshape(-1)
        idx, chosen = _spread(x, ok, half, dedupe_tol)
        # The patch's shape is taken patch_tol deep; the forces act on the pad face.
        pts.append((x[idx] - params.patch_tol * n - pos_s) @ rot_s)
        nrm.append(jnp.broadcast_to(n @ rot_s, (half, 3)))
        msk.append(chosen)
    out = jnp.concatenate(pts), jnp.concatenate(nrm), jnp.concatenate(msk)
    return out if max_pieces is None else (*out, overflow)
