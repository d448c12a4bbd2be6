"""PNG renders of an object: the solid mesh and its convex pieces side by side (matplotlib)."""

from pathlib import Path

import numpy as np
from scipy.spatial import ConvexHull


def render(vertices, faces, pieces, path, *, title: str = "") -> Path:
    """Write a two-panel PNG (mesh, pieces) to ``path``; returns the path."""
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
    fig = plt.figure(figsize=(10, 5), dpi=80)
    cmap = plt.get_cmap("tab20")
    for panel in range(2):
        ax = fig.add_subplot(1, 2, panel + 1, projection="3d")
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
