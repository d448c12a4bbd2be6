"""PNG renders of an object: the solid mesh and its convex pieces side by side (matplotlib)."""

from pathlib import Path

import numpy as np
from scipy.spatial import ConvexHull


def render(vertices, faces, pieces, path, *, title: str = "", profile=None,
           dimensions=None) -> Path:
    """Write a PNG of the mesh and its convex pieces to ``path``; returns the path.

    With ``profile`` (the (r, z) polygon of a revolved body) a third panel draws the body's
    cross-section to scale on the table line (z = 0), annotated with ``dimensions`` (height,
    diameter and, for plates, how high the rim's edge stands off the table).
    """
    # matplotlib is slow to import: only when renders are drawn (``make assets``).
    import matplotlib

    matplotlib.use("Agg")
    # pyplot only after use("Agg"): no display is needed or opened.
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    vertices = np.asarray(vertices, dtype=float)
    light = np.array([0.4, -0.6, 0.7]) / np.linalg.norm([0.4, -0.6, 0.7])

    def shaded(tri, rgb):
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        k = 0.35 + 0.65 * np.clip(n @ light, 0, 1)
        return np.clip(np.asarray(rgb)[None] * k[:, None], 0, 1)

    lo, hi = vertices.min(0), vertices.max(0)
    center, half = (lo + hi) / 2, (hi - lo).max() / 2 * 1.05
    panels = 2 if profile is None else 3
    fig = plt.figure(figsize=(5 * panels, 5), dpi=80)
    cmap = plt.get_cmap("tab20")
    if profile is not None:
        _profile_panel(fig.add_subplot(1, 3, 3), profile, dimensions or {})
    for panel in range(2):
        ax = fig.add_subplot(1, panels, panel + 1, projection="3d")
        if panel == 0:
            tri = vertices[np.asarray(faces)]
            ax.add_collection3d(Poly3DCollection(tri, facecolors=shaded(tri, (0.8, 0.75, 0.65)),
                                                 edgecolors="none"))
            ax.set_title(f"{title}: mesh ({len(faces)} faces)")
        else:
            for i, piece in enumerate(pieces):
                piece = np.asarray(piece, dtype=float)
                tri = piece[ConvexHull(piece).simplices]
                ax.add_collection3d(Poly3DCollection(
                    tri, facecolors=shaded(tri, cmap(i % 20)[:3]), edgecolors=(0, 0, 0, 0.15),
                    linewidths=0.3))
            nv = [len(p) for p in pieces]
            ax.set_title(f"{len(pieces)} convex pieces, {min(nv)}-{max(nv)} vertices")
        ax.set_xlim(center[0] - half, center[0] + half)
        ax.set_ylim(center[1] - half, center[1] + half)
        ax.set_zlim(center[2] - half, center[2] + half)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=28, azim=-60)
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        ax.set_zlabel("z")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)
    return path


def _profile_panel(ax, profile, dimensions) -> None:
    """The cross-section through the axis (both halves), to scale, on the table line."""
    rz = np.asarray(profile, dtype=float)
    for sign in (1.0, -1.0):
        ax.fill(sign * rz[:, 0], rz[:, 1], color=(0.8, 0.75, 0.65), edgecolor="k", lw=0.6)
    r_max, z_max = rz[:, 0].max(), rz[:, 1].max()
    ax.axhline(0.0, color="0.4", lw=1.0)
    ax.axvline(0.0, color="0.7", lw=0.5, ls=":")
    text = [f"{k} {1e3 * dimensions[k]:.1f} mm" for k in ("height", "diameter", "wall",
                                                          "rim_clearance") if k in dimensions]
    ax.set_title("section: " + ", ".join(text[:2]), fontsize=9)
    if "rim_clearance" in dimensions:
        ax.annotate(f"rim edge {1e3 * dimensions['rim_clearance']:.1f} mm off the table",
                    xy=(r_max, dimensions["rim_clearance"]), xytext=(0.1 * r_max, -0.25 * r_max),
                    fontsize=8, arrowprops={"arrowstyle": "->", "lw": 0.6})
    ax.set_xlim(-1.1 * r_max, 1.1 * r_max)
    ax.set_ylim(-0.35 * r_max, max(z_max, 0.3 * r_max) + 0.1 * r_max)
    ax.set_aspect("equal")
    ax.locator_params(axis="x", nbins=5)
    ax.set_xlabel("r (m)")
    ax.set_ylabel("z (m)")
