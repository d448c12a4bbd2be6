"""User meshes (OBJ/STL/PLY) -> GraspObject: validate, repair, decompose with CoACD, cache.

Assumptions (documented in :func:`from_mesh`): the file is in metres (``scale`` converts), the
object stands upright along +z (it is moved so its lowest point is at z = 0; x and y are kept),
and it is a uniform solid of density 1000 kg/m^3 unless ``density`` or ``mass`` says otherwise.
"""

import hashlib
import numbers
import os
import warnings
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import ConvexHull

from jaxgrasp.objects.base import GraspObject
from jaxgrasp.objects.decompose import MAX_PIECE_VERTICES

SUPPORTED_FORMATS = (".obj", ".stl", ".ply")
DEFAULT_DENSITY = 1000.0  # kg/m^3: water, i.e. solid plastic/wood; pass density= or mass=
MIN_EXTENT = 5e-3  # m: below 5 mm contacts (resolved to 1 mm, patch_tol) mean nothing
MAX_EXTENT = 100.0  # m: beyond this the file is in the wrong units or not an object at all
MM_WARNING_EXTENT = 1.0  # m: a kitchen object this large is most likely in millimetres
#: More triangles take minutes to repair and decompose (a 1.3M-triangle sphere: 170 s); the
#: physics only uses <= 16 convex pieces of <= 32 vertices, so simplify the mesh first.
MAX_FACES = 200_000
_CACHE_VERSION = "1"


class MeshError(ValueError):
    """A user mesh that can't be used; the message names the file and the problem."""


class MeshFileNotFoundError(MeshError, FileNotFoundError):
    """The mesh file does not exist."""


