"""Robust grasps of a learning run: how many of the distinct new grasps a robot would hold.

    .venv/bin/python benchmarks/robust_grasps.py [--objects pitcher,pan,plate] [--seeds 2]
        [--chains 8] [--iterations 1000] [--burn-in 100] [--robust-tries K] [--tries 10]
        [--flood-to TRIALS [--flood-antipodal N] [--flood-turns] [--flood-finest F]]
        [--param NAME=VALUE]
        [--out FILE.json]

Per object and seed: ``jg.learn.active`` with the library defaults (Kameleon + GDMC, biased
sketch, MuJoCo C), then ``jg.learn.robustness`` of its distinct successful grasps (each tried
``--tries`` times at poses perturbed by 3 mm per axis and 3°). Reports the distinct successful
and new grasps, the robust share (held in >= 80 % of the tries), the distinct robust new
grasps and every trial counted (the run's proposals, demo search and sketch included, plus the
robustness tries). Writes JSON and prints a table.

``--flood-to TRIALS`` measures one more lever: after scoring, ``jg.learn.grow_robust`` floods
out from the robust grasps (their untried neighbours one distinct-grasp step away simulated,
the new successes scored, the new robust ones expanded) until TRIALS trials in all. With a
TRIALS no run reaches (200000) each flood goes on until no untried neighbour is left, and with
several seeds the table ends with the seeds' robust grasps together: how many in all, how many
each pair shares, and a Lincoln-Petersen estimate (a pair's sizes over their overlap) of the
robust grasps a run and its flood can reach. ``--flood-antipodal N``: the flood draws N
antipodal grasps first and goes on from their robust successes too (``grow_robust``'s
``antipodal``, the learn CLI's ``--grow-antipodal``). ``--flood-turns``: each robust grasp's
copies turned by the object's symmetry go first among its neighbours (``grow_robust``'s
``symmetry``: the one the run's turns followed). ``--flood-finest F``: ``grow_robust``'s
``finest`` (1: no finer flood where the budget is left; default the library's).

``--recentre ROUNDS`` measures another (not in the library: it cost more trials per robust
grasp than learning): each grasp that was not robust is moved by ``--recentre-step`` times the
mean perturbation of its tries that held less that of its tries that failed, and scored again
(stopping early), up to ROUNDS times; then the run's grasps and the moved ones are both scored
once more with fresh perturbations, so the figures do not favour grasps kept for passing one
noisy test.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

import jaxgrasp as jg
from jaxgrasp.bench import env
from jaxgrasp.learn.evaluate.distinct import distinct_grasps, same_as_any
from jaxgrasp.learn.evaluate.grow import DEFER, FINEST
from jaxgrasp.learn.evaluate.robustness import perturbed_poses, tries_stopping_early
from jaxgrasp.learn.files.export import select_grasps
from jaxgrasp.objects import Symmetry
from jaxgrasp.physics import Outcome


def measure(name: str, seed: int, args) -> dict:
    obj = jg.objects.load_any(name)  # a kitchen object, random_NNN or a mesh path
    sim = jg.learn.Simulator(obj, backend="mujoco",
                             batch_size=args.chains * (1 + args.robust_tries))
    t0 = time.perf_counter()
    params = jg.learn.LearnParams(robust_tries=args.robust_tries,
                                  robust_estimate=args.robust_estimate,
                                  slip_scale=args.slip_scale, **dict(args.param))
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
    flood |= recentre(result, sim, seed, args) if args.recentre else {}
    return {**flood, "object": name, "seed": seed, "robust_tries": args.robust_tries,
            "robust_estimate": args.robust_estimate, "slip_scale": args.slip_scale,
            "params": dict(args.param), "chains": args.chains,
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
    sym = result.info.get("symmetry") if args.flood_turns else None
    grown = jg.learn.grow_robust(result, rob, trial=sim, seed=seed,
                                 budget=max(args.flood_to - sim.num_trials, 0),
                                 antipodal=args.flood_antipodal,
                                 symmetry=None if sym is None else Symmetry.from_dict(sym),
                                 finest=args.flood_finest, defer=args.flood_defer)
    robust_new = int(grown.robustness.robust_new(result.demos.poses).sum())
    robust = np.asarray(grown.grasps.grasps, np.float64)[grown.robustness.robust]
    check = {}
    if args.check:  # the same grasps scored again with fresh perturbations, not in the budget
        again = jg.learn.robustness(grown.grasps.grasps, trial=sim, seed=seed + 424242,
                                    stop_early=True)
        check = {"checked_share_with_flood": round(again.robust_share, 4),
                 "checked_robust_new_with_flood": int(
                     again.robust_new(result.demos.poses).sum())}
    return {**check, "_robust": robust, "flood_robust_all": int(len(robust)),
            "flood_swapped": grown.swapped,
            "flood_turns": args.flood_turns, "flood_finest": args.flood_finest,
            "flood_defer": args.flood_defer,
            "robust_share_with_flood": round(float(grown.robustness.robust.mean()), 4),
            "flood_rounds": grown.rounds, "flood_trials": grown.trials,
            "flood_distinct": grown.added, "flood_robust": robust_new - result.distinct_robust_new,
            "distinct_robust_new_with_flood": robust_new}


def overlap(name: str, sets: dict) -> dict:
    """The seeds' robust grasps after their floods: how many in all and how much each pair
    shares (Lincoln-Petersen: a pair's sizes over their overlap estimates the robust grasps a
    run and its flood can reach)."""
    union = distinct_grasps(np.concatenate(list(sets.values())))
    out = {"object": name, "seeds": list(sets), "robust_union": int(len(union)), "pairs": []}
    for i, a in enumerate(sets):
        for b in list(sets)[i + 1:]:
            shared = int(same_as_any(sets[a], sets[b]).sum())
            out["pairs"].append({"seeds": [a, b], "sizes": [len(sets[a]), len(sets[b])],
                                 "shared": shared, "estimate": round(
                                     len(sets[a]) * len(sets[b]) / max(shared, 1))})
    return out


def scored_tries(sim, grasps, noise, seed: int):
    """Stop-early scoring that keeps each try: (poses (N, tries, 7), outcome (N, tries), -1
    where not tried)."""
    poses = perturbed_poses(grasps, noise, seed).astype(np.float32)
    return poses, tries_stopping_early(sim, poses, noise)


def _mean(v, mask):
    return v[mask].mean(axis=0) if mask.any() else np.zeros(v.shape[-1])


def moved(grasps, poses, out, step: float) -> np.ndarray:
    """Each grasp moved by ``step`` x (mean held perturbation - mean failed perturbation)."""
    base = Rotation.from_quat(grasps[:, 3:], scalar_first=True)
    new = grasps.copy()
    for i in range(len(grasps)):
        held = out[i] == int(Outcome.SUCCESS)
        failed = (out[i] >= 0) & ~held
        dp = poses[i, :, :3] - grasps[i, :3]
        rv = (base[i].inv() * Rotation.from_quat(poses[i, :, 3:], scalar_first=True)).as_rotvec()
        new[i, :3] += step * (_mean(dp, held) - _mean(dp, failed))
        turned = base[i] * Rotation.from_rotvec(step * (_mean(rv, held) - _mean(rv, failed)))
        new[i, 3:] = turned.as_quat(scalar_first=True)
    return new


def recentre(result, sim, seed: int, args) -> dict:
    """The re-centring lever (see the module's docstring), checked by a fresh scoring."""
    noise = jg.learn.PoseNoise(tries=args.tries)
    g = select_grasps(result).grasps
    poses, out = scored_tries(sim, g, noise, seed)  # the scoring the run already paid
    start = sim.num_trials
    final, todo = g.copy(), np.flatnonzero((out == 0).sum(axis=1) < noise.min_held)
    cur, poses, out = g[todo], poses[todo], out[todo]  # rows of `todo` from here on
    for r in range(args.recentre):
        if len(todo) == 0:
            break
        cur = moved(cur, poses, out, args.recentre_step)
        poses, out = scored_tries(sim, cur, noise, seed + 7919 * (r + 1))
        good = (out == 0).sum(axis=1) >= noise.min_held
        final[todo[good]] = cur[good]
        todo, cur, poses, out = todo[~good], cur[~good], poses[~good], out[~good]
    spent = sim.num_trials - start
    check = [jg.learn.robustness(x, trial=sim, noise=noise, seed=seed + 424242)
             for x in (g, final)]
    demos = result.demos.poses
    return {"recentre_trials": int(spent), "recentre_moved": int((final != g).any(axis=1).sum()),
            "checked_share_before": check[0].robust_share,
            "checked_share_after": check[1].robust_share,
            "checked_robust_new_before": int(check[0].robust_new(demos).sum()),
            "checked_robust_new_after": int(check[1].robust_new(demos).sum()),
            "distinct_after_recentre": len(distinct_grasps(final))}


def _param(text: str) -> tuple:
    name, _, value = text.partition("=")
    try:
        return name.strip(), json.loads(value)
    except json.JSONDecodeError:
        return name.strip(), value.strip()


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
    p.add_argument("--flood-antipodal", type=int, default=0, metavar="N",
                   help="with --flood-to: the flood draws N antipodal grasps first "
                        "(jg.learn.grow_robust's antipodal)")
    p.add_argument("--check", action="store_true",
                   help="with --flood-to: score everything exported once more with fresh "
                        "perturbations (not counted in the trials)")
    p.add_argument("--flood-turns", action="store_true",
                   help="with --flood-to: the flood also turns each robust grasp by the symmetry "
                        "the run's turns followed (grow_robust's symmetry)")
    p.add_argument("--flood-finest", type=float, default=FINEST, metavar="F",
                   help="with --flood-to: grow_robust's finest (1: no finer flood; default "
                        "%(default)s)")
    p.add_argument("--flood-defer", type=int, default=DEFER, metavar="K",
                   help="with --flood-to: grow_robust's defer (default %(default)s)")
    p.add_argument("--recentre", type=int, default=0, metavar="ROUNDS",
                   help="measure the re-centring lever: ROUNDS moves of each non-robust grasp")
    p.add_argument("--recentre-step", type=float, default=1.0)
    p.add_argument("--param", action="append", default=[], type=_param, metavar="NAME=VALUE",
                   help="another LearnParams field (value as JSON, else text); repeatable")
    p.add_argument("--out", default="bench_out/robust_grasps.json")
    args = p.parse_args(argv)
    jg.enable_compilation_cache()
    rows, overlaps = [], []
    for name in args.objects.split(","):
        sets = {}
        for seed in (int(s) for s in args.seeds.split(",")):
            rows.append(measure(name, seed, args))
            r = rows[-1]
            if "_robust" in r:
                sets[seed] = r.pop("_robust")
            print(f"{r['object']:>12} seed {r['seed']}: {r['distinct_new']} distinct new, "
                  f"robust share {100 * r['robust_share']:.1f} %, {r['distinct_robust_new']} "
                  f"distinct robust new, {r['trials']} trials", flush=True)
        if len(sets) > 1:
            overlaps.append(overlap(name, sets))
            o = overlaps[-1]
            print(f"{name:>12}: {o['robust_union']} robust grasps in all after the floods; "
                  + ", ".join(f"seeds {p['seeds']} share {p['shared']} of {p['sizes']} "
                              f"(estimate {p['estimate']})" for p in o["pairs"]), flush=True)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"command": " ".join(sys.argv), "device": env.device(),
                               "versions": env.versions(), "date": time.strftime("%Y-%m-%d"),
                               "rows": rows, "overlaps": overlaps}, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
