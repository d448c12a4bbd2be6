"""The grasp atlas: candidate structure, the shipped atlases, save/load (no big physics)."""

import numpy as np
import pytest

from jaxgrasp.learn.evaluate import atlas as atlas_mod
from jaxgrasp.learn.evaluate.atlas import (
    Atlas,
    atlas_grasps,
    atlas_poses,
    load_atlas,
    save_atlas,
    sphere_poses,
    wall_poses,
)
from jaxgrasp.learn.evaluate.distinct import same_as_any, same_grasp
from jaxgrasp.objects.shipped import load
from jaxgrasp.physics import GripperParams
from jaxgrasp.physics.gripper import gripper_corners


@pytest.fixture(scope="module")
def pitcher():
    return load("pitcher")


def test_candidates(pitcher):
    poses = atlas_poses(pitcher, num_points=40, seed=0)
    assert poses.dtype == np.float32 and poses.shape[1] == 7
    q = poses[:, 3:].astype(np.float64)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-5)
    assert (q[:, 0] >= 0).all()
    # no corner of the open gripper below the support plane
    from scipy.spatial.transform import Rotation

    r = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()
    corners = np.asarray(gripper_corners(GripperParams()), np.float64)
    world = poses[:, None, :3] + np.einsum("nij,kj->nki", r, corners)
    assert world[..., 2].min() >= pitcher.support_z + 0.0009
    # both families, wall family first and most of the budget
    wall = wall_poses(pitcher, num_points=40, seed=0)
    sphere = sphere_poses(pitcher, num_points=40 // atlas_mod.SPHERE_POINTS_DIVISOR, seed=1)
    np.testing.assert_array_equal(poses, np.concatenate([wall, sphere]))
    assert len(wall) > len(sphere) > 0
    per_base = (len(atlas_mod.WALL_TILTS_X_DEG) * len(atlas_mod.WALL_TILTS_Y_DEG)
                * len(atlas_mod.WALL_SPINS_DEG) * len(atlas_mod.WALL_OFFSETS))
    assert len(wall) <= 40 * 2 * per_base
    # straight down is among the approaches
    approach = r[:, :, 2]
    assert np.isclose(approach[:, 2], -1.0, atol=1e-5).any()
    # same seed, same candidates; fewer points, fewer candidates
    np.testing.assert_array_equal(poses, atlas_poses(pitcher, num_points=40, seed=0))
    assert len(atlas_poses(pitcher, num_points=10, seed=0)) < len(poses)


def test_wall_family_contains_rim_pinches(pitcher):
    """Unperturbed wall frames are exactly rim_poses' pinches (near-rim wall points)."""
    from jaxgrasp.learn.setup.candidates import rim_poses, surface_points

    p, n = surface_points(pitcher.mesh, 60, 0, min_normal_z=-0.3)
    rim = rim_poses(p, n, pitcher.support_z, GripperParams())
    wall = wall_poses(pitcher, num_points=60, seed=0)
    same = same_grasp(rim, wall)
    # the near-rim ones (the others are dropped: the palm would hit the rim) are all there
    near = rim[:, 2] > pitcher.mesh.bounds[1, 2] - atlas_mod.WALL_MAX_DEPTH + 0.005
    assert near.any() and same[near].any(axis=1).all()
    # and deep wall pinches are not
    deep = rim[:, 2] < pitcher.mesh.bounds[1, 2] - 0.08
    assert deep.any() and not same[deep].any()
    # approaches stay within the tilt grid of straight down
    from scipy.spatial.transform import Rotation

    approach = Rotation.from_quat(wall[:, [4, 5, 6, 3]].astype(np.float64)).as_matrix()[:, :, 2]
    assert np.isclose(approach[:, 2], -1.0, atol=1e-5).any()


def test_rotation_and_depth_groups(pitcher):
    poses = sphere_poses(pitcher, num_points=1, seed=3)
    from scipy.spatial.transform import Rotation

    from jaxgrasp.learn.setup.candidates import surface_points

    p, n = surface_points(pitcher.mesh, 1, 3, min_normal_z=-0.3)
    off = poses[:, :3].astype(np.float64) - p[0]
    d = np.linalg.norm(off, axis=1)
    pz = GripperParams().pad_half_size[2]
    # every centre sits 0.6 or 1.2 pad half lengths from the surface point along the approach
    assert np.all(np.isclose(d, 0.6 * pz, atol=1e-5) | np.isclose(d, 1.2 * pz, atol=1e-5))
    approach = Rotation.from_quat(poses[:, [4, 5, 6, 3]]).as_matrix()[:, :, 2]
    np.testing.assert_allclose(off / d[:, None], approach, atol=1e-3)
    # never approaching from inside the surface
    assert (approach @ (n[0] / np.linalg.norm(n[0])) < 0.3 + 1e-5).all()
    # whole (direction, rotation, depth) groups: at most 6 rotations x 2 depths per direction
    _, per_dir = np.unique(np.round(approach, 4), axis=0, return_counts=True)
    assert per_dir.max() <= atlas_mod.NUM_ROTATIONS * len(atlas_mod.DEPTHS)


def test_shipped_pitcher_atlas():
    a = load_atlas("pitcher")
    assert a.trials >= 100_000
    assert 0 < len(a.grasps) <= a.successes <= a.trials
    assert a.grasps.shape[1] == 7
    same = same_grasp(a.grasps, a.grasps)
    np.fill_diagonal(same, False)
    assert not same.any()
    assert a.settings["object"] == "pitcher"
    assert a.settings["content_hash"] == load("pitcher").content_hash


def test_missing_atlas():
    with pytest.raises(FileNotFoundError, match="python -m jaxgrasp.learn.evaluate.atlas"):
        load_atlas("no_such_object")


def test_round_trip(tmp_path, monkeypatch):
    g = np.random.default_rng(0).normal(size=(5, 7)).astype(np.float32)
    a = Atlas(g, 1234, 56, 7, 8.5, {"seed": 0, "object": "x"})
    path = save_atlas("x", a, directory=tmp_path)
    assert path == tmp_path / "x.npz"
    b = load_atlas("x", directory=tmp_path)
    np.testing.assert_array_equal(b.grasps, g)
    assert (b.trials, b.successes, b.slipped, b.seconds, b.settings) == (1234, 56, 7, 8.5,
                                                                       a.settings)
    monkeypatch.setattr(atlas_mod, "atlas_dir", lambda: tmp_path / "atlas")
    save_atlas("y", a)
    assert load_atlas("y").trials == 1234
    np.testing.assert_array_equal(atlas_grasps("y"), g)
    assert atlas_grasps("no_such_object") is None


def test_edge_family_pinches_a_plate_by_its_edge():
    """The plates' family: the closing axis dips 50-65° below the horizontal (one pad under
    the lip; spins about the approach of up to 20° lower that to ~46°), every pose above the
    table, and only ``edge=True`` adds it."""
    from scipy.spatial.transform import Rotation  # only this test needs rotation matrices

    plate = load("plate")
    poses = atlas_mod.edge_family(plate, num_points=60, seed=2)
    assert len(poses) > 0
    rot = Rotation.from_quat(poses[:, [4, 5, 6, 3]].astype(np.float64)).as_matrix()
    dip = np.degrees(np.arcsin(np.abs(rot[:, 2, 1])))  # closing axis (grasp y) vs horizontal
    assert dip.min() > 45 and dip.max() < 65.01
    for tilt in (50.0, 55.0, 60.0, 65.0):  # the unspun pinches
        assert np.any(np.abs(dip - tilt) < 1e-3), tilt
    corners = np.asarray(gripper_corners(GripperParams()), np.float64)
    lowest = (poses[:, None, :3] + np.einsum("nij,kj->nki", rot, corners))[..., 2].min(axis=1)
    assert np.all(lowest >= plate.support_z)
    plain = atlas_poses(plate, num_points=60, seed=0)
    both = atlas_poses(plate, num_points=60, seed=0, edge=True)
    assert len(both) == len(plain) + len(poses)


def test_any_atlas_candidates_split_antipodal_and_sphere():
    """The any-mesh atlas's seeds: a quarter of the trials antipodal grasps (placement
    collisions dropped before they count), a quarter the sphere family; no wall family."""
    from jaxgrasp.learn.setup.antipodal import placement_collisions  # the MuJoCo C pass
    from jaxgrasp.objects import make_box
    from jaxgrasp.physics import load_scene

    box = make_box()
    collides = placement_collisions(load_scene(box))
    poses, num_points, counts = atlas_mod.any_poses(box, num_trials=400, seed=0,
                                                    collides=collides)
    assert len(poses) >= 200 and poses.dtype == np.float32
    assert counts["antipodal_grasps"] == 100
    assert counts["sphere_grasps"] == len(poses) - 100 >= 100
    assert not collides(poses[:100]).any()
    sphere = sphere_poses(box, num_points=num_points, seed=1)
    np.testing.assert_array_equal(poses[100:], sphere)
    # The antipodal half pinches across the box: the closing axis (grasp y) is horizontal
    # through the 6 cm sides, or vertical through its 10 cm height (too wide: none).
    from scipy.spatial.transform import Rotation  # only this test needs rotation matrices

    y = Rotation.from_quat(poses[:100, [4, 5, 6, 3]].astype(np.float64)).as_matrix()[:, :, 1]
    assert np.all(np.abs(y[:, 2]) < 0.2)
    with pytest.raises(ValueError, match="kind"):
        atlas_mod.build_atlas(box, num_trials=10, kind="vase")


def test_missing_any_atlas_names_its_command():
    with pytest.raises(FileNotFoundError, match="--kind any --trials 50000"):
        load_atlas("random_000", directory="/nonexistent")


def test_neighbours_are_one_step_away_and_distinct():
    from scipy.spatial.transform import Rotation  # only this test needs rotation matrices

    g = np.array([[0.01, -0.02, 0.05, 0.9, 0.1, -0.3, 0.2]])
    g[:, 3:] /= np.linalg.norm(g[:, 3:])
    nb = atlas_mod.neighbour_poses(g)
    assert nb.shape == (12, 7)
    rot = Rotation.from_quat(g[0, [4, 5, 6, 3]])
    step = np.linalg.norm(nb[:6, :3] - g[0, :3], axis=1)
    np.testing.assert_allclose(step, atlas_mod.NEIGHBOUR_STEP, rtol=1e-5)
    np.testing.assert_allclose(np.abs(rot.inv().apply(nb[:6, :3] - g[0, :3])).max(axis=1),
                               atlas_mod.NEIGHBOUR_STEP, rtol=1e-4)  # along the frame's axes
    turn = (Rotation.from_quat(nb[6:, [4, 5, 6, 3]].astype(np.float64)) * rot.inv()).magnitude()
    np.testing.assert_allclose(np.degrees(turn), atlas_mod.NEIGHBOUR_TURN_DEG, rtol=1e-4)
    np.testing.assert_allclose(nb[6:, :3], np.repeat(g[:, :3], 6, axis=0), atol=1e-7)
    assert not same_grasp(nb, g).any()
    same = same_grasp(nb, nb)
    np.fill_diagonal(same, False)
    assert not same.any()


def test_flood_fills_a_known_success_region():
    """A fake trial that holds wherever the grasp centre is within 3 cm of the origin and its
    orientation is the identity's (up to 15°: one 12° turn): the flood from one success finds
    the grid points inside, stays within its budget, and drops what ``collides`` says."""
    def holds(p):
        q = p[:, 3:].astype(np.float64)
        near = np.linalg.norm(p[:, :3], axis=1) < 0.03
        return near & (np.abs(q[:, 0]) > np.cos(np.radians(7.5)))

    def run(p):
        ok = holds(p)
        return np.where(ok, 0, 1).astype(np.int32), ok.astype(np.float32)

    start = np.array([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]], np.float32)
    poses, counts = atlas_mod._flood(run, start, np.zeros(1, np.int32), np.ones(1, np.float32),
                                     lambda p: p[:, 2] < -0.02, budget=100_000)
    o, _ = run(poses)
    found = atlas_mod.distinct_grasps(np.concatenate([start, poses[o == 0]]))
    # Along the three axes within 3 cm: 0, ±1.2, ±2.4 cm; below z = -2 cm collides.
    along = found[(np.abs(found[:, 3]) > 1 - 1e-6)]
    axes = np.round(along[:, :3] / atlas_mod.NEIGHBOUR_STEP).astype(int)
    for k in range(3):
        on_axis = axes[(axes[:, [j for j in range(3) if j != k]] == 0).all(axis=1), k]
        assert set(on_axis) == ({-1, 0, 1, 2} if k == 2 else {-2, -1, 0, 1, 2}), k
    assert counts["flood_collisions"] > 0
    assert not (poses[:, 2] < -0.02).any()
    assert counts["flood_grasps"] == len(poses)
    # a budget stops it early
    few, c = atlas_mod._flood(run, start, np.zeros(1, np.int32), np.ones(1, np.float32),
                              lambda p: np.zeros(len(p), bool), budget=30)
    assert len(few) == 30 and c["flood_grasps"] == 30


