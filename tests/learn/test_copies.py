"""A grasp turned by the object's symmetry (:mod:`jaxgrasp.learn.evaluate.copies`): pure
geometry, no physics."""

import numpy as np
from scipy.spatial.transform import Rotation

from jaxgrasp.learn.evaluate.atlas import NEIGHBOUR_STEP, NEIGHBOUR_TURN_DEG
from jaxgrasp.learn.evaluate.copies import as_symmetry, copy_maps, symmetric_copies
from jaxgrasp.learn.evaluate.distinct import distinct_grasps, same_as_any
from jaxgrasp.objects.symmetry import Symmetry

AXIS = (0.01, -0.02)


def _grasp(radius, seed=0):
    q = Rotation.random(random_state=seed).as_quat(scalar_first=True)
    return np.array([[AXIS[0] + radius, AXIS[1], 0.05, *q]])


def _turn_of(copy, grasp):
    """The turn about the vertical that takes ``grasp``'s frame to ``copy``'s (radians), and
    how far the relative rotation is from a turn about the vertical."""
    rel = (Rotation.from_quat(copy[3:], scalar_first=True)
           * Rotation.from_quat(grasp[3:], scalar_first=True).inv()).as_rotvec()
    return np.arctan2(np.sin(rel[2]), np.cos(rel[2])), np.linalg.norm(rel[:2])


def test_revolution_copies_go_round_the_grasp_s_circle():
    """Copies of a grasp 10 cm from the axis: on its circle at its height, each frame turned by
    the same angle as its centre, the smallest turn one flood step of arc, every copy a grasp
    of its own (none the same as another or as the grasp)."""
    sym = Symmetry("revolution", AXIS)
    g = _grasp(0.1)
    copies = symmetric_copies(g, sym).astype(np.float64)
    angles, mirror = copy_maps(0.1, sym)
    assert not mirror.any()
    assert len(copies) == len(angles) == 11
    np.testing.assert_allclose(sorted(angles), [*(-0.12 * 2.0 ** np.arange(5))[::-1],
                                                *(0.12 * 2.0 ** np.arange(5)), np.pi])
    np.testing.assert_allclose(np.linalg.norm(copies[:, :2] - AXIS, axis=1), 0.1, atol=1e-6)
    np.testing.assert_allclose(copies[:, 2], 0.05, atol=1e-6)
    for c in copies:
        turn, tilt = _turn_of(c, g[0])
        centre = np.arctan2(c[1] - AXIS[1], c[0] - AXIS[0])
        assert tilt < 1e-5 and abs(np.sin(turn - centre)) < 1e-5 and np.cos(turn - centre) > 0
    np.testing.assert_allclose(np.abs(angles).min() * 0.1, NEIGHBOUR_STEP)
    assert np.isclose(np.abs(angles).max(), np.pi)
    assert len(distinct_grasps(copies)) == len(copies) and not same_as_any(copies, g).any()
    # near the axis the step is the flood's turn
    np.testing.assert_allclose(np.abs(copy_maps(0.001, sym)[0]).min(),
                               np.radians(NEIGHBOUR_TURN_DEG))


def test_n_fold_turns_copy_to_each_place_and_none_copies_nothing():
    g = _grasp(0.04, seed=1)
    copies = symmetric_copies(g, Symmetry("turns", AXIS, 3)).astype(np.float64)
    turns = sorted(np.degrees(_turn_of(c, g[0])[0]) % 360 for c in copies)
    np.testing.assert_allclose(turns, [120.0, 240.0], atol=1e-3)
    assert symmetric_copies(g, Symmetry("none")).shape == (0, 7) and Symmetry("none").trivial
    assert not Symmetry("none", mirrors=(90.0,)).trivial
    assert symmetric_copies(np.zeros((0, 7)), Symmetry("revolution")).shape == (0, 7)


def test_copies_are_kept_only_where_the_surroundings_are_the_same():
    sym = Symmetry("revolution", AXIS)
    g = np.concatenate([_grasp(0.1), _grasp(0.05, seed=2)])
    seen = []

    def same(centres, angles, mirror):  # keeps the second grasp's copies, the first's half turn
        seen.append((np.asarray(centres), np.asarray(angles)))
        assert not np.any(mirror)
        return (np.linalg.norm(centres[:, :2] - AXIS, axis=1) < 0.07) | np.isclose(angles, np.pi)

    copies = symmetric_copies(g, sym, same)
    assert len(seen) == 1 and len(seen[0][1]) == 11 + 9  # 12° steps at 5 cm
    kept = np.linalg.norm(copies[:, :2] - AXIS, axis=1)
    assert len(copies) == 9 + 1 and np.isclose(kept, 0.1).sum() == 1


def test_a_mirror_copy_is_the_chains_mirror_move():
    """A mirror plane's copy: the same pose as the sampler's mirror move
    (:func:`jaxgrasp.mcmc.symmetry.move` with a :class:`~jaxgrasp.mcmc.symmetry.Mirror`), a
    proper rotation (the pads swapped), and a second reflection gives the grasp back."""
    import jax.numpy as jnp

    from jaxgrasp.learn.evaluate.distinct import same_grasp
    from jaxgrasp.mcmc.symmetry import Mirror, move

    sym = Symmetry("none", AXIS, mirrors=(30.0,))
    g = _grasp(0.06, seed=4)
    angles, mirror = copy_maps(0.06, sym)
    assert mirror.all() and np.allclose(np.degrees(angles), [30.0])
    copy = symmetric_copies(g, sym).astype(np.float64)
    chains = np.asarray(move(jnp.asarray(g[0], jnp.float32), Mirror(AXIS, (np.radians(30.0),)),
                             jnp.float32(0.0)), np.float64)
    chains[3:] /= np.linalg.norm(chains[3:])
    np.testing.assert_allclose(copy[0, :3], chains[:3], atol=1e-6)
    assert abs(abs(copy[0, 3:] @ chains[3:]) - 1.0) < 1e-6
    assert np.isclose(np.linalg.det(Rotation.from_quat(copy[0, 3:], scalar_first=True)
                                     .as_matrix()), 1.0)
    assert same_grasp(symmetric_copies(copy, sym), g)[0, 0]
    assert not same_grasp(copy, g)[0, 0]


def test_a_symmetry_is_read_from_each_of_its_forms():
    """``as_symmetry``: a Symmetry, its text, a run's recorded dict give the same; one with
    neither turns nor mirrors, and None, give None (no copies)."""
    four = Symmetry("turns", order=4)
    assert as_symmetry(None, four) == as_symmetry(None, four.to_dict()) == four
    assert as_symmetry(None, "turns:4") == four
    assert as_symmetry(None, Symmetry("none")) is None and as_symmetry(None, None) is None
