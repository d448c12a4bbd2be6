"""Where a dataset's time goes: each object of ``python -m jaxgrasp.learn FOLDER`` split into
its phases, and the first object's start-up against the next ones'.

    JAXGRASP_CACHE_DIR=.cache/jax .venv/bin/python benchmarks/dataset.py \
        [--meshes DIR | --objects random_206 random_459] [--decompositions DIR] \
        [--chains 2 --iterations 20 --burn-in 2 --robust-tries 2] [--out bench_out/dataset.json]

The objects run one after another in this process through the dataset's task
(:func:`jaxgrasp.learn.dataset.learn_object`, what a Dask worker runs), as a worker does with
its share. Without ``--meshes`` three small meshes are generated (a cylinder, a box, a ring:
the ring needs a CoACD decomposition), and the decomposition cache is a fresh temporary one,
so ``load_s`` includes it. Per object: ``load`` (read, repair, decompose), ``scene`` (scene
and simulator), ``demos``, ``sketch``, ``symmetry`` (found from the mesh), ``sampling`` (the
chains), ``robustness``, ``grow`` (the flood from the robust grasps, ``--grow``), ``writing``
(grasp files, HTML view, summary) and ``other`` (the rest: checks, result save);
``compile_s`` is the XLA compilation and lowering inside them (per phase in
``compile_by_phase``; the sampler compiles in a thread during the demo search and counts
there), ``programs`` the XLA programs built. ``import_s`` is the first
object's extra start-up (importing JAX and jaxgrasp). ``startup_s`` is an object's start-up,
everything before its main run's first chunk of steps, split in ``startup_split``
(``load``, ``scene``, ``demos``, ``sketch``, ``symmetry``, ``first_chunk``: the sampler's
compile and its first 10 steps), with the compile seconds and programs built up to then;
the report's ``first_object`` and ``next_objects_mean`` compare them. ``--objects`` learns
objects of the any-object set; ``--decompositions`` keeps their CoACD decompositions in a
folder (a second invocation then loads them in milliseconds). The persistent compilation cache is on
(``JAXGRASP_CACHE_DIR``): a second invocation is a fresh process with a warm cache. Timings on
a shared machine are rough.
"""

import argparse
import contextlib
import importlib.util
import json
import os
import platform
import tempfile
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
#: The phases before the main run's first chunk of steps.
STARTUP = ("load", "scene", "demos", "sketch", "symmetry")


