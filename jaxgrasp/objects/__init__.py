"""Objects: the shipped kitchenware set, user meshes, convex decomposition.

``names()``, ``load(name)`` and ``similar(name)`` serve the 9 shipped kitchen objects from
``assets/``; ``from_mesh(path)`` turns a user's OBJ/STL/PLY file into a ``GraspObject``.
Never imports jax or mujoco; coacd and matplotlib load only when used.
"""

from jaxgrasp.objects.base import GraspObject, make_box
from jaxgrasp.objects.shipped import load, names, similar
from jaxgrasp.objects.user import MeshError, from_mesh

__all__ = ["GraspObject", "MeshError", "from_mesh", "load", "make_box", "names", "similar"]
