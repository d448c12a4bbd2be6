"""Objects: the shipped kitchenware set, user meshes, convex decomposition."""

from jaxgrasp.objects.base import GraspObject, make_box

__all__ = ["GraspObject", "make_box"]
