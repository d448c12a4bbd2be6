"""Stacked and per-trial-slot collision against MJX's own driver; epsilon's contact set.

A 6 x 6 x 15 cm block made of three 5 cm box pieces (so pads can straddle a seam), placed
at fixed gripper poses: small enough that every function compiles in seconds.
"""

import dataclasses
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from mujoco import mjx

import jaxgrasp as jg
from jaxgrasp import so3
from jaxgrasp.physics import TrialParams, load_scene
from jaxgrasp.physics import _mjx_internals as mi
from jaxgrasp.physics import collision as C
from jaxgrasp.physics import trial as T
from jaxgrasp.physics.contacts import DEDUPE_TOL, grasp_contacts
from jaxgrasp.physics.rules import object_pose_from_grasp

SIDE_Q = [0.7071, 0.0, 0.7071, 0.0]  # approach from -x, pads close along the block's y
DOWN = [0.0, 1.0, 0.0, 0.0]
POSES = np.array(
    [
        [-0.01, 0.0, 0.05, *SIDE_Q],  # pads straddle the seam at z = 5 cm
        [-0.01, 0.0, 0.075, *SIDE_Q],  # middle of the middle piece
        [-0.012, 0.0, 0.1, *SIDE_Q],  # the upper seam, palm 2 mm off the face
        [0.0, 0.0, 0.16, *DOWN],  # top-down: pads on the top 1 cm of the top piece
    ],
    np.float32,
)


def _three_box_block():
    box = jg.objects.make_box((0.03, 0.03, 0.075), mass=0.3, name="block3")
    corners = np.array([[x, y, z] for x in (-0.03, 0.03) for y in (-0.03, 0.03) for z in (0, 1)])
    pieces = tuple(corners * [1, 1, 0.05] + [0, 0, 0.05 * i] for i in range(3))
    return dataclasses.replace(box, pieces=pieces)


@pytest.fixture(scope="module")
def block():
    # Fingers closed on the 6 cm block: the pads touch (pad_half y = 4 mm, open = 4.25 cm).
    scene = load_scene(_three_box_block(), params=TrialParams(pieces_per_pad=2, pieces_per_palm=1))
    c = T.scene_consts(scene)
    ids = scene.ids
    place = jax.jit(jax.vmap(lambda g: T.place(c, g, scene.params, ids)[0]))
    q = np.array(place(jnp.asarray(POSES)))
    q[:, list(ids.finger_qpos)] = 0.0298  # pads 0.2 mm into the faces at y = +-3 cm
    return scene, c, jnp.asarray(q, jnp.float32)


def _kin(m, d0, q):
    return mjx.kinematics(m, d0.replace(qpos=q))


def test_stacked_collision_equals_mjx_collision(block):
    scene, c, q = block

    @jax.jit
    @jax.vmap
    def both(q):
        d = _kin(c.m, c.d0, q)
        ours = mi.contacts(C.collide(c.m, d, c.hulls, scene.ids.layout))
        ref = mi.contacts(mjx.collision(c.m, d))
        dmin = C.min_distance(c.m, d, c.hulls, scene.ids.layout)
        return (ours.dist, ours.pos, ours.frame[:, 0], ours.geom, ref.dist, ref.pos,
                ref.frame[:, 0], dmin)

    dist, pos, n, geom, rdist, rpos, rn, dmin = map(np.asarray, both(q))
    assert (dist < 0).any(axis=1).all()  # every pose touches: the comparison is not vacuous
    np.testing.assert_allclose(dist, rdist, atol=1e-6)
    np.testing.assert_allclose(dmin, rdist.min(axis=1), atol=1e-6)  # placement's pass
    on = rdist < 0
    np.testing.assert_allclose(n[on], rn[on], atol=1e-5)
    # The same 4 manifold points per pair; their order may differ (padding changes ties).
    def per_pair(x):
        x = np.round(np.where(on[..., None], x, 0.0), 5).reshape(len(x), -1, 4, 3)
        return np.sort(x.view([("", x.dtype)] * 3), axis=2)
    np.testing.assert_array_equal(per_pair(pos), per_pair(rpos))


def test_slot_model_has_one_pair_per_slot(block):
    scene, c, _ = block
    m, slots = C.slot_model(scene.xml, scene.ids.layout, (2, 2, 1))
    assert slots.per_box == (2, 2, 1)
    assert sorted(zip(slots.pair_box, slots.pair_rank, strict=True)) == [
        (0, 0), (0, 1), (1, 0), (1, 1), (2, 0)
    ]
    d = mjx.make_data(mjx.put_model(m))
    assert mi.contacts(d).dist.shape == (4 * 5,)
    # Same bodies, joints and inertia as the full scene.
    np.testing.assert_array_equal(m.body_mass, scene.mj_model.body_mass)
    assert m.nq == scene.mj_model.nq and m.nv == scene.mj_model.nv


