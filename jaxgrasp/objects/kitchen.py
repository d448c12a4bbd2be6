"""The 9 kitchen objects of the paper (Fig. 2 and 3), built procedurally.

Every object is a thin-walled solid of revolution about z (base on z = 0) plus, for pitchers
and pans, a handle in the xz-plane along +x. Profiles are polygons in (r, z); handles are
octagonal straps swept along a polyline. The visual/solid mesh is the manifold3d union of the
revolved body and the handle straps; mass properties come from that watertight solid.

Materials: pitchers and plates are glazed ceramic (stoneware/porcelain, 2400 kg/m^3), walls
4.5-6 mm. Pans are aluminium (2700 kg/m^3) with 3-3.5 mm walls, as most frying and saute pans
are: a steel pan of realistic mass has 1-2 mm walls, and after the +-1 mm chord offset of the
sector pieces (decompose.py) its collision wall would be only ~1 mm thick at sector edges, which
a finger pressing 1 mm into it could tunnel through in MJX.
"""

import math
from dataclasses import dataclass, field

import manifold3d
import numpy as np

from jaxgrasp.objects import decompose

CERAMIC = 2400.0  # kg/m^3, porcelain/stoneware
ALUMINIUM = 2700.0  # kg/m^3, cast/pressed aluminium cookware
VISUAL_SEGMENTS = 128  # revolved mesh: chord error r (1 - cos(pi/128)) < 0.05 mm at r = 0.16 m


@dataclass(frozen=True)
class HandleSpec:
    """An octagonal strap swept along ``path`` (xz-plane), its ends cut inside the body wall."""

    path: tuple  # ((x, z), ...)
    half_thickness: float  # u: across the path, in the xz-plane
    half_width: float  # v: along y
    chamfer: float
    start_normal: tuple = (1.0, 0.0, 0.0)
    end_normal: tuple | None = None

    def __post_init__(self):
        if len(self.path) < 2:
            raise ValueError("a handle path needs at least two points")
        if min(self.half_thickness, self.half_width) <= self.chamfer:
            raise ValueError("chamfer must be smaller than the half sizes")


@dataclass(frozen=True)
class KitchenSpec:
    """A procedural kitchen object: revolved profile + cells + optional handle."""

    name: str
    kind: str  # pitcher / pan / plate
    set: str  # active / transfer_a / transfer_b
    material: str
    density: float
    profile: tuple  # ((r, z), ...) CCW
    cells: tuple  # tuples of profile indices, each a convex polygon
    handle: HandleSpec | None = None
    dimensions: dict = field(default_factory=dict)
    description: str = ""

    def __post_init__(self):
        if self.kind not in ("pitcher", "pan", "plate"):
            raise ValueError(f"unknown kind {self.kind!r}")
        if self.density <= 0:
            raise ValueError("density must be positive")


# ----------------------------------------------------------------------------- profiles
def cup_profile(height, r_bottom, r_top, wall, base):
    """Open vessel: flat base of thickness ``base``, straight (possibly flared) wall.

    ``wall`` is measured horizontally. Returns (profile, cells): a floor disk through the axis
    and one wall cell whose inner edge continues below the floor line (keeps it convex).
    """
    r_out = lambda z: r_bottom + (r_top - r_bottom) * z / height  # noqa: E731
    profile = (
        (0.0, 0.0),
        (r_bottom - wall, 0.0),
        (r_bottom, 0.0),
        (r_top, height),
        (r_top - wall, height),
        (r_out(base) - wall, base),
        (0.0, base),
    )
    return profile, ((0, 1, 5, 6), (1, 2, 3, 4, 5))


def plate_profile(radius, well_radius, foot_radius, thickness, slope):
    """Plate: flat well of ``thickness`` out to ``well_radius``, conical rim of ``slope``.

    The underside stays flat out to ``foot_radius`` (> well_radius) and then rises parallel
    to the top, so the rim keeps a thickness of about ``thickness``; the rim ends in a vertical
    lip at ``radius``.
    """
    height = thickness + (radius - well_radius) * slope
    lip_bottom = (radius - foot_radius) * slope
    profile = (
        (0.0, 0.0),
        (well_radius, 0.0),
        (foot_radius, 0.0),
        (radius, lip_bottom),
        (radius, height),
        (well_radius, thickness),
        (0.0, thickness),
    )
    return profile, ((0, 1, 5, 6), (1, 2, 3, 4, 5))