def _user_run():
    """``benchmarks/user_run.py`` (its phase clock)."""
    spec = importlib.util.spec_from_file_location("benchmarks_user_run", HERE / "user_run.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def make_meshes(folder: Path) -> Path:
    """Three small meshes in ``folder``: a cylinder, a box and a ring (non-convex)."""
    import trimesh

    folder.mkdir(parents=True, exist_ok=True)
    trimesh.creation.cylinder(radius=0.035, height=0.12).export(folder / "can.stl")
    trimesh.creation.box(extents=[0.05, 0.07, 0.09]).export(folder / "box.stl")
    trimesh.creation.annulus(r_min=0.03, r_max=0.05, height=0.04).export(folder / "ring.stl")
    return folder


def instrument(clock, cli, user_run) -> None:
    """Time the single-object command's phases (``cli``: ``jaxgrasp.learn.__main__``): the
    learning call's as ``benchmarks/user_run.py`` does, the command's own around it."""
    user_run.instrument(clock)  # demos, sketch, sampling (the chains)

    def timed(phase, fn):
        def wrapper(*args, **kwargs):
            if threading.current_thread() is not threading.main_thread():
                return fn(*args, **kwargs)  # the run's compile-ahead thread: not a phase
            with clock(phase):
                return fn(*args, **kwargs)
        return wrapper

    cli.objects.load_any = timed("load", cli.objects.load_any)
    # why: jaxgrasp loads after the decomposition cache's folder is set (main)
    from jaxgrasp.learn import pipeline

    pipeline.object_symmetry = timed("symmetry", pipeline.object_symmetry)
    for name, phase in (("load_scene", "scene"), ("Simulator", "scene"),
                        ("_measured", "robustness"), ("_grown", "grow"),
                        ("export_grasps", "writing"),
                        ("view_html", "writing")):
        setattr(cli, name, timed(phase, getattr(cli, name)))


def any_object_meshes(names, folder: Path):
    """Links to the meshes of ``names`` (the any-object set) in ``folder``: (folder, scale)."""
    from jaxgrasp.objects import any_object

    entries = any_object.any_object_set()
    scales = {entries[n]["scale"] for n in names}
    if len(scales) != 1:
        raise SystemExit(f"the objects have different scales {scales}: run them apart")
    folder.mkdir(parents=True, exist_ok=True)
    for n in names:
        (folder / f"{n}.obj").symlink_to(entries[n]["path"])
    return folder, scales.pop()


@contextlib.contextmanager
def first_chunk(clock, chains_module):
    """Record in ``clock.first_step`` the seconds from the block's start to the main run's
    first finished chunk (``DEFAULT_CHUNK`` steps): the end of the start-up."""
    mcmc = chains_module.mcmc
    sample, t0 = mcmc.sample, time.perf_counter()

    def timed_sample(*args, callback=None, **kwargs):
        def on_chunk(*a):
            if clock.first_step is None and clock.phase == "sampling":
                clock.first_step = time.perf_counter() - t0
                clock.compile_at_first_step = sum(clock.compile_s.values())
                clock.programs_at_first_step = clock.programs
            return callback(*a)
        return sample(*args, callback=on_chunk, **kwargs)

    clock.first_step = None
    chains_module.mcmc = type("Mcmc", (), {"sample": staticmethod(timed_sample)})
    try:
        yield
    finally:
        chains_module.mcmc = mcmc


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", help="a folder of meshes (default: three generated ones)")
    ap.add_argument("--chains", type=int, default=2)
    ap.add_argument("--iterations", type=int, default=20)
    ap.add_argument("--burn-in", type=int, default=2)
    ap.add_argument("--robust-tries", type=int, default=2)
    ap.add_argument("--objects", nargs="+", metavar="NAME",
                    help="objects of the any-object set (random_206 ...) instead of --meshes")
    ap.add_argument("--decompositions", metavar="DIR",
                    help="XDG cache folder for the CoACD decompositions (default: a fresh one, "
                         "so load_s includes CoACD)")
    ap.add_argument("--out", default="bench_out/dataset.json")
    args = ap.parse_args(argv)

    tmp = Path(tempfile.mkdtemp(prefix="dataset_bench_"))
    # CoACD runs unless --decompositions holds the meshes' decompositions already
    os.environ["XDG_CACHE_HOME"] = args.decompositions or str(tmp / "cache")
    scale = 1.0
    if args.objects:
        meshes, scale = any_object_meshes(args.objects, tmp / "meshes")
    else:
        meshes = Path(args.meshes) if args.meshes else make_meshes(tmp / "meshes")
    t0 = time.perf_counter()
    import jaxgrasp as jg
    from jaxgrasp.learn import __main__ as cli
    from jaxgrasp.learn import _flags, chains, dataset

    cache = jg.enable_compilation_cache()
    cache_entries = sum(1 for _ in cache.iterdir())
    import_s = time.perf_counter() - t0
    user_run = _user_run()
    clock = user_run.PhaseClock()
    clock.install()
    instrument(clock, cli, user_run)
    flags = cli.parser().parse_args([str(meshes), "--out", str(tmp / "dataset"),
                                     "--chains", str(args.chains),
                                     "--iterations", str(args.iterations),
                                     "--burn-in", str(args.burn_in),
                                     "--robust-tries", str(args.robust_tries),
                                     "--scale", str(scale)])
    flags.grow = _flags.grow_budget(flags)  # as the command's main does before a dataset
    rows = []
    for job in dataset._jobs(flags, tmp / "dataset"):
        clock.reset()
        t1 = time.perf_counter()
        with clock("task"), first_chunk(clock, chains):
            row = dataset.learn_object(cli.main, job)
        wall = time.perf_counter() - t1
        phases = {k: round(v, 2) for k, v in clock.wall.items() if k != "task"}
        # The start-up: everything before the main run's first chunk, split into phases
        # (its sampling part: the sampler's compile and the first chunk's steps).
        start = clock.first_step
        startup = None if start is None else {
            "startup_s": round(start, 2),
            "startup_split": {**{k: phases.get(k, 0.0) for k in STARTUP},
                              "first_chunk": round(start - sum(phases.get(k, 0.0)
                                                               for k in STARTUP), 2)},
            "startup_compile_s": round(clock.compile_at_first_step, 2),
            "startup_programs": clock.programs_at_first_step}
        rows.append({"object": job["object"], "status": row["status"], "error": row["error"],
                     "trials": row["trials"], "wall_s": round(wall, 2), **(startup or {}),
                     **{f"{k}_s": phases.get(k, 0.0) for k in
                        ("load", "scene", "demos", "sketch", "symmetry", "sampling",
                         "robustness", "grow", "writing")},
                     "other_s": round(wall - sum(phases.values()), 2),
                     "compile_s": round(sum(clock.compile_s.values()), 2),
                     "compile_by_phase": {k: round(v, 2) for k, v in clock.compile_s.items()},
                     "programs": clock.programs, "cache_hits": clock.cache_hits,
                     "compiled": clock.compiled})
        print(json.dumps(rows[-1]), flush=True)
    learned = [r for r in rows if r["status"] == "ok"]
    first, nxt = learned[:1], learned[1:]
    report = {
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(),
                    "load_average": os.getloadavg()},
        "flags": vars(args), "import_s": round(import_s, 2), "cache_dir": str(cache),
        "cache_entries_at_start": cache_entries, "objects": rows,
        "first_object": {k: first[0].get(k) for k in ("object", "startup_s", "wall_s",
                                                      "compile_s", "programs")}
        if first else None,
        "next_objects_mean": {k: round(sum(r.get(k) or 0.0 for r in nxt) / len(nxt), 2)
                              for k in ("startup_s", "wall_s", "compile_s", "programs")}
        if nxt else None,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=1))
    print(json.dumps({k: report[k] for k in ("import_s", "first_object", "next_objects_mean")}))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