def cache_dir() -> Path:
    """``$XDG_CACHE_HOME/jaxgrasp/objects`` (default ``~/.cache/jaxgrasp/objects``)."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "jaxgrasp" / "objects"


def reduce_hull(points, max_vertices: int = MAX_PIECE_VERTICES) -> np.ndarray:
    """At most ``max_vertices`` hull vertices of ``points``, chosen to lose the least volume.

    Greedy furthest-point insertion (quickhull's order): start from a tetrahedron of extreme
    points, then repeatedly add the point furthest outside the current hull. The result is an
    inner approximation whose error shrinks fastest where the shape sticks out most.
    """
    points = np.asarray(points, dtype=float)
    hull = ConvexHull(points)
    cand = points[np.sort(hull.vertices)]
    if len(cand) <= max_vertices:
        return cand
    i0 = int(np.argmin(cand[:, 0]))
    i1 = int(np.argmax(np.linalg.norm(cand - cand[i0], axis=1)))
    d = cand[i1] - cand[i0]
    d /= np.linalg.norm(d)
    rel = cand - cand[i0]
    i2 = int(np.argmax(np.linalg.norm(rel - np.outer(rel @ d, d), axis=1)))
    n = np.cross(cand[i1] - cand[i0], cand[i2] - cand[i0])
    i3 = int(np.argmax(np.abs(rel @ n)))
    chosen = list(dict.fromkeys([i0, i1, i2, i3]))
    while len(chosen) < max_vertices:
        eq = ConvexHull(cand[chosen]).equations
        excess = np.max(cand @ eq[:, :3].T + eq[:, 3], axis=1)
        excess[chosen] = -np.inf
        best = int(np.argmax(excess))
        if excess[best] <= 0:
            break
        chosen.append(best)
    return cand[np.sort(chosen)]


def _is_real(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)


def _fail(path, problem) -> MeshError:
    return MeshError(f"{path}: {problem}")


def _read(path: Path):
    try:
        loaded = trimesh.load(str(path), file_type=path.suffix[1:].lower(), force="mesh",
                              process=False)
    except Exception as e:  # noqa: BLE001 - any parser failure becomes one clear message
        fmt = path.suffix[1:].upper()
        # trimesh needs an optional encoding detector for bytes that are not UTF-8 text.
        why = "neither binary nor UTF-8 text" if isinstance(e, ImportError) else e
        raise _fail(path, f"could not read it as {fmt} ({why}); is it really a {fmt} "
                          "mesh file?") from None
    if not isinstance(loaded, trimesh.Trimesh):
        raise _fail(path, "empty mesh (no triangles found)")
    return loaded


def _repair(mesh, path: Path):
    """Merge duplicate vertices, drop degenerate/duplicate faces, make winding consistent."""
    mesh.merge_vertices()
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        raise _fail(path, "degenerate mesh: every triangle has zero area (zero volume)")
    trimesh.repair.fix_winding(mesh)
    if not mesh.is_watertight:
        mesh = _fill_holes(mesh)
    if not mesh.is_watertight:
        raise _fail(path, "mesh is not watertight (open boundary or non-manifold edges) and "
                          "could not be repaired by closing small holes; export a closed solid")
    trimesh.repair.fix_winding(mesh)
    if not mesh.is_winding_consistent:
        raise _fail(path, "non-manifold mesh: triangle winding can't be made consistent")
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def _fill_holes(mesh, max_loop: int = 64):
    """Close simple boundary loops (each at most ``max_loop`` vertices) with triangle fans.

    Only holes whose boundary is a set of simple loops are touched: a boundary vertex with more
    than one outgoing boundary edge means non-manifold geometry, which is left for the caller
    to reject. (trimesh.repair.fill_holes needs networkx, which we don't depend on.)
    """
    faces = np.asarray(mesh.faces)
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = np.sort(directed, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    boundary = directed[counts[inverse.ravel()] == 1]
    if len(boundary) == 0:
        return mesh
    nxt = {}
    for a, b in boundary:
        if a in nxt:
            return mesh  # two boundary edges leave one vertex: not a simple hole
        nxt[int(a)] = int(b)
    new, seen = [], set()
    for start in sorted(nxt):
        if start in seen:
            continue
        loop, v = [], start
        while v not in seen:
            seen.add(v)
            loop.append(v)
            v = nxt.get(v)
            if v is None:
                return mesh
        if v != start or len(loop) < 3 or len(loop) > max_loop:
            return mesh
        # The hole's edges run a -> b in the existing faces; the patch uses b -> a.
        new += [(loop[0], loop[i + 1], loop[i]) for i in range(1, len(loop) - 1)]
    return trimesh.Trimesh(mesh.vertices, np.concatenate([faces, np.array(new)]), process=False)


def _decompose(mesh, max_pieces: int, threshold: float) -> list:
    """Convex pieces (<= 32 vertices each): the hull if the mesh is convex, else CoACD."""
    hull = mesh.convex_hull
    if mesh.volume >= 0.99 * hull.volume:  # already convex: one exact piece
        return [reduce_hull(mesh.vertices)]
    # coacd is a large native library, needed only for non-convex user meshes.
    import coacd

    coacd.set_log_level("error")
    parts = coacd.run_coacd(
        coacd.Mesh(np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int32)),
        threshold=threshold, max_convex_hull=max_pieces, preprocess_mode="auto",
        resolution=1000, mcts_iterations=100, mcts_nodes=15, decimate=True,
        max_ch_vertex=MAX_PIECE_VERTICES, seed=0,
    )
    return [reduce_hull(np.asarray(v, float)) for v, _ in parts if len(v) >= 4]


def from_mesh(path, *, scale: float = 1.0, name: str | None = None, density: float | None = None,
              mass: float | None = None, max_pieces: int = 16, threshold: float = 0.05,
              cache: bool = True) -> GraspObject:
    """Load a user mesh (OBJ, STL or PLY) as a grasp-ready object.

    The mesh is validated, repaired where that is safe (duplicate vertices merged, degenerate
    and duplicate triangles dropped, small holes closed, winding made consistent and outward),
    moved so its lowest point is at z = 0 (it stands upright along +z; x and y are kept), and
    decomposed into at most ``max_pieces`` convex pieces of at most 32 vertices with CoACD
    (skipped when the mesh is already convex). The decomposition is cached in
    :func:`cache_dir`, keyed by the file's sha256 and the options.

    Parameters
    ----------
    path : str or Path
        Mesh file in metres (use ``scale`` otherwise: 0.001 for millimetres).
    scale : float
        Multiplies the coordinates.
    name : str, optional
        Default: the file name without its suffix.
    density, mass : float, optional
        Uniform-solid assumption: density in kg/m^3 (default 1000), or the total mass in kg
        (then density = mass / volume). Give at most one.
    max_pieces, threshold : CoACD's maximum number of hulls and concavity threshold.
    cache : bool
        Read/write the decomposition cache.

    Raises
    ------
    MeshError (a ValueError) naming the file: missing file, unsupported format, unreadable or
    empty mesh, NaN/inf vertices, absurd size, zero volume, non-manifold mesh that can't be
    repaired. A ``UserWarning`` flags meshes larger than 1 m (likely millimetres).
    """
    path = Path(path)
    if not path.is_file():
        raise MeshFileNotFoundError(f"{path}: no such mesh file")
    if path.suffix.lower() not in SUPPORTED_FORMATS:
        raise _fail(path, f"unsupported format {path.suffix!r}; use one of {SUPPORTED_FORMATS}")
    try:
        scale = float(scale)
    except (TypeError, ValueError):
        raise _fail(path, f"scale must be a positive finite number, got {scale!r}") from None
    if not np.isfinite(scale) or scale <= 0:
        raise _fail(path, f"scale must be a positive finite number, got {scale}")
    if not isinstance(max_pieces, int) or isinstance(max_pieces, bool) or max_pieces < 1:
        raise _fail(path, f"max_pieces must be a positive int, got {max_pieces!r}")
    if not _is_real(threshold) or not 0 < threshold <= 1:
        raise _fail(path, f"threshold (CoACD concavity) must lie in (0, 1], got {threshold!r}")
    if name is not None and (not isinstance(name, str) or not name.strip() or "/" in name
                             or "\\" in name or ".." in name):
        raise _fail(path, f"name must be a plain object name (no '/', '\\' or '..'), got "
                          f"{name!r}")
    if density is not None and mass is not None:
        raise _fail(path, "give density or mass, not both")
    for label, value in (("density", density), ("mass", mass)):
        if value is not None and not (_is_real(value) and np.isfinite(value) and value > 0):
            raise _fail(path, f"{label} must be positive and finite, got {value}")

    raw = path.read_bytes()
    mesh = _read(path)
    if len(mesh.vertices) == 0 or len(mesh.faces) == 0:
        raise _fail(path, "empty mesh (no vertices or no triangles)")
    if len(mesh.faces) > MAX_FACES:
        raise _fail(path, f"{len(mesh.faces)} triangles, more than {MAX_FACES}: simplify it first "
                          "(e.g. trimesh's simplify_quadric_decimation or Blender's Decimate); "
                          "the physics uses at most 16 convex pieces of 32 vertices anyway")
    vertices = np.asarray(mesh.vertices, dtype=float)
    if not np.all(np.isfinite(vertices)):
        bad = int(np.sum(~np.all(np.isfinite(vertices), axis=1)))
        raise _fail(path, f"{bad} vertices have NaN/inf coordinates")
    faces = np.asarray(mesh.faces)
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise _fail(path, "triangles reference vertices that don't exist")
    vertices = vertices * scale
    extent = vertices.max(axis=0) - vertices.min(axis=0)
    size = float(extent.max())
    if size > MAX_EXTENT or size < MIN_EXTENT:
        hint = (" (in millimetres? pass scale=0.001)" if size > MAX_EXTENT else
                f" (smaller than {MIN_EXTENT * 1e3:g} mm can't be grasped"
                + ("; already in metres? drop scale" if scale < 1 else "") + ")")
        raise _fail(path, f"absurd size: largest extent {size:.3g} m after scale={scale}{hint}")
    if size > MM_WARNING_EXTENT:
        warnings.warn(f"{path}: largest extent is {size:.3g} m; this looks like millimetres "
                      "(pass scale=0.001)", UserWarning, stacklevel=2)
    if float(extent.min()) <= 1e-9 * size:
        raise _fail(path, "degenerate mesh: all vertices lie in a plane (zero volume)")

    mesh = _repair(trimesh.Trimesh(vertices, faces, process=False), path)
    volume = float(mesh.volume)
    if volume <= 1e-9 * size**3:
        raise _fail(path, f"degenerate mesh: volume {volume:.3g} m^3 is zero")
    mesh.apply_translation([0.0, 0.0, -mesh.bounds[0, 2]])  # stand on the table, z = 0

    key = hashlib.sha256(
        raw + f"|{_CACHE_VERSION}|{scale!r}|{max_pieces}|{threshold!r}".encode()
    ).hexdigest()
    pieces = _cached_pieces(key) if cache else None
    if pieces is None:
        pieces = _decompose(mesh, max_pieces, threshold)
        if cache:
            _store_pieces(key, pieces)

    mesh.density = float(mass / volume) if mass is not None else float(density or DEFAULT_DENSITY)
    com = np.asarray(mesh.center_mass, dtype=float)
    lo, hi = mesh.bounds
    return GraspObject(
        name=name or path.stem,
        mesh=mesh,
        pieces=tuple(pieces),
        mass=float(mesh.mass),
        com=com,
        inertia=np.asarray(mesh.moment_inertia, dtype=float),
        support_z=0.0,
        max_radius=float(np.linalg.norm(mesh.vertices - com, axis=1).max()),
        kind="user",
        set="user",
        content_hash=key,
        dimensions={"length_x": float(hi[0] - lo[0]), "width_y": float(hi[1] - lo[1]),
                    "height": float(hi[2] - lo[2])},
    )


def _cached_pieces(key: str):
    path = cache_dir() / f"{key}.npz"
    if not path.exists():
        return None
    try:
        with np.load(path) as z:
            pv, off = z["piece_vertices"], z["piece_offsets"]
        return [pv[off[i] : off[i + 1]].astype(float) for i in range(len(off) - 1)]
    except Exception:  # noqa: BLE001 - a corrupt cache entry is recomputed, not fatal
        return None


def _store_pieces(key: str, pieces) -> None:
    directory = cache_dir()
    try:
        directory.mkdir(parents=True, exist_ok=True)
        tmp = directory / f"{key}.{os.getpid()}.tmp.npz"  # two processes may store one key
        off = np.concatenate([[0], np.cumsum([len(p) for p in pieces])])
        np.savez(tmp, piece_vertices=np.concatenate(pieces), piece_offsets=off)
        os.replace(tmp, directory / f"{key}.npz")  # atomic: concurrent loaders see all or nothing
    except OSError as e:
        warnings.warn(f"could not write the object cache in {directory}: {e}", stacklevel=3)
