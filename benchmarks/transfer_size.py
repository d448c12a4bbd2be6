"""Plain (the paper's) against size-aware transfer on the 6 transfer objects (JSON).

For each seed and active-set source (pitcher, pan, plate): one ``jg.learn.active`` run of
Kameleon + GDMC (biased sketch), then on each similar transfer object two
``jg.learn.transfer(..., modes="source")`` runs from it: the source's history and demos used
unchanged (``size_aware=False``, the paper) and moved with the two objects' sizes
(``size_aware=True``, :class:`jaxgrasp.learn.SizeMap`). Every run: chains x (burn_in +
iterations) proposals on MuJoCo C, measured by successes and distinct new grasps.

    python benchmarks/transfer_size.py --seeds 0,1 --out bench_out/transfer_size.json
"""

import argparse
import json
import time
from pathlib import Path

import numpy as np

import jaxgrasp as jg
from jaxgrasp.learn.params import LearnParams

SOURCES = ("pitcher", "pan", "plate")


def row_of(res, **extra):
    learned = res.learned
    counts = jg.learn.outcome_counts(res.outcomes).sum(axis=0)
    return {**extra, **learned.summary(), "slipped": int(counts[1]),
            "collision": int(counts[2]), "miss": int(counts[3])}


def run(sources, seeds, chains, iterations, burn_in, out, params):
    rows = []
    params = params.replace(iterations=iterations, burn_in=burn_in)
    for seed in seeds:
        for source in sources:
            t0 = time.perf_counter()
            src = jg.learn.active(source, chains=chains, seed=seed, params=params,
                                  backend="mujoco", progress=False)
            rows.append(row_of(src, object=source, seed=seed, kind="active",
                               seconds=time.perf_counter() - t0))
            print(json.dumps(rows[-1]), flush=True)
            targets = [n for n in jg.objects.names()
                       if n != source and jg.objects.similar(n) == source]
            for target in targets:
                sim = jg.learn.Simulator(target, backend="mujoco", batch_size=chains)
                for size_aware in (False, True):
                    t0 = time.perf_counter()
                    res = jg.learn.transfer(src, target, modes="source", seed=seed,
                                            trial=sim, progress=False, size_aware=size_aware)
                    rows.append(row_of(res, object=target, source=source, seed=seed,
                                       kind="size_aware" if size_aware else "plain",
                                       seconds=time.perf_counter() - t0))
                    print(json.dumps(rows[-1]), flush=True)
                    out.parent.mkdir(parents=True, exist_ok=True)
                    out.write_text(json.dumps({"chains": chains, "iterations": iterations,
                                               "burn_in": burn_in, "rows": rows}, indent=1))
    return rows


def summarize(rows):
    by = {}
    for r in rows:
        if r["kind"] != "active":
            by.setdefault(r["object"], {}).setdefault(r["kind"], []).append(r)
    print("| target | source | plain: successes, distinct new | size-aware: successes, "
          "distinct new |")
    print("|---|---|---|---|")
    for target, kinds in by.items():
        cells = []
        for kind in ("plain", "size_aware"):
            rs = kinds.get(kind, [])
            cells.append(" / ".join(f"{r['successes']}, {r['distinct_new']}" for r in rs))
        print(f"| {target} | {kinds['plain'][0]['source']} | {cells[0]} | {cells[1]} |")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sources", default=",".join(SOURCES))
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--chains", type=int, default=8)
    ap.add_argument("--iterations", type=int, default=1000)
    ap.add_argument("--burn-in", type=int, default=100)
    ap.add_argument("--out", type=Path, default=Path("bench_out/transfer_size.json"))
    ap.add_argument("--summary-only", action="store_true")
    a = ap.parse_args()
    if a.summary_only:
        summarize(json.loads(a.out.read_text())["rows"])
        return
    rows = run(a.sources.split(","), [int(s) for s in a.seeds.split(",")], a.chains,
               a.iterations, a.burn_in, a.out, LearnParams())
    summarize(rows)


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    main()
