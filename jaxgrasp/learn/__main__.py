"""``python -m jaxgrasp.learn MESH_OR_OBJECT --out DIR``: learn grasps for one object
(a folder or glob of meshes: a dataset, one such directory per object and an index).

Loads a shipped object or decomposes your mesh (OBJ, STL or PLY, metres), makes five
demonstrations (or reads yours), learns with Kameleon MCMC + GDMC jumps (or --method; on a
mesh with no axis of revolution a short run, then a flood from every success) and writes into
DIR:
the run (``run/``, resumable: the same command continues an interrupted run), the distinct
successful grasps (``grasps.h5`` in the ACRONYM layout, ``grasps.json``), each tried again
under a robot's pose error and sorted most robust first with its hold probability, an offline
HTML view (``grasps.html``) and ``summary.md``.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import numpy as np

from jaxgrasp import objects
from jaxgrasp._cache import enable_compilation_cache
from jaxgrasp._cli import USER_ERRORS, fail, interrupted, stopped
from jaxgrasp.learn import _flags, dataset
from jaxgrasp.learn.active_learning import active
from jaxgrasp.learn.algorithm import object_symmetry
from jaxgrasp.learn.evaluate.grow import Flooded, grow
from jaxgrasp.learn.evaluate.hold import PoseNoise, Robustness, pose_noise
from jaxgrasp.learn.evaluate.robustness import Grown, grow_robust, ranked, robustness
from jaxgrasp.learn.files.atomic import atomic_write_bytes, npz_bytes
from jaxgrasp.learn.files.export import (
    GraspSet,
    export_grasps,
    load_grasps,
    select_grasps,
    to_transforms,
)
from jaxgrasp.learn.files.html import view_html
from jaxgrasp.learn.files.results import OUTCOME_NAMES
from jaxgrasp.learn.setup.demos import Demos
from jaxgrasp.learn.sim import Simulator
from jaxgrasp.objects.symmetry import Symmetry
from jaxgrasp.physics import GRIPPERS, gripper, load_scene

#: Antipodal draws the flood (``--grow``) starts from besides the robust grasps.
GROW_ANTIPODAL = 2000

EXAMPLE = """example (no Python needed):
  python -m jaxgrasp.learn my_mug.stl --chains 8 --gripper franka --out runs/mug
  python -m jaxgrasp.learn pitcher --iterations 1000 --out runs/pitcher
  python -m jaxgrasp.learn pitcher --method antipodal --out runs/pitcher_antipodal
