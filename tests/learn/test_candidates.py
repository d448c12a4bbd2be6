"""The demo search's optimized candidates: split into parts optimized at once on threads, the
same poses as in one part up to float32 round-off, and the same on any number of cores."""

import numpy as np
import pytest

from jaxgrasp.learn.setup import candidates as C


@pytest.mark.slow  # compiles the optimizer for two batch shapes (~7 s)
def test_candidates_in_parts_equal_one_part(box, monkeypatch):
    """5 points in 3 parts of 2 (the last padded with a copy of the last point) give the poses
    of one call on all 5 up to float32 round-off (each point's optimization is its own; XLA
    rounds other batch shapes differently), and bit for bit the same on 1 core as on 8."""
    points, normals = C.surface_points(box.mesh, 5, 3, min_normal_z=C.MIN_NORMAL_Z)
    monkeypatch.setattr(C, "PARTS", 1)
    whole = C.candidate_poses(box, points, normals, seed=0)
    calls = []
    solve = C._solve_all

    def counted(q0, *args, **kw):
        calls.append(q0.shape[0])
        return solve(q0, *args, **kw)

    monkeypatch.setattr(C, "PARTS", 3)
    monkeypatch.setattr(C, "_solve_all", counted)
    monkeypatch.setattr(C.os, "cpu_count", lambda: 8)
    parts = C.candidate_poses(box, points, normals, seed=0)
    assert calls == [2, 2, 2]
    assert whole.shape == (5, 7)
    np.testing.assert_allclose(parts, whole, atol=1e-5)
    monkeypatch.setattr(C.os, "cpu_count", lambda: 1)
    np.testing.assert_array_equal(C.candidate_poses(box, points, normals, seed=0), parts)


def test_quaternions_of_many_frames_are_those_of_each_frame():
    """The batched conversion (one scipy call for every frame of a demo round) gives each
    frame's quaternion (w, x, y, z) bit for bit, as converting the frames one at a time did;
    no frames give none."""
    from scipy.spatial.transform import Rotation

    frames = Rotation.random(200, random_state=0).as_matrix().reshape(10, 20, 3, 3)
    frames[0, 0] = np.diag([1.0, -1.0, -1.0])  # a half turn: the branch away from w
    got = C._matrices_to_quaternions(frames)
    assert got.shape == (10, 20, 4)
    for idx in np.ndindex(10, 20):
        x, y, z, w = Rotation.from_matrix(frames[idx]).as_quat()
        np.testing.assert_array_equal(got[idx], [w, x, y, z])
    assert C._matrices_to_quaternions(np.zeros((0, 3, 3))).shape == (0, 4)