def _wall_point(profile, z):
    """Mid-wall radius of a cup profile at height z, and the wall's outward normal (xz)."""
    (_, _), (_, _), (rb, _), (rt, h), (rti, _), _, _ = profile
    wall = rt - rti
    r_mid = rb + (rt - rb) * z / h - 0.5 * wall
    n = np.array([1.0, 0.0, -(rt - rb) / h])
    return r_mid, tuple(float(x) for x in n / np.linalg.norm(n))


def pan_handle(profile, z_attach, length, angle_deg, half_thickness, half_width, chamfer):
    """Straight strap handle rising at ``angle_deg``, cut by a plane parallel to the wall."""
    x0, n = _wall_point(profile, z_attach)
    a = math.radians(angle_deg)
    path = ((x0, z_attach), (x0 + length * math.cos(a), z_attach + length * math.sin(a)))
    return HandleSpec(path, half_thickness, half_width, chamfer, start_normal=n)


def loop_handle(profile, z_top, z_bottom, clearance, half_thickness, half_width, chamfer,
                lean=0.0):
    """D-shaped pitcher handle: out from the wall at ``z_top``, down, back in at ``z_bottom``.

    ``clearance`` is the free gap between the body and the bar at the top; ``lean`` moves the
    bottom of the bar outwards (metres), for a slanted bar.
    """
    x_top, n_top = _wall_point(profile, z_top)
    x_bot, n_bot = _wall_point(profile, z_bottom)
    (_, _), (_, _), (rb, _), (rt, h), *_ = profile
    r_top = rb + (rt - rb) * z_top / h
    bar = r_top + clearance + half_thickness
    path = ((x_top, z_top), (bar, z_top), (bar + lean, z_bottom), (x_bot, z_bottom))
    return HandleSpec(
        path, half_thickness, half_width, chamfer, start_normal=n_top,
        end_normal=tuple(-x for x in n_bot),
    )


# ----------------------------------------------------------------------------- the 9 objects
def _cup(name, kind, set_, material, density, *, height, r_bottom, r_top, wall, base, handle,
         description):
    profile, cells = cup_profile(height, r_bottom, r_top, wall, base)
    dims = {"height": height, "diameter": 2 * max(r_bottom, r_top), "wall": wall, "base": base}
    return KitchenSpec(name, kind, set_, material, density, profile, cells, handle(profile), dims,
                       description)


def _plate(name, set_, *, radius, well_radius, foot_radius, thickness, slope, description):
    profile, cells = plate_profile(radius, well_radius, foot_radius, thickness, slope)
    dims = {"height": profile[4][1], "diameter": 2 * radius, "wall": thickness,
            "rim_clearance": profile[3][1]}
    return KitchenSpec(name, "plate", set_, "ceramic", CERAMIC, profile, cells, None, dims,
                       description)