def test_flood_rolls_later_what_a_round_cannot_afford():
    """With ``cost`` > 1 a round rolls at most ``budget // cost`` neighbours; the rest wait for
    the next rounds, so a budget that covers them finds what the unbounded flood finds (the
    flood that marked them tried and dropped them found less)."""
    def run(p):
        q = p[:, 3:].astype(np.float64)
        ok = (np.linalg.norm(p[:, :3], axis=1) < 0.03) & (np.abs(q[:, 0]) > np.cos(np.radians(7.5)))
        return np.where(ok, 0, 1).astype(np.int32), ok.astype(np.float32)

    def collides(p):
        return p[:, 2] < -0.02

    start = np.array([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]], np.float32)
    free, counts = atlas_mod._flood(run, start, np.zeros(1, np.int32), np.ones(1, np.float32),
                                    collides, budget=100_000)
    state = {"tried": [start], "found": start.astype(np.float64)}
    capped, c = atlas_mod.flood(run, start, collides, len(free) + 3, state, cost=3)
    assert c["flood_rounds"] > counts["flood_rounds"]  # the cap split the rounds
    held = [atlas_mod.distinct_grasps(p[run(p)[0] == 0]) for p in (free, capped)]
    assert len(held[0]) > 20
    assert same_grasp(held[0], held[1]).any(axis=1).all()
    assert same_grasp(held[1], held[0]).any(axis=1).all()


