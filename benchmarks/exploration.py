"""Does the learner learn? Distinct new successful grasps per method and setting (JSON).

For each object and seed, the same demonstrations are shared by every setting; each setting
is one ``jg.learn.active`` run (chains x (burn_in + iterations) proposals, MuJoCo C), measured
by :mod:`jaxgrasp.learn.evaluate.distinct` (successes, distinct, distinct new, repeat share)
and, where the object has a shipped atlas, its coverage.

    python benchmarks/exploration.py --objects pitcher,pan --seeds 0,1,2,3 \
        --settings random_walk,paper,default --out bench_out/exploration.json
"""

import argparse
import json
import time
from pathlib import Path

import numpy as np

import jaxgrasp as jg
from jaxgrasp.learn import distinct
from jaxgrasp.learn.evaluate.atlas import atlas_grasps
from jaxgrasp.learn.params import LearnParams

PAPER = LearnParams.paper()
DEFAULT = LearnParams()
#: Each lever alone on the paper's settings, then the new defaults with one lever reverted.
SETTINGS = {
    "random_walk": ("random_walk", PAPER),
    "paper": ("kameleon_darting", PAPER),
    "default": ("kameleon_darting", DEFAULT),
    "paper+metric": ("kameleon_darting", PAPER.replace(length_scale=DEFAULT.length_scale,
                                                       kernel_sigma=DEFAULT.kernel_sigma)),
    "paper+adapt": ("kameleon_darting", PAPER.replace(
        target_acceptance=DEFAULT.target_acceptance, gamma=DEFAULT.gamma)),
    "paper+floor": ("kameleon_darting", PAPER.replace(density_floor=DEFAULT.density_floor)),
    "paper+regions": ("kameleon_darting", PAPER.replace(region_scale=0.15,
                                                        uniform_jumps=True)),
    "paper+slip": ("kameleon_darting", PAPER.replace(slip_weight=DEFAULT.slip_weight)),
    "paper+p_check": ("kameleon_darting", PAPER.replace(p_check=DEFAULT.p_check)),
    "default-metric": ("kameleon_darting", DEFAULT.replace(length_scale=PAPER.length_scale,
                                                           kernel_sigma=PAPER.kernel_sigma)),
    "default-adapt": ("kameleon_darting", DEFAULT.replace(target_acceptance=None,
                                                          gamma=PAPER.gamma)),
    "default+regions": ("kameleon_darting", DEFAULT.replace(region_scale=0.15,
                                                            uniform_jumps=True)),
    "default-slip": ("kameleon_darting", DEFAULT.replace(slip_weight=1.0)),
    "default-p_check": ("kameleon_darting", DEFAULT.replace(p_check=PAPER.p_check)),
    "default-axis": ("kameleon_darting", DEFAULT.replace(axis_moves=0.0)),
    "default-pivot": ("kameleon_darting", DEFAULT.replace(pivot_share=0.0)),
    "paper+axis": ("kameleon_darting", PAPER.replace(axis_moves=DEFAULT.axis_moves,
                                                     axis_angle=DEFAULT.axis_angle)),
}


def setting(label):
    """A named setting, or ``base@field=value@...``: a named setting with LearnParams changes
    (e.g. ``default@epsilon_power=0.5``)."""
    base, *changes = label.split("@")
    method, params = SETTINGS[base]
    for change in changes:
        field, value = change.split("=")
        params = params.replace(**{field: json.loads(value)})
    return method, params


def grasps_path(out: Path) -> Path:
    return out.with_name(out.stem + "_grasps.npz")


def save(out, rows, grasps, meta):
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({**meta, "rows": rows}, indent=1))
    np.savez_compressed(grasps_path(out), **grasps)


def recompute_coverage(out: Path):
    """Coverage of every saved run against the current atlases (rebuilt after the runs)."""
    data = json.loads(out.read_text())
    grasps = dict(np.load(grasps_path(out)))
    atlases = {}
    for r in data["rows"]:
        name = r["object"]
        if name not in atlases:
            atlases[name] = atlas_grasps(name)
        key = f"{name}/{r['seed']}/{r['setting']}"
        if atlases[name] is not None and key in grasps:
            r["coverage"] = distinct.coverage(grasps[key], atlases[name])
            r["atlas_size"] = int(len(atlases[name]))
    save(out, data["rows"], grasps, {k: v for k, v in data.items() if k != "rows"})
    return data["rows"]


