"""One self-contained HTML page of a run's grasps (:func:`view_html`; the command line is
``python -m jaxgrasp.view``).

The object's mesh with the learned grasps drawn as gripper markers (colour = outcome, or
epsilon with ``color="epsilon"``) and the demonstrations in black. When the run carries a
robustness measurement (``LearnResult.with_robustness``) the successful grasps are coloured
by their hold probability, red (rarely held) to green (always held), with a colour bar that
says "held in k of N tries under 3 mm / 3°" and each grasp's count on hover. The page embeds
plotly.js, so it opens offline in any browser: drag to rotate, scroll to zoom, click a legend
entry to hide a group.
"""

from pathlib import Path

import numpy as np
import plotly.graph_objects as go

from jaxgrasp.learn.files.atomic import atomic_write_bytes
from jaxgrasp.learn.files.export import select_grasps, to_transforms
from jaxgrasp.learn.files.results import OUTCOME_NAMES
from jaxgrasp.physics import GripperParams

__all__ = ["gripper_marker", "grasp_figure", "view_html"]

OUTCOME_COLORS = ("#2ca02c", "#ff7f0e", "#d62728", "#7f7f7f")
#: Hold probability 0 -> 1: red (rarely held) -> yellow -> green (always held).
ROBUST_COLORSCALE = "RdYlGn"
#: Grasps the measurement did not cover.
UNMEASURED_COLOR = "#7f7f7f"
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


def _lines(transforms, width, name, color, *, values=None, scale=None, visible=True, dash=None,
           text=None):
    """One trace of gripper markers: one ``color``, or each grasp's ``values`` on ``scale``
    (a dict of plotly line settings: colorscale, colour bar, range; default: epsilon);
    ``text``: each grasp's hover text (default: the trace's name)."""
    seg = _segments(transforms, width)
    line = {"width": 4, "color": color}
    if values is not None:  # one colour per grasp: repeat its value over its 12 rows
        line = {"width": 4, "color": np.repeat(values, 12),
                **(scale or {"colorscale": "Viridis", "colorbar": {"title": "epsilon"},
                             "cmin": 0.0})}
    if dash:
        line["dash"] = dash
    hover = {"hoverinfo": "name"} if text is None else {
        "text": np.repeat(np.asarray(text, object), 12), "hovertemplate": "%{text}<extra></extra>"}
    return go.Scatter3d(x=seg[:, 0], y=seg[:, 1], z=seg[:, 2], mode="lines", name=name,
                        line=line, visible=True if visible else "legendonly", **hover)


def _robust_scale(noise) -> dict:
    """The colour scale of hold probabilities: ticks in tries held of ``noise.tries``."""
    n = int(noise.tries)
    ticks = list(range(0, n + 1, max(1, -(-n // 5))))
    ticks += [] if ticks[-1] == n else [n]
    return {"colorscale": ROBUST_COLORSCALE, "cmin": 0.0, "cmax": 1.0,
            # below the legend, which holds the top right
            "colorbar": {"title": {"text": f"held in k of {n} tries<br>under {noise.label}"},
                         "len": 0.6, "y": 0.35,
                         "tickvals": [k / n for k in ticks],
                         "ticktext": [f"{k} of {n}" for k in ticks]}}


def _robust_traces(g, held, tried, noise, name, label, max_grasps: int) -> list:
    """The successful grasps ``g`` coloured by hold probability (``held`` of ``tried`` each,
    NaN: not measured), the most robust drawn first; grasps not measured in grey."""
    p = held / np.maximum(tried, 1)
    measured = np.flatnonzero(np.isfinite(held))
    order = measured[np.argsort(-p[measured], kind="stable")][:max_grasps]
    robust = int((held[measured] >= noise.min_held).sum())
    text = [f"{name} grasp {i + 1}: held in {k:.0f} of {n:.0f} tries under "
            f"{noise.label} ({100 * q:.0f} %)"
            for i, k, n, q in zip(order, held[order], tried[order], p[order], strict=True)]
    label = label.replace(" distinct", f" distinct, {robust} robust: held in >= "
                                       f"{noise.min_held} of {noise.tries}")
    traces = [_lines(g.transforms[order], g.width[0], label, None, values=p[order],
                     scale=_robust_scale(noise), text=text)]
    rest = np.flatnonzero(~np.isfinite(p))[:max(max_grasps - len(order), 0)]
    if len(rest):
        traces.append(_lines(g.transforms[rest], g.width[0], f"{name}, not measured "
                             f"({len(rest)})", UNMEASURED_COLOR))
    return traces


def view_html(result, mesh, path, *, color="outcome", outcomes=("success",),
              max_grasps: int = 400, successes=None) -> Path:
    """Write the page for ``result`` (a LearnResult) over ``mesh`` (a trimesh) to ``path``
    (:func:`grasp_figure` draws it)."""
    fig = grasp_figure(result, mesh, color=color, outcomes=outcomes, max_grasps=max_grasps,
                       successes=successes)
    path = Path(path)
    atomic_write_bytes(path, fig.to_html(include_plotlyjs=True, full_html=True).encode())
    return path


def grasp_figure(result, mesh, *, color="outcome", outcomes=("success",),
                 max_grasps: int = 400, successes=None) -> go.Figure:
    """The plotly figure of :func:`view_html`. The successful grasps are coloured by hold
    probability when ``result.robustness`` holds a measurement (unless ``color="epsilon"``),
    the ``max_grasps`` most robust drawn. ``successes``: ``(GraspSet, Robustness)`` to draw
    as the successful grasps instead of the run's (``jg.learn.grow_robust``'s grown set)."""
    if color not in ("outcome", "epsilon"):
        raise ValueError(f"color must be 'outcome' or 'epsilon', got {color!r}")
    rob = getattr(result, "robustness", None)
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    traces = [go.Mesh3d(x=v[:, 0], y=v[:, 1], z=v[:, 2], i=f[:, 0], j=f[:, 1], k=f[:, 2],
                        color="#c8c8d0", opacity=0.55, name=result.object_name,
                        flatshading=True, hoverinfo="skip", showlegend=True)]
    for name in outcomes:
        if name == "success" and successes is not None:
            g, rob = successes
        else:
            g = select_grasps(result, outcome=name)
        if not len(g.grasps):
            continue
        keep = slice(0, max_grasps)
        label = f"{name} ({len(g.grasps)} distinct" + (
            f", {max_grasps} drawn)" if len(g.grasps) > max_grasps else ")")
        if name == "success" and rob is not None and color == "outcome":
            traces += _robust_traces(g, rob.held_of(g.grasps), rob.tried_of(g.grasps),
                                     rob.noise, name, label,
                                     max_grasps)
            continue
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
    return fig
