"""What a run learned, in distinct grasps (docs/design.md, "Measuring what the learner learns").

Two grasps are the **same grasp** when their positions are within ``position_tol`` (1 cm) and
their orientations within ``angle_tol`` (10°), where a rotation of 180° about the gripper's
approach axis (+z of the grasp frame) is the same grasp: the two pads swap. On this relation:

- :func:`distinct_grasps`: greedy clusters of grasps in order (keep one if no kept one is the
  same grasp);
- :func:`is_new`: which grasps are not the same grasp as any demonstration;
- :func:`same_as_any`: the same, paired by a KD-tree on positions (large clustered sets);
- :func:`coverage`: the share of reference grasps (an object's atlas) that some found grasp
  is the same as;
- :func:`repeat_share`: the share of proposals that are the same grasp as an earlier one.

:func:`canonical_grasps` and :func:`unique_grasps` put grasps in one representation (unit
quaternion, qw >= 0) and drop exact repeats, for reporting.

Host-side numpy (float64): these are reports, never part of a sampler.
"""

import math
from typing import NamedTuple

import numpy as np

__all__ = [
    "POSITION_TOL",
    "ANGLE_TOL",
    "LearnedGrasps",
    "same_grasp",
    "grasp_distances",
    "distinct_grasps",
    "distinct_indices",
    "is_new",
    "same_as_any",
    "coverage",
    "repeat_share",
    "learned_grasps",
    "canonical_grasps",
    "unique_grasps",
]

#: Positions closer than this are the same grasp (metres) ...
POSITION_TOL = 0.01
#: ... when their orientations are also closer than this (radians; 10°).
ANGLE_TOL = math.radians(10.0)
#: Rows per block of pairwise comparisons (memory bound: block x n x 7 float64).
_BLOCK = 1024


def _unit(grasps) -> np.ndarray:
    g = np.array(grasps, dtype=np.float64, copy=True).reshape(-1, 7)
    norm = np.linalg.norm(g[:, 3:], axis=1, keepdims=True)
    g[:, 3:] /= np.where(norm > 0, norm, 1.0)
    return g


def _flipped(q: np.ndarray) -> np.ndarray:
    """``q ⊗ (0, 0, 0, 1)``: the same gripper rotated 180° about its approach axis."""
    w, x, y, z = q.T
    return np.stack([-z, y, -x, w], axis=1)


def _relation(a: np.ndarray, b: np.ndarray, cos_half: float, position_tol: float):
    """(len(a), len(b)) bool: a_i is the same grasp as b_j."""
    close = np.sum((a[:, None, :3] - b[None, :, :3]) ** 2, axis=-1) <= position_tol**2
    dot = np.abs(a[:, 3:] @ b[:, 3:].T)
    dot_flip = np.abs(a[:, 3:] @ _flipped(b[:, 3:]).T)
    # angle <= tol  <=>  |<q_a, q_b>| = cos(angle / 2) >= cos(tol / 2)
    return close & (np.maximum(dot, dot_flip) >= cos_half)


def same_grasp(a, b, *, position_tol=POSITION_TOL, angle_tol=ANGLE_TOL) -> np.ndarray:
    """(len(a), len(b)) bool matrix of the same-grasp relation between two sets of grasps."""
    return _relation(_unit(a), _unit(b), math.cos(0.5 * angle_tol), position_tol)


def grasp_distances(a, b, *, length_scale: float) -> np.ndarray:
    """(len(a), len(b)) metres: position distance plus ``length_scale`` x rotation angle, the
    gripper's 180° turn about its approach folded (the same-grasp relation's two parts)."""
    a, b = _unit(a), _unit(b)
    pos = np.linalg.norm(a[:, None, :3] - b[None, :, :3], axis=-1)
    dot = np.maximum(np.abs(a[:, 3:] @ b[:, 3:].T), np.abs(a[:, 3:] @ _flipped(b[:, 3:]).T))
    return pos + length_scale * 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))


def _any_same(a: np.ndarray, b: np.ndarray, cos_half, position_tol) -> np.ndarray:
    """(len(a),) bool: a_i is the same grasp as some b_j (blocked over a)."""
    out = np.zeros(len(a), bool)
    if len(a) == 0 or len(b) == 0:
        return out
    for lo in range(0, len(a), _BLOCK):
        for blo in range(0, len(b), _BLOCK):
            hit = _relation(a[lo:lo + _BLOCK], b[blo:blo + _BLOCK], cos_half, position_tol)
            out[lo:lo + _BLOCK] |= hit.any(axis=1)
    return out


def distinct_grasps(grasps, *, position_tol=POSITION_TOL, angle_tol=ANGLE_TOL) -> np.ndarray:
    """Greedy clusters in order: the grasps kept, (k, 7) with unit quaternions."""
    return _unit(grasps)[distinct_indices(grasps, position_tol=position_tol,
                                          angle_tol=angle_tol)]


def distinct_indices(grasps, *, position_tol=POSITION_TOL, angle_tol=ANGLE_TOL) -> np.ndarray:
    """(k,) int: the rows :func:`distinct_grasps` keeps, in order."""
    g = _unit(grasps)
    cos_half = math.cos(0.5 * angle_tol)
    kept, rows = np.zeros((0, 7)), []
    for lo in range(0, len(g), 256):
        block = g[lo:lo + 256]
        # most of a block is decided against the kept set at once; the rest one by one
        fresh = np.flatnonzero(~_any_same(block, kept, cos_half, position_tol))
        new = []
        for i in fresh:
            if not new or not _relation(block[i][None], block[new], cos_half,
                                        position_tol).any():
                new.append(i)
        if new:
            kept = np.concatenate([kept, block[new]])
            rows.extend(lo + i for i in new)
    return np.asarray(rows, np.int64)


