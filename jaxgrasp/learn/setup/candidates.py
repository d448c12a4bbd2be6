"""Candidate gripper poses at surface points: the optimized grasps demonstrations start from.

The paper picks random points on the object's surface and finds a gripper orientation there by
optimization (Zech et al. 2015). Here, per surface point ``p`` with outward normal ``n`` (points
facing the table are skipped):

- the gripper pose (orientation ``q`` and the grasp center's small offset from ``p``, see
  ``jaxgrasp.physics.gripper`` for the grasp frame) minimizes a smooth geometric cost on a
  surface point cloud: ``p`` stays between the pads; the surface inside the closing region
  faces the pads (normals along the closing axis: pads antipodal across the local wall); no
  material beyond the open pads, in the pads or in the palm; no gripper corner below the
  support plane; plus an alignment term of one of two start families: approach along
  ``-n`` (family 0: e.g. down onto a rim, pads across the wall below it) or closing axis
  along ``n`` (family 1: pads on both faces of a thin wall, approaching along it);
- it runs with optax (Adam) on the Riemannian gradient of ``q``, each step followed by the
  retraction ``q <- q / |q|`` onto the unit sphere, from 2 x 4 starts (rotations about n).

:func:`rim_poses` adds cheap top-down pinches across a wall (no optimization), and
:func:`edge_poses` tilted pinches of a rim's edge (a plate's lip: one pad on the rim, the other
hooked under its edge).
"""

import os
from concurrent.futures import ThreadPoolExecutor

import jax
import jax.numpy as jnp
import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from jaxgrasp import so3
from jaxgrasp._exported import locked_cache, stored_jit
from jaxgrasp.learn.evaluate.distinct import canonical_grasps
from jaxgrasp.physics import GripperParams
from jaxgrasp.physics.gripper import gripper_corners

__all__ = ["candidate_poses", "rim_poses", "edge_poses", "surface_points", "MIN_NORMAL_Z"]

#: Parts a batch of points is optimized in, at once on threads (as many as there are cores):
#: XLA CPU runs one computation's loops on one thread (40 points on 2 cores: 3.5 s in one
#: part, 2.4 s in two). A constant, not the core count: the poses are those of one machine
#: whatever its cores (other batch shapes round differently, ~1e-6).
PARTS = 2

#: Starts of the orientation search: rotations of the closing axis about the normal.
NUM_STARTS = 4
#: Adam steps and learning rate of the orientation search.
OPT_STEPS = 80
OPT_LR = 0.03
#: Depth of the grasp center below the surface, as a fraction of the pad half length.
DEPTH_FRACTION = 0.6
#: Family-1 starts: the center this far inside the wall along -n (metres).
WALL_DEPTH = 0.002
#: Smoothing length of the soft indicator functions (metres).
SOFT = 0.002
#: Candidate points must not face the table: normal z >= this (approach from above or side).
MIN_NORMAL_Z = -0.3
#: Edge pinches: depression of the closing axis below the horizontal (degrees).
EDGE_TILTS_DEG = (50.0, 55.0, 60.0, 65.0)
#: Edge pinches: grasp-centre offset towards the upper pad, in open half-widths.
EDGE_LIFTS = (0.6, 0.7, 0.8)
#: Edge pinches: grasp-centre offset back along the approach, in pad half lengths.
EDGE_BACKS = (0.25, 0.5)


def rim_poses(points, normals, support_z: float, gripper) -> np.ndarray:
    """Top-down pinches across a wall (thin-walled revolved objects: pitcher, pan, plate rims).

    At each wall point (normal mostly horizontal) the approach is straight down (-z), the
    closing axis along the horizontal normal and the grasp center just inside the wall, at the
    point's height: the pads straddle the wall below a rim. Poses whose open gripper reaches
    below the support plane are dropped (they would be collisions). Returns (k, 7) poses.
    """
    n_h = np.asarray(normals, np.float64).copy()
    n_h[:, 2] = 0.0
    norm = np.linalg.norm(n_h, axis=1)
    wall = norm > 0.7
    p, y = np.asarray(points, np.float64)[wall], n_h[wall] / norm[wall, None]
    z = np.broadcast_to([0.0, 0.0, -1.0], y.shape)
    r = np.stack([np.cross(y, z), y, z], axis=2)  # columns x, y, z of the grasp frame
    center = p - WALL_DEPTH * y
    corners = np.asarray(gripper_corners(gripper), np.float64)
    lowest = (center[:, None, :] + np.einsum("nij,kj->nki", r, corners))[..., 2].min(axis=1)
    keep = lowest >= support_z + 0.001
    quats = _matrices_to_quaternions(r[keep])
    poses = np.concatenate([center[keep], quats], axis=1)
    return canonical_grasps(poses).astype(np.float32) if len(poses) else poses.astype(
        np.float32)


