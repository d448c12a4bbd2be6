"""The antipodal sampler: antipodal pairs on the test box, a uniform approach angle about the
closing axis, placement collisions without a rollout, and ``active(method="antipodal")``."""

import numpy as np
import pytest
import trimesh
from scipy import stats
from scipy.spatial.transform import Rotation

import jaxgrasp as jg
from jaxgrasp.learn.setup import antipodal

#: The batch of the shared box simulator (conftest.CHAINS): runs reuse its compiled trial.
CHAINS = 4


def _frames(poses):
    q = np.asarray(poses, np.float64)[:, 3:]
    return Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()


def _box_normal(points, half, center):
    """Outward normal of the analytic box face each point lies on (nearest face)."""
    rel = (points - center) / half
    axis = np.argmax(np.abs(rel), axis=1)
    n = np.zeros_like(points)
    n[np.arange(len(points)), axis] = np.sign(rel[np.arange(len(points)), axis])
    return n


def _approach_angles(poses):
    """Angle of the approach about the closing axis from the test's own zero direction (not
    the sampler's): a uniform angle stays uniform under any per-axis offset."""
    r = _frames(poses)
    y, z = r[:, :, 1], r[:, :, 2]
    w = np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8])
    u = w - np.sum(w * y, axis=1, keepdims=True) * y
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(y, u)
    return np.mod(np.arctan2(np.sum(z * v, axis=1), np.sum(z * u, axis=1)), 2 * np.pi)


def test_box_candidates_are_antipodal_and_fit_the_opening(box):
    gripper = jg.physics.GripperParams()
    found = antipodal.antipodal_grasps(box, 300, seed=1, gripper=gripper,
                                       collides=antipodal.placement_collisions(box))
    assert found.poses.shape == (300, 7) and found.collisions > 0
    r = _frames(found.poses)
    assert np.allclose(np.linalg.det(r), 1.0, atol=1e-5)
    half = np.array([0.03, 0.03, 0.05])
    center = np.array([0.0, 0.0, 0.05])
    y = r[:, :, 1]
    w = found.widths[:, None].astype(np.float64)
    mid = found.poses[:, :3] + found.depths[:, None] * r[:, :, 2]
    assert np.all(np.abs(found.depths) <= 0.75 * gripper.pad_half_size[2] + 1e-7)
    contacts = (mid + 0.5 * w * y, mid - 0.5 * w * y)
    cos_cone = np.cos(np.arctan(gripper.pad_friction))
    for c, sign in zip(contacts, (1.0, -1.0), strict=True):
        # On the surface: on a face plane and inside the box's extent.
        rel = np.abs(c - center) / half
        assert np.allclose(rel.max(axis=1), 1.0, atol=1e-3)
        n = _box_normal(c, half, center)
        assert np.all(np.sum(n * sign * y, axis=1) >= cos_cone - 1e-6)  # inside the cone
    assert np.all(found.widths <= gripper.max_opening)
    assert np.allclose(found.widths, 0.06, atol=1e-4)  # across x or y; z (10 cm) is too wide
    assert np.all(np.abs(y[:, 2]) < 1e-6)


def test_friction_cone_drops_tilted_pairs():
    # A prism tapered in x (sides 10 degrees off vertical, 20 degrees apart), straight in y.
    a = np.tan(np.radians(10.0)) * 0.05
    xz = [(-0.03, 0.0), (0.03, 0.0), (0.03 - a, 0.05), (-0.03 + a, 0.05)]
    mesh = trimesh.convex.convex_hull([(x, y, z) for x, z in xz for y in (-0.025, 0.025)])
    pts, nrm = trimesh.sample.sample_surface(mesh, 4000, seed=0)
    nrm = mesh.face_normals[nrm]
    side_x = np.abs(nrm[:, 0]) > 0.9
    for mu, kept_x in ((0.5, True), (0.2, False)):  # cone 26.6 / 11.3 degrees vs 20 degrees
        keep, p, q = antipodal.antipodal_pairs(mesh, pts, nrm, max_width=0.08,
                                               cone_deg=np.degrees(np.arctan(mu)))
        assert keep[np.abs(nrm[:, 1]) > 0.99].mean() > 0.95  # straight y walls: always kept
        assert (keep[side_x].mean() > 0.5) == kept_x


def test_interior_faces_of_touching_parts_are_not_surface():
    # Two boxes touching at x = 0: the coincident faces are inside the solid.
    a = trimesh.creation.box(extents=(0.02, 0.04, 0.04))
    a.apply_translation((-0.01, 0.0, 0.02))
    b = a.copy()
    b.apply_translation((0.02, 0.0, 0.0))
    mesh = trimesh.util.concatenate([a, b])
    inner = np.array([[0.0, 0.005, 0.02]])
    ok, _, _ = antipodal.opposite_points(mesh, inner, [[1.0, 0.0, 0.0]])
    assert not ok[0]
    ok, q, n_q = antipodal.opposite_points(mesh, [[-0.02, 0.005, 0.02]], [[-1.0, 0.0, 0.0]])
    assert ok[0] and np.allclose(q[0], [0.02, 0.005, 0.02], atol=1e-9)  # through both parts
    assert np.allclose(n_q[0], [1.0, 0.0, 0.0])