def _flood_from_identity(run, budget, **kwargs):
    """A flood from the identity pose with no table: the poses it rolled out and how many of
    them held."""
    start = np.array([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]], np.float32)
    state = {"tried": [start], "found": start.astype(np.float64)}
    poses, _ = atlas_mod.flood(run, start, lambda p: np.zeros(len(p), bool), budget, state,
                               **kwargs)
    return poses, int((run(poses)[0] == 0).sum())


def test_flood_defers_the_kinds_of_step_that_fail():
    """``defer=2`` on a trial that holds only in a slab about z = 0, within 6 cm, up to 15°
    from the identity's orientation: the moves along the grasp's z axis leave the slab. Once
    they have held least often their neighbours wait, so a budget that binds finds more
    grasps than the same flood without deferring (the companion); with budget to spare both
    run dry with about the same grasps."""
    def run(p):
        q = p[:, 3:].astype(np.float64)
        ok = ((np.abs(p[:, 2]) < 0.005) & (np.linalg.norm(p[:, :3], axis=1) < 0.06)
              & (np.abs(q[:, 0]) > np.cos(np.radians(7.5))))
        return np.where(ok, 0, 1).astype(np.int32), ok.astype(np.float32)

    def found(budget, defer):
        poses, ok = _flood_from_identity(run, budget, defer=defer)
        return len(poses), ok

    (n0, ok0), (n8, ok8) = found(120, 0), found(120, 2)
    assert n0 == n8 == 120 and ok8 >= ok0 + 15, (ok0, ok8)
    (a, a_ok), (b, b_ok) = found(100_000, 0), found(100_000, 2)
    # (the greedy one-per-grasp cover depends on the order, so the two covers differ a little)
    assert a < 100_000 and b < 100_000 and abs(a_ok - b_ok) < 0.1 * a_ok and b_ok > ok8


