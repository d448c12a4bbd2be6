"""The grasp atlas: candidate structure, the shipped atlases, save/load (no big physics)."""

import numpy as np
import pytest

from jaxgrasp.learn.evaluate import atlas as atlas_mod
from jaxgrasp.learn.evaluate.atlas import (
    Atlas,
    atlas_poses,
    load_atlas,
    save_atlas,
    sphere_poses,
    wall_poses,
)
from jaxgrasp.learn.evaluate.distinct import same_grasp
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
