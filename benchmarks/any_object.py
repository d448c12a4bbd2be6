"""Grasps for objects nobody here made: the any-object set, three samplers, distinct new grasps.

    .venv/bin/python benchmarks/any_object.py [--objects random_459,random_206] [--seeds 0]
        [--methods random_walk,antipodal,kameleon_darting] [--chains 8] [--iterations 1000]
        [--burn-in 100] [--variants "auto:;old:symmetry=revolution"]
        [--shift X,Y] [--robust-tries 10] [--out bench_out/any_object.json]
    .venv/bin/python benchmarks/any_object.py --coverage --out bench_out/any_object.json

Per object of the set (``jg.objects.any_object_set()``; default: all 24) and seed, the
demonstrations are made once (``jg.learn.demonstrations``, the library defaults) and shared by
every method; each method is one ``jg.learn.active(obj, method=..., sketch="biased",
chains=8, seed=s, backend="mujoco")`` run of chains x (burn_in + iterations) proposals:
the random walk, the antipodal sampler and Kameleon + GDMC. Reports per run the distinct
successful and distinct new grasps (:mod:`jaxgrasp.learn.evaluate.distinct`), the ratios of
each method's distinct new grasps to the random walk's, and the physics trials it cost (its
proposals, the sketch run, and for the chains the shared demo search, counted once per
object and seed in ``demo_trials``). Where the demo search finds no demo, the random walk
and Kameleon + GDMC cannot start: their rows record the error, and the antipodal sampler
(which needs no demo) runs without demos. ``--variants NAME:FIELD=VALUE,...;...`` adds one
Kameleon + GDMC run per variant with those ``LearnParams`` fields changed (method
``kameleon_darting[NAME]``, same demos). Each row records the symmetry the turns followed.
Where the object has an atlas (``python -m jaxgrasp.learn.evaluate.atlas NAME --kind any``),
each row also gets its size, the run's coverage of it (:func:`jaxgrasp.learn.evaluate.distinct
.coverage`) and the run's distinct new grasps over the atlas's distinct grasps. Each run's
distinct successful grasps are kept beside the JSON (``<out>.grasps.npz``), so ``--coverage``
measures them again against the atlases built since. Writes JSON and prints a table.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import jaxgrasp as jg
from jaxgrasp.bench import env
from jaxgrasp.learn.evaluate import distinct
from jaxgrasp.learn.evaluate.atlas import atlas_grasps

METHODS = ("random_walk", "antipodal", "kameleon_darting")
#: Chain methods: they start at the demos.
NEEDS_DEMOS = ("random_walk", "kameleon_darting")


def shifted(name: str, shift, out: Path):
    """Object ``name`` with its mesh file's origin moved by ``shift`` (x, y metres): a user's
    mesh whose frame is not at the object (decomposed again on first use)."""
    import trimesh

    e = jg.objects.any_object_set()[name]
    mesh = trimesh.load(e["path"], force="mesh")
    mesh.apply_translation([shift[0] / e["scale"], shift[1] / e["scale"], 0.0])
    path = out.parent / f"{name}_shifted_{shift[0]:g}_{shift[1]:g}.obj"
    mesh.export(path)
    return jg.objects.from_mesh(path, scale=e["scale"], name=f"{name}+shift")


#: Each run's distinct successful grasps, by row key (saved beside the JSON).
GRASPS = {}


def add_coverage(row: dict, grasps, atlas) -> None:
    row.update(atlas_size=int(len(atlas)),
               coverage=round(distinct.coverage(grasps, atlas), 4),
               new_vs_atlas=round(row["distinct_new"] / max(len(atlas), 1), 3))


def recompute_coverage(out: Path) -> list:
    """The rows of ``out`` with their coverage measured against today's atlases."""
    rows = json.loads(out.read_text())["rows"]
    with np.load(out.with_suffix(".grasps.npz")) as z:
        grasps = {k.replace("|", "/"): z[k] for k in z.files}
    for r in rows:
        atlas = atlas_grasps(r["object"]) if "error" not in r and not r.get("shift") else None
        if atlas is not None and r.get("grasps_key") in grasps:
            add_coverage(r, grasps[r["grasps_key"]], atlas)
    return rows