def test_flood_ranks_the_neighbours_likeliest_to_hold_first():
    """``rank=True`` on a trial that holds in a ball, everywhere on its x < 0 half and at about
    every other pose on the other: the poses a ranked flood has tried around a neighbour say
    where it is likelier to hold, so a budget that binds finds more grasps (572 against 481;
    600 with rounds of a quarter of the budget left, 555-574 with rounds of 8-64: on this
    trial's coin-toss half the counts around a pose say little) than the same flood unranked
    (the companion); with budget to spare both roll out the same neighbours."""
    def run(p):
        q = p[:, 3:].astype(np.float64)
        coin = np.sin(1e3 * p[:, 0] + 7e2 * p[:, 1] + 5e2 * p[:, 2]) > 0
        ok = ((np.linalg.norm(p[:, :3], axis=1) < 0.05)
              & (np.abs(q[:, 0]) > np.cos(np.radians(7.5))) & ((p[:, 0] < 0) | coin))
        return np.where(ok, 0, 1).astype(np.int32), ok.astype(np.float32)

    def found(budget, rank):
        return _flood_from_identity(run, budget, rank=rank)

    (p0, ok0), (p1, ok1) = found(1000, False), found(1000, True)
    assert len(p0) == len(p1) == 1000 and ok1 >= 1.15 * ok0, (ok0, ok1)
    (a, a_ok), (b, b_ok) = found(100_000, False), found(100_000, True)
    assert len(a) < 100_000 and len(a) == len(b) and a_ok == b_ok > ok1
    assert same_as_any(a, b).all()