def is_new(grasps, demos, *, position_tol=POSITION_TOL, angle_tol=ANGLE_TOL) -> np.ndarray:
    """(n,) bool: the grasp is not the same grasp as any demonstration."""
    return ~_any_same(_unit(grasps), _unit(demos), math.cos(0.5 * angle_tol), position_tol)


def same_as_any(grasps, others, *, position_tol=POSITION_TOL, angle_tol=ANGLE_TOL) -> np.ndarray:
    """(n,) bool: the grasp is the same grasp as some of ``others`` (what :func:`is_new`
    negates, with candidate pairs from a KD-tree on positions: O(pairs), for the thousands of
    clustered grasps of an atlas search)."""
    return count_same(grasps, others, position_tol=position_tol, angle_tol=angle_tol) > 0


def count_same(grasps, others, *, position_tol=POSITION_TOL, angle_tol=ANGLE_TOL) -> np.ndarray:
    """(n,) int: how many of ``others`` each grasp is the same grasp as (within the
    tolerances), from a KD-tree on positions."""
    # why: scipy.spatial is a heavy import that only the large-set reports need.
    from scipy.spatial import cKDTree

    a, b = _unit(grasps), _unit(others)
    out = np.zeros(len(a), np.int64)
    if len(a) == 0 or len(b) == 0:
        return out
    pairs = cKDTree(a[:, :3]).sparse_distance_matrix(cKDTree(b[:, :3]), position_tol,
                                                      output_type="ndarray")
    qa, qb = a[pairs["i"], 3:], b[pairs["j"], 3:]
    dot = np.maximum(np.abs(np.sum(qa * qb, axis=1)), np.abs(np.sum(qa * _flipped(qb), axis=1)))
    return np.bincount(pairs["i"][dot >= math.cos(0.5 * angle_tol)], minlength=len(a))


def coverage(found, reference, *, position_tol=POSITION_TOL, angle_tol=ANGLE_TOL) -> float:
    """Share of ``reference`` grasps that are the same grasp as some ``found`` grasp."""
    ref = _unit(reference)
    if len(ref) == 0:
        return float("nan")
    hit = _any_same(ref, _unit(found), math.cos(0.5 * angle_tol), position_tol)
    return float(hit.mean())


def repeat_share(proposals, *, position_tol=POSITION_TOL, angle_tol=ANGLE_TOL) -> float:
    """Share of proposals (in order) that are the same grasp as an earlier proposal."""
    # why: scipy.spatial is a heavy import that only this report needs.
    from scipy.spatial import cKDTree

    g = _unit(proposals)
    if len(g) == 0:
        return float("nan")
    # Candidate pairs (i < j) from a KD-tree on positions (a hair wider than the tolerance),
    # then the same-grasp rule itself on each pair: O(pairs), not O(n^2) (9 s -> ~0.1 s on a
    # run of 8 x 1100 proposals).
    pairs = cKDTree(g[:, :3]).query_pairs(position_tol * (1 + 1e-9), output_type="ndarray")
    a, b = g[pairs[:, 0]], g[pairs[:, 1]]
    close = np.sum((a[:, :3] - b[:, :3]) ** 2, axis=1) <= position_tol**2
    dot = np.abs(np.sum(a[:, 3:] * b[:, 3:], axis=1))
    dot_flip = np.abs(np.sum(a[:, 3:] * _flipped(b[:, 3:]), axis=1))
    same = close & (np.maximum(dot, dot_flip) >= math.cos(0.5 * angle_tol))
    repeat = np.zeros(len(g), bool)
    repeat[pairs[same].max(axis=1)] = True  # the later one of each pair repeats the earlier
    return float(repeat.mean())


class LearnedGrasps(NamedTuple):
    """What a run learned, in distinct grasps.

    successes : successful proposals (demo re-proposals included).
    distinct : (k, 7) distinct successful grasps.
    new : (k_new, 7) the distinct ones that are not a demo.
    repeat_share : share of all proposals that repeat an earlier proposal.
    """

    successes: int
    distinct: np.ndarray
    new: np.ndarray
    repeat_share: float

    def summary(self) -> dict:
        return {"successes": self.successes, "distinct": len(self.distinct),
                "distinct_new": len(self.new), "repeat_share": self.repeat_share}


def learned_grasps(proposals, outcomes, demos, *, success: int = 0) -> LearnedGrasps:
    """The measures of one run from its proposals (S, C, 7) and outcomes (S, C), step-major."""
    p = np.asarray(proposals).reshape(-1, 7)
    ok = np.asarray(outcomes).reshape(-1) == success
    distinct = distinct_grasps(p[ok])
    demos = np.asarray(demos).reshape(-1, 7)
    new = distinct[is_new(distinct, demos)] if len(demos) else distinct
    return LearnedGrasps(int(ok.sum()), distinct, new, repeat_share(p))


def canonical_grasps(grasps) -> np.ndarray:
    """Normalize the quaternion part and flip it to qw >= 0 (q and -q are the same rotation)."""
    g = np.array(grasps, dtype=np.float64, copy=True).reshape(-1, 7)
    q = g[:, 3:]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    g[:, 3:] = q
    return g


def unique_grasps(grasps, *, position_tol=1e-4, quaternion_tol=1e-4) -> np.ndarray:
    """Canonical grasps with repeats removed (a chain that stays put re-proposes its state).

    Two grasps are the same when they round to the same grid cell: ``position_tol`` metres,
    ``quaternion_tol`` per quaternion component. Order of first appearance is kept.
    """
    g = canonical_grasps(grasps)
    if len(g) == 0:
        return g
    scale = np.array([position_tol] * 3 + [quaternion_tol] * 4)
    keys = np.round(g / scale).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return g[np.sort(first)]
