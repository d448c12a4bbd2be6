"""Figures of a bench run (matplotlib, Agg): Fig.-5-style grasps, outcome bars, acceptance and
trace plots. Functions take plain (numpy) arrays and write PNGs; no physics."""

import numpy as np

from jaxgrasp import so3
from jaxgrasp.bench.paper import OUTCOMES
from jaxgrasp.bench.tables import METHOD_TITLES

COLORS = {"success": "#2a9d3a", "slipped": "#e9a23b", "collision": "#c8423b", "miss": "#8d99ae"}


def _plt():
    # matplotlib is slow to import: it loads when the first figure is drawn, not with the bench.
    import matplotlib

    matplotlib.use("Agg", force=True)
    # pyplot only after use("Agg"): no display is needed or opened.
    import matplotlib.pyplot as plt

    return plt


def gripper_segments(grasps, *, approach_axis, closing_axis, span, depth):
    """Line segments that draw grasps like the paper's Fig. 5.

    Parameters
    ----------
    grasps : (N, 7) gripper poses in the object frame.
    approach_axis, closing_axis : (3,) unit vectors in the gripper frame: the direction
        the gripper reaches toward the object, and the direction the jaws close along.
    span : float
        Jaw opening (metres): length of the red span line, centred on the grasp point.
    depth : float
        Length of the black orientation line, from the grasp centre back along the approach.

    Returns
    -------
    orient : (N, 2, 3) segments (black: gripper orientation), spans : (N, 2, 3) (red).
    """
    g = np.asarray(grasps, float).reshape(-1, 7)
    R = so3.to_matrix(g[:, 3:], xp=np)
    p = g[:, :3]
    a = R @ np.asarray(approach_axis, float)
    c = R @ np.asarray(closing_axis, float)
    orient = np.stack([p, p - depth * a], axis=1)
    spans = np.stack([p - 0.5 * span * c, p + 0.5 * span * c], axis=1)
    return orient, spans


def _mesh_polys(mesh, max_faces=3000):
    faces = np.asarray(mesh.faces)
    if len(faces) > max_faces:
        # Deterministic thinning: enough triangles for a silhouette, fast to draw.
        faces = faces[:: int(np.ceil(len(faces) / max_faces))]
    return np.asarray(mesh.vertices)[faces]


def draw_grasps(ax, mesh, grasps, demos, *, approach_axis, closing_axis, span, depth,
                title="", max_grasps=60):
    """One 3-D panel: object mesh (light grey), learned grasps (black orientation, red span),
    demonstrated grasps (green)."""
    # Loads matplotlib: only when drawing (see _plt).
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    # Fixed drawing order (mplot3d's depth sort hides thin lines inside a translucent mesh):
    # mesh, then demos as a wide green halo, then the learned grasps on top, so a learned
    # grasp that coincides with a demo shows as black/red inside green.
    ax.computed_zorder = False
    polys = _mesh_polys(mesh)
    ax.add_collection3d(Poly3DCollection(polys, facecolor=(0.75, 0.78, 0.82, 0.25),
                                         edgecolor=(0.45, 0.5, 0.55, 0.12), linewidth=0.2,
                                         zorder=1))
    grasps = np.asarray(grasps, float).reshape(-1, 7)
    if len(grasps) > max_grasps:
        # Evenly spaced subset: all of them would be an unreadable tangle.
        grasps = grasps[np.linspace(0, len(grasps) - 1, max_grasps).astype(int)]
        title = f"{title} ({max_grasps} drawn)"
    kw = dict(approach_axis=approach_axis, closing_axis=closing_axis, span=span, depth=depth)
    pts = [np.asarray(mesh.vertices)]
    demos = np.asarray(demos, float).reshape(-1, 7)
    if len(demos):
        o, s = gripper_segments(demos, **kw)
        ax.add_collection3d(Line3DCollection(np.concatenate([o, s]), colors="#1b9e3a",
                                             linewidths=4.0, alpha=0.55, zorder=2))
        pts += [o.reshape(-1, 3), s.reshape(-1, 3)]
    if len(grasps):
        o, s = gripper_segments(grasps, **kw)
        line = dict(linewidths=0.7, alpha=0.85, zorder=3)
        ax.add_collection3d(Line3DCollection(o, colors="black", **line))
        ax.add_collection3d(Line3DCollection(s, colors="red", **line))
        pts += [o.reshape(-1, 3), s.reshape(-1, 3)]
    allp = np.concatenate(pts)
    lo, hi = allp.min(0), allp.max(0)
    c, r = 0.5 * (lo + hi), 0.5 * float((hi - lo).max())
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2] - r, c[2] + r)
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(elev=25, azim=-60)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_zticks([])
    ax.set_title(title, fontsize=9)


def grasp_grid(panels, path, *, ncols=3, **kw):
    """Grid of :func:`draw_grasps` panels (paper Fig. 5 layout: active set on top, transfer
    sets below). ``panels``: list of dicts with mesh, grasps, demos, title."""
    plt = _plt()
    n = len(panels)
    ncols = min(ncols, max(n, 1))
    nrows = int(np.ceil(n / ncols))
    fig = plt.figure(figsize=(3.6 * ncols, 3.5 * nrows))
    for i, p in enumerate(panels):
        ax = fig.add_subplot(nrows, ncols, i + 1, projection="3d")
        draw_grasps(ax, p["mesh"], p["grasps"], p["demos"], title=p["title"], **kw)
    fig.text(0.5, 0.005, "black: gripper orientation, red: span, green: demonstrated grasps",
             ha="center", fontsize=8)
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _stacked(ax, x, cell, width, hatch=None, alpha=1.0):
    bottom = 0.0
    for o in OUTCOMES:
        v = cell[o] / cell["proposals"]
        ax.bar(x, v, width, bottom=bottom, color=COLORS[o], hatch=hatch, alpha=alpha,
               edgecolor="white" if hatch is None else "black", linewidth=0.3)
        bottom += v