def test_approach_angle_is_uniform_about_the_closing_axis(box):
    found = antipodal.antipodal_grasps(box, 2000, seed=3)  # no collision filter: unbiased
    r = _frames(found.poses)
    assert np.allclose(np.sum(r[:, :, 1] * r[:, :, 2], axis=1), 0.0, atol=1e-6)
    assert stats.kstest(_approach_angles(found.poses) / (2 * np.pi), "uniform").pvalue > 0.01


def test_a_biased_approach_angle_fails_the_same_test(box):
    found = antipodal.antipodal_grasps(box, 2000, seed=3)
    axes = _frames(found.poses)[:, :, 1]
    rng = np.random.default_rng(0)
    for angles in (2 * np.pi * rng.beta(2.0, 2.0, len(axes)),  # peaked at pi
                   rng.uniform(0.0, np.pi, len(axes))):  # one half-turn only
        frames = antipodal.grasp_frames(axes, angles)
        q = Rotation.from_matrix(frames).as_quat()[:, [3, 0, 1, 2]]
        poses = np.concatenate([found.poses[:, :3], q], axis=1)
        assert stats.kstest(_approach_angles(poses) / (2 * np.pi), "uniform").pvalue < 1e-6


def test_too_few_grasps_is_a_clear_error(box):
    with pytest.raises(ValueError, match="antipodal grasps on 'box'.*surface points"):
        antipodal.antipodal_grasps(box, 10, seed=0, collides=lambda g: np.ones(len(g), bool),
                                   max_rounds=1)
    # fewer=True hands back what the rounds found (the atlas's seeds), but never nothing
    every_other = lambda g: np.arange(len(g)) % 2 == 1  # noqa: E731 - a tiny filter
    few = antipodal.antipodal_grasps(box, 100_000, seed=0, collides=every_other, max_rounds=1,
                                     fewer=True)
    assert 0 < len(few.poses) < 100_000 and few.collisions + len(few.poses) == few.pairs
    with pytest.raises(ValueError, match="antipodal grasps on 'box'"):
        antipodal.antipodal_grasps(box, 10, seed=0, collides=lambda g: np.ones(len(g), bool),
                                   max_rounds=1, fewer=True)


def test_active_antipodal_reports(box, box_sim, small_params, tmp_path):
    demos = jg.learn.Demos(np.array([[0.0, 0.0, 0.05, 0.5, 0.5, -0.5, 0.5]], np.float32))
    res = jg.learn.active(box, method="antipodal", chains=CHAINS, seed=0,
                          params=small_params, trial=box_sim, demos=demos, progress=False,
                          checkpoint_dir=tmp_path / "run")
    steps = small_params.num_steps
    assert res.method == "antipodal" and res.sketch == "none" and res.proposals.shape == (
        steps, CHAINS, 7)
    assert res.counts.sum() == steps * CHAINS
    assert res.counts[:, 2].sum() == 0  # placement collisions never reach the physics
    assert res.counts[:, 0].sum() > 0 and res.acceptance_rate.tolist() == [1.0] * CHAINS
    assert np.all(res.epsilons[res.outcomes > 1] == 0.0)
    assert res.info["placement_collisions"] > 0
    learned = res.learned
    assert 0 < len(learned.new) <= len(learned.distinct) == len(res.grasps)
    assert "antipodal" in res.summary()
    again = jg.learn.active(box, method="antipodal", chains=CHAINS, seed=0,
                            params=small_params, trial=box_sim, demos=demos, progress=False,
                            checkpoint_dir=tmp_path / "run")  # the finished result, read back
    np.testing.assert_array_equal(again.proposals, res.proposals)
    loaded = jg.learn.load(tmp_path / "run", box)
    assert loaded.method == "antipodal" and len(loaded.grasps) == len(res.grasps)
    rob = jg.learn.robustness(res, trial=box_sim, noise=jg.learn.PoseNoise(tries=2), seed=0)
    assert len(rob.held) == len(res.grasps)
    assert res.with_robustness(rob).distinct_robust_new is not None


def test_active_antipodal_arguments(box):
    with pytest.raises(ValueError, match="antipodal"):
        jg.learn.active(box, method="nope")
    with pytest.raises(ValueError, match="devices"):
        jg.learn.active(box, method="antipodal", devices="all")


def test_some_antipodal_grasps_may_be_none(box):
    """The ingredient's draw: the same grasps as the sampler's, or none (no error) where no
    pair places."""
    some = antipodal.some_antipodal_grasps(box, 50, seed=2)
    np.testing.assert_array_equal(some, antipodal.antipodal_grasps(box, 50, seed=2).poses)
    none = antipodal.some_antipodal_grasps(box, 10, seed=0,
                                           collides=lambda g: np.ones(len(g), bool))
    assert none.shape == (0, 7)
