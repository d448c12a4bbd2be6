"""One self-contained HTML page of a run's grasps (:func:`view_html`; the command line is
``python -m jaxgrasp.view``).

The object's mesh with the learned grasps drawn as gripper markers (colour = outcome, or
epsilon with ``color="epsilon"``) and the demonstrations in black. The page embeds plotly.js,
so it opens offline in any browser: drag to rotate, scroll to zoom, click a legend entry to
hide a group.
"""

from pathlib import Path

import numpy as np
import plotly.graph_objects as go

from jaxgrasp.learn.files.atomic import atomic_write_bytes
from jaxgrasp.learn.files.export import select_grasps, to_transforms
from jaxgrasp.learn.files.results import OUTCOME_NAMES
from jaxgrasp.physics import GripperParams

__all__ = ["gripper_marker", "view_html"]

OUTCOME_COLORS = ("#2ca02c", "#ff7f0e", "#d62728", "#7f7f7f")
#: Marker geometry in the grasp frame (m): pads 4 cm long, palm 4 cm behind the grasp center.
_PAD, _PALM, _STEM = 0.02, -0.04, -0.09


def gripper_marker(width: float) -> np.ndarray:
    """(8, 3) polyline vertices (pairs = segments) of a parallel-jaw gripper, grasp frame."""
    h = 0.5 * width
    return np.array([[0, h, _PAD], [0, h, _PALM], [0, -h, _PAD], [0, -h, _PALM],
                     [0, h, _PALM], [0, -h, _PALM], [0, 0, _PALM], [0, 0, _STEM]], float)


def _segments(transforms: np.ndarray, width: float) -> np.ndarray:
    """(N * 12, 3) marker segments in the object frame, NaN rows between segments."""
    m = np.concatenate([gripper_marker(width), np.ones((8, 1))], axis=1)
    pts = np.einsum("nij,kj->nki", transforms, m)[..., :3].reshape(-1, 2, 3)
    gap = np.full((len(pts), 1, 3), np.nan)
    return np.concatenate([pts, gap], axis=1).reshape(-1, 3)


def _lines(transforms, width, name, color, *, values=None, visible=True, dash=None):
    seg = _segments(transforms, width)
    line = {"width": 4, "color": color}
    if values is not None:  # one colour per grasp: repeat its value over its 12 rows
        line = {"width": 4, "color": np.repeat(values, 12), "colorscale": "Viridis",
                "colorbar": {"title": "epsilon"}, "cmin": 0.0}
    if dash:
        line["dash"] = dash
    return go.Scatter3d(x=seg[:, 0], y=seg[:, 1], z=seg[:, 2], mode="lines", name=name,
                        line=line, visible=True if visible else "legendonly",
                        hoverinfo="name")


def view_html(result, mesh, path, *, color="outcome", outcomes=("success",),
              max_grasps: int = 400) -> Path:
    """Write the page for ``result`` (a LearnResult) over ``mesh`` (a trimesh) to ``path``."""
    if color not in ("outcome", "epsilon"):
        raise ValueError(f"color must be 'outcome' or 'epsilon', got {color!r}")
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    traces = [go.Mesh3d(x=v[:, 0], y=v[:, 1], z=v[:, 2], i=f[:, 0], j=f[:, 1], k=f[:, 2],
                        color="#c8c8d0", opacity=0.55, name=result.object_name,
                        flatshading=True, hoverinfo="skip", showlegend=True)]
    for name in outcomes:
        g = select_grasps(result, outcome=name)
        if not len(g.grasps):
            continue
        keep = slice(0, max_grasps)
        label = f"{name} ({len(g.grasps)} distinct" + (
            f", {max_grasps} drawn)" if len(g.grasps) > max_grasps else ")")
        traces.append(_lines(g.transforms[keep], g.width[0], label,
                             OUTCOME_COLORS[OUTCOME_NAMES.index(name)],
                             values=g.epsilon[keep] if color == "epsilon" else None,
                             visible=name == "success"))
    demos = np.asarray(result.demos.poses, np.float64)
    traces.append(_lines(to_transforms(demos), GripperParams().max_opening,
                         f"demos ({len(demos)})", "black"))
    fig = go.Figure(traces)
    fig.update_layout(
        title=f"{result.object_name}: {result.method} ({result.workflow}), seed {result.seed}",
        scene={"aspectmode": "data", "xaxis_title": "x (m)", "yaxis_title": "y (m)",
               "zaxis_title": "z (m)"},
        legend={"itemsizing": "constant"}, margin={"l": 0, "r": 0, "t": 40, "b": 0})
    path = Path(path)
    atomic_write_bytes(path, fig.to_html(include_plotlyjs=True, full_html=True).encode())
    return path
