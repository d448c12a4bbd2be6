"""Grasp atlas: an object's distinct successful grasps from a large structured search.

The atlas is the ground truth the learners' coverage is measured against. Candidates are
structured, not sampled around demos, in two families over area-uniform surface points
(normals not facing the table):

- wall-aligned (most of the budget, :func:`wall_poses`): at a point whose normal is mostly
  horizontal (``|n_h| > 0.7``) the base frame is the top-down wall pinch of
  :func:`jaxgrasp.learn.setup.demos.rim_poses` (closing axis y = horizontal normal, approach
  z = -z_world, centre ``WALL_DEPTH`` inside the wall at the point's height); at any other
  point (rim tops, the top and underside of a handle) two base frames approach along the
  inward normal (z = -n) with the closing axis the horizontal radial or tangential direction
  (about the mesh's bounding-box axis), centre 0.6 pad half lengths inside the surface. Each
  base frame is perturbed by tilts of the approach about its x and y axes
  (``WALL_TILTS_X_DEG``, ``WALL_TILTS_Y_DEG``), rotations about the approach
  (``WALL_SPINS_DEG``) and centre offsets along the base approach (``WALL_OFFSETS``); wall
  points more than ``WALL_MAX_DEPTH`` below the end of their wall are dropped (the palm would
  hit the rim);
- sphere (:func:`sphere_poses`, on ``num_points // SPHERE_POINTS_DIVISOR`` points): approach
  directions (the gripper's +z axis, object frame) on a Fibonacci sphere plus straight down,
  kept where ``dot(approach, outward normal) < 0.3`` (not from inside the surface), x
  rotations about the approach (6 angles in [0, pi): the gripper is symmetric under 180°), x
  2 depths: grasp centre = point + depth * approach, depth in {0.6, 1.2} x pad half length.

Poses whose open gripper reaches below the support plane are dropped.

The wall family assumes a vessel (walls that end in a rim). For any other mesh the atlas
(``kind="any"``) seeds with a quarter of its trials each from the sphere family and the field's
antipodal sampler (:func:`any_poses`; :func:`jaxgrasp.learn.setup.antipodal.antipodal_grasps`:
friction-cone pairs across the solid, the approach uniform about the closing axis), then
spends the rest flooding out from its distinct successes (:func:`neighbour_poses`: each grasp
moved 1.2 cm along, or turned 12° about, each axis of its frame; a neighbour that is the same
grasp as one already tried is not tried again), most robust first, round by round, until the
trials are spent or no new distinct success is left to expand; then, trials left, a new
quarter of antipodal seeds and their flood (``SEED_ROUNDS`` at most). Placement collisions of
the antipodal and flood candidates are dropped before any rollout. Every candidate runs on
the MuJoCo C backend; the successes are reduced to distinct grasps (1 cm / 10°, 180° symmetry,
:func:`jaxgrasp.learn.evaluate.distinct.distinct_grasps`), most robust (highest epsilon) first.

Shipped as ``assets/atlas/<name>.npz``; rebuild with::

    python -m jaxgrasp.learn.evaluate.atlas pitcher pan tall_pitcher --trials 100000 --seed 0
    python -m jaxgrasp.learn.evaluate.atlas random_222 --kind any --trials 50000 --seed 0
"""

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import NamedTuple

import jax
import numpy as np
from scipy.spatial.transform import Rotation

from jaxgrasp.learn.evaluate.distinct import (
    ANGLE_TOL,
    POSITION_TOL,
    canonical_grasps,
    count_same,
    distinct_grasps,
    distinct_indices,
    same_as_any,
)
from jaxgrasp.learn.setup.antipodal import antipodal_grasps, placement_collisions
from jaxgrasp.learn.setup.candidates import (
    DEPTH_FRACTION,
    MIN_NORMAL_Z,
    WALL_DEPTH,
    edge_poses,
    surface_points,
)
from jaxgrasp.objects import load_any, shipped
from jaxgrasp.physics import GripperParams, Outcome, load_scene, make_trial
from jaxgrasp.physics.gripper import gripper_corners

__all__ = ["Atlas", "atlas_poses", "any_poses", "neighbour_poses", "wall_poses", "sphere_poses",
           "build_atlas", "save_atlas", "load_atlas", "atlas_dir", "atlas_grasps"]