def _wall_frames(points, normals):
    """Wall points (horizontal normal part > 0.7): the points and their unit horizontal normals."""
    n_h = np.asarray(normals, np.float64).copy()
    n_h[:, 2] = 0.0
    norm = np.linalg.norm(n_h, axis=1)
    wall = norm > 0.7
    return np.asarray(points, np.float64)[wall], n_h[wall] / norm[wall, None]


def _poses_above(center, r, support_z, gripper) -> np.ndarray:
    """(k, 7) canonical poses of frames ``r`` at ``center`` whose open gripper stays above."""
    corners = np.asarray(gripper_corners(gripper), np.float64)
    lowest = (center[:, None, :] + np.einsum("nij,kj->nki", r, corners))[..., 2].min(axis=1)
    keep = lowest >= support_z + 0.001
    if not keep.any():
        return np.zeros((0, 7), np.float32)
    quats = _matrices_to_quaternions(r[keep])
    return canonical_grasps(np.concatenate([center[keep], quats], axis=1)).astype(np.float32)


def edge_poses(points, normals, support_z: float, gripper) -> np.ndarray:
    """Tilted pinches of a rim's edge (a plate's lip, where the rim stands off the table).

    At each wall point (normal mostly horizontal, ``y0`` its horizontal part) the closing axis
    points outwards and down, ``EDGE_TILTS_DEG`` below the horizontal, and the approach is
    perpendicular to it in the vertical plane through ``y0`` (in and down): the outer pad
    reaches under the edge, the inner pad comes down on the rim. The grasp centre sits above
    the edge, ``EDGE_LIFTS`` open half-widths towards the inner pad and ``EDGE_BACKS`` pad
    half lengths back along the approach, so the pads close on the edge from both sides
    without the open outer pad reaching below the support plane (poses that would are
    dropped). Returns (k, 7) poses in (tilt, lift, back)-major, point-minor order, so that
    the first successes of a batch lie at different points.
    """
    p, y0 = _wall_frames(points, normals)
    down = np.array([0.0, 0.0, 1.0])
    frames, centres = [], []
    for tilt in EDGE_TILTS_DEG:
        b = np.radians(tilt)
        y = np.cos(b) * y0 - np.sin(b) * down
        z = -np.sin(b) * y0 - np.cos(b) * down
        r = np.stack([np.cross(y, z), y, z], axis=2)
        for lift in EDGE_LIFTS:
            for back in EDGE_BACKS:
                frames.append(r)
                centres.append(p - WALL_DEPTH * y0 - lift * float(gripper.open_width) * y
                               - back * float(gripper.pad_half_size[2]) * z)
    if not len(p):
        return np.zeros((0, 7), np.float32)
    r = np.concatenate(frames)  # (tilt, lift, back)-major, point-minor
    c = np.concatenate(centres)
    return _poses_above(c, r, support_z, gripper)


def surface_points(mesh, count: int, seed: int, *, min_normal_z: float | None = None):
    """``count`` seeded area-uniform surface points and their outward face normals.

    ``min_normal_z``: keep only points whose normal's z component is at least this (a
    gripper cannot approach a surface facing the table from below).
    """
    draw = count if min_normal_z is None else 8 * count
    points, faces = trimesh.sample.sample_surface(mesh, draw, seed=seed)
    normals = np.asarray(mesh.face_normals)[faces]
    if min_normal_z is not None:
        keep = np.flatnonzero(normals[:, 2] >= min_normal_z)[:count]
        points, normals = points[keep], normals[keep]
    return np.asarray(points, np.float32), np.asarray(normals, np.float32)


def _frame_from_normal(n, angle):
    """A rotation matrix with z = -n and y rotated by ``angle`` about n (numpy, (3, 3))."""
    z = -n / np.linalg.norm(n)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    y0 = np.cross(z, helper)
    y0 /= np.linalg.norm(y0)
    x0 = np.cross(y0, z)
    y = np.cos(angle) * y0 + np.sin(angle) * x0
    x = np.cross(y, z)
    return np.stack([x, y, z], axis=1)


def _matrices_to_quaternions(r):
    """(..., 3, 3) rotations -> unit quaternions (..., 4) (w, x, y, z), numerically stable
    branch choice. One scipy call: one per matrix cost a pitcher demo round 0.35 s."""
    r = np.asarray(r, np.float64)
    xyzw = Rotation.from_matrix(r.reshape(-1, 3, 3)).as_quat() if r.size else np.zeros((0, 4))
    return xyzw[:, [3, 0, 1, 2]].reshape(r.shape[:-2] + (4,))


