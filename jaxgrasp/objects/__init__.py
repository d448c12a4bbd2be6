"""Objects: the shipped kitchenware set, user meshes, convex decomposition.

``names()``, ``load(name)`` and ``similar(name)`` serve the 9 shipped kitchen objects from
``assets/``; ``any_object_set()`` lists the 24 shipped random objects of pybullet (the
any-object evaluation set, ``load_any("random_NNN")``); ``from_mesh(path)`` turns a user's
OBJ/STL/PLY file into a ``GraspObject``; ``find_symmetry(obj)`` finds its turn and mirror
symmetry about a vertical axis.
Never imports jax or mujoco; coacd and matplotlib load only when used.
"""

from jaxgrasp.objects import any_object
from jaxgrasp.objects.any_object import any_object_set
from jaxgrasp.objects.base import GraspObject, make_box
from jaxgrasp.objects.shipped import load, names, similar
from jaxgrasp.objects.symmetry import Symmetry, find_symmetry
from jaxgrasp.objects.user import MeshError, from_mesh

__all__ = ["GraspObject", "MeshError", "Symmetry", "any_object_set", "find_symmetry",
           "from_mesh", "load", "load_any", "make_box", "names", "similar"]

MESH_SUFFIXES = (".obj", ".stl", ".ply")


def load_any(spec, *, scale: float = 1.0) -> GraspObject:
    """A shipped object by name (a kitchen object or ``random_NNN`` of the any-object set), or
    a user mesh file (``from_mesh``) by path."""
    if str(spec).lower().endswith(MESH_SUFFIXES):
        return from_mesh(spec, scale=scale)
    if str(spec).startswith(any_object.PREFIX) and str(spec) not in names():
        return any_object.load(str(spec))
    return load(str(spec))