#: Fibonacci-sphere approach directions (straight down is added on top).
NUM_DIRECTIONS = 20
#: Rotations about the approach, in [0, pi).
NUM_ROTATIONS = 6
#: Grasp-centre depths along the approach, in pad half lengths.
DEPTHS = (0.6, 1.2)
#: An approach is kept where dot(approach, outward normal) < this.
MAX_APPROACH_DOT = 0.3
#: Wall family: a point is a wall point where its normal's horizontal part exceeds this.
WALL_MIN_HORIZONTAL = 0.7
#: Wall family: a wall point is kept where its wall ends (the first surface straight above the
#: centre, inside the wall) at most this far above it (metres): deeper pinches put the palm on
#: the rim, so they are all collisions.
WALL_MAX_DEPTH = 0.03
#: Wall family: tilts of the approach about the base frame's x axis (degrees). This tilts the
#: closing axis out of the horizontal, pads no longer parallel to the wall: beyond ~10° the
#: trials slip (measured on the pitcher), so the grid is narrow.
WALL_TILTS_X_DEG = (-10.0, 0.0, 10.0)
#: Wall family: tilts of the approach about the base frame's y (closing) axis (degrees).
WALL_TILTS_Y_DEG = (-30.0, -15.0, 0.0, 15.0, 30.0)
#: Wall family: rotations about the (tilted) approach (degrees).
WALL_SPINS_DEG = (-20.0, -10.0, 0.0, 10.0, 20.0)
#: Wall family: grasp-centre offsets along the base approach (metres; + = deeper / lower).
WALL_OFFSETS = (0.0, -0.01, 0.01)
#: The sphere family runs on num_points // this surface points.
SPHERE_POINTS_DIVISOR = 4
#: Any-mesh atlas: shares of the trials seeded by the antipodal and the sphere family (the rest
#: floods out from their distinct successes).
ANTIPODAL_SHARE = 0.25
SPHERE_SHARE = 0.25
#: Flood steps: along each axis of the grasp frame (metres) and about it (degrees); a little
#: over the same-grasp tolerances (1 cm, 10°), so each neighbour is a distinct grasp.
NEIGHBOUR_STEP = 0.012
NEIGHBOUR_TURN_DEG = 12.0
# neighbour_poses' kinds of step: a move, then a turn, along and about -x, +x, -y, ... each
_STEP_KINDS = 12
#: A ranked flood's neighbourhood (times the same-grasp tolerances), its kind prior's weight
#: (pseudo-trials), its smallest round (neighbours rolled out between two rankings) and the
#: share of the budget left a larger round takes (1 / RANK_SHARE).
RANK_REACH = 1.5
RANK_PRIOR = 2.0
RANK_ROUND = 64
RANK_SHARE = 16
#: Rounds of antipodal seeds at most (a new round where the flood ran dry with trials left).
SEED_ROUNDS = 4
#: Rounds of surface points per antipodal seeding (:func:`antipodal_grasps`): where the table
#: blocks nearly every pair (a flat part lying down), fewer seeds, the sphere and flood fill up.
SEED_POINT_ROUNDS = 64
#: Bump when the candidate generator changes (stored in the atlas settings).
VERSION = 2
#: Atlas kinds: the wall-aligned vessel atlas, or antipodal + sphere for any mesh.
KINDS = ("vessel", "any")

REBUILD = "python -m jaxgrasp.learn.evaluate.atlas {name} --trials 100000 --seed 0"
REBUILD_ANY = "python -m jaxgrasp.learn.evaluate.atlas {name} --kind any --trials 50000 --seed 0"


class Atlas(NamedTuple):
    """grasps (k, 7) distinct successful grasps; trial/success/slip counts; build seconds."""

    grasps: np.ndarray
    trials: int
    successes: int
    slipped: int
    seconds: float
    settings: dict


def atlas_dir() -> Path:
    """``assets/atlas`` (follows ``$JAXGRASP_ASSETS`` like the shipped objects)."""
    return shipped.assets_dir() / "atlas"


def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z**2)
    phi = math.pi * (3.0 - math.sqrt(5.0)) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _directions() -> np.ndarray:
    return np.concatenate([_fibonacci_sphere(NUM_DIRECTIONS), [[0.0, 0.0, -1.0]]])


