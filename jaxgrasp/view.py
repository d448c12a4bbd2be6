"""``python -m jaxgrasp.view RUN_DIR``: one self-contained HTML page of a run's grasps.

The object's mesh with the learned grasps drawn as gripper markers (colour = outcome, or
epsilon with ``--color epsilon``; a run that carries a robustness measurement colours its
successful grasps by hold probability, red to green) and the demonstrations in black. The
page embeds plotly.js, so it opens offline in any browser: drag to rotate, scroll to zoom,
click a legend entry to hide a group.

For a run on your own mesh pass the mesh file and the ``--scale`` given to
``python -m jaxgrasp.learn``: the object is drawn in the frame the grasps were learned in
(stood on z = 0, scaled), and a file or scale other than the run's is refused.
"""

import argparse
import sys
from pathlib import Path

from jaxgrasp import objects
from jaxgrasp._cli import USER_ERRORS, fail
from jaxgrasp.learn.files.html import grasp_figure, gripper_marker, view_html
from jaxgrasp.learn.files.results import OUTCOME_NAMES, load

__all__ = ["grasp_figure", "gripper_marker", "view_html", "main"]


def _object(result, args) -> objects.GraspObject:
    """The object ``result`` was learned on, in its frame (a user mesh stood on z = 0, scaled).

    With ``--mesh`` the file is loaded as ``python -m jaxgrasp.learn`` loaded it (the same
    decomposition cache, so this is quick after a learn run) and must have the run's content
    hash; without it the run must be on a shipped object.
    """
    if not args.mesh and args.scale != 1.0:
        raise ValueError("--scale goes with --mesh (the scale of your mesh file)")
    if args.mesh:
        if not args.scale > 0:
            raise ValueError(f"--scale must be > 0, got {args.scale}")
        path = Path(args.mesh)
        obj = (objects.load_any(path, scale=args.scale)
               if path.suffix.lower() in objects.MESH_SUFFIXES
               else objects.from_mesh(path, scale=args.scale))  # raises: not a mesh file
        if obj.content_hash != result.object_hash:
            raise ValueError(
                f"--mesh {args.mesh} --scale {args.scale:g} is not the object {args.run} was "
                f"learned on ({result.object_name!r}): the mesh file or the scale differs; pass "
                "the mesh file and --scale given to `python -m jaxgrasp.learn`")
        return obj
    name, mesh_hint = result.object_name, "pass --mesh PATH (and --scale S if the run used one)"
    if name not in objects.names():
        raise ValueError(f"{args.run} was learned on your own mesh {name!r}: {mesh_hint}")
    obj = objects.load(name)
    if obj.content_hash != result.object_hash:  # e.g. a user mesh file named pitcher.stl
        raise ValueError(f"{args.run} was learned on an object {name!r} that is not the shipped "
                         f"{name!r} (another content hash); if it was your own mesh, {mesh_hint}")
    return obj


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m jaxgrasp.view", description=__doc__.splitlines()[0],
        epilog="example: python -m jaxgrasp.view runs/pitcher/run --out pitcher.html; for a "
               "run on your own mesh: python -m jaxgrasp.view runs/mug/run --mesh my_mug.stl "
               "--scale 0.001")
    p.add_argument("run", help="a run directory (result.npz + result.json)")
    p.add_argument("--out", help="HTML file to write (default: RUN/grasps.html)")
    p.add_argument("--mesh", help="the object's mesh file, for a run on your own mesh (the "
                                  "file given to `python -m jaxgrasp.learn`; default: the "
                                  "shipped object of the run's name)")
    p.add_argument("--scale", type=float, default=1.0,
                   help="the --scale the run was learned with (with --mesh)")
    p.add_argument("--color", choices=("outcome", "epsilon"), default="outcome")
    p.add_argument("--outcomes", default="success",
                   help="comma-separated outcomes to draw (success,slipped,collision,miss)")
    args = p.parse_args(argv)
    try:
        result = load(args.run)
        mesh = _object(result, args).mesh
        outcomes = tuple(s.strip() for s in args.outcomes.split(",") if s.strip())
        for name in outcomes:
            if name not in OUTCOME_NAMES:
                raise ValueError(f"--outcomes: unknown outcome {name!r}; use {OUTCOME_NAMES}")
        out = view_html(result, mesh, args.out or Path(args.run) / "grasps.html",
                        color=args.color, outcomes=outcomes)
    except USER_ERRORS as err:
        return fail(err)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
