"""Geometry for MJX-ready objects: revolved solids, analytic convex pieces, coverage checks.

Revolved bodies are described by a closed profile polygon in the (r, z) half-plane (CCW, r >= 0)
and a partition of that polygon into convex *cells* (tuples of profile-vertex indices). A cell
revolved over an angular sector is not convex, so each sector piece is the convex hull of a few
samples of the cell on that sector:

* a cell touching the axis becomes one piece: the cell revolved at ``M`` angles (a polygonal
  prism/frustum), radially scaled by ``2 / (1 + cos(pi / M))`` so its chords straddle the
  circle (deviation +-r (1 - cos h) / (1 + cos h), h = pi / M);
* other cells are cut into ``N`` sectors. On faces that look *away* from the axis (outer walls)
  the piece samples ``k`` angles per sector, so the hull follows the arc closely (it lies inside,
  recessed by r (1 - cos(delta / 2)) <= 0.15 mm). A face that looks *towards* the axis (inner
  walls, the top of a plate rim) is concave in the angular direction: whatever the sampling, the
  hull spans it with one chord from sector edge to sector edge, which bulges into the cavity by
  the sagitta s = r (1 - cos h) |n_r| (h = pi / N, n_r the radial part of the face normal).
  Those faces are offset into the material by d = r |n_r| (1 - cos h) / (1 + cos h) ~ s / 2 at
  the sector edges, so the chord deviates +-d instead of +s: half the sagitta, i.e. sqrt(2)
  fewer sectors for the same bound. The sector count of each cell is the smallest one with
  d <= tolerance.

Handles are swept polygons along a polyline with mitred joints: every segment is exactly convex,
so handle pieces are exact and the visual mesh is their union with the revolved body.

Everything here is plain numpy/scipy; trigonometry uses ``math`` (libm) so that regeneration is
bit-for-bit identical across CPUs (numpy's SIMD sin/cos may differ in the last bit).
"""

import math

import numpy as np
from scipy.spatial import ConvexHull

MAX_PIECE_VERTICES = 32