then open runs/mug/grasps.html in a browser; runs/mug/grasps.h5 reads with ACRONYM's tools."""


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m jaxgrasp.learn", description=__doc__,
                                epilog=EXAMPLE, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("object", help=f"a shipped object ({', '.join(objects.names())}) or a "
                                  "mesh file (.obj/.stl/.ply, metres); a folder or glob of "
                                  "meshes: a dataset")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--demos", help="demonstrated grasps: a grasp file (.npz/.json/.h5, see "
                                   "docs/grasp_files.md); default: simulated demos")
    p.add_argument("--chains", type=_flags.integer(1), default=8)
    recipe = ("; with none of --iterations, --burn-in, --sketch, --grow-every given, an "
              "object with no axis of revolution gets {}")
    p.add_argument("--iterations", type=_flags.integer(1), default=1000, action=_flags.Given,
                   help="chain steps after burn-in (default: %(default)s"
                        + recipe.format(_flags.FLOOD["iterations"]) + ")")
    p.add_argument("--burn-in", type=_flags.integer(1), default=100, action=_flags.Given,
                   help="(default: %(default)s" + recipe.format(_flags.FLOOD["burn_in"]) + ")")
    p.add_argument("--sketch", choices=("biased", "random"), default="biased",
                   action=_flags.Given,
                   help="Kameleon's rough sketch: the proposals of a short random-walk run "
                        "from the demos (their trials counted) or uniformly random poses (no "
                        "trials) (default: %(default)s"
                        + recipe.format(_flags.FLOOD["sketch"]) + ")")
    p.add_argument("--gripper", choices=list(GRIPPERS), default="default")
    p.add_argument("--scale", type=float, default=1.0, help="mesh scale (e.g. 0.001 for mm)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--robust-tries", type=int, default=PoseNoise().tries, metavar="N",
                   help="after learning, try each learned grasp up to N more times under the "
                        "pose error (--pose-error; a grasp that can no longer hold in 80 %% of "
                        "them is not tried further) and sort the grasp files most robust first "
                        "(default: %(default)s; 0: skip). Scoring only: --learn-tries sets the "
                        "tries while learning")
    p.add_argument("--pose-error", default="3,3", metavar="MM,DEG",
                   help="your robot's pose error: position sd (mm, per axis) and orientation "
                        "sd (degrees) (default: %(default)s)")
    p.add_argument("--grow", type=_flags.integer(0), default=None, metavar="TRIALS",
                   help="after scoring, spend up to TRIALS more trials on the holding "
                        "neighbours of the robust grasps (jg.learn.grow_robust: a flood that "
                        "stops where none is left; then, trials left, their copies under the "
                        "object's turns and mirror planes) and export them too (default: as "
                        "many as the chains' proposals, chains x (burn-in + iterations); 0: "
                        "skip)")
    p.add_argument("--grow-antipodal", type=_flags.integer(0), default=GROW_ANTIPODAL,
                   metavar="N", help="the flood (--grow) draws N antipodal grasps first and "
                   "goes on from those that hold robustly too: robust regions the chains did "
                   "not touch, such as a pan's handle; --grow-every's flood draws them where "
                   "it runs dry (default: %(default)s; 0: none)")
    p.add_argument("--grow-every", type=_flags.integer(0), default=0, metavar="TRIALS",
                   action=_flags.Given,
                   help="before scoring, spend up to TRIALS more trials on a flood from every "
                        "distinct success (jg.learn.grow; it never tries a grasp twice; "
                        "where it runs dry, copies under the object's symmetry, then "
                        "--grow-antipodal draws): several times the distinct grasps, a lower "
                        "robust share (default: %(default)s, none"
                        + recipe.format(f"{_flags.FLOOD['grow_every']} per 8 chains") + ")")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    _flags.add_arguments(p)
    dataset.add_arguments(p)
    return p


#: What a ``command.json`` written before a setting was recorded held for it.
UNRECORDED = {"method": "kameleon_darting", "learn_params": {}, "sketch": "biased"}


# the recorded settings a flag of the same name gives back (a resume's hint)
_RESUMED_BY = ("gripper", "seed", "chains", "iterations", "burn_in", "scale", "method", "sketch")


def _check_out(out: Path, args, learn_record: dict) -> None:
    """An output directory belongs to one command: refuse to mix another object, gripper,
    method or learning parameter (``learn_record``: the non-default LearnParams fields)."""
    want = {"object": args.object, "gripper": args.gripper, "seed": args.seed,
            "chains": args.chains, "iterations": args.iterations, "burn_in": args.burn_in,
            "scale": args.scale, "demos": args.demos, "method": args.method,
            "sketch": args.sketch, "learn_params": learn_record}
    record = out / "command.json"
    if record.exists():
        have = {**UNRECORDED, **json.loads(record.read_text())}
        diff = {k: (have.get(k), v) for k, v in want.items() if have.get(k) != v}
        if diff:
            again = " ".join(f"--{k.replace('_', '-')} {old}" for k, (old, _) in diff.items()
                             if k in _RESUMED_BY and old is not None)
            raise ValueError(f"{out} holds a run with other settings {diff}; use another --out"
                             + (f", or resume it with {again}" if again else ""))
    atomic_write_bytes(record, json.dumps(want, indent=1).encode())


#: The summary's words for the recipe the run followed (:func:`_flags.choose_recipe`).
RECIPES = {"chains": "the chains (an axis of revolution, or a recipe flag given)",
           "flood": "no axis of revolution: a short run, then a flood from every success "
                    "(--grow-every)"}


