"""Robust grasps of a learning run: how many of the distinct new grasps a robot would hold.

    .venv/bin/python benchmarks/robust_grasps.py [--objects pitcher,pan,plate] [--seeds 2]
        [--chains 8] [--iterations 1000] [--burn-in 100] [--robust-tries K] [--tries 10]
        [--flood-to TRIALS] [--out FILE.json]

Per object and seed: ``jg.learn.active`` with the library defaults (Kameleon + GDMC, biased
sketch, MuJoCo C), then ``jg.learn.robustness`` of its distinct successful grasps (each tried
``--tries`` times at poses perturbed by 3 mm per axis and 3°). Reports the distinct successful
and new grasps, the robust share (held in >= 80 % of the tries), the distinct robust new
grasps and every trial counted (the run's proposals, demo search and sketch included, plus the
robustness tries). Writes JSON and prints a table.

``--flood-to TRIALS`` measures one more lever: after scoring, flood out from the robust grasps
(each one's 12 neighbours at 1.2 cm / 12°, the atlas's step; those the same grasp as any pose
tried before or colliding at placement skipped), score the new successes, and go on from the
new robust ones until TRIALS trials in all.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import jaxgrasp as jg
from jaxgrasp.bench import env
from jaxgrasp.learn.evaluate.atlas import neighbour_poses
from jaxgrasp.learn.evaluate.distinct import distinct_grasps, is_new, same_as_any
from jaxgrasp.learn.setup.antipodal import placement_collisions
from jaxgrasp.physics import Outcome


def measure(name: str, seed: int, args) -> dict:
    obj = jg.objects.load(name)
    sim = jg.learn.Simulator(obj, backend="mujoco",
                             batch_size=args.chains * (1 + args.robust_tries))
    t0 = time.perf_counter()
    params = jg.learn.LearnParams(robust_tries=args.robust_tries,
                                  robust_estimate=args.robust_estimate,
                                  slip_scale=args.slip_scale)
    result = jg.learn.active(obj, method="kameleon_darting", sketch="biased", chains=args.chains,
                             seed=seed, iterations=args.iterations, burn_in=args.burn_in,
                             params=params, trial=sim, progress=False)
    learn_s, learn_trials = time.perf_counter() - t0, sim.num_trials
    t1 = time.perf_counter()
    noise = jg.learn.PoseNoise(tries=args.tries)
    rob = jg.learn.robustness(result, trial=sim, noise=noise, seed=seed,
                              stop_early=args.stop_early)
    result = result.with_robustness(rob)
    flood = flood_robust(result, rob, sim, seed, args) if args.flood_to else {}
    return {**flood, "object": name, "seed": seed, "robust_tries": args.robust_tries,
            "robust_estimate": args.robust_estimate, "slip_scale": args.slip_scale,
            "stop_early": args.stop_early,
            "iterations": args.iterations, "burn_in": args.burn_in,
            "distinct_successful": int(len(rob.grasps)),
            "distinct_new": len(result.learned.new), "robust": int(rob.robust.sum()),
            "robust_share": rob.robust_share, "distinct_robust_new": result.distinct_robust_new,
            "mean_hold_probability": rob.summary()["mean_hold_probability"],
            "learning_trials": int(learn_trials), "robustness_trials": rob.num_trials,
            "trials": int(learn_trials + rob.num_trials), "learn_s": round(learn_s, 1),
            "robustness_s": round(time.perf_counter() - t1, 1)}


def flood_robust(result, rob, sim, seed: int, args) -> dict:
    """Flood out from the robust grasps until ``args.flood_to`` trials in all (see above)."""
    collides = placement_collisions(sim.scene)
    tried = [np.asarray(result.proposals, np.float64).reshape(-1, 7)]
    found, robust = rob.grasps, [rob.grasps[rob.robust]]
    order = np.argsort(-rob.probability, kind="stable")
    frontier, start, rounds = rob.grasps[order][rob.robust[order]], sim.num_trials, 0
    noise = jg.learn.PoseNoise(tries=args.tries)
    while sim.num_trials < args.flood_to and len(frontier):
        cand = distinct_grasps(neighbour_poses(frontier))
        cand = cand[~same_as_any(cand, np.concatenate(tried))]
        tried.append(cand)
        cand = cand[~np.asarray(collides(cand.astype(np.float32)), bool)].astype(np.float32)
        # a budget left of L trials tries at most L / 4 (a success costs 1 + up to 10 more)
        cand = cand[:max((args.flood_to - sim.num_trials) // 4, 1)]
        if len(cand) == 0:
            break
        held = cand[np.asarray(sim.simulate_now(cand, merged=True).outcome) == Outcome.SUCCESS]
        held = distinct_grasps(held) if len(held) else held
        held = held[~same_as_any(held, found)] if len(held) else held
        if len(held) == 0:
            break
        found = np.concatenate([found, held])
        r = jg.learn.robustness(held, trial=sim, noise=noise, seed=seed + 1000 * (rounds + 1),
                                stop_early=True)
        order = np.argsort(-r.probability, kind="stable")
        frontier = held[order][r.robust[order]]
        robust.append(frontier)
        rounds += 1
    robust_new = int(is_new(np.concatenate(robust), result.demos.poses).sum())
    return {"flood_rounds": rounds, "flood_trials": int(sim.num_trials - start),
            "flood_distinct": int(len(found) - len(rob.grasps)),
            "flood_robust": robust_new - result.distinct_robust_new,
            "distinct_robust_new_with_flood": robust_new}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--objects", default="pitcher,pan,plate")
    p.add_argument("--seeds", default="2", help="comma-separated seeds")
    p.add_argument("--chains", type=int, default=8)
    p.add_argument("--iterations", type=int, default=1000)
    p.add_argument("--burn-in", type=int, default=100)
    p.add_argument("--robust-tries", type=int, default=0,
                   help="perturbed tries per proposal while learning (LearnParams.robust_tries)")
    p.add_argument("--robust-estimate", default="mean", choices=jg.density.ESTIMATES)
    p.add_argument("--slip-scale", type=float, default=jg.learn.LearnParams().slip_scale,
                   help="metres: weigh the target by exp(-displacement / SLIP_SCALE) "
                        "(default: the library's, %(default)s; 0: the paper's density)")
    p.add_argument("--tries", type=int, default=10)
    p.add_argument("--stop-early", action="store_true",
                   help="stop trying a grasp once it can no longer be robust")
    p.add_argument("--flood-to", type=int, default=0, metavar="TRIALS",
                   help="after scoring, flood out from the robust grasps up to TRIALS in all")
    p.add_argument("--out", default="bench_out/robust_grasps.json")
    args = p.parse_args(argv)
    jg.enable_compilation_cache()
    rows = []
    for name in args.objects.split(","):
        for seed in (int(s) for s in args.seeds.split(",")):
            rows.append(measure(name, seed, args))
            r = rows[-1]
            print(f"{r['object']:>12} seed {r['seed']}: {r['distinct_new']} distinct new, "
                  f"robust share {100 * r['robust_share']:.1f} %, {r['distinct_robust_new']} "
                  f"distinct robust new, {r['trials']} trials", flush=True)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"command": " ".join(sys.argv), "device": env.device(),
                               "versions": env.versions(), "date": time.strftime("%Y-%m-%d"),
                               "rows": rows}, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
