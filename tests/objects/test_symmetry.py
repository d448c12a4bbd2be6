"""An object's symmetry about a vertical axis, found from its mesh, and the moves that follow
it (:mod:`jaxgrasp.objects.symmetry`, :func:`jaxgrasp.learn.algorithm.turn_moves`)."""

import numpy as np
import pytest
import trimesh

import jaxgrasp as jg
from jaxgrasp.learn.algorithm import turn_moves
from jaxgrasp.mcmc import symmetry as moves
from jaxgrasp.objects.symmetry import Symmetry, find_symmetry


def _standing(mesh, shift=(0.0, 0.0)):
    mesh.apply_translation([shift[0], shift[1], -mesh.bounds[0, 2]])
    return mesh


def test_a_cylinder_is_a_solid_of_revolution_about_its_axis():
    s = find_symmetry(_standing(trimesh.creation.cylinder(0.04, 0.1, sections=96),
                                (0.013, -0.007)))
    assert s.kind == "revolution" and s.match > 0.95
    np.testing.assert_allclose(s.centre, (0.013, -0.007), atol=1e-3)


@pytest.mark.parametrize("extents, order, mirrors", [
    ((0.06, 0.06, 0.1), 4, (0.0, 45.0, 90.0, 135.0)),
    ((0.04, 0.07, 0.1), 2, (0.0, 90.0)),
])
def test_a_box_turns_by_its_section_s_symmetry(extents, order, mirrors):
    s = find_symmetry(_standing(trimesh.creation.box(extents), (0.02, 0.01)))
    assert (s.kind, s.order) == ("turns", order)
    np.testing.assert_allclose(s.centre, (0.02, 0.01), atol=1e-3)
    np.testing.assert_allclose(s.mirrors, mirrors, atol=1.5)


def test_an_irregular_solid_has_no_turn_and_a_mirror_where_it_has_one():
    """An L of two boxes: mirror-symmetric through one vertical plane only, no turn."""
    a = trimesh.creation.box((0.08, 0.03, 0.05))
    b = trimesh.creation.box((0.03, 0.06, 0.05))
    b.apply_translation([0.0, 0.045, 0.0])
    s = find_symmetry(_standing(trimesh.util.concatenate([a, b])))
    assert s.kind == "none" and s.order == 1
    np.testing.assert_allclose(s.mirrors, (90.0,), atol=1.5)
    rot = trimesh.transformations.rotation_matrix(0.3, [1, 1, 0])  # tilted: no mirror either
    tilted = _standing(trimesh.util.concatenate([a, b]).apply_transform(rot))
    assert find_symmetry(tilted).mirrors == ()


def test_the_shipped_pitcher_turns_about_its_own_z_axis():
    """The handle covers a few percent of the surface: still a solid of revolution, on the
    object frame's z axis exactly (its turns are the z-axis planes, unchanged)."""
    s = find_symmetry(jg.objects.load("pitcher"))
    assert s.kind == "revolution" and s.centre == (0.0, 0.0)
    params = jg.learn.LearnParams()
    found, frame_z = turn_moves(params, s), turn_moves(params, Symmetry("revolution"))
    assert found["symmetry_planes"][0] == moves.Z_AXIS_PLANES
    assert found.keys() == frame_z.keys() and all(
        np.array_equal(found[k], frame_z[k]) for k in found if k != "symmetry_planes")
    assert found["symmetry_planes"] == frame_z["symmetry_planes"]