def _frames(approach: np.ndarray) -> np.ndarray:
    """(D, R, 3, 3) grasp frames (columns x, y, z) with z = approach, y rotated about z."""
    z = approach / np.linalg.norm(approach, axis=1, keepdims=True)
    helper = np.where(np.abs(z[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    y0 = np.cross(z, helper)
    y0 /= np.linalg.norm(y0, axis=1, keepdims=True)
    x0 = np.cross(y0, z)
    ang = math.pi * np.arange(NUM_ROTATIONS) / NUM_ROTATIONS
    y = np.cos(ang)[None, :, None] * y0[:, None] + np.sin(ang)[None, :, None] * x0[:, None]
    zz = np.broadcast_to(z[:, None], y.shape)
    x = np.cross(y, zz)
    return np.stack([x, y, zz], axis=-1)


def _default_gripper(gripper):
    return GripperParams() if gripper is None else gripper


def _to_poses(centres, frames) -> np.ndarray:
    """(N, 3) centres and (N, 3, 3) frames -> canonical (N, 7) float32 poses."""
    if len(centres) == 0:
        return np.zeros((0, 7), np.float32)
    quats = Rotation.from_matrix(frames).as_quat()[:, [3, 0, 1, 2]]
    return canonical_grasps(np.concatenate([centres, quats], axis=1)).astype(np.float32)


def _axis_rotations(axis: int, angles_deg) -> np.ndarray:
    """(A, 3, 3) rotations about a coordinate axis (0 = x, 1 = y, 2 = z)."""
    a = np.deg2rad(np.asarray(angles_deg, np.float64))
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    r = np.zeros((len(a), 3, 3))
    r[:, axis, axis] = 1.0
    r[:, i, i] = c
    r[:, j, j] = c
    r[:, i, j] = -s
    r[:, j, i] = s
    return r


def _perturbations() -> np.ndarray:
    """(K, 3, 3) local perturbations Rx(a) Ry(b) Rz(c), a, b tilts, c spin (x-major order)."""
    rx = _axis_rotations(0, WALL_TILTS_X_DEG)
    ry = _axis_rotations(1, WALL_TILTS_Y_DEG)
    rz = _axis_rotations(2, WALL_SPINS_DEG)
    p = np.einsum("aij,bjk,ckl->abcil", rx, ry, rz)
    return p.reshape(-1, 3, 3)


def _first_hit_above(mesh, origins, chunk: int = 512) -> np.ndarray:
    """(N,) distance from each origin straight up (+z) to the first mesh triangle (inf: none).

    A vertical ray hits a triangle where its xy lies in the triangle's xy projection; the hit
    height is the barycentric interpolation of the vertex heights (numpy, no ray library).
    """
    tri = np.asarray(mesh.triangles, np.float64)  # (F, 3, 3)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    v0, v1 = b[:, :2] - a[:, :2], c[:, :2] - a[:, :2]
    det = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
    ok = np.abs(det) > 1e-14
    a, b, c, v0, v1, det = a[ok], b[ok], c[ok], v0[ok], v1[ok], det[ok]
    out = np.full(len(origins), np.inf)
    for lo in range(0, len(origins), chunk):
        o = np.asarray(origins[lo:lo + chunk], np.float64)
        d = o[:, None, :2] - a[None, :, :2]  # (n, F, 2)
        u = (d[..., 0] * v1[:, 1] - d[..., 1] * v1[:, 0]) / det
        v = (v0[:, 0] * d[..., 1] - v0[:, 1] * d[..., 0]) / det
        inside = (u >= 0) & (v >= 0) & (u + v <= 1)
        z = (1 - u - v) * a[:, 2] + u * b[:, 2] + v * c[:, 2]
        h = np.where(inside & (z > o[:, None, 2]), z - o[:, None, 2], np.inf)
        out[lo:lo + chunk] = h.min(axis=1) if h.shape[1] else np.inf
    return out


def _base_frames(obj, points, normals, gripper):
    """Base frames (B, 3, 3), their centres (B, 3) and owning point index (B,)."""
    n_h = normals.copy()
    n_h[:, 2] = 0.0
    norm_h = np.linalg.norm(n_h, axis=1)
    wall_like = norm_h > WALL_MIN_HORIZONTAL
    # wall points whose wall ends within WALL_MAX_DEPTH above (deeper ones are dropped)
    wall = wall_like.copy()
    idx_wall = np.flatnonzero(wall)
    inside = points[idx_wall] - WALL_DEPTH * n_h[idx_wall] / norm_h[idx_wall, None]
    wall[idx_wall[_first_hit_above(obj.mesh, inside) > WALL_MAX_DEPTH]] = False
    down = np.array([0.0, 0.0, -1.0])
    frames, centres, owner = [], [], []
    # wall points: the rim_poses pinch
    if wall.any():
        y = n_h[wall] / norm_h[wall, None]
        z = np.broadcast_to(down, y.shape)
        frames.append(np.stack([np.cross(y, z), y, z], axis=2))
        centres.append(points[wall] - WALL_DEPTH * y)
        owner.append(np.flatnonzero(wall))
    # other points: approach along the inward normal, closing radial or tangential
    idx = np.flatnonzero(~wall_like)
    if len(idx):
        lo, hi = np.asarray(obj.mesh.bounds, np.float64)
        axis_xy = 0.5 * (lo[:2] + hi[:2])
        z = -normals[idx]
        radial = np.zeros((len(idx), 3))
        radial[:, :2] = points[idx, :2] - axis_xy
        r_norm = np.linalg.norm(radial, axis=1)
        radial = np.where(r_norm[:, None] > 1e-6, radial / np.maximum(r_norm, 1e-9)[:, None],
                          [[1.0, 0.0, 0.0]])
        tangential = np.cross([0.0, 0.0, 1.0], radial)
        centre = points[idx] + DEPTH_FRACTION * float(gripper.pad_half_size[2]) * z
        for d in (radial, tangential):
            y = d - np.sum(d * z, axis=1, keepdims=True) * z
            y_norm = np.linalg.norm(y, axis=1, keepdims=True)
            good = y_norm[:, 0] > 0.2  # degenerate where the direction is along the normal
            y = y[good] / y_norm[good]
            frames.append(np.stack([np.cross(y, z[good]), y, z[good]], axis=2))
            centres.append(centre[good])
            owner.append(idx[good])
    if not frames:
        return np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0, np.int64)
    return np.concatenate(frames), np.concatenate(centres), np.concatenate(owner)


def _unit_surface(obj, num_points, seed):
    """Seeded area-uniform surface points (float64) and unit outward normals."""
    points, normals = surface_points(obj.mesh, int(num_points), int(seed),
                                     min_normal_z=MIN_NORMAL_Z)
    normals = normals.astype(np.float64)
    return points.astype(np.float64), normals / np.linalg.norm(normals, axis=1, keepdims=True)


def wall_poses(obj, *, num_points: int, seed: int, gripper=None) -> np.ndarray:
    """Wall-aligned candidates (N, 7) float32, object frame (the atlas's main family).

    Base frames (:func:`_base_frames`: wall points first, then the other points' radial and
    tangential frames), each x the ``len(WALL_TILTS_X_DEG) * len(WALL_TILTS_Y_DEG) *
    len(WALL_SPINS_DEG)``
    perturbations ``R_base @ Rx(a) @ Ry(b) @ Rz(c)`` x ``WALL_OFFSETS`` (centre + offset * base
    approach), in that nesting order; poses whose open gripper reaches below the support plane
    are dropped.
    """
    gripper = _default_gripper(gripper)
    obj = getattr(obj, "obj", obj)
    points, normals = _unit_surface(obj, num_points, seed)
    base, centre, _ = _base_frames(obj, points, normals, gripper)
    frames = np.einsum("bij,kjl->bkil", base, _perturbations())  # (B, K, 3, 3)
    offsets = np.asarray(WALL_OFFSETS, np.float64)
    centres = centre[:, None, :] + offsets[None, :, None] * base[:, None, :, 2]  # (B, O, 3)
    corners = np.asarray(gripper_corners(gripper), np.float64)
    low = np.einsum("bkij,cj->bkci", frames, corners)[..., 2].min(axis=-1)  # (B, K)
    above = centres[:, None, :, 2] + low[:, :, None] >= float(obj.support_z) + 0.001
    shape = above.shape  # (B, K, O)
    c_all = np.broadcast_to(centres[:, None], shape + (3,))[above]
    f_all = np.broadcast_to(frames[:, :, None], shape + (3, 3))[above]
    return _to_poses(c_all, f_all)


def edge_family(obj, *, num_points: int, seed: int, gripper=None) -> np.ndarray:
    """Edge-pinch candidates (N, 7) float32 (objects held by their edge: the plates): the
    tilted pinches of :func:`jaxgrasp.learn.setup.candidates.edge_poses` at the wall points, each
    spun about its approach by ``WALL_SPINS_DEG``; poses reaching below the support dropped."""
    gripper = _default_gripper(gripper)
    obj = getattr(obj, "obj", obj)
    points, normals = _unit_surface(obj, num_points, seed)
    base = edge_poses(points, normals, float(obj.support_z), gripper)
    if len(base) == 0:
        return np.zeros((0, 7), np.float32)
    rot = Rotation.from_quat(base[:, [4, 5, 6, 3]]).as_matrix()
    frames = np.einsum("bij,kjl->bkil", rot, _axis_rotations(2, WALL_SPINS_DEG))
    centres = np.broadcast_to(base[:, None, :3].astype(np.float64), frames.shape[:2] + (3,))
    corners = np.asarray(gripper_corners(gripper), np.float64)
    low = np.einsum("bkij,cj->bkci", frames, corners)[..., 2].min(axis=-1)
    above = centres[..., 2] + low >= float(obj.support_z) + 0.001
    return _to_poses(centres[above], frames[above])


def atlas_poses(obj, *, num_points: int, seed: int, gripper=None, edge: bool = False
                ) -> np.ndarray:
    """All atlas candidates (N, 7) float32: :func:`wall_poses` on ``num_points`` points, then
    :func:`sphere_poses` on ``max(1, num_points // SPHERE_POINTS_DIVISOR)`` points (seed + 1),
    then with ``edge`` :func:`edge_family` on ``num_points`` points (seed + 2).
    """
    families = [
        wall_poses(obj, num_points=num_points, seed=seed, gripper=gripper),
        sphere_poses(obj, num_points=max(1, int(num_points) // SPHERE_POINTS_DIVISOR),
                     seed=int(seed) + 1, gripper=gripper),
    ]
    if edge:
        families.append(edge_family(obj, num_points=num_points, seed=int(seed) + 2,
                                    gripper=gripper))
    return np.concatenate(families)


def sphere_poses(obj, *, num_points: int, seed: int, gripper=None) -> np.ndarray:
    """Sphere-family candidates (N, 7) float32 ``(x, y, z, qw, qx, qy, qz)``, object frame.

    For each of ``num_points`` surface points (in point order): approach directions (in
    :func:`_directions` order) with ``dot(approach, normal) < 0.3``, x ``NUM_ROTATIONS``
    rotations, x ``DEPTHS``; poses whose open gripper reaches below the support plane are
    dropped. Unit quaternions with qw >= 0.
    """
    gripper = _default_gripper(gripper)
    obj = getattr(obj, "obj", obj)
    points, normals = _unit_surface(obj, num_points, seed)
    dirs = _directions()
    frames = _frames(dirs)  # (D, R, 3, 3)
    depths = np.asarray(DEPTHS) * float(gripper.pad_half_size[2])
    corners = np.asarray(gripper_corners(gripper), np.float64)
    # lowest corner offset (z) of each frame, relative to the grasp centre
    low = np.einsum("drij,kj->drki", frames, corners)[..., 2].min(axis=-1)  # (D, R)
    ok_dir = normals @ dirs.T < MAX_APPROACH_DOT  # (P, D)
    # centres (P, D, G, 3)
    centres = points[:, None, None, :] + depths[None, None, :, None] * dirs[None, :, None, :]
    # (P, D, R, G): above the support plane
    above = centres[:, :, None, :, 2] + low[None, :, :, None] >= float(obj.support_z) + 0.001
    keep = ok_dir[:, :, None, None] & above
    shape = keep.shape
    c_all = np.broadcast_to(centres[:, :, None], shape + (3,))[keep]
    quats = Rotation.from_matrix(frames.reshape(-1, 3, 3)).as_quat()[:, [3, 0, 1, 2]]
    quats = quats.reshape(frames.shape[:2] + (4,))
    q_all = np.broadcast_to(quats[None, :, :, None], shape + (4,))[keep]
    poses = np.concatenate([c_all, q_all], axis=1)
    if len(poses) == 0:
        return np.zeros((0, 7), np.float32)
    return canonical_grasps(poses).astype(np.float32)


def any_poses(obj, *, num_trials: int, seed: int, gripper=None, collides=None):
    """Seed candidates of the any-mesh atlas (N, 7) float32, the sphere points, and counts.

    ``ceil(ANTIPODAL_SHARE * num_trials)`` antipodal grasps (seed ``seed + 3``; ``collides``
    drops placement collisions before they count), or those found in ``SEED_POINT_ROUNDS``
    rounds of surface points, then :func:`sphere_poses` on the fewest points giving the rest of
    ``ceil((ANTIPODAL_SHARE + SPHERE_SHARE) * num_trials)`` (seed ``seed + 1``). Raises
    ValueError where the mesh has no collision-free antipodal pair (the sampler says why).
    """
    gripper = _default_gripper(gripper)
    obj = getattr(obj, "obj", obj)
    num_antipodal = int(math.ceil(ANTIPODAL_SHARE * num_trials))
    anti = antipodal_grasps(obj, num_antipodal, seed=int(seed) + 3, gripper=gripper,
                            collides=collides, max_rounds=SEED_POINT_ROUNDS, fewer=True)
    rest = int(math.ceil((ANTIPODAL_SHARE + SPHERE_SHARE) * num_trials)) - len(anti.poses)
    sphere = _enough(lambda n: sphere_poses(obj, num_points=n, seed=int(seed) + 1,
                                            gripper=gripper), rest, obj.name)
    counts = {"antipodal_grasps": int(len(anti.poses)), "antipodal_points": anti.points,
              "antipodal_pairs": anti.pairs, "antipodal_collisions": anti.collisions,
              "sphere_grasps": int(len(sphere[0]))}
    return np.concatenate([anti.poses, sphere[0]]).astype(np.float32), sphere[1], counts


def neighbour_poses(grasps) -> np.ndarray:
    """(12 n, 7) float32: each grasp moved by ``NEIGHBOUR_STEP`` along -x, +x, -y, ... of its
    own frame, then turned by ``NEIGHBOUR_TURN_DEG`` about -x, +x, ... (grasp-major order)."""
    g = _unit_rows(grasps)
    if len(g) == 0:
        return np.zeros((0, 7), np.float32)
    rot = Rotation.from_quat(g[:, [4, 5, 6, 3]]).as_matrix()  # (n, 3, 3)
    signs = np.array([-1.0, 1.0])
    moves = (signs[None, :, None, None] * NEIGHBOUR_STEP * np.swapaxes(rot, 1, 2)[:, None])
    moved = g[:, None, None, :3] + moves  # (n, 2, 3 axes, 3)
    moved = np.swapaxes(moved, 1, 2).reshape(len(g), 6, 3)
    turns = np.concatenate([_axis_rotations(k, signs * NEIGHBOUR_TURN_DEG) for k in range(3)])
    turned = np.einsum("nij,kjl->nkil", rot, turns)  # (n, 6, 3, 3)
    centres = np.concatenate([moved, np.broadcast_to(g[:, None, :3], (len(g), 6, 3))], axis=1)
    frames = np.concatenate([np.broadcast_to(rot[:, None], (len(g), 6, 3, 3)), turned], axis=1)
    return _to_poses(centres.reshape(-1, 3), frames.reshape(-1, 3, 3))


def _unit_rows(grasps) -> np.ndarray:
    g = np.asarray(grasps, np.float64).reshape(-1, 7).copy()
    g[:, 3:] /= np.linalg.norm(g[:, 3:], axis=1, keepdims=True)
    return g


def _enough(poses_on, num_trials: int, name: str):
    """``poses_on(num_points)`` of the smallest tried ``num_points`` giving >= num_trials."""
    num_points = max(8, num_trials // 400)
    for _ in range(20):
        poses = poses_on(num_points)
        if len(poses) >= num_trials:
            return poses, num_points
        per_point = max(len(poses), 1) / num_points
        num_points = max(num_points + 1, int(math.ceil(1.02 * num_trials / per_point)))
    raise RuntimeError(f"could not generate {num_trials} candidates on {name!r}")


def _enough_poses(obj, num_trials: int, seed: int, gripper=None, edge: bool = False):
    """The candidates of the smallest tried ``num_points`` giving >= num_trials poses."""
    return _enough(lambda n: atlas_poses(obj, num_points=n, seed=seed, gripper=gripper,
                                         edge=edge), num_trials, obj.name)


def build_atlas(obj, *, num_trials: int = 100_000, seed: int = 0, batch: int = 1024,
                progress: bool = True, edge: bool = False, kind: str = "vessel") -> Atlas:
    """Run the structured candidates (>= ``num_trials``) on MuJoCo C; keep distinct successes.

    ``obj``: a GraspObject or a shipped object's name (a kitchen object or ``random_NNN``).
    Every generated candidate is tried (the count is >= num_trials). Successes are ordered by
    epsilon (descending, stable) before the greedy reduction, so each distinct grasp is
    represented by its most robust member.
    ``edge``: add the edge-pinch family (:func:`edge_family`; version 3), for the plates.
    ``kind``: ``"vessel"`` (the wall and sphere families) or ``"any"`` (:func:`any_poses`:
    antipodal and sphere families, for a mesh that is not a vessel).
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    if isinstance(obj, str):
        obj = load_any(obj)
    t0 = time.perf_counter()
    scene = load_scene(obj)
    trial = make_trial(scene, backend="mujoco")
    outcome, epsilon = [], []

    def run(poses):
        """Roll out ``poses`` in padded batches (one compiled shape); record the results."""
        done = sum(map(len, outcome))
        out_o, out_e = np.empty(len(poses), np.int32), np.zeros(len(poses), np.float32)
        for lo in range(0, len(poses), batch):
            chunk = poses[lo:lo + batch]
            n = len(chunk)
            if n < batch:
                chunk = np.concatenate([chunk, np.repeat(chunk[:1], batch - n, axis=0)])
            res = jax.device_get(trial(chunk))
            out_o[lo:lo + n] = np.asarray(res.outcome)[:n]
            out_e[lo:lo + n] = np.nan_to_num(np.asarray(res.epsilon, np.float32)[:n], nan=0.0)
            if progress:
                held = sum(int((o == Outcome.SUCCESS).sum()) for o in outcome + [out_o[:lo + n]])
                print(f"\r{obj.name}: {done + lo + n} trials, {held} successes, "
                      f"{time.perf_counter() - t0:.0f} s", end="", file=sys.stderr, flush=True)
        outcome.append(out_o)
        epsilon.append(out_e)
        return out_o, out_e

    counts_any = {}
    if kind == "any":
        collides = placement_collisions(scene)
        poses, num_points, counts_any = any_poses(obj, num_trials=int(num_trials),
                                                  seed=int(seed), collides=collides)
        state, rolled = {"tried": [], "found": np.zeros((0, 7))}, [poses]
        for r in range(SEED_ROUNDS):
            if r:  # the flood ran dry with trials left: more antipodal seeds, a new region?
                seeds = antipodal_grasps(obj, int(math.ceil(ANTIPODAL_SHARE * num_trials)),
                                         seed=int(seed) + 3 + r, collides=collides,
                                         max_rounds=SEED_POINT_ROUNDS, fewer=True)
                poses = seeds.poses
                for k, v in (("grasps", len(poses)), ("points", seeds.points),
                             ("pairs", seeds.pairs), ("collisions", seeds.collisions)):
                    counts_any[f"antipodal_{k}"] += int(v)
                rolled.append(poses)
            o, e = run(poses)
            left = int(num_trials) - sum(map(len, rolled))
            flood, counts = _flood(run, poses, o, e, collides, left, state)
            rolled.append(flood)
            for k, v in counts.items():
                counts_any[k] = counts_any.get(k, 0) + v
            if sum(map(len, rolled)) >= int(num_trials):
                break
        counts_any["seed_rounds"] = r + 1
        poses = np.concatenate(rolled)
    else:
        poses, num_points = _enough_poses(obj, int(num_trials), int(seed), edge=edge)
        run(poses)
    if progress:
        print(file=sys.stderr)
    outcome, epsilon = np.concatenate(outcome), np.concatenate(epsilon)
    ok = np.flatnonzero(outcome == Outcome.SUCCESS)
    ok = ok[np.argsort(-epsilon[ok], kind="stable")]
    grasps = canonical_grasps(distinct_grasps(poses[ok])).astype(np.float32)
    counts = np.bincount(outcome, minlength=4)
    settings = {
        "version": VERSION + int(edge), "edge_family": bool(edge), "kind": kind,
        "object": obj.name, **counts_any,
        **({"flood_untried_first": True} if kind == "any" else {}),
        "content_hash": obj.content_hash,
        "num_trials": int(num_trials), "seed": int(seed), "num_points": int(num_points),
        "wall_min_horizontal": WALL_MIN_HORIZONTAL, "wall_depth": WALL_DEPTH,
        "wall_max_depth": WALL_MAX_DEPTH, "wall_tilts_x_deg": list(WALL_TILTS_X_DEG),
        "wall_tilts_y_deg": list(WALL_TILTS_Y_DEG), "wall_spins_deg": list(WALL_SPINS_DEG),
        "wall_offsets": list(WALL_OFFSETS), "depth_fraction": DEPTH_FRACTION,
        "sphere_points_divisor": SPHERE_POINTS_DIVISOR,
        "num_directions": NUM_DIRECTIONS + 1, "num_rotations": NUM_ROTATIONS,
        "depths": list(DEPTHS), "max_approach_dot": MAX_APPROACH_DOT,
        "min_normal_z": MIN_NORMAL_Z, "position_tol": POSITION_TOL, "angle_tol": ANGLE_TOL,
        "backend": "mujoco", "outcome_counts": {o.name.lower(): int(counts[o]) for o in Outcome},
    }
    return Atlas(grasps, int(len(poses)), int(len(ok)), int(counts[Outcome.SLIPPED]),
                 float(time.perf_counter() - t0), settings)


def _flood(run, poses, outcome, epsilon, collides, budget: int, state=None):
    """Flood out from the distinct successes of ``poses`` for up to ``budget`` more rollouts
    (``run(poses) -> (outcome, epsilon)``). ``state`` (``{"tried": [...], "found": (k, 7)}``,
    updated) carries what earlier floods tried and found: they are not tried or expanded
    again. Returns the poses rolled out and counts."""
    state = {"tried": [], "found": np.zeros((0, 7))} if state is None else state
    state["tried"].append(poses)
    ok = np.flatnonzero(outcome == Outcome.SUCCESS)
    start = distinct_grasps(poses[ok[np.argsort(-epsilon[ok], kind="stable")]])
    start = start[~same_as_any(start, state["found"])] if len(state["found"]) else start
    state["found"] = np.concatenate([state["found"], start])
    return flood(run, start, collides, budget, state)


def flood(run, frontier, collides, budget: int, state, expand=None, cost: int = 1,
          first=None, near: float = 1.0, defer: int = 0, rank: bool = False):
    """Roll out the neighbours (:func:`neighbour_poses`) of ``frontier``, then of the new
    distinct successes among them, and so on, for up to ``budget`` trials.

    ``run(poses) -> (outcome, epsilon)``; ``collides(poses) -> bool mask`` (skipped before a
    rollout); ``state`` (``{"tried": [(n, 7), ...], "found": (k, 7)}``, updated): neighbours
    the same grasp as anything tried are not tried, successes the same as anything found are
    not new. ``expand(new) -> (frontier, trials)``: which new successes to go on from, and the
    trials that choice spent (default: all of them, none); ``cost``: the most one neighbour
    may spend in all, its rollout and what ``expand`` spends on it (a round tries at most
    ``budget // cost`` of them, so the budget holds). ``first`` (k, 7), optional: poses from
    elsewhere (another sampler's) that join the first round's neighbours, filtered the same
    way. ``near`` < 1: a neighbour counts as tried only within ``near`` times the same-grasp
    distance (1 cm / 10°) of a pose tried before, so a grasp where one pose failed is tried
    again at a pose that far from every tried one (unless it is the same grasp as one found).
    ``defer``: the neighbours of the ``defer`` kinds of step (of the 12) that have held least
    often so far in this flood wait while others are queued (the budget goes first where
    grasps hold; with budget to spare every neighbour is still tried). ``rank``: where the
    queue holds more than a round (a sixteenth of the budget left, at least 64:
    :data:`RANK_SHARE`, :data:`RANK_ROUND`), the round's neighbours are those most likely to
    hold: those with the most successes and fewest failures of this
    flood within 1.5 cm / 15° (:data:`RANK_REACH`), their kind of step's share of successes
    as a prior (:func:`hold_odds`). Returns the poses rolled out (in order) and counts.
    """
    tol = {"position_tol": near * POSITION_TOL, "angle_tol": near * ANGLE_TOL}
    # each kind of step's successes and rollouts so far, from a uniform prior (1 of 2)
    kind_held, kind_rolled = np.ones(_STEP_KINDS), np.full(_STEP_KINDS, 2.0)

    def successes(p, o, e):
        ok = np.flatnonzero(o == Outcome.SUCCESS)
        return distinct_grasps(p[ok[np.argsort(-e[ok], kind="stable")]])

    def untried(cand, kinds):
        # untried first, then one per grasp: every untried neighbour is then one rolled out
        # or the same grasp as one (the same-grasp test is not transitive)
        fresh = ~same_as_any(cand, np.concatenate(state["tried"]), **tol)
        cand, kinds = cand[fresh], kinds[fresh]
        keep = distinct_indices(cand, **tol)
        cand, kinds = _unit_rows(cand)[keep], kinds[keep]
        if near < 1.0 and len(cand) and len(state["found"]):
            new = ~same_as_any(cand, state["found"])  # found: it would not be new
            cand, kinds = cand[new], kinds[new]
        state["tried"].append(_to_float32(cand))
        hit = np.asarray(collides(cand), bool) if len(cand) else np.zeros(0, bool)
        counts["flood_collisions"] += int(hit.sum())
        return _to_float32(cand[~hit]), kinds[~hit]

    rolled, rounds, counts, failed = [], 0, {"flood_collisions": 0}, [np.zeros((0, 7))]
    reach = {"position_tol": RANK_REACH * POSITION_TOL, "angle_tol": RANK_REACH * ANGLE_TOL}

    def around(poses, held, missed):
        # (2, n) successes and failures of this flood around each pose, for its ranking
        if not rank or not len(poses):
            return np.zeros((2, len(poses)))
        return np.stack([count_same(poses, held, **reach),
                         count_same(poses, missed, **reach)]).astype(np.float64)

    # poses from elsewhere (kind -1, never deferred) are first in line, then the neighbours
    queue, kinds = ((np.zeros((0, 7), np.float32), np.zeros(0, np.int64)) if first is None
                    or not len(first) else untried(first, np.full(len(first), -1)))
    near_by = around(queue, state["found"], failed[0])
    while budget > 0 and (len(frontier) or len(queue)):
        # the neighbours a round cannot afford wait for the next, first in line
        more, more_kinds = untried(neighbour_poses(frontier),
                                   np.tile(np.arange(_STEP_KINDS), len(frontier)))
        near_by = np.concatenate([near_by, around(more, state["found"],
                                                  np.concatenate(failed))], axis=1)
        queue, kinds = np.concatenate([queue, more]), np.concatenate([kinds, more_kinds])
        go = np.ones(len(queue), bool)
        if defer:
            go = ~np.isin(kinds, np.argsort(kind_held / kind_rolled, kind="stable")[:defer])
            go = go if go.any() else ~go
        pick = np.flatnonzero(go)
        size = max(RANK_ROUND, (budget // cost) // RANK_SHARE)
        if rank and len(pick) > size:  # a choice: the likeliest to hold first
            odds = hold_odds(*near_by[:, pick], kinds[pick], kind_held / kind_rolled)
            pick = np.sort(pick[np.argsort(-odds, kind="stable")[:size]])
        pick = pick[:budget // cost]
        if len(pick) == 0:
            break
        cand, step = queue[pick], kinds[pick]
        wait = np.ones(len(queue), bool)
        wait[pick] = False
        queue, kinds, near_by = queue[wait], kinds[wait], near_by[:, wait]
        o, e = run(cand)
        rolled.append(cand)
        budget -= len(cand)
        rounds += 1
        ours = step >= 0
        np.add.at(kind_held, step[ours], (o[ours] == Outcome.SUCCESS))
        np.add.at(kind_rolled, step[ours], 1.0)
        if rank:  # what a ranking counts against a neighbour
            failed.append(np.asarray(cand, np.float64)[o != Outcome.SUCCESS])
        new = successes(cand, o, e)
        new = new[~same_as_any(new, state["found"])] if len(new) and len(state["found"]) else new
        state["found"] = np.concatenate([state["found"], new])
        near_by += around(queue, new, failed[-1] if rank else None)  # the counts go on
        frontier, spent = expand(new) if expand is not None and len(new) else (new, 0)
        budget -= spent
    out = np.concatenate(rolled) if rolled else np.zeros((0, 7), np.float32)
    return out, {"flood_rounds": rounds, "flood_grasps": int(len(out)), **counts}


def hold_odds(s, f, kinds, kind_rate) -> np.ndarray:
    """(n,) each candidate's chance to hold as the poses around it say: ``s`` successes and
    ``f`` failures within :data:`RANK_REACH` of it, with its kind of step's rate
    ``kind_rate[kinds]`` as :data:`RANK_PRIOR` pseudo-trials (kind -1, poses from elsewhere:
    first in line)."""
    prior = np.asarray(kind_rate)[np.maximum(kinds, 0)]
    odds = (s + RANK_PRIOR * prior) / (s + f + RANK_PRIOR)
    return np.where(kinds < 0, np.inf, odds)


def _to_float32(g) -> np.ndarray:
    return canonical_grasps(g).astype(np.float32) if len(g) else np.zeros((0, 7), np.float32)


def save_atlas(name: str, atlas: Atlas, *, directory=None) -> Path:
    """Write ``<directory or assets/atlas>/<name>.npz`` (arrays only)."""
    d = Path(directory) if directory is not None else atlas_dir()
    d.mkdir(parents=True, exist_ok=True)
    path = d / f"{name}.npz"
    np.savez_compressed(
        path, grasps=np.asarray(atlas.grasps, np.float32).reshape(-1, 7),
        trials=np.int64(atlas.trials), successes=np.int64(atlas.successes),
        slipped=np.int64(atlas.slipped), seconds=np.float64(atlas.seconds),
        settings=np.asarray(json.dumps(atlas.settings, sort_keys=True)))
    return path


def load_atlas(name: str, *, directory=None) -> Atlas:
    """The shipped atlas of an object (FileNotFoundError naming the rebuild command)."""
    d = Path(directory) if directory is not None else atlas_dir()
    path = d / f"{name}.npz"
    if not path.is_file():
        rebuild = REBUILD if name in shipped.names() else REBUILD_ANY
        raise FileNotFoundError(f"no grasp atlas for {name!r} at {path}; build it with "
                                f"`{rebuild.format(name=name)}`")
    with np.load(path, allow_pickle=False) as z:
        return Atlas(np.asarray(z["grasps"], np.float32), int(z["trials"]),
                     int(z["successes"]), int(z["slipped"]), float(z["seconds"]),
                     json.loads(str(z["settings"])))


def atlas_grasps(name: str, *, directory=None) -> np.ndarray | None:
    """The shipped atlas's grasps (k, 7) of an object, or None where it has none."""
    try:
        return np.asarray(load_atlas(name, directory=directory).grasps)
    except FileNotFoundError:
        return None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m jaxgrasp.learn.evaluate.atlas",
                                 description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("objects", nargs="+", metavar="OBJECT",
                    help="shipped object names (kitchen objects or random_NNN)")
    ap.add_argument("--trials", type=int, default=100_000, help="minimum trials per object")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--batch", type=int, default=1024)
    ap.add_argument("--edge", action="store_true",
                    help="add the edge-pinch family (objects held by their edge: the plates)")
    ap.add_argument("--kind", choices=KINDS, default="vessel",
                    help="vessel: wall and sphere families; any: antipodal and sphere families")
    args = ap.parse_args(argv)
    for name in args.objects:
        atlas = build_atlas(name, num_trials=args.trials, seed=args.seed, batch=args.batch,
                            edge=args.edge, kind=args.kind)
        path = save_atlas(name, atlas)
        print(f"{name}: trials={atlas.trials} successes={atlas.successes} "
              f"slipped={atlas.slipped} distinct={len(atlas.grasps)} "
              f"seconds={atlas.seconds:.0f} -> {path}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
