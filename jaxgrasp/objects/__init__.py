"""Objects: the shipped kitchenware set, user meshes, convex decomposition.

``names()``, ``load(name)`` and ``similar(name)`` serve the 9 shipped kitchen objects from
``assets/``; ``from_mesh(path)`` turns a user's OBJ/STL/PLY file into a ``GraspObject``.
Never imports jax or mujoco; coacd and matplotlib load only when used.
"""

from jaxgrasp.objects.base import GraspObject, make_box
from jaxgrasp.objects.shipped import load, names, similar
from jaxgrasp.objects.user import MeshError, from_mesh

__all__ = ["GraspObject", "MeshError", "from_mesh", "load", "load_any", "make_box", "names",
           "similar"]

MESH_SUFFIXES = (".obj", ".stl", ".ply")


def load_any(spec, *, scale: float = 1.0) -> GraspObject:
    """A shipped object by name, or a user mesh file (``from_mesh``) by path."""
    if str(spec).lower().endswith(MESH_SUFFIXES):
        return from_mesh(spec, scale=scale)
    return load(str(spec))