def outcome_bars(table: dict, paper: dict, path, *, columns, titles, suptitle, ncols=3):
    """Stacked outcome fractions per cell: this run (solid) beside the paper (hatched).

    ``table``: {row: {column: cell}}; ``paper`` the same layout or {}.
    """
    plt = _plt()
    rows = list(table)
    ncols = min(ncols, len(rows))
    nrows = int(np.ceil(len(rows) / ncols))
    fig, axes = plt.subplots(nrows, ncols,
                             figsize=(max(3.2 * ncols + 1.0, 6.0), 3.3 * nrows + 0.9),
                             sharey=True, squeeze=False)
    for ax in list(axes.flat)[len(rows):]:
        ax.set_visible(False)
    for ax, r in zip(axes.flat, rows, strict=False):
        ticks, labels = [], []
        for i, col in enumerate(columns):
            if col not in table[r]:
                continue
            _stacked(ax, i - 0.19, table[r][col], 0.36)
            pc = paper.get(r, {}).get(col)
            if pc:
                _stacked(ax, i + 0.19, pc, 0.36, hatch="///", alpha=0.55)
            # Success fraction is small next to collisions: print it on the bar.
            s = table[r][col]
            ax.text(i - 0.19, 1.01, f"{100 * s['success'] / s['proposals']:.1f}%",
                    ha="center", va="bottom", fontsize=6.5, color=COLORS["success"])
            ticks.append(i)
            labels.append(titles[col])
        ax.set_xticks(ticks)
        ax.set_xticklabels(labels, rotation=20, ha="right", fontsize=7)
        ax.set_title(r, fontsize=9)
        ax.set_ylim(0, 1.08)
    for ax in axes[:, 0]:
        ax.set_ylabel("fraction of proposals")
    handles = [plt.Rectangle((0, 0), 1, 1, color=COLORS[o]) for o in OUTCOMES]
    handles.append(plt.Rectangle((0, 0), 1, 1, facecolor="white", edgecolor="black",
                                 hatch="///"))
    fig.legend(handles, list(OUTCOMES) + ["paper (hatched)"], loc="lower center", fontsize=7,
               ncol=5, frameon=False)
    fig.suptitle(suptitle, fontsize=10, x=0.01, ha="left")
    fig.tight_layout(rect=(0, 0.06 / nrows, 1, 1 - 0.06 / nrows))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def acceptance_plot(curves: dict, path, *, burn_in: int, title: str):
    """Running acceptance rate (mean over chains) per step.

    ``curves``: {panel: {label: (steps, chains) bool array of accepted proposals}}.
    """
    plt = _plt()
    panels = list(curves)
    ncols = min(3, len(panels))
    nrows = int(np.ceil(len(panels) / ncols))
    fig, axes = plt.subplots(nrows, ncols, figsize=(3.6 * ncols + 0.6, 2.8 * nrows + 0.4),
                             squeeze=False, sharey=True)
    for ax in list(axes.flat)[len(panels):]:
        ax.set_visible(False)
    for ax, p in zip(axes.flat, panels, strict=False):
        for label, acc in curves[p].items():
            acc = np.asarray(acc, float).reshape(len(acc), -1)
            running = np.cumsum(acc.mean(1)) / np.arange(1, len(acc) + 1)
            ax.plot(np.arange(1, len(acc) + 1), running, label=label, lw=1.2)
        ax.axvline(burn_in, color="grey", ls=":", lw=0.8)
        ax.set_title(p, fontsize=9)
        ax.set_xlabel("step")
        ax.set_ylim(0, 1)
    for ax in axes[:, 0]:
        ax.set_ylabel("running acceptance rate")
    axes.flat[len(panels) - 1].legend(fontsize=6.5, loc="upper right")
    fig.suptitle(title, fontsize=10, x=0.01, ha="left")
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.07 / nrows))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def trace_plot(traces: dict, path, *, burn_in: int, title: str, ylabel: str, points=None,
               ncols=3):
    """Per-chain traces (thin lines) of a scalar per step, one panel per entry.

    ``traces``: {panel: (steps, chains) array}; ``points``: optional {panel: (steps, chains)}
    drawn as faint dots (e.g. the value at each proposal, accepted or not).
    """
    plt = _plt()
    panels = list(traces)
    ncols = min(ncols, len(panels))
    nrows = int(np.ceil(len(panels) / ncols))
    fig, axes = plt.subplots(nrows, ncols, figsize=(3.4 * ncols + 0.6, 2.5 * nrows),
                             squeeze=False)
    for ax, p in zip(axes.flat, panels, strict=False):
        t = np.asarray(traces[p], float)
        t = t.reshape(len(t), -1)
        steps = np.arange(1, len(t) + 1)
        if points is not None and p in points:
            pt = np.asarray(points[p], float).reshape(len(t), -1)
            for j in range(pt.shape[1]):
                ax.scatter(steps, pt[:, j], s=7, alpha=0.6, linewidths=0, color=f"C{j % 10}")
        ax.plot(steps, t, lw=0.9, alpha=0.9)
        ax.axvline(burn_in, color="grey", ls=":", lw=0.8)
        ax.set_title(p, fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(panels):]:
        ax.set_visible(False)
    for ax in axes[:, 0]:
        ax.set_ylabel(ylabel, fontsize=8)
    fig.suptitle(title, fontsize=10, x=0.01, ha="left")
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


ACTIVE_TITLES = {m: t.replace("Kameleon+GDMC, ", "K+G ") for m, t in METHOD_TITLES.items()}
TRANSFER_TITLES = {"source": "similar object's modes", "target": "own modes"}
