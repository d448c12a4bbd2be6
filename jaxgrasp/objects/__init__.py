"""Objects: the shipped kitchenware set, user meshes, convex decomposition.

Light at import: numpy only (trimesh, scipy, manifold3d and coacd load when used); never jax or
mujoco.
"""

from jaxgrasp.objects.base import GraspObject, make_box
from jaxgrasp.objects.shipped import load, names, similar

__all__ = ["GraspObject", "load", "make_box", "names", "similar"]
