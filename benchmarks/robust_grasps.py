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

``--flood-to TRIALS`` measures one more lever: after scoring, ``jg.learn.grow_robust`` floods
out from the robust grasps (their untried neighbours one distinct-grasp step away simulated,
the new successes scored, the new robust ones expanded) until TRIALS trials in all.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import jaxgrasp as jg
from jaxgrasp.bench import env


def measure(name: str, seed: int, args) -> dict:
    obj = jg.objects.load_any(name)  # a kitchen object, random_NNN or a mesh path
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
    """``jg.learn.grow_robust`` after scoring, until ``args.flood_to`` trials in all."""
    grown = jg.learn.grow_robust(result, rob, trial=sim, seed=seed,
                                 budget=max(args.flood_to - sim.num_trials, 0))
    robust_new = int(grown.robustness.robust_new(result.demos.poses).sum())
    return {"flood_rounds": grown.rounds, "flood_trials": grown.trials,
            "flood_distinct": grown.added, "flood_robust": robust_new - result.distinct_robust_new,
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