def per_chain_new(res, demos):
    """Distinct new successful grasps of each chain alone (which chains find the grasps)."""
    return [int(distinct.learned_grasps(res.proposals[:, c:c + 1], res.outcomes[:, c:c + 1],
                                        demos).summary()["distinct_new"])
            for c in range(res.proposals.shape[1])]


def run(objects, seeds, settings, chains, iterations, burn_in, sketch, out):
    rows, grasps = [], {}
    meta = {"chains": chains, "iterations": iterations, "burn_in": burn_in, "sketch": sketch}
    for name in objects:
        obj = jg.objects.load(name)
        sim = jg.learn.Simulator(obj, backend="mujoco", batch_size=chains)
        atlas = atlas_grasps(name)
        for seed in seeds:
            demos = jg.learn.demonstrations(obj, num=5, seed=seed, trial=sim)
            for label in settings:
                method, params = setting(label)
                params = params.replace(iterations=iterations, burn_in=burn_in)
                t0 = time.perf_counter()
                res = jg.learn.active(obj, method=method, sketch=sketch, chains=chains,
                                      seed=seed, params=params, backend="mujoco", trial=sim,
                                      demos=demos, progress=False)
                learned = distinct.learned_grasps(res.proposals, res.outcomes, demos.poses)
                counts = jg.learn.outcome_counts(res.outcomes).sum(axis=0)
                row = {"object": name, "seed": seed, "setting": label, "method": method,
                       **learned.summary(), "slipped": int(counts[1]),
                       "collision": int(counts[2]), "miss": int(counts[3]),
                       "acceptance": float(np.mean(res.accepted)),
                       "coverage": (distinct.coverage(learned.distinct, atlas)
                                    if atlas is not None else None),
                       "distinct_new_per_chain": per_chain_new(res, demos.poses),
                       "seconds": time.perf_counter() - t0}
                rows.append(row)
                grasps[f"{name}/{seed}/{label}"] = learned.distinct.astype(np.float32)
                print(json.dumps(row), flush=True)
                save(out, rows, grasps, meta)  # every finished run is kept
    return rows


def summarize(rows):
    by = {}
    for r in rows:
        by.setdefault((r["object"], r["setting"]), []).append(r)
    print(f"{'object':10s} {'setting':16s} {'succ':>6s} {'slip':>6s} {'distinct':>8s} "
          f"{'new':>6s} {'repeat':>6s} {'cover':>6s}  (median over seeds)")
    for (o, s), rs in by.items():
        med = {k: float(np.median([r[k] for r in rs])) for k in
               ("successes", "slipped", "distinct", "distinct_new", "repeat_share")}
        cov = [r["coverage"] for r in rs if r["coverage"] is not None]
        print(f"{o:10s} {s:16s} {med['successes']:6.0f} {med['slipped']:6.0f} "
              f"{med['distinct']:8.0f} {med['distinct_new']:6.0f} {med['repeat_share']:6.2f} "
              f"{(np.median(cov) if cov else float('nan')):6.3f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", default="pitcher,pan")
    ap.add_argument("--seeds", default="0,1,2,3")
    ap.add_argument("--settings", default="random_walk,paper,default")
    ap.add_argument("--chains", type=int, default=8)
    ap.add_argument("--iterations", type=int, default=1000)
    ap.add_argument("--burn-in", type=int, default=100)
    ap.add_argument("--sketch", default="biased", choices=("biased", "random"))
    ap.add_argument("--out", type=Path, default=Path("bench_out/exploration.json"))
    ap.add_argument("--coverage-only", action="store_true",
                    help="recompute the coverage of the runs saved in --out (new atlases)")
    a = ap.parse_args()
    if a.coverage_only:
        summarize(recompute_coverage(a.out))
        return
    settings = a.settings.split(",")
    unknown = [s for s in settings if s.split("@")[0] not in SETTINGS]
    if unknown:
        ap.error(f"unknown settings {unknown}; known: {sorted(SETTINGS)}")
    rows = run(a.objects.split(","), [int(s) for s in a.seeds.split(",")], settings,
               a.chains, a.iterations, a.burn_in, a.sketch, a.out)
    summarize(rows)


if __name__ == "__main__":
    main()