def summary(result, grasps, seconds: float, gripper_name: str, grown: Grown | None = None,
            flooded: Flooded | None = None, scored: Robustness | None = None,
            recipe: str | None = None) -> str:
    """The summary table; the robustness rows when ``result`` carries a measurement (of
    every exported grasp: ``grown``'s, else ``scored``, the scoring of the run's grasps and
    ``flooded``'s, else the run's own); ``recipe``: the one the run followed."""
    learned = result.learned
    counts = result.counts.sum(axis=0)
    rows = [("object", result.object_name), ("gripper", gripper_name),
            ("method", result.method), *((("recipe", RECIPES[recipe]),) if recipe else ()),
            *((("symmetry the turns followed", Symmetry.from_dict(sym).describe()),)
              if (sym := result.info.get("symmetry")) else ()),
            ("chains x proposals", f"{result.num_chains} x {result.num_steps}"),
            *((name, int(c)) for name, c in zip(OUTCOME_NAMES, counts, strict=True)),
            ("distinct successful grasps", len(learned.distinct)),
            ("distinct new grasps (not a demo)", len(learned.new)),
            ("repeated proposals", f"{100 * learned.repeat_share:.1f} %"),
            ("exported grasps", len(grasps.grasps))]
    scored = result.robustness if scored is None else scored
    rob = scored if grown is None else grown.robustness
    if result.robustness is not None:
        n = rob.noise
        rows += [(f"robust grasps (held in >= {n.min_held} of {n.tries} tries under "
                  f"{n.label})", f"{int(rob.robust.sum())} ({100 * rob.robust_share:.1f} %)"),
                 ("distinct robust new grasps", int(rob.robust_new(result.demos.poses).sum())),
                 ("trials to measure robustness", scored.num_trials)]
    if flooded is not None:
        rows.append(("grasps added by --grow-every (a flood from every success)",
                     f"{flooded.added} in {flooded.trials} trials"))
    if grown is not None:
        added = (f"{grown.added} ({int(grown.robustness.robust[-grown.added:].sum())} robust)"
                 if grown.added else "0")
        swapped = f", {grown.swapped} replaced by a robust symmetric copy" if grown.swapped else ""
        rows.append(("grasps added by --grow (robust ones' neighbours and symmetric copies, "
                     "antipodal draws)", f"{added}{swapped} in {grown.trials} trials"))
    rows.append(("wall time (this run's own, every invocation that worked)", f"{seconds:.0f} s"))
    return "| | |\n|---|---:|\n" + "".join(f"| {k} | {v} |\n" for k, v in rows)


def _measured(out: Path, grasps, noise: PoseNoise, obj, sim, seed: int):
    """``(Robustness of grasps, whether it was measured now)``: read from
    ``out/robustness.npz`` when that measured these grasps under this noise (a rerun does not
    try them again)."""
    path = out / "robustness.npz"
    if path.exists():
        with np.load(path) as z:
            same = (z["selected"].shape == grasps.grasps.shape  # a reloaded run: round-off
                    and np.allclose(z["selected"], grasps.grasps, rtol=0.0, atol=1e-9))
            if (same
                    and tuple(z["noise"]) == tuple(float(v) for v in noise)
                    and int(z["seed"]) == seed):
                tried = z["tried"] if "tried" in z.files else None
                return Robustness(z["grasps"], z["held"], noise, tried), False
    # A grasp that can no longer be robust is not tried further (about a third fewer trials).
    rob = robustness(grasps, obj, trial=sim, noise=noise, seed=seed, stop_early=True)
    atomic_write_bytes(path, npz_bytes({"selected": grasps.grasps, "grasps": rob.grasps,
                                        "held": rob.held, "tried": rob.tries_made,
                                        "noise": np.array(tuple(noise), float),
                                        "seed": np.int64(seed)}))
    return rob, True


def _first(rob: Robustness, n: int) -> Robustness:
    """The measurement of the first ``n`` grasps."""
    return Robustness(rob.grasps[:n], rob.held[:n], rob.noise, rob.tries_made[:n])


def _run_symmetry(result) -> Symmetry | None:
    """The symmetry the run's turns followed (None: none recorded)."""
    return Symmetry.from_dict(sym) if (sym := result.info.get("symmetry")) else None


def _same_flood(z, grasps, budget: int, seed: int, antipodal: int, copies: bool) -> bool:
    """Whether the saved flood ``z`` started from these grasps with these settings (a file
    from before a setting was recorded holds its default; no seed recorded: any)."""
    return (z["selected"].shape == grasps.grasps.shape
            and np.allclose(z["selected"], grasps.grasps, rtol=0.0, atol=1e-9)
            and int(z["budget"]) == budget
            and int(z["seed"] if "seed" in z.files else seed) == seed
            and int(z["antipodal"] if "antipodal" in z.files else 0) == antipodal
            and int(z["copies"] if "copies" in z.files else 0) == copies)


