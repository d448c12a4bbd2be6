"""Size-aware transfer: grasp poses of a source object mapped into a similar target's frame.

Objects share one canonical frame (standing on z = 0, revolution axis z, handle along +x), so
the paper uses a source pose on the target unchanged; a rim pinch of a 20 cm pan then lands
2 cm beside a 16 cm saucepan's rim. :class:`SizeMap` moves poses with the two objects' sizes:

- radially, ``r' = r R_t / R_s`` inside the source's rim radius ``R_s`` (the rim goes to the
  rim) and ``r' = r + (R_t - R_s)`` outside it (a handle keeps its distance from the rim);
- vertically, ``z' = z H_t / H_s`` up to the source's height ``H_s`` (the rim top goes to the
  rim top) and ``z' = z + (H_t - H_s)`` above it;
- orientations unchanged (the surface normals of two similar solids of revolution agree at
  corresponding points only approximately; the chains correct the rest).

Both pieces are continuous and increasing, so the map keeps the order of the poses it moves.
"""

from dataclasses import dataclass

import numpy as np

__all__ = ["SizeMap", "object_size"]


def object_size(obj) -> tuple[float, float]:
    """``(rim radius, height)`` in metres: the object's ``dimensions`` (``diameter``,
    ``height``) when it has them (shipped objects), else its mesh's y half-extent (the handle
    lies along +x) and height above the support plane."""
    dims = getattr(obj, "dimensions", None) or {}
    if "diameter" in dims and "height" in dims:
        return 0.5 * float(dims["diameter"]), float(dims["height"])
    lo, hi = np.asarray(obj.mesh.bounds, np.float64)
    return 0.5 * float(hi[1] - lo[1]), float(hi[2] - max(lo[2], float(obj.support_z)))


@dataclass(frozen=True)
class SizeMap:
    """Map of grasp poses ``(x, y, z, qw, qx, qy, qz)`` from a source's frame to a target's."""

    source_radius: float
    source_height: float
    target_radius: float
    target_height: float

    def __post_init__(self):
        for name in ("source_radius", "source_height", "target_radius", "target_height"):
            value = float(getattr(self, name))
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"SizeMap.{name} must be finite and > 0, got {value!r}")

    @classmethod
    def between(cls, source, target) -> "SizeMap":
        """The map from ``source``'s frame to ``target``'s (GraspObjects)."""
        return cls(*object_size(source), *object_size(target))

    def __call__(self, poses) -> np.ndarray:
        """``poses`` (n, 7) or (7,) mapped into the target's frame (float32)."""
        g = np.asarray(poses, np.float64)
        if g.shape[-1] != 7:
            raise ValueError(f"poses must be (..., 7), got shape {g.shape}")
        out = g.copy()
        r = np.linalg.norm(g[..., :2], axis=-1)
        r_new = np.where(r <= self.source_radius,
                         r * (self.target_radius / self.source_radius),
                         r + (self.target_radius - self.source_radius))
        factor = np.divide(r_new, r, out=np.ones_like(r), where=r > 0)
        out[..., :2] = g[..., :2] * factor[..., None]
        z = g[..., 2]
        out[..., 2] = np.where(z <= self.source_height,
                               z * (self.target_height / self.source_height),
                               z + (self.target_height - self.source_height))
        return out.astype(np.float32)