def test_slots_find_the_touching_pieces(block):
    """With 2 of 3 pieces per pad, each pad's deepest contact is the full scene's."""
    scene, c, q = block
    ids, slots = scene.ids, T.slot_layout(scene)[1]
    sl = partial(C.collide_slots, hulls=c.hulls, frames=c.frames, slots=slots,
                 object_body=ids.object_body)

    @jax.jit
    @jax.vmap
    def both(q):
        full = mi.contacts(C.collide(c.m, _kin(c.m, c.d0, q), c.hulls, ids.layout))
        part = mi.contacts(sl(c.m_roll, _kin(c.m_roll, c.d0_roll, q)))
        return full.dist, full.geom, part.dist, part.geom

    fd, fg, sd, sg = map(np.asarray, both(q))
    assert sd.shape[1] == 4 * 5
    for pad in ids.pad_geoms:
        f = np.min(np.where((fg == pad).any(-1), fd, 1.0), axis=1)
        s = np.min(np.where((sg == pad).any(-1), sd, 1.0), axis=1)
        assert (f < 0).all()
        np.testing.assert_allclose(s, f, atol=1e-6)
        # Both pieces at a seam touch: the slots hold both (pose 0: z = 5 cm seam).
        assert np.sum((sd[0] < 0) & (sg[0] == pad).any(-1)) >= np.sum(
            (fd[0] < 0) & (fg[0] == pad).any(-1)
        ) > 4


def test_separation_bound_is_a_lower_bound(block):
    """The SAT bound never exceeds the true distance (random box poses around the block)."""
    scene, c, _ = block
    rng = np.random.default_rng(0)
    n = 64
    pos = rng.uniform([-0.08, -0.08, -0.02], [0.08, 0.08, 0.17], (n, 3)).astype(np.float32)
    quat = rng.normal(size=(n, 4)).astype(np.float32)
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    half = jnp.asarray(scene.mj_model.geom_size[scene.ids.pad_geoms[0]], jnp.float32)
    frames = c.frames

    @jax.jit
    @jax.vmap
    def bound_and_true(p, qt):
        mat = so3.unit_to_matrix(qt)
        b = C.separation_bound(p, mat, half, frames["pos"], frames["mat"], c.hulls)
        pieces = mi.ConvexInfo(pos=frames["pos"], mat=frames["mat"], size=frames["size"], **c.hulls)
        dist, _, _ = C.pair_collision(p[None], mat[None], half[None], np.zeros(3, int), pieces)
        return b, jnp.min(dist, axis=1)

    b, true = map(np.asarray, bound_and_true(jnp.asarray(pos), jnp.asarray(quat)))
    near = true < 0.05  # MJX reports a capped separation for far pairs
    assert near.sum() > 20 and (true[near] < 0).sum() > 5
    assert np.all(b[near] <= true[near] + 1e-5)


def test_grasp_contacts_spread_over_the_pads(block):
    """Epsilon's contacts: K/2 per pad on the faces y = +-3 cm, normals into the block,
    spread over a patch (not duplicates of one point, not a line)."""
    scene, c, q = block
    params, ids = scene.params, scene.ids
    half = params.num_contacts // 2

    @jax.jit
    @jax.vmap
    def contacts(q, g):
        pos, _, rot = object_pose_from_grasp(g)
        return grasp_contacts(c.contacts, q, pos, rot, params, ids)

    pts, nrm, msk = map(np.asarray, contacts(q, jnp.asarray(POSES)))
    assert msk.all()
    np.testing.assert_allclose(np.abs(pts[..., 1]), 0.03, atol=1.5e-3)
    assert np.all(nrm[..., 1] * -np.sign(pts[..., 1]) > 0.99)
    for i in range(len(POSES)):
        for k in range(2):
            p = pts[i, k * half : (k + 1) * half]
            gaps = np.linalg.norm(p[:, None] - p[None], axis=-1)[np.triu_indices(half, 1)]
            assert gaps.min() > DEDUPE_TOL
            # A patch: the points span two directions in the pad plane (x and z).
            sv = np.linalg.svd(p - p.mean(0), compute_uv=False)
            assert sv[1] > 0.005, (i, k, sv)


def test_grasp_contacts_empty_when_apart(block):
    scene, c, q = block
    params, ids = scene.params, scene.ids
    qo = np.array(q[0])
    qo[list(ids.finger_qpos)] = scene.gripper.open_width  # pads 1.25 cm off the faces
    pos, _, rot = object_pose_from_grasp(jnp.asarray(POSES[0]))
    contacts = jax.jit(partial(grasp_contacts, params=params, ids=ids))
    _, _, msk = contacts(c.contacts, jnp.asarray(qo), pos, rot)
    assert not np.asarray(msk).any()