def test_the_moves_follow_the_symmetry():
    params = jg.learn.LearnParams(symmetry_share=0.25)
    scale = params.length_scale
    none = turn_moves(params, Symmetry("none", (0.01, 0.0), mirrors=()))
    turn, pivot, *never = none["symmetry_planes"]
    assert (turn, pivot) == (moves.Turn((0.01 / scale, 0.0)), moves.PIVOT_PLANES)
    # no own symmetry: the two own-move slots of an offset axis are there, never picked
    assert len(never) == 2 and all(isinstance(g, moves.Turn) and g.order for g in never)
    np.testing.assert_allclose(none["symmetry_weights"], [0.5, 0.5, 0.0, 0.0])
    on_z = turn_moves(params, Symmetry("none", (0.0, 0.0), mirrors=()))
    assert on_z["symmetry_planes"] == (moves.Z_AXIS_PLANES, moves.PIVOT_PLANES)  # unpadded
    assert none["p_symmetry"] == pytest.approx(params.axis_moves * params.p_check)
    box = turn_moves(params, Symmetry("turns", (0.023, 0.0), 4, (0.0, 45.0)))
    turn, pivot, n_fold, mirror = box["symmetry_planes"]
    assert turn == moves.Turn((0.023 / scale, 0.0)) and pivot == moves.PIVOT_PLANES
    assert n_fold == moves.Turn((0.023 / scale, 0.0), 4)
    assert mirror.angles == pytest.approx((0.0, np.pi / 4))
    np.testing.assert_allclose(box["symmetry_weights"], [0.25, 0.5, 0.125, 0.125])
    assert turn_moves(params.replace(axis_moves=0.0), Symmetry("revolution")) == {}


def test_a_user_override_parses_or_says_what_it_accepts():
    assert Symmetry.parse("turns:3@0.01,-0.02") == Symmetry("turns", (0.01, -0.02), 3)
    assert Symmetry.parse("none").kind == "none"
    assert Symmetry.from_dict(Symmetry.parse("revolution").to_dict()) == Symmetry.parse(
        "revolution")
    for bad in ("turns:1", "spiral", "revolution@x"):
        with pytest.raises(ValueError, match="symmetry"):
            Symmetry.parse(bad)
    with pytest.raises(ValueError, match="symmetry"):
        jg.learn.LearnParams(symmetry="turns:x")


def test_same_surroundings_turns_a_body_grasp_but_not_its_handle():
    """A cylinder with a box handle on +x (a solid of revolution by find_symmetry's share):
    the body's surroundings turn onto the body, not onto the handle, and the handle's turn into
    air; a square box's surroundings turn onto themselves by its own quarter turns only."""
    from jaxgrasp.objects.symmetry import same_surroundings  # why: only these tests use it

    body = trimesh.creation.cylinder(0.05, 0.12, sections=96)
    handle = trimesh.creation.box((0.03, 0.015, 0.06))
    handle.apply_translation([0.065, 0.0, 0.0])
    mug = _standing(trimesh.util.concatenate([body, handle]))
    same = same_surroundings(mug, Symmetry("revolution"), radius=0.03)
    centres = np.array([[-0.05, 0.0, 0.06]] * 3 + [[0.07, 0.0, 0.06]])
    np.testing.assert_array_equal(same(centres, [np.pi / 4, -np.pi / 2, np.pi, np.pi / 2]),
                                  [True, True, False, False])
    square = _standing(trimesh.creation.box((0.06, 0.06, 0.1)))
    corner = np.array([[0.03, 0.03, 0.05]] * 3)
    for sym in (Symmetry("turns", order=4), Symmetry("revolution")):  # the test is the mesh's
        np.testing.assert_array_equal(
            same_surroundings(square, sym, radius=0.02)(corner, [np.pi / 2, np.pi, np.pi / 4]),
            [True, True, False])


def test_same_surroundings_through_a_mirror_plane():
    """The L of two boxes reflects onto itself through its mirror plane (the y-z plane), not
    through the x-z plane: its short arm's surroundings land in air there."""
    from jaxgrasp.objects.symmetry import same_surroundings  # why: only these tests use it

    a = trimesh.creation.box((0.08, 0.03, 0.05))
    b = trimesh.creation.box((0.03, 0.06, 0.05))
    b.apply_translation([0.0, 0.045, 0.0])
    ell = _standing(trimesh.util.concatenate([a, b]))
    same = same_surroundings(ell, Symmetry("none", mirrors=(90.0,)), radius=0.02)
    arm = np.array([[0.0, 0.06, 0.025], [0.0, 0.06, 0.025], [0.03, 0.0, 0.025]])
    np.testing.assert_array_equal(same(arm, np.radians([90.0, 0.0, 90.0]), [True, True, True]),
                                  [True, False, True])