def _saved(z, grasps) -> GraspSet:
    """The saved flood's grasps."""
    g = z["grasps"]
    return GraspSet(g, to_transforms(g), z["width"], z["epsilon"], z["outcome"],
                    grasps.object_name, grasps.object_hash)


def _record(grasps, found, budget: int, seed: int, antipodal: int, copies: bool) -> dict:
    """What a flood file holds of any flood ``found`` (a Flooded or a Grown)."""
    g = found.grasps
    return {"selected": grasps.grasps, "grasps": g.grasps, "width": g.width,
            "epsilon": g.epsilon, "outcome": g.outcome, "added": np.int64(found.added),
            "trials": np.int64(found.trials), "rounds": np.int64(found.rounds),
            "rolled": found.rolled, "budget": np.int64(budget), "seed": np.int64(seed),
            "antipodal": np.int64(antipodal), "copies": np.int64(copies)}


def _flooded(out: Path, grasps, result, sim, budget: int, seed: int, antipodal: int):
    """``(Flooded, whether it flooded now)``: read from ``out/flooded.npz`` when that flooded
    from these grasps with this budget, seed and antipodal draws, and with the copies under the
    symmetry the chains followed or without (a rerun does not flood again)."""
    symmetry, path = _run_symmetry(result), out / "flooded.npz"
    settings = (budget, seed, antipodal, symmetry is not None)
    if path.exists():
        with np.load(path) as z:
            if _same_flood(z, grasps, *settings):
                return Flooded(_saved(z, grasps), int(z["added"]), int(z["trials"]),
                               int(z["rounds"]), z["rolled"]), False
    flooded = grow(grasps, sim.obj, trial=sim, budget=budget, tried=result.proposals,
                   symmetry=symmetry, antipodal=antipodal, seed=seed)
    atomic_write_bytes(path, npz_bytes(_record(grasps, flooded, *settings)))
    return flooded, True


def _grown(out: Path, grasps, rob: Robustness, result, sim, budget: int, seed: int,
           antipodal: int):
    """``(Grown, whether it grew now)``: read from ``out/grown.npz`` when that grew these
    measured grasps with this budget, seed and antipodal draws, and with the copies under the
    symmetry the chains followed or without (a rerun does not flood again)."""
    symmetry, path = _run_symmetry(result), out / "grown.npz"
    settings = (budget, seed, antipodal, symmetry is not None)
    if path.exists():
        with np.load(path) as z:
            if (_same_flood(z, grasps, *settings) and "seed" in z.files
                    and np.array_equal(z["input_held"] if "input_held" in z.files
                                       else z["held"][:len(rob.held)], rob.held)):
                both = Robustness(z["rob_grasps"], z["held"], rob.noise, z["tried"])
                return Grown(_saved(z, grasps), both, int(z["added"]), int(z["trials"]),
                             int(z["rounds"]), z["rolled"],
                             int(z["swapped"]) if "swapped" in z.files else 0), False
    grown = grow_robust(grasps, rob, sim.obj, trial=sim, budget=budget, seed=seed,
                        tried=result.proposals, antipodal=antipodal, symmetry=symmetry)
    r = grown.robustness
    atomic_write_bytes(path, npz_bytes({
        **_record(grasps, grown, *settings), "rob_grasps": r.grasps, "held": r.held,
        "tried": r.tries_made, "swapped": np.int64(grown.swapped), "input_held": rob.held}))
    return grown, True


