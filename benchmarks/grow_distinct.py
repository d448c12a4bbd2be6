"""Shorter chains, then a flood from every distinct success, at the chains' trial count.

    .venv/bin/python benchmarks/grow_distinct.py [--objects random_814,random_264] [--seeds 0]
        [--iterations 500] [--sketch biased] [--trials 9856] [--copies] [--antipodal N]
        [--defer K] [--no-rank] [--robust] [--random-walk] [--out FILE.json]

Per object and seed: ``jg.learn.active`` (Kameleon + GDMC, the library defaults, the
``--sketch``, 8 chains, MuJoCo C) for ``--iterations`` (burn-in a tenth), then
``jg.learn.grow`` (its defaults: ranked floods; ``--no-rank``, ``--defer K`` for the levers)
from its distinct successful grasps until ``--trials`` trials in all (demo search and sketch
included: 9856 is what 8 x 1100 proposals cost); with ``--copies`` the budget the flood leaves
goes to the copies of its grasps under the symmetry the chains followed, with ``--antipodal N``
then to N antipodal draws and their flood. Reports the chains' distinct new grasps and those
with the flood's, the atlas coverage of both where the object has an atlas, and, with
``--robust``, the robust share of everything (each grasp tried up to 10 times under 3 mm / 3°,
stopping early; not counted in the trials). ``--random-walk`` also runs the baseline on the
same demos and trial: the random walk for 8 chains x (100 + 1000) proposals (the row of
``benchmarks/any_object.py``); each row gets its distinct new over the random walk's, and the
end the median ratio, its lowest quarter and the median coverage. Writes JSON and prints a
table.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import jaxgrasp as jg
from jaxgrasp.bench import env
from jaxgrasp.learn.evaluate.atlas import load_atlas
from jaxgrasp.learn.evaluate.distinct import coverage, is_new
from jaxgrasp.objects.symmetry import Symmetry


def measure(name: str, seed: int, args) -> dict:
    obj = jg.objects.load_any(name)  # a kitchen object, random_NNN or a mesh path
    sim = jg.learn.Simulator(obj, backend="mujoco", batch_size=8)
    t0 = time.perf_counter()
    result = jg.learn.active(obj, method="kameleon_darting", sketch=args.sketch, chains=8,
                             seed=seed, iterations=args.iterations,
                             burn_in=max(args.iterations // 10, 1), trial=sim, progress=False)
    chain_trials = sim.num_trials
    sym = result.info.get("symmetry") if args.copies else None
    grown = jg.learn.grow(result, trial=sim, budget=max(args.trials - chain_trials, 0),
                          symmetry=Symmetry.from_dict(sym) if sym else None,
                          antipodal=args.antipodal, seed=seed, defer=args.defer,
                          rank=args.rank)
    demos = np.asarray(result.demos.poses, np.float64)
    g = np.asarray(grown.grasps.grasps, np.float64)
    chains = g[:len(g) - grown.added]
    row = {"object": name, "seed": seed, "iterations": args.iterations,
           "chain_trials": int(chain_trials), "trials": int(sim.num_trials),
           "chains_new": int(is_new(chains, demos).sum()),
           "with_grow_new": int(is_new(g, demos).sum()), "grow_rounds": grown.rounds,
           "sketch": args.sketch, "copies": bool(args.copies), "antipodal": args.antipodal,
           "defer": args.defer, "rank": args.rank,
           "seconds": round(time.perf_counter() - t0, 1)}
    try:
        atlas = load_atlas(name).grasps
        row |= {"coverage_chains": round(coverage(chains, atlas), 4),
                "coverage_with_grow": round(coverage(g, atlas), 4)}
    except FileNotFoundError:
        pass
    if args.robust:
        rob = jg.learn.robustness(g, trial=sim, seed=seed, stop_early=True)
        new = rob.robust_new(demos)
        row |= {"robust_share_chains": round(float(rob.robust[:len(chains)].mean()), 4),
                "robust_share_with_grow": round(rob.robust_share, 4),
                "robust_new_chains": int(new[:len(chains)].sum()),
                "robust_new_with_grow": int(new.sum())}
    if args.random_walk:
        rw = jg.learn.active(obj, method="random_walk", chains=8, seed=seed, demos=result.demos,
                             trial=sim, progress=False)
        row["random_walk_new"] = int(rw.learned.summary()["distinct_new"])
        row["new_vs_random_walk"] = round(row["with_grow_new"] / max(row["random_walk_new"], 1),
                                          2)
    return row


def summary(rows) -> str:
    """The issue's figures over the rows: median ratio to the random walk, its lowest quarter
    (per object, the median over seeds), and the median coverage per seed."""
    lines, by = [], {}
    for r in rows:
        by.setdefault(r["object"], []).append(r)
    ratios = sorted(float(np.median([r["new_vs_random_walk"] for r in rs]))
                    for rs in by.values() if all("new_vs_random_walk" in r for r in rs))
    if ratios:
        low = ratios[:max(len(ratios) // 4, 1)]
        lines.append(f"x random walk, per object the median of its seeds: median "
                     f"{np.median(ratios):.2f}, lowest quarter {low[0]:.2f}-{low[-1]:.2f} "
                     f"({len(ratios)} objects)")
    for seed in sorted({r["seed"] for r in rows}):
        cover = [r["coverage_with_grow"] for r in rows
                 if r["seed"] == seed and "coverage_with_grow" in r]
        if cover:
            lines.append(f"seed {seed}: median coverage {100 * np.median(cover):.1f} % over "
                         f"{len(cover)} atlases")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--objects", default="random_814,random_264")
    p.add_argument("--seeds", default="0", help="comma-separated seeds")
    p.add_argument("--iterations", type=int, default=500)
    p.add_argument("--trials", type=int, default=9856,
                   help="trials in all, chains and flood (9856: what 8 x 1100 proposals cost)")
    p.add_argument("--copies", action="store_true",
                   help="the flood's leftover budget to copies under the object's symmetry")
    p.add_argument("--sketch", default="biased", choices=("biased", "random"),
                   help="Kameleon's sketch (biased: a random-walk run's proposals, simulated)")
    p.add_argument("--antipodal", type=int, default=0,
                   help="antipodal draws flooded from with the budget left after that")
    p.add_argument("--defer", type=int, default=0,
                   help="kinds of flood step that wait while others are queued (default "
                        "%(default)s: none)")
    p.add_argument("--rank", action=argparse.BooleanOptionalAction, default=True,
                   help="the flood tries the neighbours likeliest to hold first (default: on)")
    p.add_argument("--robust", action="store_true",
                   help="also score everything under 3 mm / 3° (not counted in --trials)")
    p.add_argument("--random-walk", action="store_true",
                   help="also run the random walk (8 x 1100 proposals, the same demos): ratios")
    p.add_argument("--out", default="bench_out/grow_distinct.json")
    args = p.parse_args(argv)
    rows = []
    for name in args.objects.split(","):
        for seed in (int(s) for s in args.seeds.split(",")):
            rows.append(measure(name, seed, args))
            r = rows[-1]
            print(f"{name:>12} seed {seed}: distinct new {r['chains_new']} -> {r['with_grow_new']}"
                  f" ({r['chain_trials']} + {r['trials'] - r['chain_trials']} trials)"
                  + (f", coverage {100 * r['coverage_chains']:.1f} -> "
                     f"{100 * r['coverage_with_grow']:.1f} %" if "coverage_chains" in r else "")
                  + (f", robust share {100 * r['robust_share_chains']:.1f} -> "
                     f"{100 * r['robust_share_with_grow']:.1f} %, robust new "
                     f"{r['robust_new_chains']} -> {r['robust_new_with_grow']}"
                     if args.robust else "")
                  + (f", random walk {r['random_walk_new']} ({r['new_vs_random_walk']} x)"
                     if args.random_walk else ""), flush=True)
    if text := summary(rows):
        print(text)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"command": " ".join(sys.argv), "device": env.device(),
                               "versions": env.versions(), "date": time.strftime("%Y-%m-%d"),
                               "rows": rows},
                              indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