def _box_sdf(p, center, half):
    """Signed distance of points p (..., 3) to an axis-aligned box (negative inside)."""
    d = jnp.abs(p - center) - half
    # sqrt with an epsilon: the plain norm has a NaN gradient at zero.
    outside = jnp.sqrt(jnp.sum(jnp.maximum(d, 0.0) ** 2, axis=-1) + 1e-12)
    inside = jnp.minimum(jnp.max(d, axis=-1), 0.0)
    return outside + inside


def _cost(pose, point, normal, family, cloud, cloud_normals, support_z, gripper):
    """The pose cost of one candidate (pure JAX; ``gripper`` is static).

    ``pose = (q, o)``: orientation and the grasp center's offset from the surface point in
    the grasp frame (``center = point + R o``, so the point sits at ``-o`` between the pads).
    ``family`` 0: approach along -n (pads across the wall under the point); 1: closing axis
    along n (pads on both faces of a thin wall, approach along the wall).
    """
    px, py, pz = (float(v) for v in gripper.pad_half_size)
    open_w = float(gripper.open_width)
    palm_c = jnp.array([0.0, 0.0, gripper.palm_center_z], jnp.float32)
    palm_h = jnp.asarray(gripper.palm_half_size, jnp.float32)
    pad_h = jnp.asarray(gripper.pad_half_size, jnp.float32)
    pads = jnp.array([[0.0, open_w + py, 0.0], [0.0, -(open_w + py), 0.0]], jnp.float32)
    corners = jnp.asarray(gripper_corners(gripper), jnp.float32)

    def soft_pos(x):
        # Squared hinge: exactly zero when clear (sums over many points add no offset).
        return jnp.maximum(x, 0.0) ** 2 / SOFT

    q, o = pose
    r = so3.to_matrix(q / jnp.linalg.norm(q))
    center = point + r @ o
    local = (cloud - center) @ r  # gripper-frame coordinates of the cloud
    local_n = cloud_normals @ r
    aligned = jnp.where(family == 0, 1.0 + jnp.dot(r[:, 2], normal),
                        1.0 - jnp.dot(r[:, 1], normal) ** 2)
    # Material in the closing region (between the pads' x and z extents).
    w = jax.nn.sigmoid((px - jnp.abs(local[:, 0])) / SOFT) * jax.nn.sigmoid(
        (pz - jnp.abs(local[:, 2])) / SOFT)
    facing = jnp.sum(w * (1.0 - local_n[:, 1] ** 2)) / (jnp.sum(w) + 1e-6)
    too_wide = jnp.sum(w * soft_pos(jnp.abs(local[:, 1]) - (open_w - 0.005)))
    hits = soft_pos(-_box_sdf(local, palm_c, palm_h)).sum()
    hits = hits + sum(soft_pos(-_box_sdf(local, c, pad_h)).sum() for c in pads)
    world_corners = center + corners @ r.T
    below = soft_pos(support_z + 0.003 - world_corners[:, 2]).sum()
    # The chosen surface point stays between the pads (the grasp is *at* that point).
    held = (soft_pos(jnp.abs(o[0]) - 0.5 * px) + soft_pos(jnp.abs(o[2]) - 0.8 * pz)
            + soft_pos(jnp.abs(o[1]) - (open_w - 0.005)))
    spread = jnp.sum(o**2) / pz**2
    return (aligned + 0.5 * facing + 0.05 * spread
            + 1000.0 * (too_wide + hits + below + held))


def _solve_all(q0, o0, family, points, normals, cloud, cloud_normals, support_z, gripper):
    """Optimize (N, S) starts at N points; returns quaternions, centers and costs."""
    return _solver(gripper)(q0, o0, family, points, normals, cloud, cloud_normals, support_z)


