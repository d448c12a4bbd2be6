"""The object record shared by objects, physics and quality: mesh, convex pieces, mass props."""

from dataclasses import dataclass, field

import numpy as np
import trimesh


@dataclass(frozen=True, eq=False)
class GraspObject:
    """A rigid object ready for grasp trials, in its canonical frame (metres, kilograms).

    Attributes
    ----------
    name : str
    mesh : trimesh.Trimesh
        Watertight visual/solid mesh; base on z = ``support_z``, revolution axis on z.
    pieces : tuple of (V_i, 3) float arrays
        Vertices of the convex collision pieces (each V_i <= 32), object frame.
    mass : float
    com : (3,) array
        Center of mass, object frame.
    inertia : (3, 3) array
        Inertia tensor about ``com``, axes of the object frame.
    support_z : float
        Height of the plane the object stands on (the table); grippers below it collide.
    max_radius : float
        Largest distance from ``com`` to the surface; torque scale of the epsilon metric.
    kind, set : str
        E.g. ``"pitcher"`` / ``"active"``; ``"user"`` for meshes from ``from_mesh``.
    content_hash : str
        Hash of the mesh and pieces (manifest entry, chain-file checks).
    """

    name: str
    mesh: trimesh.Trimesh
    pieces: tuple
    mass: float
    com: np.ndarray
    inertia: np.ndarray
    support_z: float = 0.0
    max_radius: float = 0.0
    kind: str = "user"
    set: str = "user"
    content_hash: str = ""
    dimensions: dict = field(default_factory=dict)


def make_box(half_extents=(0.03, 0.03, 0.05), mass=0.2, name="box") -> GraspObject:
    """A solid box standing on z = 0: the cheapest object for tests (one convex piece)."""
    h = np.asarray(half_extents, dtype=float)
    mesh = trimesh.creation.box(extents=2 * h)
    mesh.apply_translation([0.0, 0.0, h[2]])
    mesh.density = mass / mesh.volume
    com = np.asarray(mesh.center_mass, dtype=float)
    inertia = np.asarray(mesh.moment_inertia, dtype=float)
    verts = np.asarray(mesh.vertices, dtype=float)
    return GraspObject(
        name=name,
        mesh=mesh,
        pieces=(verts,),
        mass=float(mass),
        com=com,
        inertia=inertia,
        support_z=0.0,
        max_radius=float(np.linalg.norm(verts - com, axis=1).max()),
        kind="box",
        set="test",
        dimensions={"x": 2 * h[0], "y": 2 * h[1], "z": 2 * h[2]},
    )