def test_flood_ranking_pays_where_holding_is_decided_by_place():
    """``rank=True`` on a trial that holds inside twelve ellipsoids (one at the start) under a
    tilt limit that narrows away from z = 0, no coin: the counts around a neighbour say where
    it holds, so a budget of 1000 finds a fifth more grasps ranked (917 against 742) than the
    same flood unranked (the companion)."""
    rng = np.random.default_rng(0)
    centres, sizes = rng.uniform(-0.08, 0.08, (12, 3)), rng.uniform(0.01, 0.04, (12, 3))
    centres[0] = 0.0

    def run(p):
        q = p[:, 3:].astype(np.float64)
        inside = ((((p[:, None, :3] - centres) / sizes) ** 2).sum(-1) < 1).any(1)
        tilt = np.degrees(2 * np.arccos(np.clip(np.abs(q[:, 0]), 0, 1)))
        ok = inside & (tilt < 25 - 200 * np.abs(p[:, 2]))
        return np.where(ok, 0, 1).astype(np.int32), ok.astype(np.float32)

    (p0, ok0), (p1, ok1) = (_flood_from_identity(run, 1000, rank=r) for r in (False, True))
    assert len(p0) == len(p1) == 1000 and ok1 >= 1.2 * ok0, (ok0, ok1)


def test_flood_rolls_poses_from_elsewhere_first():
    """``first``: poses from elsewhere join the first round, filtered like neighbours (one per
    grasp, none tried before, none colliding), so a second success region the neighbours of
    the first cannot reach is filled as fully as the first; without them it stays empty."""
    centres = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0]])

    def run(p):
        q = p[:, 3:].astype(np.float64)
        near = np.linalg.norm(p[:, None, :3] - centres, axis=-1).min(axis=1) < 0.03
        ok = near & (np.abs(q[:, 0]) > np.cos(np.radians(7.5)))
        return np.where(ok, 0, 1).astype(np.int32), ok.astype(np.float32)

    def collides(p):
        return p[:, 2] < -0.02

    start = np.array([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]], np.float32)
    other = np.array([[0.2, 0.0, 0.0, 1, 0, 0, 0], [0.2, 0.0, 0.0, 1, 0, 0, 0],
                      [0.2, 0.0, 0.001, 1, 0, 0, 0], [0.2, 0.0, -0.05, 1, 0, 0, 0],
                      [0.0, 0.0, 0.0, 1, 0, 0, 0]], np.float32)
    found = {}
    for name, first in (("alone", None), ("with", other)):
        state = {"tried": [start], "found": start.astype(np.float64)}
        rolled, _ = atlas_mod.flood(run, start, collides, 100_000, state, first=first)
        found[name] = state["found"]
        if first is not None:  # the duplicates once, the colliding one and the start never
            assert same_grasp(rolled, other[:1]).any(axis=1).sum() == 1
            assert not same_grasp(rolled, other[3:]).any()
            assert not same_grasp(rolled, start).any()
    far = {k: int((v[:, 0] > 0.1).sum()) for k, v in found.items()}
    assert far["alone"] == 0
    assert far["with"] == len(found["alone"]) > 20  # the same grid about the other centre