def specs() -> dict:
    """Name -> KitchenSpec of the 9 shipped objects (sizes in metres)."""
    out = [
        # Pitchers: the transfer to tall_pitcher is meant to fail (paper §7): it is 1.4x taller,
        # narrower, strongly tapered, with a higher, slanted handle. small_jug is a scaled pitcher.
        _cup("pitcher", "pitcher", "active", "ceramic", CERAMIC,
             height=0.21, r_bottom=0.062, r_top=0.058, wall=0.005, base=0.007,
             handle=lambda p: loop_handle(p, 0.175, 0.065, 0.035, 0.0055, 0.011, 0.003),
             description="1.8 l ceramic jug, near-cylindrical, D-shaped strap handle"),
        _cup("tall_pitcher", "pitcher", "transfer_a", "ceramic", CERAMIC,
             height=0.30, r_bottom=0.052, r_top=0.036, wall=0.0045, base=0.007,
             handle=lambda p: loop_handle(p, 0.265, 0.135, 0.03, 0.005, 0.009, 0.0025,
                                          lean=0.008),
             description="tall tapered ceramic pitcher, high slanted handle"),
        _cup("small_jug", "pitcher", "transfer_b", "ceramic", CERAMIC,
             height=0.155, r_bottom=0.049, r_top=0.046, wall=0.0045, base=0.006,
             handle=lambda p: loop_handle(p, 0.128, 0.05, 0.03, 0.005, 0.010, 0.0025),
             description="0.9 l ceramic jug, a smaller pitcher"),
        # Pans: aluminium, a flat strap handle rising along +x. The transfer pans share the
        # pan's 20 cm rim and its handle's line (attached 5-5.5 cm up, rising at 12 degrees)
        # so that the pan's demonstrations can land on them (paper §7: pans transfer); they
        # differ in depth (8 vs 6.5 cm; 5.5 cm and flared), wall, handle length and mass.
        _cup("pan", "pan", "active", "aluminium", ALUMINIUM,
             height=0.065, r_bottom=0.10, r_top=0.10, wall=0.003, base=0.004,
             handle=lambda p: pan_handle(p, 0.05, 0.18, 12.0, 0.004, 0.0125, 0.002),
             description="20 cm aluminium saute pan, straight walls"),
        _cup("saucepan", "pan", "transfer_a", "aluminium", ALUMINIUM,
             height=0.08, r_bottom=0.10, r_top=0.10, wall=0.003, base=0.004,
             handle=lambda p: pan_handle(p, 0.055, 0.20, 12.0, 0.004, 0.0125, 0.002),
             description="20 cm deep aluminium saucepan, long handle"),
        _cup("frying_pan", "pan", "transfer_b", "aluminium", ALUMINIUM,
             height=0.055, r_bottom=0.085, r_top=0.10, wall=0.0035, base=0.004,
             handle=lambda p: pan_handle(p, 0.05, 0.19, 12.0, 0.004, 0.0125, 0.002),
             description="20 cm shallow aluminium frying pan, flared walls"),
        # Plates: ceramic, standing on a flat foot (the footprint of a real plate's foot
        # ring), conical rim whose edge stands 2.8-3.9 cm off the table: a parallel-jaw hand
        # holds a plate by its edge, one pad on the rim and the other hooked under the lip
        # (candidates.edge_poses). Edges within 5 mm of each other in radius and height and
        # rims of similar slope, so the plate's demonstrations land on the transfer plates
        # (paper §7); the soup plate is deeper (4.7 cm) with a narrow well, the platter has a
        # broad flat well and a narrow steep rim.
        _plate("plate", "active", radius=0.13, well_radius=0.075, foot_radius=0.08,
               thickness=0.004, slope=0.6, description="26 cm dinner plate, 3.7 cm high"),
        _plate("soup_plate", "transfer_a", radius=0.125, well_radius=0.06, foot_radius=0.065,
               thickness=0.0045, slope=0.65, description="25 cm deep soup plate, 4.7 cm high"),
        _plate("platter", "transfer_b", radius=0.135, well_radius=0.09, foot_radius=0.095,
               thickness=0.0045, slope=0.7,
               description="27 cm round serving platter, broad flat well"),
    ]
    return {s.name: s for s in out}


# ----------------------------------------------------------------------------- building
@dataclass(frozen=True)
class Built:
    """Geometry of a built object, before mass properties."""

    vertices: np.ndarray  # (V, 3) float32, visual/solid mesh
    faces: np.ndarray  # (F, 3) int32
    pieces: tuple  # (V_i, 3) float32
    body_pieces: int  # the first ``body_pieces`` pieces come from the revolved body


def handle_pieces(spec: KitchenSpec) -> list:
    if spec.handle is None:
        return []
    hs = spec.handle
    path = np.array([[x, 0.0, z] for x, z in hs.path])
    section = decompose.chamfered_rectangle(hs.half_thickness, hs.half_width, hs.chamfer)
    return decompose.sweep_pieces(path, section, start_normal=hs.start_normal,
                                  end_normal=hs.end_normal)


def build(spec: KitchenSpec, *, tolerance: float = 1.0e-3) -> Built:
    """Visual mesh (revolved body union handle) and convex pieces of one spec."""
    profile = np.asarray(spec.profile, dtype=float)
    body = []
    for cell in spec.cells:
        body += decompose.cell_pieces(profile, cell, tolerance=tolerance)
    handle = handle_pieces(spec)

    v, f = decompose.revolve(profile, VISUAL_SEGMENTS)
    solid = manifold3d.Manifold(manifold3d.Mesh64(np.ascontiguousarray(v), f.astype(np.uint64)))
    if solid.status() != manifold3d.Error.NoError:
        raise ValueError(f"{spec.name}: revolved body is not a manifold: {solid.status()}")
    for piece in handle:
        solid = solid + manifold3d.Manifold.hull_points(np.ascontiguousarray(piece))
    mesh = solid.to_mesh64()
    vertices = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    faces = np.asarray(mesh.tri_verts, dtype=np.int64)
    pieces = tuple(np.asarray(p, dtype=np.float32) for p in body + handle)
    return Built(vertices.astype(np.float32), faces.astype(np.int32), pieces, len(body))