@locked_cache
def _solver(gripper):
    """:func:`_solve_all` of one gripper, jitted; stored, so a fresh process reads its
    traced program (``jaxgrasp._exported``)."""
    # why: optax is imported only where demonstrations are optimized (0.2 s at import)
    import optax

    # The quaternion moves in units of 1, the offset in metres: separate step sizes.
    opt = optax.multi_transform(
        {"q": optax.adam(OPT_LR), "x": optax.adam(OPT_LR * 0.05)}, ("q", "x"))

    def solve_all(q0, o0, family, points, normals, cloud, cloud_normals, support_z):
        def cost(pose, point, normal, fam):
            return _cost(pose, point, normal, fam, cloud, cloud_normals, support_z, gripper)

        def solve(q, o, fam, point, normal):
            def step(carry, _):
                pose, opt_state = carry
                g_q, g_o = jax.grad(cost)(pose, point, normal, fam)
                q = pose[0]
                g_q = g_q - jnp.dot(g_q, q) * q  # Riemannian gradient: tangent to the unit sphere
                updates, opt_state = opt.update((g_q, g_o), opt_state, pose)
                q, o = optax.apply_updates(pose, updates)
                return ((q / jnp.linalg.norm(q), o), opt_state), None  # retraction onto S^3

            pose = (q, o)
            (pose, _), _ = jax.lax.scan(step, (pose, opt.init(pose)), None, length=OPT_STEPS)
            q, o = pose
            return q, point + so3.to_matrix(q) @ o, cost(pose, point, normal, fam)

        per_start = jax.vmap(solve, in_axes=(0, 0, 0, None, None))
        return jax.vmap(per_start, in_axes=(0, 0, None, 0, 0))(q0, o0, family, points, normals)

    return stored_jit(solve_all, name="candidates", static=repr((gripper, optax.__version__)))


def candidate_poses(obj, points, normals, *, gripper=None, cloud_size: int = 768,
                    seed: int = 0) -> np.ndarray:
    """Optimized gripper poses (N, 7) at surface ``points`` with outward ``normals``.

    Parameters
    ----------
    obj : GraspObject
    points, normals : (N, 3) arrays
    gripper : GripperParams, optional
        Gripper geometry (default: the physics default).
    cloud_size : int
        Surface points used by the cost (collision and antipodal terms).
    seed : int
        Seed of the cost's point cloud.

    Returns
    -------
    (N, 7) float32 poses (x, y, z, qw, qx, qy, qz), unit quaternion with qw >= 0.
    """
    gripper = gripper or GripperParams()
    obj = getattr(obj, "obj", obj)
    points = np.asarray(points, np.float32).reshape(-1, 3)
    normals = np.asarray(normals, np.float32).reshape(-1, 3)
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    cloud, cloud_normals = surface_points(obj.mesh, cloud_size, seed + 7919)
    pz = float(gripper.pad_half_size[2])
    angles = np.pi * np.arange(NUM_STARTS) / NUM_STARTS  # y and -y are the same gripper
    frames, o0 = [], []
    for n in normals:
        rows_o = []
        for a in angles:  # family 0: approach along -n, center below the surface
            frames.append(_frame_from_normal(n, a))
            rows_o.append([0.0, 0.0, DEPTH_FRACTION * pz])
        for a in angles:  # family 1: closing along n, center just inside a thin wall
            f = _frame_from_normal(n, a)
            frames.append(np.stack([f[:, 0], -f[:, 2], f[:, 1]], axis=1))  # y <- n, z <- old y
            rows_o.append([0.0, -WALL_DEPTH, 0.0])
        o0.append(rows_o)
    q0 = _matrices_to_quaternions(np.reshape(frames, (-1, 3, 3)))
    family = np.repeat([0, 1], NUM_STARTS).astype(np.int32)
    rows = (np.asarray(q0, np.float32).reshape(-1, 2 * NUM_STARTS, 4),
            np.asarray(o0, np.float32).reshape(-1, 2 * NUM_STARTS, 3), points, normals)
    shared = (jnp.asarray(cloud), jnp.asarray(cloud_normals), jnp.float32(obj.support_z))

    def solve(part):
        q0, o0, p, n = (jnp.asarray(x) for x in part)
        return jax.device_get(_solve_all(q0, o0, jnp.asarray(family), p, n, *shared, gripper))

    n = len(points)
    k = max(1, min(PARTS, n))
    size = -(-n // k) if n else 0
    # Equal parts (one compiled shape), the last padded with copies of the last point.
    padded = [np.pad(x, [(0, k * size - n)] + [(0, 0)] * (x.ndim - 1), mode="edge")
              for x in rows]
    parts = [tuple(x[lo:lo + size] for x in padded)
             for lo in range(0, k * size, max(size, 1))] or [rows]
    with ThreadPoolExecutor(max(1, min(len(parts), os.cpu_count() or 1))) as pool:
        q, c, final = (np.concatenate(x)[:n] for x in zip(*pool.map(solve, parts), strict=True))
    best = np.argmin(np.where(np.isfinite(final), final, np.inf), axis=1)
    q_best, c_best = q[np.arange(len(q)), best], c[np.arange(len(q)), best]
    return canonical_grasps(np.concatenate([c_best, q_best], axis=1)).astype(np.float32)
