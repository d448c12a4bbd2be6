"""MJX grasp-trial throughput, outcome shares and the cost of colliding trials.

    .venv/bin/python benchmarks/physics_trial.py [--object pitcher] [--out PATH.json]

Measures, on one object:
- trials/s of the pure trial (``make_trial(scene)``) for B = 1, 16, 64, 256, compile time
  (first call, persistent cache disabled unless ``--cache``) reported separately;
- outcome shares for poses drawn uniformly near the object (position uniform in the object's
  bounding box grown by the pad reach, orientation uniform on SO(3));
- the share of a batch's rollout time spent on colliding trials (pure path: every trial costs
  the same under vmap, so it equals the colliding fraction) and the speed-up of the compact
  path (collision pass, then rollouts only on the non-colliding trials).
"""

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np


def random_poses(obj, n, seed, reach=0.04):
    """Poses near the object: grasp centers in its bounding box grown by ``reach``."""
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(obj.mesh.bounds, float)
    lo, hi = lo - reach, hi + reach
    lo[2] = max(lo[2], obj.support_z)  # grasp centers above the table
    pos = rng.uniform(lo, hi, (n, 3))
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return np.concatenate([pos, q], axis=1).astype(np.float32)


def _time(fn, *args, repeats):
    import jax

    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t)
    return best


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--object", default="pitcher", help="shipped object name, or 'box'")
    ap.add_argument("--batch", type=int, nargs="+", default=[1, 16, 64, 256])
    ap.add_argument("--num-poses", type=int, default=256, help="poses for the outcome shares")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cache", action="store_true", help="use the persistent compile cache")
    ap.add_argument("--out", default="bench_out/physics_trial.json")
    args = ap.parse_args(argv)

    import jax
    import mujoco

    import jaxgrasp as jg
    from jaxgrasp.physics import Outcome, load_scene, make_trial

    if args.cache:
        jg.enable_compilation_cache()
    obj = jg.objects.make_box() if args.object == "box" else jg.objects.load(args.object)
    scene = load_scene(obj)
    trial = make_trial(scene)
    steps = scene.params.num_steps
    poses = random_poses(obj, max(max(args.batch), args.num_poses), args.seed)

    rows = []
    for b in args.batch:
        g = poses[:b]
        t = time.perf_counter()
        jax.block_until_ready(trial(g))
        first = time.perf_counter() - t
        run = _time(trial, g, repeats=args.repeats)
        rows.append(
            {
                "B": b,
                "compile_s": round(first - run, 3),
                "run_s": round(run, 5),
                "trials_per_s": round(b / run, 2),
                "steps_per_s": round(b * steps / run, 1),
            }
        )
        print(rows[-1], flush=True)

    # Outcome shares on num_poses random poses (pure path, vmapped).
    n = args.num_poses
    res = trial(poses[:n])
    out = np.asarray(res.outcome)
    shares = {o.name: float(np.mean(out == o)) for o in Outcome}
    unstable = float(np.mean(np.asarray(res.unstable)))
    print("shares", shares, "unstable", unstable, flush=True)

    # Colliding trials: pure path time vs compact path on the same poses.
    b = max(args.batch)
    g = poses[:b]
    pure = _time(trial, g, repeats=args.repeats)
    compact = make_trial(scene, compact=True, chunk_size=64, min_bucket=64)
    t = time.perf_counter()
    compact(g)
    compact_first = time.perf_counter() - t
    compact_run = _time(lambda x: compact(x).outcome, g, repeats=args.repeats)
    coll = float(np.mean(np.asarray(trial(g).outcome) == Outcome.COLLISION))
    same = bool(np.array_equal(np.asarray(compact(g).outcome), np.asarray(trial(g).outcome)))
    collision = {
        "B": b,
        "colliding_fraction": coll,
        "pure_run_s": round(pure, 5),
        "pure_time_share_on_collisions": coll,
        "compact_run_s": round(compact_run, 5),
        "compact_first_call_s": round(compact_first, 3),
        "compact_speedup": round(pure / compact_run, 2),
        "compact_outcomes_equal_pure": same,
    }
    print("collision", collision, flush=True)

    result = {
        "object": obj.name,
        "num_pieces": len(obj.pieces),
        "ncon_slots": int(np.asarray(res.contact_mask).shape[1]),
        "steps_per_trial": steps,
        "timestep": scene.params.timestep,
        "throughput": rows,
        "outcome_shares": {"num_poses": n, "seed": args.seed, **shares, "unstable": unstable},
        "collision_cost": collision,
        "device": jax.devices()[0].device_kind,
        "platform": platform.platform(),
        "versions": {"jax": jax.__version__, "mujoco": mujoco.__version__},
    }
    path = Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=2))
    print("wrote", path)


if __name__ == "__main__":
    main()