def measure(name: str, seed: int, args) -> list:
    """The rows of one object and seed: one per method."""
    obj = (shifted(name, args.shift, Path(args.out)) if args.shift
           else jg.objects.load_any(name))
    params = jg.learn.LearnParams(iterations=args.iterations, burn_in=args.burn_in)
    sim = jg.learn.Simulator(obj, backend="mujoco",
                             batch_size=args.chains * params.trials_per_proposal)
    entry = jg.objects.any_object_set()[name]
    base = {"object": name, "shape": entry["shape"], "extents_mm": entry["extents_mm"],
            "shift": args.shift, "seed": seed, "chains": args.chains, "iterations": args.iterations,
            "burn_in": args.burn_in}
    atlas = None if args.shift else atlas_grasps(name)
    t0 = time.perf_counter()
    try:
        demos = jg.learn.demonstrations(obj, num=params.num_demos, seed=seed, trial=sim,
                                        params=params)
        demo_error = None
    except ValueError as e:
        demos, demo_error = None, str(e)
    demo_trials, demo_s = sim.num_trials, time.perf_counter() - t0
    base.update(demo_trials=int(demo_trials), demos=0 if demos is None else len(demos.poses),
                demo_s=round(demo_s, 1))
    rows = []
    runs = [(m, m, params) for m in args.methods] + [
        (f"kameleon_darting[{v}]", "kameleon_darting", params.replace(**kw))
        for v, kw in args.variants.items()]
    for label, method, run_params in runs:
        row = {**base, "method": label}
        if demos is None and method in NEEDS_DEMOS:
            rows.append({**row, "error": demo_error})
            print(f"{name:>11} seed {seed} {label:>16}: {demo_error}", flush=True)
            continue
        before, t1 = sim.num_trials, time.perf_counter()
        try:
            res = jg.learn.active(obj, method=method, sketch="biased", chains=args.chains,
                                  seed=seed, params=run_params, backend="mujoco", trial=sim,
                                  demos=demos, progress=False)
        except ValueError as e:  # e.g. too few collision-free antipodal grasps: the row says
            rows.append({**row, "error": str(e)})
            print(f"{name:>11} seed {seed} {label:>16}: {e}", flush=True)
            continue
        learned = res.learned.summary()
        counts = jg.learn.outcome_counts(res.outcomes).sum(axis=0)
        row.update(learned, slipped=int(counts[1]), collision=int(counts[2]),
                   miss=int(counts[3]), proposals=int(res.outcomes.size),
                   trials=int(sim.num_trials - before), seconds=round(time.perf_counter() - t1, 1),
                   symmetry=res.info.get("symmetry"))
        row["grasps_key"] = f"{name}/{seed}/{label}"
        GRASPS[row["grasps_key"]] = np.asarray(res.learned.distinct, np.float32)
        if atlas is not None:
            add_coverage(row, res.learned.distinct, atlas)
        if args.robust_tries:
            rob = jg.learn.robustness(res, trial=sim, noise=jg.learn.PoseNoise(
                tries=args.robust_tries), seed=seed, stop_early=True)
            res = res.with_robustness(rob)
            row.update(robust_share=round(rob.robust_share, 4),
                       distinct_robust_new=int(res.distinct_robust_new),
                       robustness_trials=int(rob.num_trials))
        if method == "antipodal":
            row.update({k: res.info[k] for k in ("surface_points", "antipodal_pairs",
                                                  "placement_collisions")})
        rows.append(row)
        print(f"{name:>11} seed {seed} {label:>16}: {row['distinct']} distinct, "
              f"{row['distinct_new']} new, {row['successes']} successes, {row['trials']} "
              f"trials, {row['seconds']} s", flush=True)
    rw = next((r for r in rows if r["method"] == "random_walk" and "error" not in r), None)
    for r in rows:
        if rw is not None and "error" not in r and rw["distinct_new"] > 0:
            r["new_vs_random_walk"] = round(r["distinct_new"] / rw["distinct_new"], 2)
    return rows


def parse_variants(text: str) -> dict:
    """``'a:x=1,y=b;c:'`` -> ``{"a": {"x": 1, "y": "b"}, "c": {}}`` (values as JSON, else
    strings)."""
    out = {}
    for part in filter(None, (p.strip() for p in text.split(";"))):
        name, _, fields = part.partition(":")
        kw = {}
        for item in filter(None, fields.split(",")):
            key, _, value = item.partition("=")
            try:
                kw[key.strip()] = json.loads(value)
            except json.JSONDecodeError:
                kw[key.strip()] = value.strip()
        out[name.strip()] = kw
    return out


