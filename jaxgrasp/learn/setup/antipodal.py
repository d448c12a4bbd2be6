"""Antipodal grasp sampling: the field's standard parallel-jaw sampler (as behind ACRONYM).

1. area-uniform surface points ``p`` with outward normals ``n_p``
   (:func:`~jaxgrasp.learn.setup.candidates.surface_points`);
2. a ray from ``p`` along the inward normal ``-n_p`` finds the opposite surface ``q``, where
   the ray leaves the solid (:func:`opposite_points`; coincident faces of two touching convex
   parts, as in meshes assembled from a convex decomposition, are passed through);
3. the pair is kept when both normals lie inside the friction cone about the closing axis
   ``a = (q - p) / |q - p|`` (``-n_p . a >= cos theta`` and ``n_q . a >= cos theta``,
   ``theta = atan(mu)``) and its width ``|q - p|`` fits the open gripper;
4. the grasp centre is the midpoint, the grasp frame's ``y`` (closing axis, see
   :mod:`jaxgrasp.physics.gripper`) is ``a`` and its ``z`` (approach) is drawn uniformly
   about ``a`` (:func:`grasp_frames`); the centre then moves along the approach by a depth
   drawn uniformly within :data:`DEPTH_FRACTION` of the pad half length, so the pair stays
   between the pads (ACRONYM samples this standoff too): at the midpoint itself the 4 cm pads
   of a grasp from above reach under the table on any object lower than 4 cm;
5. grasps whose open gripper collides at placement are dropped before any physics: one
   MuJoCo C collision pass per grasp, no rollout (:func:`placement_collisions`).
"""

from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from jaxgrasp.learn.evaluate.distinct import canonical_grasps
from jaxgrasp.learn.setup.candidates import surface_points
from jaxgrasp.physics import GripperParams

__all__ = ["AntipodalGrasps", "antipodal_grasps", "antipodal_pairs", "grasp_frames",
           "opposite_points", "placement_collisions", "ray_hits", "reference_axes",
           "some_antipodal_grasps"]

#: Distance (m) below which an exit and an entry along a ray are one internal face pair, and
#: the ray origin's offset outside the surface.
FACE_TOL = 1e-4
#: Hits kept per ray (sorted by distance); the random objects cross at most a few parts.
MAX_HITS = 16
#: Ray-triangle tests per numpy block (memory: ~200 bytes each).
BLOCK = 500_000
#: Surface points drawn per round (at least; more when many grasps are asked for).
ROUND_POINTS = 4096
#: Rounds of surface points before giving up (a 3 cm bar lying on the table keeps ~1 pair in
#: 700: the table blocks most approaches about a horizontal closing axis).
MAX_ROUNDS = 512
#: Rounds for :func:`some_antipodal_grasps` (an ingredient, not the sampler): a pitcher gives
#: thousands in one; where the table blocks nearly every pair (a plate lying flat) it stops.
FEW_ROUNDS = 16
#: Open-width margin (m): a pair this close to the opening would touch an open pad.
WIDTH_MARGIN = 0.005
#: Depth range of the centre along the approach, as a fraction of the pad half length.
DEPTH_FRACTION = 0.75


class AntipodalGrasps(NamedTuple):
    """Collision-free antipodal grasps and what it took to find them.

    Attributes
    ----------
    poses : (n, 7) float32
        Grasps (x, y, z, qw, qx, qy, qz), canonical (qw >= 0), in the order drawn.
    widths : (n,) float32
        Distance between the contact pair of each grasp (metres).
    depths : (n,) float32
        How far the centre sits back along the approach from the pair's midpoint (metres):
        the midpoint is ``centre + depth * z``.
    points : int
        Surface points drawn.
    pairs : int
        Antipodal pairs among them (friction cone and width tests passed).
    collisions : int
        Pairs dropped for a placement collision (decided without a rollout).
    """

    poses: np.ndarray
    widths: np.ndarray
    depths: np.ndarray
    points: int
    pairs: int
    collisions: int


