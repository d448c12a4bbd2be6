"""``python -m jaxgrasp.view RUN_DIR``: one self-contained HTML page of a run's grasps.

The object's mesh with the learned grasps drawn as gripper markers (colour = outcome, or
epsilon with ``--color epsilon``) and the demonstrations in black. The page embeds plotly.js,
so it opens offline in any browser: drag to rotate, scroll to zoom, click a legend entry to
hide a group.
"""

import argparse
import sys
from pathlib import Path

import trimesh

from jaxgrasp import objects
from jaxgrasp._cli import USER_ERRORS, fail
from jaxgrasp.learn.files.html import gripper_marker, view_html
from jaxgrasp.learn.files.results import OUTCOME_NAMES, load

__all__ = ["gripper_marker", "view_html", "main"]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m jaxgrasp.view", description=__doc__.splitlines()[0],
        epilog="example: python -m jaxgrasp.view runs/pitcher --out pitcher.html")
    p.add_argument("run", help="a run directory (result.npz + result.json)")
    p.add_argument("--out", help="HTML file to write (default: RUN/grasps.html)")
    p.add_argument("--mesh", help="the object's mesh file, for a run on your own mesh "
                                  "(default: the shipped object of the run's name)")
    p.add_argument("--color", choices=("outcome", "epsilon"), default="outcome")
    p.add_argument("--outcomes", default="success",
                   help="comma-separated outcomes to draw (success,slipped,collision,miss)")
    args = p.parse_args(argv)
    try:
        result = load(args.run)
        mesh = (trimesh.load(args.mesh, force="mesh") if args.mesh
                else objects.load(result.object_name).mesh)
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