# ----------------------------------------------------------------------------- small helpers
def _cos_sin(angles) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin through libm, one scalar at a time: identical on every x86/ARM machine."""
    a = [float(x) for x in np.atleast_1d(angles)]
    return np.array([math.cos(x) for x in a]), np.array([math.sin(x) for x in a])


def hull_vertices(points) -> np.ndarray:
    """Vertices of the convex hull of ``points``, in input order (deterministic)."""
    points = np.asarray(points, dtype=float)
    hull = ConvexHull(points)
    return points[np.sort(hull.vertices)]


def _edge_normals(poly: np.ndarray) -> np.ndarray:
    """Outward unit normals (n_r, n_z) of the edges i -> i+1 of a CCW polygon in (r, z)."""
    d = np.roll(poly, -1, axis=0) - poly
    n = np.stack([d[:, 1], -d[:, 0]], axis=1)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _signed_area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _chord_factor(h: float) -> float:
    """(1 - cos h) / (1 + cos h): half the relative sagitta of a chord spanning 2h."""
    c = math.cos(h)
    return (1.0 - c) / (1.0 + c)


# ----------------------------------------------------------------------------- revolved mesh
def revolve(profile, num_segments: int) -> tuple[np.ndarray, np.ndarray]:
    """Watertight triangle mesh of a closed (r, z) profile revolved about the z axis.

    Parameters
    ----------
    profile : (P, 2) array
        CCW polygon in the (r, z) half-plane; vertices with r == 0 lie on the axis.
    num_segments : int
        Angular resolution of the visual mesh.

    Returns
    -------
    vertices : (V, 3) float array
    faces : (F, 3) int array, outward winding.
    """
    profile = np.asarray(profile, dtype=float)
    if _signed_area(profile) <= 0:
        raise ValueError("profile must be a counter-clockwise polygon in (r, z)")
    c, s = _cos_sin(2.0 * np.pi * np.arange(num_segments) / num_segments)
    on_axis = profile[:, 0] == 0.0
    index = np.empty(len(profile), dtype=object)
    verts = []
    count = 0
    for i, (r, z) in enumerate(profile):
        if on_axis[i]:
            verts.append(np.array([[0.0, 0.0, z]]))
            index[i] = np.full(num_segments, count)
            count += 1
        else:
            verts.append(np.stack([r * c, r * s, np.full(num_segments, z)], axis=1))
            index[i] = count + np.arange(num_segments)
            count += num_segments
    faces = []
    j = np.arange(num_segments)
    jn = (j + 1) % num_segments
    for i in range(len(profile)):
        k = (i + 1) % len(profile)
        if on_axis[i] and on_axis[k]:
            continue  # an edge on the axis sweeps nothing
        a0, a1, b0, b1 = index[i][j], index[i][jn], index[k][j], index[k][jn]
        # Edge i -> k is CCW in (r, z): outward normal is (dz, -dr); this winding matches it.
        if not on_axis[i]:
            faces.append(np.stack([a0, a1, b0], axis=1))
        if not on_axis[k]:
            faces.append(np.stack([a1, b1, b0], axis=1))
    return np.concatenate(verts), np.concatenate(faces).astype(np.int64)


# ----------------------------------------------------------------------------- sector pieces
def _offset_vertex(p, lines) -> np.ndarray:
    """Intersection of the given offset lines through p (each (normal, offset)); p if none."""
    if not lines:
        return p
    if len(lines) == 1:
        n, d = lines[0]
        return p + d * n
    (n1, d1), (n2, d2) = lines
    a = np.stack([n1, n2])
    if abs(np.linalg.det(a)) < 1e-9:  # (nearly) collinear: shift along the larger offset
        n, d = max(lines, key=lambda t: t[1])
        return p + d * n
    # Displacement v with v . n_i = d_i: the vertex of the inward-offset polygon.
    return p + np.linalg.solve(a, np.array([d1, d2]))


def cell_pieces(
    profile,
    cell,
    *,
    tolerance: float = 0.9e-3,
    dense_tolerance: float = 0.15e-3,
    axis_segments: int = 16,
    num_sectors: int | None = None,
) -> list[np.ndarray]:
    """Convex pieces of one convex profile cell revolved about z (see module docstring).

    Parameters
    ----------
    profile : (P, 2) array
        The whole CCW profile (to tell surface edges from internal ones).
    cell : tuple of int
        CCW indices into ``profile`` of a convex polygon.
    tolerance : float
        Bound on the chord deviation of faces that look towards the axis (metres).
    dense_tolerance : float
        Bound on the (inward) chord recess of faces that look away from the axis.
    axis_segments : int
        Angles of a cell that touches the axis (one piece).
    num_sectors : int, optional
        Force the sector count (default: smallest meeting ``tolerance``).

    Returns
    -------
    list of (V, 3) arrays, hull vertices only, V <= 32.
    """
    profile = np.asarray(profile, dtype=float)
    cell = tuple(int(i) for i in cell)
    poly = profile[list(cell)]
    if _signed_area(poly) <= 0:
        raise ValueError(f"cell {cell} is not a counter-clockwise polygon")
    normals = _edge_normals(poly)
    m = len(cell)
    if np.any(poly[:, 0] == 0.0):
        off = poly[:, 0] > 0.0
        # Fewer angles when the cell has more off-axis vertices, to stay within 32.
        segs = min(axis_segments, MAX_PIECE_VERTICES // max(int(off.sum()), 1))
        c, s = _cos_sin(2.0 * np.pi * np.arange(segs) / segs)
        scale = 2.0 / (1.0 + math.cos(math.pi / segs))
        pts = [np.array([[0.0, 0.0, z]]) for r, z in poly if r == 0.0]
        pts += [np.stack([scale * r * c, scale * r * s, np.full(segs, z)], 1) for r, z in poly[off]]
        return [hull_vertices(np.concatenate(pts))]

    n = len(profile)
    surface = [
        (cell[(e + 1) % m] - cell[e]) % n == 1 for e in range(m)
    ]  # edge e of the cell is an edge of the profile
    toward_axis = normals[:, 0] < -1e-9
    rmax = np.maximum(poly[:, 0], np.roll(poly[:, 0], -1))

    def offsets(h: float) -> np.ndarray:
        d = rmax * np.abs(normals[:, 0]) * _chord_factor(h) * toward_axis
        # An internal edge is offset only where it continues a concave surface edge (the inner
        # wall below the floor line): else that edge's chord would pull the hull into the cavity.
        out = np.where(surface, d, 0.0)
        for e in range(m):
            if not surface[e] and toward_axis[e]:
                nb = [
                    k
                    for k in ((e - 1) % m, (e + 1) % m)
                    if surface[k] and toward_axis[k] and normals[k] @ normals[e] > 0.94
                ]
                if nb:
                    out[e] = min(d[e], max(out[k] for k in nb))
        return out

    if num_sectors is None:
        worst = float(np.max(np.where(surface, rmax * np.abs(normals[:, 0]) * toward_axis, 0)))
        num_sectors = 3
        while worst * _chord_factor(math.pi / num_sectors) > tolerance:
            num_sectors += 1
    h = math.pi / num_sectors
    d = offsets(h)

    dense = np.zeros(m, bool)  # vertices on an edge that looks away from the axis
    extreme_lines = [[] for _ in range(m)]
    for e in range(m):
        a, b = e, (e + 1) % m
        if normals[e, 0] > 1e-9:
            dense[a] = dense[b] = True
        if d[e] > 0:
            # Inward normal of edge e, with its offset: the vertex moves into the material.
            extreme_lines[a].append((-normals[e], d[e]))
            extreme_lines[b].append((-normals[e], d[e]))
    # Angles per sector on outer faces: chord recess r (1 - cos(delta/2)) <= dense_tolerance.
    r_out = float(poly[dense, 0].max()) if dense.any() else 0.0
    k = 2
    while r_out * (1.0 - math.cos(h / (k - 1))) > dense_tolerance:
        k += 1
    needs = int(dense.sum()) * k + 2 * int((~dense).sum())
    if needs > MAX_PIECE_VERTICES:
        raise ValueError(f"cell {cell}: {needs} vertices per piece > {MAX_PIECE_VERTICES}")

    pieces = []
    for sector in range(num_sectors):
        phi0 = 2.0 * h * sector
        ce, se = _cos_sin([phi0, phi0 + 2.0 * h])
        cd, sd = _cos_sin(phi0 + 2.0 * h * np.arange(k) / (k - 1))
        pts = []
        for i in range(m):
            # A vertex of a concave face moves into the material even where it also bounds an
            # outer face (plate rim edge): else the chord of its dense arc would stick out of
            # the concave face. The move is along the outer face, so that face is unchanged.
            r, z = _offset_vertex(poly[i], extreme_lines[i])
            if dense[i]:
                pts.append(np.stack([r * cd, r * sd, np.full(k, z)], 1))
            else:
                pts.append(np.stack([r * ce, r * se, np.full(2, z)], 1))
        pieces.append(hull_vertices(np.concatenate(pts)))
    return pieces


# ----------------------------------------------------------------------------- swept handles
def sweep_pieces(path, section, *, start_normal=None, end_normal=None) -> list[np.ndarray]:
    """Convex pieces of a polygon swept along a polyline in the xz-plane, with mitred joints.

    Parameters
    ----------
    path : (K, 3) array
        Polyline with y = 0 (handles stand in the xz-plane).
    section : (S, 2) array
        Cross-section polygon (u, v): u along the in-plane normal (y x tangent), v along +y.
    start_normal, end_normal : (3,) array, optional
        Normals of the end cut planes (default: the path tangent). A handle that enters a wall
        is cut by the plane x = const so its end stays inside the wall.

    Returns
    -------
    list of (2S, 3) arrays, one exactly convex piece per path segment.
    """
    path = np.asarray(path, dtype=float)
    section = np.asarray(section, dtype=float)
    t = np.diff(path, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    y = np.array([0.0, 1.0, 0.0])
    planes = [np.asarray(start_normal if start_normal is not None else t[0], float)]
    for i in range(1, len(path) - 1):
        b = t[i - 1] + t[i]  # mitre plane: bisects the turn
        planes.append(b / np.linalg.norm(b))
    planes.append(np.asarray(end_normal if end_normal is not None else t[-1], float))
    pieces = []
    for i in range(len(t)):
        u = np.cross(y, t[i])
        rings = []
        for j, plane in ((i, planes[i]), (i + 1, planes[i + 1])):
            q = path[i] + section[:, :1] * u + section[:, 1:] * y
            # Slide each section point along the segment's tangent onto the cut plane at j.
            lam = ((path[j] - q) @ plane) / float(t[i] @ plane)
            rings.append(q + lam[:, None] * t[i])
        pieces.append(np.concatenate(rings))
    return pieces


def chamfered_rectangle(half_u: float, half_v: float, chamfer: float) -> np.ndarray:
    """Octagonal section: a rectangle with 45-degree chamfered corners, CCW in (u, v)."""
    a, b, c = half_u, half_v, chamfer
    return np.array(
        [[a, -b + c], [a, b - c], [a - c, b], [-a + c, b], [-a, b - c], [-a, -b + c],
         [-a + c, -b], [a - c, -b]]
    )


# ----------------------------------------------------------------------------- distances
def _point_triangle_distance(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Euclidean distance of points (P, 3) to triangles (T, 3, 3) -> (P, T) (Ericson 5.1.5)."""
    a, b, c = tri[None, :, 0], tri[None, :, 1], tri[None, :, 2]
    p = p[:, None, :]
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.sum(ab * ap, -1), np.sum(ac * ap, -1)
    bp = p - b
    d3, d4 = np.sum(ab * bp, -1), np.sum(ac * bp, -1)
    cp = p - c
    d5, d6 = np.sum(ab * cp, -1), np.sum(ac * cp, -1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = np.where(denom != 0, vb / denom, 0.0)
        w = np.where(denom != 0, vc / denom, 0.0)
        closest = a + ab * v[..., None] + ac * w[..., None]  # interior
        tab = np.clip(d1 / (d1 - d3), 0, 1)
        tac = np.clip(d2 / (d2 - d6), 0, 1)
        tbc = np.clip((d4 - d3) / ((d4 - d3) + (d5 - d6)), 0, 1)
    on_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    on_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    on_bc = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
    closest = np.where(on_bc[..., None], b + (c - b) * np.nan_to_num(tbc)[..., None], closest)
    closest = np.where(on_ac[..., None], a + ac * np.nan_to_num(tac)[..., None], closest)
    closest = np.where(on_ab[..., None], a + ab * np.nan_to_num(tab)[..., None], closest)
    closest = np.where(((d6 >= 0) & (d5 <= d6))[..., None], c, closest)
    closest = np.where(((d3 >= 0) & (d4 <= d3))[..., None], b, closest)
    closest = np.where(((d1 <= 0) & (d2 <= 0))[..., None], a, closest)
    return np.linalg.norm(p - closest, axis=-1)


def distance_to_pieces(points, pieces, *, cutoff: float = 5e-3) -> np.ndarray:
    """Distance of each point to the union of convex pieces (0 inside), exact up to ``cutoff``.

    Distances above ``cutoff`` are reported as a lower bound (the largest face-plane excess).
    """
    points = np.asarray(points, dtype=float)
    best = np.full(len(points), np.inf)
    for piece in pieces:
        hull = ConvexHull(np.asarray(piece, dtype=float))
        excess = np.max(points @ hull.equations[:, :3].T + hull.equations[:, 3], axis=1)
        inside = excess <= 0.0
        best[inside] = 0.0
        near_mask = ~inside & (excess < np.minimum(best, cutoff))
        far = ~inside & ~near_mask  # excess is a lower bound of the distance to this piece
        best[far] = np.minimum(best[far], excess[far])
        near = np.flatnonzero(near_mask)
        tri = hull.points[hull.simplices]
        for chunk in np.array_split(near, max(1, len(near) // 2048 + 1)):
            if len(chunk):
                dist = _point_triangle_distance(points[chunk], tri).min(axis=1)
                best[chunk] = np.minimum(best[chunk], dist)
    return best


def distance_outside_profile(points, profile) -> np.ndarray:
    """Distance of 3-D points to the solid of revolution of ``profile`` (0 inside); exact."""
    points = np.asarray(points, dtype=float)
    rz = np.stack([np.hypot(points[:, 0], points[:, 1]), points[:, 2]], axis=1)
    poly = np.asarray(profile, dtype=float)
    a, b = poly, np.roll(poly, -1, axis=0)
    ab = b - a
    t = np.clip(
        np.einsum("pkd,kd->pk", rz[:, None, :] - a[None], ab) / np.sum(ab * ab, 1), 0.0, 1.0
    )
    closest = a[None] + t[..., None] * ab[None]
    dist = np.linalg.norm(rz[:, None, :] - closest, axis=-1).min(axis=1)
    # Even-odd ray casting along +r for the inside test.
    y = rz[:, 1:2]
    crosses = (a[None, :, 1] > y) != (b[None, :, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        r_at = a[None, :, 0] + (y - a[None, :, 1]) * ab[None, :, 0] / ab[None, :, 1]
    inside = np.sum(crosses & (rz[:, :1] < r_at), axis=1) % 2 == 1
    return np.where(inside, 0.0, dist)


def sample_hull_surfaces(pieces, count_per_piece: int, rng) -> np.ndarray:
    """Area-uniform random points on the boundary of each convex piece."""
    out = []
    for piece in pieces:
        hull = ConvexHull(np.asarray(piece, dtype=float))
        tri = hull.points[hull.simplices]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        idx = rng.choice(len(tri), size=count_per_piece, p=area / area.sum())
        u, v = rng.random((2, count_per_piece))
        flip = u + v > 1
        u, v = np.where(flip, 1 - u, u), np.where(flip, 1 - v, v)
        t = tri[idx]
        out.append(t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0]))
    return np.concatenate(out)
