"""Figures of a bench run, drawn from the saved LearnResults (see :mod:`jaxgrasp.bench.figures`)."""

from pathlib import Path

import numpy as np

from jaxgrasp.bench import figures, paper
from jaxgrasp.bench.profiles import ACTIVE_METHODS, TRANSFER_MODES
from jaxgrasp.bench.tables import METHOD_TITLES, MODES_TITLES


def gripper_drawing() -> dict:
    """How a grasp is drawn, from the gripper's geometry (jaxgrasp.physics.gripper): approach
    along the grasp frame's +z (black line back to the palm), jaws closing along y (red line,
    the open span)."""
    from jaxgrasp.physics.gripper import GripperParams

    g = GripperParams()
    return dict(approach_axis=(0.0, 0.0, 1.0), closing_axis=(0.0, 1.0, 0.0),
                span=g.max_opening, depth=g.pad_half_size[2] + 2 * g.palm_half_size[2])


def chain_epsilon(result) -> np.ndarray:
    """(steps, chains) epsilon of each chain's *state* (the last accepted proposal; NaN
    before the first acceptance: the start point's quality is not recorded)."""
    eps, acc = np.asarray(result.epsilons, float), np.asarray(result.accepted, bool)
    steps, chains = eps.shape
    idx = np.where(acc, np.arange(steps)[:, None], -1)
    idx = np.maximum.accumulate(idx, axis=0)
    return np.where(idx >= 0, eps[np.maximum(idx, 0), np.arange(chains)], np.nan)


def _title(cell, result):
    if cell.table == "active":
        col = METHOD_TITLES[cell.column]
    else:
        col = f"{cell.key[0]}: {MODES_TITLES[cell.column].lower()}"
    learned = result.learned
    return (f"{cell.obj} — {col}\n{len(learned.distinct)} distinct successful grasps "
            f"({len(learned.new)} new), {len(result.modes)} modes")


def make_figures(out: Path, cells: list, results: dict, profile, load_mesh=None) -> list:
    """Write every figure of the run under ``out/figures``; return paths relative to ``out``.

    ``load_mesh(name) -> trimesh.Trimesh`` defaults to ``jg.objects.load(name).mesh``.
    """
    if load_mesh is None:
        from jaxgrasp import objects

        def load_mesh(name):
            return objects.load(name).mesh

    fig_dir = out / "figures"
    (fig_dir / "grasps").mkdir(parents=True, exist_ok=True)
    draw = gripper_drawing()
    meshes = {}

    def mesh(name):
        if name not in meshes:
            meshes[name] = load_mesh(name)
        return meshes[name]

    written = []
    done = [c for c in cells if c.id in results]

    def panel(c):
        r = results[c.id]
        # GDMC modes are the demonstrated grasps the chain used (for transfer with source
        # modes: the similar object's); the random walk has none, show its demos.
        demos = r.modes if r.method != "random_walk" else r.demos.poses
        return dict(mesh=mesh(c.obj), grasps=r.grasps, demos=demos, title=_title(c, r))

    # Paper Fig. 5 layout: active set (biased sketch) on top, each transfer set below
    # (modes of the actual object).
    fig5 = [c for c in done if c.key[-1] in ("kameleon_darting_biased", "target")]
    if fig5:
        p = fig_dir / "fig5_grasps.png"
        figures.grasp_grid([panel(c) for c in fig5], p, ncols=3, **draw)
        written.append(p)
    for c in done:
        p = fig_dir / "grasps" / (c.id.replace("/", "_") + ".png")
        figures.grasp_grid([panel(c)], p, ncols=1, **draw)
        written.append(p)

    tbl_active = {}
    tbl_transfer = {}
    from jaxgrasp.bench.run import cell_from_result

    for c in done:
        cell = cell_from_result(results[c.id])
        if c.table == "active":
            tbl_active.setdefault(c.obj, {})[c.column] = cell
        else:
            tbl_transfer.setdefault(f"{c.key[0]}/{c.obj}", {})[c.column] = cell
    pub = paper.paper_tables()
    if tbl_active:
        p = fig_dir / "outcomes_active.png"
        figures.outcome_bars(tbl_active, pub["active"], p, columns=list(ACTIVE_METHODS),
                             titles=figures.ACTIVE_TITLES,
                             suptitle=f"Table II outcomes ({profile.proposals} proposals "
                                      f"x {profile.chains} chains; hatched: paper)")
        written.append(p)
    if tbl_transfer:
        pt = {f"{s}/{o}": row for s, b in pub["transfer"].items() for o, row in b.items()}
        p = fig_dir / "outcomes_transfer.png"
        figures.outcome_bars(tbl_transfer, pt, p, columns=list(TRANSFER_MODES),
                             titles=figures.TRANSFER_TITLES,
                             suptitle=f"Table III outcomes ({profile.proposals} proposals "
                                      f"x {profile.chains} chains; hatched: paper)")
        written.append(p)

    for table in ("active", "transfer"):
        sel = [c for c in done if c.table == table]
        if not sel:
            continue
        curves = {}
        for c in sel:
            panel_name = c.obj if table == "active" else f"{c.key[0]}/{c.obj}"
            curves.setdefault(panel_name, {})[c.column] = results[c.id].accepted
        p = fig_dir / f"acceptance_{table}.png"
        figures.acceptance_plot(curves, p, burn_in=profile.burn_in,
                                title=f"Running acceptance rate ({table}; mean over chains)")
        written.append(p)
        traces = {c.id.split("/", 1)[1]: chain_epsilon(results[c.id]) for c in sel}
        props = {c.id.split("/", 1)[1]: results[c.id].epsilons for c in sel}
        p = fig_dir / f"trace_{table}.png"
        # One row per table row: methods (Table II) or modes (Table III) side by side.
        ncols = len(ACTIVE_METHODS) if table == "active" else len(TRANSFER_MODES)
        figures.trace_plot(traces, p, burn_in=profile.burn_in, ylabel="epsilon", points=props,
                           ncols=ncols,
                           title=f"Chain traces ({table}): epsilon of each chain's state "
                                 "(lines, from its first accepted move) and of every proposal "
                                 "(dots)")
        written.append(p)
    return [str(Path(p).relative_to(out)) for p in written]
