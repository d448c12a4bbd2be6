"""The same-grasp relation (1 cm and 10°, the gripper's 180° symmetry) and the run measures."""

import math

import numpy as np

from jaxgrasp.learn import distinct

Q0 = np.array([1.0, 0.0, 0.0, 0.0])


def _about(axis, deg):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    h = math.radians(deg) / 2
    return np.concatenate([[math.cos(h)], math.sin(h) * axis])


def _mul(p, q):
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return np.array([pw * qw - px * qx - py * qy - pz * qz, pw * qx + px * qw + py * qz - pz * qy,
                     pw * qy - px * qz + py * qw + pz * qx, pw * qz + px * qy - py * qx + pz * qw])


def g(pos, q=Q0):
    return np.concatenate([pos, q])


def test_relation_thresholds_and_symmetry():
    base = g([0, 0, 0], _about([1, 2, 3], 40))
    assert distinct.same_grasp([base], [g([0.009, 0, 0], base[3:])])[0, 0]
    assert not distinct.same_grasp([base], [g([0.011, 0, 0], base[3:])])[0, 0]
    assert distinct.same_grasp([base], [g([0, 0, 0], _mul(base[3:], _about([0, 1, 0], 9)))])[0, 0]
    assert not distinct.same_grasp([base], [g([0, 0, 0], _mul(base[3:], _about([0, 1, 0], 11)))])[
        0, 0]
    # 180° about the approach axis (+z of the grasp frame): the pads swap, the same grasp
    flipped = _mul(base[3:], _about([0, 0, 1], 180))
    assert distinct.same_grasp([base], [g([0, 0, 0], flipped)])[0, 0]
    # 180° about the closing axis is another grasp; -q is the same rotation
    assert not distinct.same_grasp([base], [g([0, 0, 0], _mul(base[3:], _about([0, 1, 0], 180)))])[
        0, 0]
    assert distinct.same_grasp([base], [g([0, 0, 0], -base[3:])])[0, 0]


def test_distinct_new_coverage_repeats():
    # a line of grasps 6 mm apart: greedy clustering keeps every second one
    line = np.stack([g([0.006 * i, 0, 0]) for i in range(10)])
    kept = distinct.distinct_grasps(line)
    assert len(kept) == 5
    np.testing.assert_allclose(kept[:, 0], [0, 0.012, 0.024, 0.036, 0.048])
    demos = line[:1]
    assert distinct.is_new(kept, demos).tolist() == [False, True, True, True, True]
    assert distinct.coverage(kept, line) == 1.0
    assert distinct.coverage(kept[:1], line) == 0.2  # the first two of ten
    # proposals: the same grasp three times, then a new one
    props = np.stack([g([0, 0, 0]), g([0.001, 0, 0]), g([0, 0.002, 0]), g([0.5, 0, 0])])
    assert distinct.repeat_share(props) == 0.5
    outcomes = np.array([0, 0, 1, 0])
    learned = distinct.learned_grasps(props[:, None], outcomes[:, None], demos)
    assert learned.successes == 3
    assert len(learned.distinct) == 2 and len(learned.new) == 1


def test_large_sets_block_correctly():
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 0.3, (3000, 3))
    grasps = np.concatenate([pts, np.tile(Q0, (3000, 1))], axis=1)
    kept = distinct.distinct_grasps(grasps)
    rel = distinct.same_grasp(kept, kept)
    np.fill_diagonal(rel, False)
    assert not rel.any()  # no two kept grasps are the same grasp
    assert distinct.is_new(grasps, kept).sum() == 0  # every grasp is near a kept one


def test_repeat_share_matches_the_pairwise_definition():
    """The KD-tree repeat share equals the definition on the full same-grasp matrix, on
    clustered proposals whose positions and angles straddle both tolerances."""
    rng = np.random.default_rng(1)
    centres = rng.uniform(0, 0.1, (40, 3))
    pos = centres[rng.integers(0, 40, 1500)] + rng.normal(0, 0.006, (1500, 3))
    axis = rng.normal(size=(1500, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    half = 0.5 * rng.uniform(0, np.radians(25), 1500)[:, None]
    q = np.concatenate([np.cos(half), np.sin(half) * axis], axis=1)
    q[::3] = q[::3, [3, 2, 1, 0]] * [-1, 1, -1, 1]  # some turned 180° about the approach
    props = np.concatenate([pos, q], axis=1)
    rel = distinct.same_grasp(props, props)
    want = np.tril(rel, k=-1).any(axis=1).mean()
    assert 0.2 < want < 0.95  # the set exercises both outcomes
    assert distinct.repeat_share(props) == want


def test_same_as_any_matches_the_pairwise_definition():
    """The KD-tree test equals the full same-grasp matrix on clustered grasps straddling both
    tolerances (the 180° turn about the approach included)."""
    rng = np.random.default_rng(2)
    centres = rng.uniform(0, 0.1, (30, 3))

    def clustered(n):
        pos = centres[rng.integers(0, 30, n)] + rng.normal(0, 0.006, (n, 3))
        axis = rng.normal(size=(n, 3))
        axis /= np.linalg.norm(axis, axis=1, keepdims=True)
        half = 0.5 * rng.uniform(0, np.radians(25), n)[:, None]
        q = np.concatenate([np.cos(half), np.sin(half) * axis], axis=1)
        q[::3] = q[::3, [3, 2, 1, 0]] * [-1, 1, -1, 1]
        return np.concatenate([pos, q], axis=1)

    a, b = clustered(800), clustered(600)
    want = distinct.same_grasp(a, b).any(axis=1)
    assert 0.2 < want.mean() < 0.95
    np.testing.assert_array_equal(distinct.same_as_any(a, b), want)
    np.testing.assert_array_equal(distinct.same_as_any(a, b), ~distinct.is_new(a, b))
    assert not distinct.same_as_any(a, b[:0]).any() and distinct.same_as_any(a[:0], b).size == 0