def table(rows) -> str:
    """Median over seeds of distinct new grasps, the ratio to the random walk and trials."""
    by = {}
    for r in rows:
        by.setdefault((r["object"], r["method"]), []).append(r)
    lines = [f"{'object':>11} {'shape':>24} {'method':>22} {'distinct':>8} {'new':>6} "
             f"{'/ rw':>6} {'trials':>7} {'atlas':>6} {'cover':>6}  (median over seeds)"]
    for (o, m), rs in by.items():
        ok = [r for r in rs if "error" not in r]
        if not ok:
            lines.append(f"{o:>11} {rs[0]['shape']:>24} {m:>22}  error: {rs[0]['error'][:60]}")
            continue
        med = {k: float(np.median([r[k] for r in ok])) for k in ("distinct", "distinct_new",
                                                                   "trials")}
        ratios = [r["new_vs_random_walk"] for r in ok if "new_vs_random_walk" in r]
        ratio = f"{np.median(ratios):6.2f}" if ratios else f"{'-':>6}"
        cover = [r["coverage"] for r in ok if "coverage" in r]
        atlas = (f"{ok[0]['atlas_size']:6d} {np.median(cover):6.1%}" if cover
                 else f"{'-':>6} {'-':>6}")
        lines.append(f"{o:>11} {rs[0]['shape']:>24} {m:>22} {med['distinct']:8.0f} "
                     f"{med['distinct_new']:6.0f} {ratio} {med['trials']:7.0f} {atlas}")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--objects", default=None,
                   help="comma-separated names of the set (default: all 24)")
    p.add_argument("--seeds", default="0", help="comma-separated seeds")
    p.add_argument("--methods", default=",".join(METHODS),
                   help="comma-separated, or 'none' (only --variants)")
    p.add_argument("--chains", type=int, default=8)
    p.add_argument("--iterations", type=int, default=1000)
    p.add_argument("--burn-in", type=int, default=100)
    p.add_argument("--variants", default="",
                   help="extra Kameleon + GDMC runs: 'NAME:FIELD=VALUE,...;NAME2:...' "
                        "(LearnParams fields; NAME: alone is the defaults)")
    p.add_argument("--robust-tries", type=int, default=0, metavar="N",
                   help="also try each run's distinct grasps N times under 3 mm / 3° (early "
                        "stop) and report the robust share and the distinct robust new grasps")
    p.add_argument("--shift", default=None,
                   help="X,Y: move each mesh's origin by this much (metres) first")
    p.add_argument("--out", default="bench_out/any_object.json")
    p.add_argument("--coverage", action="store_true",
                   help="run nothing: measure the coverage of the runs saved in --out against "
                        "the atlases there are now, rewrite it and print the table")
    args = p.parse_args(argv)
    out = Path(args.out)
    if args.coverage:
        data = json.loads(out.read_text())
        data["rows"] = recompute_coverage(out)
        out.write_text(json.dumps(data, indent=1))
        print(table(data["rows"]))
        return 0
    args.shift = [float(v) for v in args.shift.split(",")] if args.shift else None
    args.variants = parse_variants(args.variants)
    args.methods = [m for m in args.methods.split(",") if m and m != "none"]
    unknown = [m for m in args.methods if m not in METHODS]
    if unknown:
        p.error(f"unknown methods {unknown}; known: {list(METHODS)}")
    known = tuple(jg.objects.any_object_set())
    objects = args.objects.split(",") if args.objects else list(known)
    if missing := [o for o in objects if o not in known]:
        p.error(f"not in the any-object set: {missing}; the set is {list(known)}")
    jg.enable_compilation_cache()
    rows = []
    out.parent.mkdir(parents=True, exist_ok=True)
    for name in objects:
        for seed in (int(s) for s in args.seeds.split(",")):
            rows += measure(name, seed, args)
            # Every finished object is kept: a long run stopped midway loses nothing.
            out.write_text(json.dumps({"command": " ".join(sys.argv), "device": env.device(),
                                       "versions": env.versions(),
                                       "date": time.strftime("%Y-%m-%d"), "rows": rows},
                                      indent=1))
            np.savez_compressed(out.with_suffix(".grasps.npz"),
                                **{k.replace("/", "|"): v for k, v in GRASPS.items()})
    print(table(rows))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