def ray_hits(origins, dirs, triangles, normals=None, *, max_hits: int = MAX_HITS):
    """The first ``max_hits`` hits of each ray, nearest first (Moller-Trumbore in numpy:
    trimesh's ray module needs rtree, which is not a dependency).

    Returns
    -------
    t : (n, K) distances along the unit ``dirs`` (inf: no hit)
    face : (n, K) triangle indices
    exits : (n, K) bool, whether the ray leaves the solid there (face normal along the ray);
        None without ``normals``
    """
    origins = np.asarray(origins, np.float64).reshape(-1, 3)
    dirs = np.asarray(dirs, np.float64).reshape(-1, 3)
    triangles = np.asarray(triangles, np.float64)
    n, f = len(origins), len(triangles)
    k = min(max_hits, f)
    t_out = np.full((n, k), np.inf)
    face_out = np.zeros((n, k), np.int64)
    v0 = triangles[:, 0]
    e1, e2 = triangles[:, 1] - v0, triangles[:, 2] - v0
    step = max(1, BLOCK // max(f, 1))
    for lo in range(0, n, step):
        o, d = origins[lo:lo + step, None, :], dirs[lo:lo + step, None, :]
        pvec = np.cross(d, e2)
        det = np.sum(e1 * pvec, axis=-1)
        ok = np.abs(det) > 1e-15
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tvec = o - v0
        u = np.sum(tvec * pvec, axis=-1) * inv
        qvec = np.cross(tvec, e1)
        v = np.sum(d * qvec, axis=-1) * inv
        t = np.sum(e2 * qvec, axis=-1) * inv
        eps = 1e-9  # hits on a shared edge count for both triangles: no ray slips through
        hit = ok & (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps) & (t > 0)
        t = np.where(hit, t, np.inf)
        idx = np.argsort(t, axis=1)[:, :k]
        t_out[lo:lo + step] = np.take_along_axis(t, idx, axis=1)
        face_out[lo:lo + step] = idx
    if normals is None:
        return t_out, face_out, None
    exits = np.einsum("nkj,nj->nk", np.asarray(normals, np.float64)[face_out], dirs) > 0
    return t_out, face_out, exits


def opposite_points(mesh, points, normals, *, tol: float = FACE_TOL):
    """Where a ray from each surface point along its inward normal leaves the solid.

    Coincident faces of touching parts (an exit and an entry within ``tol`` along the ray)
    are interior and skipped; a point on such an interior face is not on the surface.

    Returns
    -------
    ok : (n,) bool
        The point is on the outer surface and the ray leaves the solid.
    q : (n, 3) float64
        The exit points (undefined where not ``ok``).
    n_q : (n, 3) float64
        Outward normals at ``q``.
    """
    p = np.asarray(points, np.float64).reshape(-1, 3)
    d = -np.asarray(normals, np.float64).reshape(-1, 3)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    origins = p - 2 * tol * d  # just outside: the point's own face is the first entry
    face_normals = np.asarray(mesh.face_normals, np.float64)
    t, face, exits = ray_hits(origins, d, mesh.triangles, face_normals)
    finite = np.isfinite(t)
    with np.errstate(invalid="ignore"):  # inf - inf between two missing hits: not near
        near = np.abs(t[:, :, None] - t[:, None, :]) < tol
    twin = near & (exits[:, :, None] != exits[:, None, :]) & finite[:, None, :]
    inner = twin.any(axis=2) & finite
    own = finite & ~exits & ~inner & (np.abs(t - 2 * tol) < tol)
    beyond = finite & exits & ~inner & (t > 3 * tol)
    first = np.argmax(beyond, axis=1)
    ok = own.any(axis=1) & beyond.any(axis=1)
    rows = np.arange(len(p))
    q = origins + t[rows, first, None] * d
    return ok, np.where(ok[:, None], q, 0.0), face_normals[face[rows, first]]


def antipodal_pairs(mesh, points, normals, *, max_width: float, cone_deg: float):
    """Surface point pairs across the solid that a parallel-jaw gripper could pinch.

    Parameters
    ----------
    mesh : trimesh.Trimesh
    points, normals : (n, 3) arrays
        Surface points and their outward normals.
    max_width : float
        Widest pair kept (metres).
    cone_deg : float
        Friction-cone half angle (degrees): both normals within it of the closing axis.

    Returns
    -------
    keep : (n,) bool
    p, q : (n, 3) float64
        The pairs (``q`` the opposite point; rows not kept are undefined).
    """
    p = np.asarray(points, np.float64).reshape(-1, 3)
    n_p = np.asarray(normals, np.float64).reshape(-1, 3)
    n_p = n_p / np.linalg.norm(n_p, axis=1, keepdims=True)
    ok, q, n_q = opposite_points(mesh, p, n_p)
    axis = q - p
    width = np.linalg.norm(axis, axis=1)
    a = axis / np.maximum(width, 1e-12)[:, None]
    cos = np.cos(np.radians(cone_deg))
    inside = (np.sum(-n_p * a, axis=1) >= cos) & (np.sum(n_q * a, axis=1) >= cos)
    keep = ok & inside & (width > 2 * FACE_TOL) & (width <= max_width)
    return keep, p, q


def reference_axes(axes):
    """Unit vectors ``u`` perpendicular to each unit axis (the zero of the approach angle)."""
    a = np.asarray(axes, np.float64).reshape(-1, 3)
    helper = np.where((np.abs(a[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    u = np.cross(a, helper)
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def grasp_frames(axes, angles):
    """Rotations (n, 3, 3) whose ``y`` column is the closing axis ``axes`` and ``z`` (approach)
    is ``cos(angle) u + sin(angle) (axis x u)`` with ``u`` :func:`reference_axes`."""
    y = np.asarray(axes, np.float64).reshape(-1, 3)
    y = y / np.linalg.norm(y, axis=1, keepdims=True)
    u = reference_axes(y)
    v = np.cross(y, u)
    ang = np.asarray(angles, np.float64).reshape(-1, 1)
    z = np.cos(ang) * u + np.sin(ang) * v
    return np.stack([np.cross(y, z), y, z], axis=2)


def placement_collisions(sim_or_scene):
    """``poses (n, 7) -> (n,) bool``: whether the open gripper collides where it is placed
    (a corner below the support plane or a penetration beyond the protocol's tolerance),
    decided by one MuJoCo C collision pass per grasp, without a rollout (the engine of a
    MuJoCo C trial, else one built for the scene)."""
    # why: MuJoCo C is loaded only where grasps are filtered (the sampler package never is)
    from jaxgrasp.physics.mujoco_backend import MujocoEngine
    from jaxgrasp.physics.scene import load_scene

    engine = getattr(getattr(sim_or_scene, "trial", None), "engine", None)
    if engine is None:
        scene = getattr(sim_or_scene, "scene", None)
        if scene is None:
            scene = sim_or_scene if hasattr(sim_or_scene, "gripper") else load_scene(
                getattr(sim_or_scene, "obj", sim_or_scene))
        engine = MujocoEngine(scene, nthread=1)
    return lambda poses: np.asarray(engine.place(np.asarray(poses, np.float64))[1], bool)


def antipodal_grasps(obj, num: int, *, seed: int = 0, gripper=None, friction=None,
                     collides=None, max_rounds: int = MAX_ROUNDS,
                     fewer: bool = False) -> AntipodalGrasps:
    """``num`` antipodal grasps of ``obj``, seeded, collision-free where ``collides`` says.

    Parameters
    ----------
    obj : GraspObject (or anything with ``.obj`` / ``.mesh``)
    num : int
        Grasps wanted.
    seed : int
        Seeds the surface points and the approach angles.
    gripper : GripperParams, optional
        Its ``max_opening`` (less :data:`WIDTH_MARGIN`) bounds the pair width, its
        ``pad_friction`` sets the cone and its pad length the depth range (default: the
        physics default).
    friction : float, optional
        Friction coefficient of the cone ``atan(friction)`` (default ``gripper.pad_friction``).
    collides : callable ``(k, 7) -> (k,) bool``, optional
        Placement collision test (:func:`placement_collisions`); None keeps every pair.
    max_rounds : int
        Rounds of surface points (:data:`ROUND_POINTS` or more each) before giving up.
    fewer : bool
        Return the grasps found when fewer than ``num`` are (default: a ValueError).

    Returns
    -------
    AntipodalGrasps
        Raises ValueError when fewer than ``num`` are found (the counts say why), unless
        ``fewer``.
    """
    if not isinstance(num, int | np.integer) or num < 1:
        raise ValueError(f"num must be a positive int, got {num!r}")
    gripper = gripper or GripperParams()
    mu = float(gripper.pad_friction if friction is None else friction)
    if not mu > 0:
        raise ValueError(f"friction must be positive, got {friction!r}")
    cone_deg = float(np.degrees(np.arctan(mu)))
    max_width = float(gripper.max_opening) - WIDTH_MARGIN
    obj = getattr(obj, "obj", obj)
    rng = np.random.default_rng(seed)
    per_round = max(ROUND_POINTS, 2 * int(num))
    max_depth = DEPTH_FRACTION * float(gripper.pad_half_size[2])
    poses, widths, depths = [], [], []
    drawn = pairs = collisions = found = 0
    for _ in range(max_rounds):
        pts, nrm = surface_points(obj.mesh, per_round, int(rng.integers(2**31)))
        keep, p, q = antipodal_pairs(obj.mesh, pts, nrm, max_width=max_width,
                                     cone_deg=cone_deg)
        drawn += len(pts)
        p, q = p[keep], q[keep]
        pairs += len(p)
        # One angle and depth per drawn point, used or not: neither depends on the filter.
        angles = rng.uniform(0.0, 2 * np.pi, len(pts))[keep]
        depth = rng.uniform(-max_depth, max_depth, len(pts))[keep]
        if not len(p):
            continue
        axis = (q - p) / np.linalg.norm(q - p, axis=1, keepdims=True)
        frames = grasp_frames(axis, angles)
        quats = Rotation.from_matrix(frames).as_quat()[:, [3, 0, 1, 2]]  # (w, x, y, z)
        centre = (p + q) / 2 - depth[:, None] * frames[:, :, 2]
        g = canonical_grasps(np.concatenate([centre, quats], axis=1))
        w = np.linalg.norm(q - p, axis=1)
        if collides is not None:
            hit = np.asarray(collides(g), bool)
            collisions += int(hit.sum())
            g, w, depth = g[~hit], w[~hit], depth[~hit]
        poses.append(g[: num - found])
        widths.append(w[: num - found])
        depths.append(depth[: num - found])
        found += len(poses[-1])
        if found >= num:
            break
    if found < num and not (fewer and found):
        raise ValueError(
            f"only {found} of {num} antipodal grasps on {getattr(obj, 'name', 'the object')!r} "
            f"after {drawn} surface points ({pairs} antipodal pairs within the "
            f"{max_width * 1e3:.0f} mm opening and the {cone_deg:.0f} deg cone, {collisions} "
            "of them colliding at placement)")
    return AntipodalGrasps(np.concatenate(poses).astype(np.float32),
                           np.concatenate(widths).astype(np.float32),
                           np.concatenate(depths).astype(np.float32), drawn, pairs, collisions)


def some_antipodal_grasps(obj, num: int, *, seed: int, gripper=None, collides=None) -> np.ndarray:
    """Up to ``num`` collision-free antipodal grasps (k, 7), k = 0 where :data:`FEW_ROUNDS`
    rounds of surface points place none: for callers that go on without them."""
    try:
        return antipodal_grasps(obj, num, seed=seed, gripper=gripper, collides=collides,
                                max_rounds=FEW_ROUNDS, fewer=True).poses
    except ValueError:  # no pair placed
        return np.zeros((0, 7), np.float32)