def _seconds(out: Path, add: float = 0.0) -> float:
    """The seconds every invocation that did work has spent on this output, ``add`` added."""
    path = out / "timings.json"
    spent = json.loads(path.read_text())["seconds"] if path.exists() else []
    if add:
        spent.append(round(float(add), 3))
        atomic_write_bytes(path, json.dumps({"seconds": spent}).encode())
    return float(sum(spent))


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    if dataset.is_dataset(args.object):
        # Dask workers import this module by its name (not as __main__) to learn each object
        from jaxgrasp.learn import __main__ as command

        return dataset.main(args, single=command.main)
    out = Path(args.out)
    t0 = time.perf_counter()
    # The CLI owns process-wide JAX settings: a later process (a dataset's worker, a rerun)
    # reads the compiled programs that have no host callback from the persistent cache (one
    # a caller set up already is kept).
    if jax.config.jax_compilation_cache_dir is None:
        enable_compilation_cache()
    try:
        if not args.scale > 0:
            raise ValueError(f"--scale must be > 0, got {args.scale}")
        if args.seed < 0:
            raise ValueError(f"--seed must be >= 0, got {args.seed}")
        obj = objects.load_any(args.object, scale=args.scale)
        args.recipe = _flags.choose_recipe(args, object_symmetry(obj))
        args.grow = _flags.grow_budget(args)  # the recipe's, unless given
        params, learn_record = _flags.learn_params(args)
        grip = gripper(args.gripper)
        demos = None
        if args.demos:
            g = load_grasps(args.demos)
            if len(g.grasps) == 0:
                raise ValueError(f"{args.demos} holds no grasps")
            demos = Demos(g.grasps, None)
        if args.robust_tries < 0:
            raise ValueError(f"--robust-tries must be >= 0, got {args.robust_tries}")
        if args.grow and not args.robust_tries:
            raise ValueError("--grow starts from the robust grasps: it needs --robust-tries > 0")
        noise = pose_noise(args.pose_error, args.robust_tries) if args.robust_tries else None
        out.mkdir(parents=True, exist_ok=True)
        _check_out(out, args, learn_record)
        learned_before = (out / "run" / "result.json").exists()
        scene = load_scene(obj, gripper=grip)
        # one step simulates every chain's proposal and its --learn-tries in one batch
        sim = Simulator(scene, batch_size=args.chains * params.trials_per_proposal)
        result = active(scene, method=args.method, sketch=args.sketch, chains=args.chains,
                        seed=args.seed, params=params, trial=sim, demos=demos,
                        checkpoint_dir=out / "run", progress=not args.quiet)
        grasps = select_grasps(result, width=grip.max_opening)
        measured = grew = flooded_now = False
        grown = drawn = flooded = scored = None
        if args.grow_every:
            flooded, flooded_now = _flooded(out, grasps, result, sim, args.grow_every,
                                            args.seed, args.grow_antipodal)
            grasps = flooded.grasps
        if noise is not None:
            rob, measured = _measured(out, grasps, noise, scene, sim, args.seed)
            scored = rob
            # the page colours by it; the flood's grasps are the last rows, not the run's
            result = result.with_robustness(_first(rob, len(result.grasps)))
            if args.grow:
                grown, grew = _grown(out, grasps, rob, result, sim, args.grow, args.seed,
                                     args.grow_antipodal)
                grasps, rob, drawn = grown.grasps, grown.robustness, grown
            grasps = ranked(grasps, rob)
        export_grasps(grasps, out / "grasps.h5", mesh_file=Path(args.object).name
                      if Path(args.object).suffix else None)
        export_grasps(grasps, out / "grasps.json")
        # the page draws what the files hold: the flood's grasps too
        shown = ((drawn.grasps, drawn.robustness) if drawn is not None
                 else (grasps, scored) if flooded is not None else None)
        view_html(result, obj.mesh, out / "grasps.html", successes=shown)
        worked = not learned_before or measured or grew or flooded_now
        seconds = _seconds(out, time.perf_counter() - t0 if worked else 0.0)
        text = summary(result, grasps, seconds, args.gripper, grown, flooded, scored,
                       args.recipe if args.method == "kameleon_darting" else None)
        atomic_write_bytes(out / "summary.md", text.encode())
    except USER_ERRORS as err:
        return fail(err)
    except (KeyboardInterrupt, RuntimeError) as err:
        if not interrupted(err):
            raise
        if args.method == "antipodal" and not (out / "run" / "result.json").exists():
            # one batch of candidates, simulated and saved at once: nothing to resume from
            return stopped(f"--method antipodal keeps no partial run in {out / 'run'}; the "
                           f"same command again starts it over")
        if out.is_dir():
            _seconds(out, time.perf_counter() - t0)  # the work it did is kept, so is its time
        return stopped(f"the finished demo batches, sketch and chain steps are kept in "
                       f"{out / 'run'}; run the same command again to resume")
    print(text)
    print(f"wrote {out}/grasps.h5, grasps.json, grasps.html, summary.md and run/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
